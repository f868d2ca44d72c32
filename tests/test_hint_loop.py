"""The commands the view -> fuse -> calibrate messages name, run as written: each leads to the
next step (a session without a calibration or a fused result: view says fuse --store, which says
calibrate --method full --store, which stores it and names the fuse, which stores the result and
names the view, which then serves it). ``calibrate`` says where its result went."""

from __future__ import annotations

import asyncio
import re
import shlex
import shutil
from pathlib import Path

import pytest

from kinefuse.app.cli.main import main
from kinefuse.app.workflows.view import run_view

ROOT = Path(__file__).resolve().parents[1]
WALK = "motion/cmu/02_walk_a.amc"


def run(capsys: pytest.CaptureFixture[str], argv: list[str]) -> tuple[int, str, str]:
    code = main(argv)
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def hinted(text: str, pattern: str) -> list[str]:
    """The argv of the ``kinefuse ...`` command a message names (in backticks or after
    ``next: ``/``: ``), checked against ``pattern``."""
    m = re.search(r"`(kinefuse [^`]+)`", text) or re.search(r": (kinefuse .+)$", text, re.M)
    assert m, text
    cmd = m.group(1).strip()
    assert re.fullmatch(pattern, cmd), cmd
    return shlex.split(cmd)[1:]


@pytest.fixture(scope="module")
def take(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated session with its wand phase, no calibration and no fused result stored."""
    s = tmp_path_factory.mktemp("loop") / "take.sqlite"
    assert main(["simulate", "--clip", str(shared_data / WALK), "--rig",
                 str(ROOT / "rigs" / "level4.toml"), "--seconds", "0.5",
                 "--calibration-seconds", "20", "--out", str(s)]) == 0  # fmt: skip
    return s


def test_view_fuse_calibrate_loop(
    take: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = tmp_path / "take.sqlite"
    shutil.copy(take, s)
    capsys.readouterr()
    code, _, err = run(capsys, ["view", str(s)])
    assert code == 2
    fuse = hinted(err, r"kinefuse fuse \S+ --method best --store")
    code, _, err = run(capsys, fuse)
    assert code == 2
    calibrate = hinted(err, r"kinefuse calibrate \S+ --method full --store")
    # without --store, calibrate says the result went nowhere, and how to keep it
    code, out, err = run(capsys, calibrate[:-1])
    assert code == 0, err
    assert "not stored anywhere" in out
    assert hinted(out, r"kinefuse calibrate \S+ --method full --store") == calibrate
    code, out, err = run(capsys, calibrate)
    assert code == 0, err
    assert f"stored the calibration in {s}" in out
    fuse2 = hinted(out, r"kinefuse fuse \S+ --method best --store")
    assert fuse2 == fuse
    code, out, err = run(capsys, fuse2)
    assert code == 0, err
    view = hinted(out, r"kinefuse view \S+")
    assert view == ["view", str(s)]
    said: list[str] = []
    stop = asyncio.Event()

    def say(line: str) -> None:
        said.append(line)
        if line.startswith("open http"):
            stop.set()

    assert run_view(Path(view[1]), say=say, stop=stop) == 0
    assert any("results: best" in ln for ln in said), said


def test_calibrate_with_out_names_the_fuse_that_uses_the_file(
    take: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = tmp_path / "take.sqlite"
    shutil.copy(take, s)
    capsys.readouterr()
    cal = tmp_path / "cal.toml"
    code, out, err = run(capsys, ["calibrate", str(s), "--out", str(cal)])
    assert code == 0, err
    assert f"wrote {cal}" in out and "only read" in out
    fuse = hinted(out, r"kinefuse fuse \S+ --calibration \S+ --method best --store")
    code, out, err = run(capsys, fuse)
    assert code == 0, err
    assert str(cal) in out and "stored the fused skeleton" in out
