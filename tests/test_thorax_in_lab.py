"""A capture without a pelvis (the upper-limb ISB set) gets trunk angles: ISB's thorax relative
to the lab (``thorax_extension``, ``thorax_lateral_bend``, ``thorax_rotation``; the vertical and
the thorax's heading at the start of the motion), and its status says so. The set is placed on
real CMU clips (kinefuse.lab.marker_placement), whose true thorax motion is known."""

from __future__ import annotations

import csv
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli.main import main
from kinefuse.app.workflows.analyze import load_input
from kinefuse.lab.marker_placement import marker_trial, write_trc
from test_marker_sets import START_STOP, THORAX_2, WALK, prefixed, write_trial

THORAX = ("thorax_extension", "thorax_lateral_bend", "thorax_rotation")


def test_an_upper_limb_capture_gives_arm_and_thorax_angles_and_says_the_legs_were_skipped(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    tr = marker_trial(shared_data / START_STOP, "upper-limb-isb")
    walk, static = write_trial(tr, tmp_path, prefixed("Name"), "+z")
    out = tmp_path / "out"
    code = main(["analyze", str(walk), "--static", str(static), "--out", str(out), "--no-plots"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert "partial body" in err and "thigh_left" in err  # the legs: said skipped
    assert "upper-limb-isb marker set has none" in err
    report = json.loads((out / "analysis.json").read_text())
    assert {"thigh_left", "shank_right", "foot_left"} <= set(report["skipped_limbs"])
    anat = report["anatomical"]
    assert anat["segment_status"]["trunk"].startswith("ok: no pelvis")
    assert "relative to the lab" in anat["segment_status"]["trunk"]
    assert "trunk" not in anat["skipped"] and "pelvis" in anat["skipped"]
    got: dict[str, list[float]] = defaultdict(list)
    with (out / "angles.csv").open() as f:
        for row in csv.DictReader(f):
            if row["method"] == "anatomical" and row["angle"] in THORAX:
                got[row["angle"]].append(float(row["degrees"]) if row["degrees"] else np.nan)
                assert row["status"] == "ok", row
    assert set(got) == set(THORAX)
    with (out / "angles.csv").open() as f:
        angles = {row["angle"] for row in csv.DictReader(f)}
    assert {"elbow_flexion_left", "elbow_flexion_right"} <= angles  # the arms
    assert not any(a.startswith(("knee", "hip_", "ankle")) for a in angles), angles
    # no pelvis for the trunk to be relative to
    assert not any(a.startswith("trunk_") for a in anat["angle_names"])
    for name in THORAX:
        a, b = np.asarray(got[name]), tr.true_angles[name]
        assert a.shape == b.shape
        # the clip turns about 120 deg and bends 44 deg sideways: a real motion, not noise
        assert np.ptp(b) > 25.0, name
        assert np.nanmax(np.abs(a - b)) < 0.5, name  # angles.csv holds 0.01 deg


@pytest.mark.parametrize("clip", [WALK, START_STOP])
def test_the_thorax_in_the_lab_follows_the_clip_in_the_second_thorax_naming(
    clip: str, shared_data: Path, tmp_path: Path
) -> None:
    """STER/XIPH/T1/T10 instead of IJ/PX/C7/T8: the same angles."""
    tr = marker_trial(shared_data / clip, "upper-limb-isb")
    walk, static = write_trial(tr, tmp_path, lambda n: THORAX_2.get(n, n), "+z")
    inp = load_input(walk, static=static)
    assert inp.anatomical is not None
    for name in THORAX:
        err = inp.anatomical[name] - tr.true_angles[name]
        assert np.isfinite(err).mean() > 0.99, name
        assert np.nanmax(np.abs(err)) < 0.1, name


def _turn(p: np.ndarray, about: np.ndarray, axis: np.ndarray, deg: float) -> np.ndarray:
    """Markers ``p (..., 3)`` turned by ``deg`` about ``axis`` through the point ``about``."""
    a = np.radians(deg)
    k = axis / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    r = np.eye(3) + np.sin(a) * kx + (1 - np.cos(a)) * kx @ kx
    return (p - about) @ r.T + about


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


@pytest.mark.parametrize(
    ("angle", "axis_of", "deg"),
    [
        ("thorax_rotation", "thorax_y", 20.0),  # turned to the left about its own long axis
        ("thorax_extension", "lab_right", 15.0),  # front up: leaning back
        ("thorax_lateral_bend", "floating", 10.0),  # the right side down: bending to the right
    ],
)
def test_the_sign_of_each_thorax_angle(
    angle: str, axis_of: str, deg: float, shared_data: Path, tmp_path: Path
) -> None:
    """The standing pose held, then every marker turned as one body about the thorax's middle,
    about the axis each angle turns about (``Z-X-Y``: the lab's right, the floating axis, the
    thorax's long axis): that angle changes by the turn with the documented sign, the others
    stay."""
    tr = marker_trial(shared_data / START_STOP, "upper-limb-isb", static_s=2.0)
    names = tr.names
    still = tr.static  # the reference pose, held
    m = {n: still[0, k] for k, n in enumerate(names)}
    lower = 0.5 * (m["PX"] + m["T8"])
    y = _unit(0.5 * (m["IJ"] + m["C7"]) - lower)  # ISB's thorax
    forward = m["IJ"] - m["C7"]
    z = _unit(np.cross(forward, y))  # normal to the plane of IJ, C7 and lower, to the right
    x = np.cross(y, z)
    up = np.array([0.0, 0.0, 1.0])
    lab_right = _unit(np.cross(x * np.array([1.0, 1.0, 0.0]), up))
    axis = {"thorax_y": y, "lab_right": lab_right, "floating": _unit(np.cross(y, lab_right))}
    n = still.shape[0]
    motion = np.concatenate([still, _turn(still, lower, axis[axis_of], deg)])
    t = np.arange(2 * n) / tr.rate_hz
    static = write_trc(tmp_path / "static.trc", t[:n], names, still, up="+z")
    walk = write_trc(tmp_path / "walk.trc", t, names, motion, up="+z")
    inp = load_input(walk, static=static)
    assert inp.anatomical is not None
    for name in THORAX:
        before, after = inp.anatomical[name][:n], inp.anatomical[name][n:]
        change = float(np.nanmedian(after) - np.nanmedian(before))
        assert change == pytest.approx(deg if name == angle else 0.0, abs=0.2), name
