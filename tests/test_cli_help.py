"""Every option and argument of every command says what it is in ``kinefuse CMD --help``
(issue 23 C)."""

from __future__ import annotations

import argparse

import pytest

from kinefuse.app.cli.main import COMMANDS, build_parser


def _commands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


@pytest.mark.parametrize("name", sorted(_commands()))
def test_every_option_has_help(name: str) -> None:
    p = _commands()[name]
    missing = [
        "/".join(a.option_strings) or a.dest
        for a in p._actions
        if not isinstance(a, argparse._HelpAction) and not (a.help or "").strip()
    ]
    assert not missing, f"kinefuse {name}: no help text for {', '.join(missing)}"
    assert p.format_help()  # and the help renders


def test_every_command_is_checked() -> None:
    assert len(_commands()) == len(COMMANDS)
