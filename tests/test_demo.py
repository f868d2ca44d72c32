"""The main command, end to end, as a newcomer runs it (bundled clip, no ../shared needed)."""

from __future__ import annotations

import json

import numpy as np

from kinefuse.app.cli import main
from kinefuse.capture.calibration.calib_file import read_calibration


def test_demo_runs_the_whole_pipeline(tmp_path, capsys) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--offline", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    for step in ("1/4 simulate", "2/4 calibrate", "3/4 fuse", "4/4 evaluate"):
        assert step in text
    expected = (
        "session.sqlite",
        "inspect.json",
        "calibration.toml",
        "fused.c3d",
        "fused.trc",
        "fused.csv",
        "fused.bvh",
        "calibration/calibration_errors_full.png",
        "evaluation/trajectories.png",
        "evaluation/table1_c_threshold.md",
        "evaluation/table3_per_joint.csv",
    )
    for name in expected:
        assert (out / name).stat().st_size > 0, name
    assert len(read_calibration(out / "calibration.toml").sensors) == 4
    # the exports open in the readers their users have
    import ezc3d

    c3d = ezc3d.c3d(str(out / "fused.c3d"))
    n_frames = c3d["data"]["points"].shape[2]
    assert c3d["parameters"]["POINT"]["LABELS"]["value"][0] == "SpineBase"
    try:
        import opensim
    except ImportError:
        opensim = None  # the opensim wheel exists for CPython 3.11 on x86_64 only
    if opensim is not None:
        trc = opensim.TimeSeriesTableVec3(str(out / "fused.trc"))
        assert trc.getNumRows() == n_frames and trc.getNumColumns() == 25
    report = json.loads((out / "evaluation" / "evaluate.json").read_text())
    assert report["calibration"] == "session calibration (full)"
    assert report["best"]["mae_m"] < 0.6 * report["paper"]["mae_m"]
    # every comparison and every part of the ablation comes with its 95 % interval
    gains = [*report["comparisons"].values(), *report["ablation"].values()]
    assert len(report["comparisons"]) == 5 and len(report["ablation"]) == 8
    for g in gains:
        low, high = g["gain_ci95_percent"]
        assert low <= g["gain_percent"] <= high
        # one definition of gain: centimetres and percent always agree in sign
        assert np.sign(g["gain_m"]) == np.sign(g["gain_percent"])
        lo_m, hi_m = g["gain_ci95_m"]
        assert lo_m <= g["gain_m"] <= hi_m
        if low <= 0 <= high:
            assert g["verdict"] == "no clear difference"
    assert report["comparisons"]["best vs paper"]["gain_ci95_percent"][0] > 40
    assert "95 % interval" in text
    # a second run replaces the first one's folder, which it made
    first = (out / "session.sqlite").stat().st_mtime_ns
    assert main(["demo", "--offline", "--out", str(out)]) == 0
    assert (out / "session.sqlite").stat().st_mtime_ns != first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo"]
