"""End to end: ``kinefuse analyze`` on every shared motion and marker file, on a simulated
session with a range-of-motion phase, and on bad input (clear message, exit 2, no traceback)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.formats.angles import read_angles_mot

MOTION = [
    "motion/cmu/131_01_scaled_metres.bvh",
    "motion/cmu/01_01.bvh",
    "motion/cmu/01_01.amc",
    "motion/cmu/02_walk_a.amc",
    "motion/cmu/02_walk_b.amc",
]
MARKERS = [
    "markers/opensim/Pipelines_Rajagopal_ExpData_motion_capture_walk.trc",
    "markers/opensim/Pipelines_Rajagopal_ExpData_static_walk_1.trc",
    "markers/c3d/kinematics_tennis_serve.c3d",
]
#: Walking inputs: the knee flexes through a gait cycle, 25-100 degrees peak to peak.
WALKS = {
    "motion/cmu/02_walk_a.amc",
    "motion/cmu/02_walk_b.amc",
    "markers/opensim/Pipelines_Rajagopal_ExpData_motion_capture_walk.trc",
}
#: The one input whose plots are drawn (plots take most of a run's time).
PLOTTED = "motion/cmu/02_walk_a.amc"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def load_mot_in_opensim(path: Path, monkeypatch: pytest.MonkeyPatch) -> int:
    """Rows of a .mot as OpenSim reads it; Storage (which stops at a value it cannot parse)
    and TimeSeriesTable must both read every row the header declares."""
    opensim = pytest.importorskip("opensim", reason="opensim (the test extra) is not installed")
    monkeypatch.chdir(path.parent)  # OpenSim writes opensim.log into the working folder
    table = opensim.TimeSeriesTable(str(path))
    storage = opensim.Storage(str(path))
    assert storage.isInDegrees()
    n_rows = int(read_angles_mot(path)[2]["nRows"])
    assert int(storage.getSize()) == int(table.getNumRows()) == n_rows
    return n_rows


#: A static trial: nothing moves, so no axes are learned and every limb says so.
STATIC = "markers/opensim/Pipelines_Rajagopal_ExpData_static_walk_1.trc"


@pytest.mark.parametrize("rel", MOTION + MARKERS)
def test_analyze_every_shared_file(
    rel: str,
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    out = tmp_path / "out"
    argv = ["analyze", str(shared_data / rel), "--out", str(out), "--json"]
    if rel.startswith("motion/cmu/01_01"):
        argv += ["--calibration-phase", "0:8"]  # a long take: learn the axes on 8 s
    if rel != PLOTTED:
        argv.append("--no-plots")
    code, stdout, err = run(capsys, *argv)
    assert code == 0, err
    report = json.loads(stdout)
    for key in ("default_pose_frame", "axes", "reconstruction_error_m", "timing_ms_per_frame"):
        assert key in report
    names = {p.name for p in out.iterdir()}
    assert {"angles.csv", "angles.mot", "limb_frames.csv", "analysis.json"} <= names
    if rel == PLOTTED:
        assert {"angles.png", "axes_on_spheres.png"} <= names
        assert (out / "angles.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".out*"))  # the staging folder is gone
    t, ang, head = read_angles_mot(out / "angles.mot")
    mot = report["angles_mot"]
    assert int(head["nRows"]) == t.size == mot["rows"]
    for a, b in mot["rows_left_out_s"]:  # the frames left out are not in the file
        assert not ((t >= a - 1e-6) & (t <= b + 1e-6)).any()
    assert mot["rows"] == report["frames"] or mot["rows_left_out_s"]
    assert load_mot_in_opensim(out / "angles.mot", monkeypatch) == t.size
    for a in report["axes"].values():
        np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-9)  # unit axes
    if rel == STATIC:  # standing still: explicit per-limb status instead of angles
        assert report["limb_status"]["shank_left"].startswith("no movement")
        assert not [k for k in ang if k.startswith("knee_flexion")]
        return
    if rel in ("motion/cmu/02_walk_a.amc", "motion/cmu/02_walk_b.amc"):
        # a walk without a calibration phase: the thighs' quick swings make one main direction,
        # and one axis would leave them 20-24 mm off its plane (02_walk_b): both keep two axes
        # (the second perpendicular to the first and the rest) and the reconstruction holds
        for side in ("left", "right"):
            name = f"thigh_{side}"
            assert len(report["axes"][name]) == 2, report["limb_status"][name]
        assert report["reconstruction_error_m"]["mean"] < 1e-3
    # plausible curves: every knee flexion stays within the human range and moves
    knees = [v for k, v in ang.items() if k.startswith("knee_flexion")]
    assert knees
    for v in knees:
        v = v[np.isfinite(v)]
        assert np.abs(v).max() < 160.0  # degrees: no knee bends further
        if rel in WALKS:
            assert 25.0 < float(np.ptp(v)) < 100.0  # a gait cycle's swing (degrees)
    csv = (out / "angles.csv").read_text().splitlines()
    assert csv[0] == "time_s,joint,angle,method,degrees,filled,status"
    assert any(",KneeLeft,knee_flexion_left,functional," in line for line in csv[1:50])


def test_several_takes_report_normalization_consistency(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, b = (str(shared_data / f"motion/cmu/02_walk_{x}.amc") for x in "ab")
    code, stdout, err = run(
        capsys, "analyze", a, b, "--out", str(tmp_path / "o"), "--json", "--no-plots"
    )
    assert code == 0, err
    r = json.loads(stdout)
    c = r["normalization_consistency_deg"]
    assert 0.0 < c["median"] < 10.0 and c["mean"] >= 0.0  # same subject: a few degrees
    assert [Path(x["input"]).name for x in r["inputs"]] == ["02_walk_a.amc", "02_walk_b.amc"]
    assert (tmp_path / "o" / "01_02_walk_a" / "angles.mot").is_file()


@pytest.mark.slow
def test_rom_session_end_to_end(
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    s = tmp_path / "rom.sqlite"
    clip = shared_data / "motion/cmu/02_walk_a.amc"
    code, _, err = run(capsys, "simulate", "--clip", str(clip), "--rom", "60",
                       "--calibration-seconds", "0", "--out", str(s))  # fmt: skip
    assert code == 0, err
    out = tmp_path / "out"
    code, stdout, err = run(capsys, "analyze", str(s), "--true-calibration", "--out", str(out),
                            "--json")  # fmt: skip
    assert code == 0, err
    r = json.loads(stdout)
    assert r["calibration_phase"]["source"].startswith("the session's range-of-motion phase")
    assert r["calibration_phase"]["end_s"] == pytest.approx(60.0, abs=0.1)
    for key in ("axis_error_deg", "twist_error_deg", "angle_rmse_deg", "axis_error_by_method_deg"):
        assert key in r
    assert set(r["axis_error_by_method_deg"]) == {"dj", "pca", "em"}
    assert {"median", "mean", "by_limb"} <= set(r["axis_error_deg"])
    assert "knee_flexion_left" in r["angle_rmse_deg"]
    assert load_mot_in_opensim(out / "angles.mot", monkeypatch) == r["angles_mot"]["rows"]
    code, stdout, err = run(capsys, "evaluate", str(s), "--true-calibration", "--methods",
                            "best", "--json")  # fmt: skip
    assert code == 0, err
    p = json.loads(stdout)["plausibility"]
    assert p["calibration"] == "the session's range-of-motion phase"
    assert 0.0 <= p["best"]["recall"] <= 1.0 and "by_joint" in p["best"]


def test_bad_inputs_fail_clearly(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    walk = str(shared_data / MARKERS[0])
    bad_map = tmp_path / "bad.toml"
    bad_map.write_text('[joints]\nSpineBase = { mean = ["R.ASIS", "L.ASIS"] }\nHead = "TopHead"\n')
    code, _, err = run(capsys, "analyze", walk, "--map", str(bad_map), "--out", str(tmp_path / "a"))
    assert code == 2 and "Head: missing TopHead" in err and "Traceback" not in err
    trc = tmp_path / "broken.trc"
    lines = (shared_data / MARKERS[0]).read_text().splitlines()[:12]
    cells = lines[8].split("\t")
    cells[4] = "12.3.4"  # a coordinate that is not a number
    lines[8] = "\t".join(cells)
    trc.write_text("\n".join(lines) + "\n")
    code, _, err = run(capsys, "analyze", str(trc), "--out", str(tmp_path / "b"))
    assert code == 2 and "broken.trc:9" in err and "not a number" in err
    full = tmp_path / "full"
    full.mkdir()
    (full / "notes.txt").write_text("mine")
    code, _, err = run(capsys, "analyze", walk, "--out", str(full))
    assert code == 2 and "holds files kinefuse did not write" in err
    assert [p.name for p in full.iterdir()] == ["notes.txt"]
    code, _, err = run(capsys, "analyze", str(tmp_path / "none.bvh"), "--out", str(tmp_path / "c"))
    assert code == 2 and "no such file" in err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_read_only_output_folder_fails_clearly(
    shared_data: Path, readonly_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clip = str(shared_data / "motion/cmu/02_walk_a.amc")
    code, _, err = run(capsys, "analyze", clip, "--out", str(readonly_folder / "out"))
    assert code == 2 and "Traceback" not in err
    reasons = ("Permission denied", "not permitted", "Read-only file system", "not writable")
    assert str(readonly_folder) in err and any(r in err for r in reasons)
    assert list(readonly_folder.iterdir()) == []
