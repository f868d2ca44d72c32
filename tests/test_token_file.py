"""The token stays out of ``ps``: ``--token-file`` (and KINEFUSE_TOKEN) for serve, sensor and
calibrate --live (issue 23); ``--token`` still works but the docs no longer show it."""

from __future__ import annotations

import pytest

from kinefuse.app.cli.main import build_parser
from kinefuse.app.workflows.serve import token_from
from kinefuse.errors import InputError


def test_the_token_is_read_from_a_file_or_the_environment(tmp_path, monkeypatch) -> None:
    f = tmp_path / "token"
    f.write_text("s3cret-from-file\n", encoding="utf-8")
    monkeypatch.setenv("KINEFUSE_TOKEN", "from-env")
    assert token_from(None, f) == "s3cret-from-file"
    assert token_from(None, None) == "from-env"
    monkeypatch.delenv("KINEFUSE_TOKEN")
    assert token_from(None, None) is None
    (tmp_path / "empty").write_text("\n", encoding="utf-8")
    with pytest.raises(InputError, match="empty"):
        token_from(None, tmp_path / "empty")
    with pytest.raises(InputError, match="cannot read"):
        token_from(None, tmp_path / "missing")
    with pytest.raises(InputError, match="not both"):
        token_from("x", f)


@pytest.mark.parametrize(
    "argv",
    [
        ["serve", "--token-file", "T"],
        ["sensor", "--server", "127.0.0.1:7400", "--source", "sim:x#k0", "--token-file", "T"],
        ["calibrate", "--live", "127.0.0.1:7400", "--token-file", "T"],
    ],
)
def test_every_command_that_needs_the_token_takes_a_token_file(argv) -> None:
    args = build_parser().parse_args(argv)
    assert str(args.token_file) == "T" and args.token is None


def test_the_docs_show_the_token_file_not_the_token() -> None:
    from pathlib import Path

    docs = Path(__file__).resolve().parents[1] / "docs"
    for name in ("live.md", "protocol.md"):
        text = (docs / name).read_text(encoding="utf-8")
        assert "--token-file" in text, name
        assert "--token TOKEN" not in text and "`--token` or" not in text, name
