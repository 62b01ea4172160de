"""The documentation builds with MkDocs in strict mode (a broken link or anchor fails), and the command-line
reference page (docs/cli.md) is the one the parser generates."""

import argparse
import subprocess
import sys
from pathlib import Path

from snreg.cli import build_parser
from snreg.cli.reference import REGENERATE, reference

ROOT = Path(__file__).resolve().parents[1]


def _subparsers(parser: argparse.ArgumentParser):
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _subparsers(sub)


def test_the_site_builds_strictly_without_warnings(tmp_path):
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(tmp_path / "site")],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and "WARNING" not in run.stderr, run.stderr
    assert (tmp_path / "site" / "cli" / "index.html").is_file()


def test_the_committed_cli_reference_is_current():
    committed = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert committed == reference(), (f"docs/cli.md differs from the parser (a command or option added, changed or "
                                      f"removed); regenerate it: {REGENERATE}")


def test_every_command_and_option_is_in_the_reference():
    parser = build_parser()
    page = reference(parser)
    for sub in _subparsers(parser):
        if sub is parser:
            continue
        assert f"# {sub.prog}\n" in page, sub.prog
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):     # every command has -h; the page says so once
                continue
            for option in action.option_strings:
                assert f"`{option}" in page or f", {option}" in page, f"{sub.prog} {option}"


def test_a_new_undocumented_option_makes_the_page_stale():
    parser = build_parser()
    budget = next(sub for sub in _subparsers(parser) if sub.prog == "snreg budget")
    budget.add_argument("--undocumented-knob", help="a knob nobody documented")
    page = reference(parser)
    assert page != (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    assert "`--undocumented-knob UNDOCUMENTED_KNOB`: a knob nobody documented" in page
