"""``kinefuse realdata`` on a real two-Kinect log: a summary first (per scenario, how much was
fused and how far each sensor is from the fused skeleton), then the details; ``--out`` exports
the fused take (every scenario, on one frame grid, gaps between them as gaps) as ``fuse --out``
does, read back here."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli.main import main
from kinefuse.core.skeleton import JOINTS
from kinefuse.formats.markers import read_trc

LOG = "kinect/kinect_multitrack/Study_4_Kinect_0_Time_1_17_51_PM.csv"


def test_summary_first_and_the_fused_take_exported(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "take.trc"
    code = main(["realdata", str(shared_data / LOG), "--out", str(out)])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    lines = cap.out.splitlines()
    assert lines[0].startswith("Study_4_Kinect_0_Time_1_17_51_PM.csv: layout parallel")
    scen = [ln for ln in lines[1:4] if ln.startswith("  scenario ")]
    assert len(scen) == 3, lines[:5]
    fused = [int(ln.split("fused on ")[1].split(" of ")[0]) for ln in scen]
    assert lines[-1] == f"wrote {out}"
    m = read_trc(out)
    assert set(JOINTS) <= set(m.names)
    finite = np.isfinite(m.positions).all(axis=(1, 2))
    assert finite.sum() >= sum(fused)  # every fused frame of every scenario is in the file
    assert (~finite).any()  # the gaps between the scenarios stay gaps
    dt = np.diff(m.t_s)
    assert np.allclose(dt, dt[0], atol=1e-4)  # one frame rate


def test_out_takes_one_log(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = str(shared_data / LOG)
    assert main(["realdata", log, log, "--out", str(tmp_path / "x.bvh")]) == 2
    assert "one log" in capsys.readouterr().err
    assert not (tmp_path / "x.bvh").exists()
