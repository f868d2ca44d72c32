"""Issue 20, partial bodies: an upper-body-only or lower-body-only marker capture is analysed
for the limbs it has; every limb it cannot have gets the status ``skipped: <the missing joints
and markers>``, the angle files hold only the analysed limbs (and OpenSim reads every row of
angles.mot), and a file with too little for any limb fails with exit 2 naming what each joint
lacks. The partial files are cut from the shared full-body recordings."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.formats.angles import read_angles_mot
from kinefuse.formats.markers import read_markers

TENNIS = "markers/c3d/kinematics_tennis_serve.c3d"
WALK = "markers/opensim/Pipelines_Rajagopal_ExpData_motion_capture_walk.trc"

#: Plug-in Gait leg markers (below the pelvis) and pelvis markers, without the side letter.
PIG_LEG = ("THI", "KNE", "TIB", "ANK", "HEE", "TOE")
PIG_PELVIS = ("ASI", "PSI")
#: The Rajagopal walk's leg markers (below the pelvis), by prefix after the side.
RAJ_LEG = ("TH", "Knee", "SH", "Ankle", "Heel", "MT5", "Toe")

LEG_LIMBS = [f"{k}_{s}" for s in ("left", "right") for k in ("thigh", "shank", "foot")]
ARM_LIMBS = [f"{k}_{s}" for s in ("left", "right") for k in ("upper_arm", "forearm")]
LEG_ANGLES = ("hip_", "knee_", "ankle_")
UPPER_ANGLES = ("shoulder_", "elbow_", "forearm_", "trunk_", "head_")


def write_c3d_subset(src: Path, dst: Path, keep: Callable[[str], bool]) -> list[str]:
    """A copy of the C3D ``src`` with the markers ``keep(name without prefix)`` accepts."""
    ezc3d = pytest.importorskip("ezc3d")
    c = ezc3d.c3d(str(src))
    labels = list(c["parameters"]["POINT"]["LABELS"]["value"])
    idx = [i for i, lab in enumerate(labels) if keep(lab.split(":")[-1])]
    out = ezc3d.c3d()
    out["parameters"]["POINT"]["RATE"]["value"] = c["parameters"]["POINT"]["RATE"]["value"]
    out["parameters"]["POINT"]["UNITS"]["value"] = c["parameters"]["POINT"]["UNITS"]["value"]
    out["parameters"]["POINT"]["LABELS"]["value"] = [labels[i] for i in idx]
    out["data"]["points"] = c["data"]["points"][:, idx, :]
    out.write(str(dst))
    return [labels[i] for i in idx]


def write_trc_subset(src: Path, dst: Path, keep: Callable[[str], bool]) -> list[str]:
    """A TRC (mm, +y up as OpenSim writes it) with the markers of ``src`` ``keep`` accepts."""
    m = read_markers(src, up="+y")  # z-up world (x, -z_file, y_file): undo it for the file
    idx = [i for i, n in enumerate(m.names) if keep(n)]
    names = [m.names[i] for i in idx]
    p = m.positions[:, idx] * 1000.0
    p = np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)
    n = p.shape[0]
    head = [
        f"PathFileType\t4\t(X/Y/Z)\t{dst.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame"
        "\tOrigNumFrames",
        f"{m.rate_hz:g}\t{m.rate_hz:g}\t{n}\t{len(names)}\tmm\t{m.rate_hz:g}\t1\t{n}",
        "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(len(names))),
        "",
    ]
    rows = []
    for k in range(n):
        cells = ["" if not np.isfinite(v) else f"{v:.5f}" for v in p[k].ravel()]
        rows.append("\t".join([str(k + 1), f"{m.t_s[k]:.5f}", *cells]))
    dst.write_text("\n".join(head + rows) + "\n")
    return names


def _pig_leg(name: str) -> bool:
    return name[1:] in PIG_LEG


def _raj_leg(name: str) -> bool:
    side, _, rest = name.partition(".")
    return side in ("R", "L") and rest.startswith(RAJ_LEG)


def analyze(
    capsys: pytest.CaptureFixture[str], path: Path, out: Path
) -> tuple[int, dict[str, object], str]:
    code = main(["analyze", str(path), "--out", str(out), "--json", "--no-plots"])
    stdout, err = capsys.readouterr()
    return code, (json.loads(stdout) if code == 0 else {}), err


def mot_rows_in_opensim(path: Path, monkeypatch: pytest.MonkeyPatch) -> int:
    opensim = pytest.importorskip("opensim", reason="opensim (the test extra) is not installed")
    monkeypatch.chdir(path.parent)  # OpenSim writes opensim.log into the working folder
    return int(opensim.Storage(str(path)).getSize())


def csv_angles(path: Path) -> set[str]:
    lines = path.read_text().splitlines()
    assert lines[0] == "time_s,joint,angle,method,degrees,filled,status"
    return {line.split(",")[2] for line in lines[1:]}


def check_files(out: Path, monkeypatch: pytest.MonkeyPatch) -> tuple[set[str], set[str]]:
    """(angles in angles.csv, columns of angles.mot); OpenSim reads every row of the .mot."""
    t, ang, head = read_angles_mot(out / "angles.mot")
    n_rows = int(head["nRows"])
    assert n_rows == t.size > 0
    assert mot_rows_in_opensim(out / "angles.mot", monkeypatch) == n_rows
    return csv_angles(out / "angles.csv"), set(ang)


@pytest.mark.parametrize("source", ["c3d", "trc"])
def test_upper_body_only_analyses_the_arms_and_skips_the_legs(
    source: str,
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    if source == "c3d":
        path = tmp_path / "upper.c3d"
        kept = write_c3d_subset(shared_data / TENNIS, path, lambda n: not _pig_leg(n))
        knee_markers = ("LKNE", "RKNE")
    else:
        path = tmp_path / "upper.trc"
        kept = write_trc_subset(shared_data / WALK, path, lambda n: not _raj_leg(n))
        knee_markers = ("L.Knee", "R.Knee")
    assert not any(k in " ".join(kept) for k in knee_markers)
    out = tmp_path / "out"
    code, report, err = analyze(capsys, path, out)
    assert code == 0, err
    status = report["limb_status"]
    assert isinstance(status, dict)
    for lb in LEG_LIMBS:
        assert status[lb].startswith("skipped: "), (lb, status[lb])
        side = "Left" if lb.endswith("left") else "Right"
        assert f"Knee{side}" in status[lb] or f"Ankle{side}" in status[lb]
    assert "KneeLeft" in status["thigh_left"] and knee_markers[0] in status["thigh_left"]
    assert set(report["skipped_limbs"]) == set(LEG_LIMBS)  # type: ignore[arg-type]
    for lb in ("trunk", *ARM_LIMBS):
        assert not status[lb].startswith("skipped"), (lb, status[lb])
        assert lb in report["analysed_limbs"]  # type: ignore[operator]
    assert "partial body" in err  # the warning on stderr names the skipped limbs
    in_csv, in_mot = check_files(out, monkeypatch)
    assert {"elbow_flexion_left", "elbow_flexion_right"} <= in_csv
    assert any(k.startswith("elbow_flexion") for k in in_mot)
    for names in (in_csv, in_mot):
        assert not [k for k in names if k.startswith(LEG_ANGLES)], names


def test_lower_body_only_analyses_the_legs_and_skips_the_arms(
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    path = tmp_path / "lower.c3d"
    write_c3d_subset(shared_data / TENNIS, path, lambda n: _pig_leg(n) or n[1:] in PIG_PELVIS)
    out = tmp_path / "out"
    code, report, err = analyze(capsys, path, out)
    assert code == 0, err
    status = report["limb_status"]
    assert isinstance(status, dict)
    for lb in ("trunk", "head", *ARM_LIMBS):
        assert status[lb].startswith("skipped: "), (lb, status[lb])
    assert "ShoulderLeft" in status["upper_arm_left"] and "LSHO" in status["upper_arm_left"]
    assert "ElbowRight" in status["forearm_right"] and "RELB" in status["forearm_right"]
    assert "pelvis" not in report["skipped_limbs"]  # type: ignore[operator]
    for lb in LEG_LIMBS:
        assert not status[lb].startswith("skipped"), (lb, status[lb])
    in_csv, in_mot = check_files(out, monkeypatch)
    assert {"knee_flexion_left", "knee_flexion_right", "hip_flexion_left"} <= in_csv
    assert {"knee_flexion_left", "knee_flexion_right"} <= in_mot
    for names in (in_csv, in_mot):
        assert not [k for k in names if k.startswith(UPPER_ANGLES)], names
    _, ang, _ = read_angles_mot(out / "angles.mot")
    for side in ("left", "right"):  # a real knee flexion, not a constant
        v = ang[f"knee_flexion_{side}"]
        assert float(np.ptp(v)) > 10.0
        assert np.abs(v).max() < 160.0


@pytest.mark.parametrize("use_map", [False, True])
def test_nothing_to_analyse_fails_clearly(
    use_map: bool,
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Only arm markers: no root, no body: exit 2, the missing markers per joint, no output."""
    path = tmp_path / "arms.c3d"
    write_c3d_subset(shared_data / TENNIS, path, lambda n: n[1:] in ("ELB", "WRA", "WRB", "FIN"))
    out = tmp_path / "out"
    argv = ["analyze", str(path), "--out", str(out), "--no-plots"]
    if use_map:
        argv += ["--map", "plug-in-gait"]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err
    for joint, marker in (("SpineBase", "RASI"), ("KneeLeft", "LKNE"), ("ShoulderLeft", "LSHO")):
        assert any(joint in ln and marker in ln for ln in err.splitlines()), err
    if use_map:
        assert "Nothing can be analysed" in err
    assert not out.exists()


