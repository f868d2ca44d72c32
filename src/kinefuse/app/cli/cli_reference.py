"""The command reference as Markdown, generated from the parsers (so it cannot drift).

``mkdocs build`` calls :func:`render` through ``docs/hooks/cli_reference.py`` and publishes the
result as ``reference/cli.md``.
"""

from __future__ import annotations

import argparse
import os


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def render(width: int = 100) -> str:
    """The reference page: every command's usage, description and options, in ``--help`` order."""
    from kinefuse.app.cli.main import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(width)  # argparse wraps help text at $COLUMNS
    try:
        parser = build_parser()
        commands = _subparsers(parser)
        out = [
            "# Command reference",
            "",
            "Generated from kinefuse's own parsers when this guide is built: it is what "
            "`kinefuse COMMAND --help` prints. Exit codes: 0 done, 2 bad input (one line says "
            "what to do), 3 a refusal the command explains (a failed calibration, nothing "
            "analysed, a server that refused the sensor).",
            "",
        ]
        out += [f"- [`kinefuse {name}`](#kinefuse-{name})" for name in commands]
        for name, sub in commands.items():
            out += ["", f"## kinefuse {name}", "", "```text", sub.format_help().rstrip(), "```"]
        return "\n".join(out) + "\n"
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
