"""docs/maps.md: every ``$ kinefuse ...`` command on the page runs as written, in order, from a
folder beside ``../shared`` (as the page says), with the one edit it describes (deleting the
``= "TODO"`` lines) between ``maps suggest`` and ``maps check``."""

from __future__ import annotations

import os
import re
import shlex
from pathlib import Path

import pytest

from kinefuse.app.cli.main import main

DOC = Path(__file__).resolve().parents[1] / "docs" / "maps.md"


def doc_commands() -> list[str]:
    text = DOC.read_text(encoding="utf-8")
    blocks = re.findall(r"```console\n(.*?)```", text, flags=re.S)
    return [ln[2:] for b in blocks for ln in b.splitlines() if ln.startswith("$ kinefuse ")]


def test_every_command_in_the_maps_doc_runs(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "shared").symlink_to(shared_data.parent)
    work = tmp_path / "work"
    work.mkdir()
    cwd = os.getcwd()
    os.chdir(work)
    try:
        commands = doc_commands()
        assert len(commands) == 6, commands
        codes = []
        for cmd in commands:
            argv = shlex.split(cmd)[1:]
            codes.append(main(argv))
            out, err = capsys.readouterr()
            assert "Traceback" not in err
            if argv[:2] == ["maps", "suggest"]:
                assert '"TODO"' in out
                text = Path("my_map.toml").read_text()
                Path("my_map.toml").write_text(
                    "\n".join(ln for ln in text.splitlines() if not ln.endswith('= "TODO"'))
                )
            if argv[:2] == ["maps", "check"]:
                assert "map 'my_map' builds 16 joints (151 frames)" in out
                nxt = out.strip().splitlines()[-1]
                assert nxt == f"next: {commands[-1].removesuffix(' --no-plots')}"
        assert codes == [0, 2, 0, 0, 0, 0], codes  # the first analyze: nothing fits
        assert Path("results/angles.csv").is_file() and Path("results_static/angles.csv").is_file()
    finally:
        os.chdir(cwd)