@pytest.mark.parametrize("names", ["kinefuse", "opensim"])
def test_upper_body_only_with_its_static_trial(
    names: str,
    shared_data: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Issue 20 item 5 with --static: the Gait2354 walk and static trial without any leg marker
    are analysed for the trunk and arms (anatomical angles too); the legs are skipped, each
    with the reason, in the functional and the anatomical part."""
    gait = "markers/opensim/Pipelines_Gait2354_Simbody_subject01_"
    legs = ("Thigh", "Knee", "Shank", "Ankle", "Heel", "Midfoot", "Toe")
    paths = {}
    for k in ("walk1", "static"):
        paths[k] = tmp_path / f"{k}.trc"
        write_trc_subset(shared_data / f"{gait}{k}.trc", paths[k],
                         lambda n: not any(x in n for x in legs))  # fmt: skip
    out = tmp_path / "out"
    code = main(["analyze", str(paths["walk1"]), "--static", str(paths["static"]), "--names",
                 names, "--out", str(out), "--json", "--no-plots"])  # fmt: skip
    got, err = capsys.readouterr()
    assert code == 0, err
    report = json.loads(got)
    assert set(report["skipped_limbs"]) == set(LEG_LIMBS)
    assert "KneeLeft" in report["limb_status"]["thigh_left"]
    anat = report["anatomical"]
    for lb in LEG_LIMBS:
        assert anat["segment_status"][lb].startswith("skipped"), lb
    for lb in ("pelvis", "trunk", *ARM_LIMBS):
        assert anat["segment_status"][lb] == "ok", (lb, anat["segment_status"][lb])
    assert {"elbow_flexion_left", "shoulder_elevation_right", "pelvis_tilt"} <= set(
        anat["angle_names"]
    )
    assert not [k for k in anat["angle_names"] if k.startswith(LEG_ANGLES)]
    _, in_mot = check_files(out, monkeypatch)  # OpenSim reads every row
    want = "elbow_flex_l" if names == "opensim" else "elbow_flexion_left_anatomical"
    assert want in in_mot
