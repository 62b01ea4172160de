"""The command-line reference page (docs/cli.md), generated from the parser ``snreg`` itself runs.

Why generated: a hand-written table drifts from the parser (options added to a command and never documented);
this page cannot, and ``tests/test_docs.py`` fails when the committed page differs from what this prints.
Regenerate with ``python -m snreg.cli.reference > docs/cli.md``.

The text is fixed-width (``WIDTH`` columns) whatever the terminal, so the page is the same on every machine.
"""

from __future__ import annotations

import argparse
import sys

from snreg.cli import build_parser

__all__ = ["reference", "WIDTH", "REGENERATE"]

WIDTH = 100
REGENERATE = "python -m snreg.cli.reference > docs/cli.md"

_HEADER = f"""# Command-line reference

Every `snreg` command with its usage and options, as `snreg COMMAND --help` prints them. This page is generated from
the parser (`snreg/cli/__init__.py` builds it); do not edit it by hand, regenerate it:

```
{REGENERATE}
```

Errors a user can cause are one line on stderr and exit status 2; `--json` output is one JSON object on stdout
(see [Design, Command line](design.md#command-line-snreg)). The app's own options: `snreg-gui --help`.
"""


def _formatter(parser: argparse.ArgumentParser) -> argparse.HelpFormatter:
    return parser.formatter_class(prog=parser.prog, width=WIDTH)


def _usage(parser: argparse.ArgumentParser) -> str:
    formatter = _formatter(parser)
    formatter.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups, prefix="")
    return formatter.format_help().strip()


def _subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """(name, one-line help, parser) of each subcommand, in the order ``--help`` lists them."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
            return [(name, helps.get(name, ""), sub) for name, sub in action.choices.items()]
    return []


def _options(parser: argparse.ArgumentParser) -> list[str]:
    """One markdown list item per argument: its names (with metavar) and its help, defaults expanded."""
    formatter = _formatter(parser)
    lines = []
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) or action.help == argparse.SUPPRESS:
            continue
        names = formatter._format_action_invocation(action)
        text = " ".join(formatter._expand_help(action).split()) if action.help else ""
        lines.append(f"- `{names}`" + (f": {text}" if text else ""))
    return lines


def _section(parser: argparse.ArgumentParser, summary: str, level: int) -> list[str]:
    out = [f"{'#' * level} {parser.prog}", ""]
    description = " ".join((parser.description or summary or "").split())
    if description:
        out += [description, ""]
    out += ["```", _usage(parser), "```", ""]
    options = _options(parser)
    if options:
        out += options + [""]
    for name, helptext, sub in _subcommands(parser):
        out += _section(sub, helptext, min(level + 1, 4))
    return out


def reference(parser: argparse.ArgumentParser | None = None) -> str:
    """The whole page: a header, then every command and subcommand (depth first) with usage and options."""
    parser = parser or build_parser()
    lines = [_HEADER]
    for name, helptext, sub in _subcommands(parser):
        lines += _section(sub, helptext, 2)
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":
    sys.stdout.write(reference())
