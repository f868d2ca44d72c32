"""The shared argument types: one rule for numbers and one for addresses, in every command."""

from __future__ import annotations

import argparse

import pytest

from kinefuse.app.cli import args
from kinefuse.app.cli.main import main


@pytest.mark.parametrize("text", ["inf", "-inf", "nan", "1e999"])
def test_no_command_takes_a_non_finite_number(text: str) -> None:
    for parse in (args.finite_float, args.positive_float, args.nonneg_float):
        with pytest.raises(argparse.ArgumentTypeError, match="finite"):
            parse(text)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("127.0.0.1:7400", ("127.0.0.1", 7400)),
        ("localhost:0", ("localhost", 0)),
        ("[::1]:7400", ("::1", 7400)),
    ],
)
def test_an_address_reads_one_way(text: str, expected: tuple[str, int]) -> None:
    assert args.host_port(text) == expected


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("::1:7400", "needs brackets"),  # an address, or an address and a port: refused
        ("127.0.0.1", "no port"),
        ("127.0.0.1:99999", "0-65535"),
        ("[::1", "closing"),
        (":7400", "no host"),
    ],
)
def test_an_unclear_address_is_refused_with_the_form_it_needs(text: str, words: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=words):
        args.host_port(text)


def test_a_listen_address_without_a_port_takes_a_free_one() -> None:
    assert args.listen_address("127.0.0.1") == ("127.0.0.1", 0)


def test_the_commands_share_the_rule(capsys: pytest.CaptureFixture[str]) -> None:
    # the same text is refused the same way by a command of each family
    with pytest.raises(SystemExit):
        main(["simulate", "--clip", "x.bvh", "--out", "s.sqlite", "--seconds", "inf"])
    assert "expected a finite number, got 'inf'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["sensor", "--server", "::1:7400", "--source", "sim:x.sqlite#k0"])
    assert "needs brackets" in capsys.readouterr().err
