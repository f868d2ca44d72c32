"""The main command, end to end, as a newcomer runs it (bundled clip, no ../shared needed)."""

from __future__ import annotations

import json

from kinefuse.calibration.calib_file import read_calibration
from kinefuse.cli import main


def test_demo_runs_the_whole_pipeline(tmp_path, capsys) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    for step in ("1/4 simulate", "2/4 calibrate", "3/4 fuse", "4/4 evaluate"):
        assert step in text
    expected = (
        "session.sqlite",
        "inspect.json",
        "calibration.toml",
        "fused.c3d",
        "fused.trc",
        "calibration_errors_full.png",
        "evaluation/trajectories.png",
        "evaluation/table1_c_threshold.md",
        "evaluation/table3_per_joint.csv",
    )
    for name in expected:
        assert (out / name).stat().st_size > 0, name
    assert len(read_calibration(out / "calibration.toml").sensors) == 4
    report = json.loads((out / "evaluation" / "evaluate.json").read_text())
    assert report["calibration"] == "session calibration (full)"
    assert report["best"]["mae_m"] < 0.6 * report["paper"]["mae_m"]
    # every comparison and every part of the ablation comes with its 95 % interval
    gains = [*report["comparisons"].values(), *report["ablation"].values()]
    assert len(report["comparisons"]) == 5 and len(report["ablation"]) == 6
    for g in gains:
        low, high = g["gain_ci95_percent"]
        assert low <= g["gain_percent"] <= high
    assert report["comparisons"]["best vs paper"]["gain_ci95_percent"][0] > 40
    assert "95 % interval" in text
