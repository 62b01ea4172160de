"""The layout's rules (docs/design.md, Layout): imports point down the layers, the core never imports Qt, no import cycles.

The rules are import-linter contracts in pyproject.toml (``lint-imports`` checks them from the command line);
here they are checked on the real tree, and shown to fail on the imports they forbid.
"""

import ast
import copy
import subprocess
import sys
from pathlib import Path

import grimp
import pytest
from importlinter import api
from importlinter.contracts.acyclic_siblings import AcyclicSiblingsContract
from importlinter.contracts.forbidden import ForbiddenContract
from importlinter.contracts.layers import LayersContract

import snreg
import snreg_gui

FORBIDDEN = ("PySide6", "PyQt5", "PyQt6", "PySide2", "pyqtgraph", "shiboken6", "qtpy")
CORE = Path(snreg.__file__).parent
ROOT = CORE.parent
CONTRACT_TYPES = {"layers": LayersContract, "forbidden": ForbiddenContract, "acyclic_siblings": AcyclicSiblingsContract}


def imported_roots(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    roots = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(node.module.split(".")[0])
    return roots


@pytest.fixture(scope="module")
def configuration():
    return api.read_configuration(str(ROOT / "pyproject.toml"))


@pytest.fixture(scope="module")
def graph(configuration):
    return grimp.build_graph(*configuration["session_options"]["root_packages"], include_external_packages=True,
                             cache_dir=None)


def broken_contracts(configuration, graph) -> list[str]:
    """The names of the contracts in pyproject.toml that ``graph`` breaks."""
    broken = []
    for options in configuration["contracts_options"]:
        contract = CONTRACT_TYPES[options["type"]](name=options["name"], session_options=configuration["session_options"],
                                                   contract_options=options)
        if not contract.check(copy.deepcopy(graph), verbose=False).kept:
            broken.append(options["name"])
    return broken


def test_every_layering_contract_is_kept(configuration, graph):
    assert {o["type"] for o in configuration["contracts_options"]} == set(CONTRACT_TYPES)
    assert broken_contracts(configuration, graph) == []


@pytest.mark.parametrize("importer, imported, contract", [
    ("snreg.camera", "snreg.registration", "snreg: core types"),         # a core type reaching up to an algorithm
    ("snreg.tracking.stereo", "snreg.demo.renderer", "snreg: core types"),  # tracking knowing about the demo
    ("snreg.workflow.acquisition", "PySide6", "never imports Qt"),
    ("snreg.session.reader", "snreg_gui.app", "never imports Qt"),
    ("snreg_gui.common.workers", "snreg_gui.acquisition.worker", "snreg_gui: entry points"),
    ("snreg.session.schema", "snreg.session.timeline", "no import cycles"),
])
def test_a_forbidden_import_breaks_its_contract(configuration, graph, importer, imported, contract):
    changed = copy.deepcopy(graph)
    if imported not in changed.modules:
        changed.add_module(imported)
    changed.add_import(importer=importer, imported=imported)
    assert [name for name in broken_contracts(configuration, changed) if contract in name]


def test_the_graph_holds_imports_made_inside_functions_and_for_type_checking(tmp_path, monkeypatch):
    package = tmp_path / "layered"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "low.py").write_text("def f():\n    from layered import high\n")
    (package / "high.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import layered.low\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    found = grimp.build_graph("layered", cache_dir=None)
    assert found.direct_import_exists(importer="layered.low", imported="layered.high")
    assert found.direct_import_exists(importer="layered.high", imported="layered.low")


def test_the_gui_keeps_its_code_in_subpackages():
    top = sorted(p.name for p in Path(snreg_gui.__file__).parent.glob("*.py"))
    assert len(top) <= 8, top


def test_no_core_module_imports_qt():
    offenders = {str(p.relative_to(CORE)): sorted(imported_roots(p) & set(FORBIDDEN)) for p in CORE.rglob("*.py")}
    assert {k: v for k, v in offenders.items() if v} == {}


@pytest.mark.slow
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
