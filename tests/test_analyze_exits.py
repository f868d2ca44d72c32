"""``analyze`` that analyses nothing exits 3 and says why, per reason, instead of exiting 0 with
a header-only angles.csv: a lower-body marker take (Helen Hayes, on a real CMU walk) whose
calibration phase has only the pelvis markers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli.main import main
from kinefuse.lab.marker_placement import marker_trial, write_trc

WALK = "motion/cmu/02_walk_a.amc"


def take(shared_data: Path, path: Path, unseen_s: float) -> Path:
    tr = marker_trial(shared_data / WALK, "helen-hayes")
    m = tr.motion.copy()
    legs = [i for i, n in enumerate(tr.motion_names) if n not in ("RASI", "LASI", "SACR")]
    m[: int(unseen_s * tr.rate_hz), legs] = np.nan
    return write_trc(path, tr.t_s, tr.motion_names, m, up="+z")


def test_nothing_analysed_exits_3_and_says_why(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trc = take(shared_data, tmp_path / "legs_unseen.trc", 1.5)
    out = tmp_path / "out"
    argv = ["analyze", str(trc), "--calibration-phase", "0:1.5", "--out", str(out), "--no-plots"]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 3, err
    line = next(ln for ln in err.splitlines() if ln.startswith("kinefuse: nothing analysed in"))
    assert "thigh_left" in line and "present in too few of" in line
    assert "the helen-hayes marker set has none" in line  # the legs-only set's skipped arms
    assert (out / "angles.csv").read_text().count("\n") == 1  # the header: kept, and said


def test_the_same_take_with_its_legs_seen_exits_0(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    trc = take(shared_data, tmp_path / "legs_seen.trc", 0.0)
    out = tmp_path / "out"
    code = main(["analyze", str(trc), "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "nothing analysed" not in err
    assert (out / "angles.csv").read_text().count("\n") > 100
