"""The core library never imports Qt (DESIGN.md §2, §5)."""

import ast
import subprocess
import sys
from pathlib import Path

import snreg

FORBIDDEN = ("PySide6", "PyQt5", "PyQt6", "PySide2", "pyqtgraph", "shiboken6", "qtpy")
CORE = Path(snreg.__file__).parent


def imported_roots(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(node.module.split(".")[0])
    return roots


def test_no_core_module_imports_qt():
    offenders = {str(p.relative_to(CORE)): sorted(imported_roots(p) & set(FORBIDDEN)) for p in CORE.rglob("*.py")}
    assert {k: v for k, v in offenders.items() if v} == {}


def test_importing_every_core_module_loads_no_qt():
    code = (
        "import pkgutil, sys, snreg\n"
        "for m in pkgutil.walk_packages(snreg.__path__, 'snreg.'):\n"
        "    __import__(m.name)\n"
        f"print(sorted(set(sys.modules) & set({FORBIDDEN!r})))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_the_checker_catches_a_qt_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from PySide6.QtCore import QObject\nimport pyqtgraph as pg\n")
    assert imported_roots(bad) & set(FORBIDDEN) == {"PySide6", "pyqtgraph"}
