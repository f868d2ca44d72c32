"""Issue 20 items 2 and 4: the Gait2354 marker set placed on real clips' segments (CMU walk,
start-walk-stop and jumps with turns: motions other than the shared OpenSim walk), with the true
joint centres and anatomical angles known; ``analyze``'s marker chain (TRC axes and units,
clusters, landmarks carried from the static trial, Harrington's hip centres, the
joint-constrained cluster fit, ISB frames, joint coordinate systems, the lab frame) must give
them back (kinefuse.lab.marker_placement)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.workflows.analyze import load_input
from kinefuse.lab.marker_placement import gait2354_trial, marker_trial, write_trc

CLIPS = ["motion/cmu/02_walk_a.amc", "motion/cmu/131_01_scaled_metres.bvh", "motion/cmu/01_01.bvh"]
LEGS = ("hip_flexion", "hip_adduction", "hip_internal_rotation", "knee_flexion",
        "knee_adduction", "ankle_dorsiflexion")  # fmt: skip


@pytest.mark.parametrize("clip", CLIPS)
def test_gait2354_markers_on_a_real_clip_give_back_the_true_angles(
    clip: str, shared_data: Path, tmp_path: Path
) -> None:
    tr = gait2354_trial(shared_data / clip)
    t_static = np.arange(tr.static.shape[0]) / tr.rate_hz
    static = write_trc(tmp_path / "static.trc", t_static, tr.names, tr.static)
    walk = write_trc(tmp_path / "walk.trc", tr.t_s, tr.motion_names, tr.motion)
    inp = load_input(walk, marker_map="gait2354", static=static)
    assert inp.anatomical is not None
    # the joint centres: Harrington's hips from the ASIS/sacrum, the knees and ankles carried
    # from the static trial's epicondyles and malleoli by the thigh and shank clusters
    for j in ("HipLeft", "HipRight", "KneeLeft", "KneeRight", "AnkleLeft", "AnkleRight"):
        got = inp.seq.positions[:, inp.seq.index(j)]
        err = np.linalg.norm(got - tr.true_joints[j], axis=-1)
        assert np.nanmax(err) < 1e-3, (j, np.nanmax(err))  # metres (TRC: 0.1 um digits)
    names = [f"{a}_{s}" for a in LEGS for s in ("left", "right")]
    names += ["pelvis_tilt", "pelvis_obliquity", "pelvis_rotation"]
    for k in names:
        e, t = inp.anatomical[k], tr.true_angles[k]
        assert np.isfinite(e).mean() > 0.99, k
        d = (e - t + 180.0) % 360.0 - 180.0
        assert np.sqrt(np.nanmean(d**2)) < 0.5, (k, np.sqrt(np.nanmean(d**2)))  # degrees
    for s in ("left", "right"):  # the elbow: the acromion marker moves with the arm
        d = inp.anatomical[f"elbow_flexion_{s}"] - tr.true_angles[f"elbow_flexion_{s}"]
        assert np.sqrt(np.nanmean(d**2)) < 2.0


def test_the_check_can_fail(shared_data: Path, tmp_path: Path) -> None:
    """The static trial's right knee markers 2 cm off (along the world's x, whichever way the
    subject faces) give wrong knee angles: the comparison above would see it."""
    tr = gait2354_trial(shared_data / CLIPS[0])
    st = tr.static.copy()
    for n in ("R.Knee.Lat", "R.Knee.Med"):
        st[:, tr.names.index(n), 0] += 0.02
    t_static = np.arange(st.shape[0]) / tr.rate_hz
    static = write_trc(tmp_path / "static.trc", t_static, tr.names, st)
    walk = write_trc(tmp_path / "walk.trc", tr.t_s, tr.motion_names, tr.motion)
    inp = load_input(walk, marker_map="gait2354", static=static)
    assert inp.anatomical is not None
    rmse = [
        np.sqrt(np.nanmean((inp.anatomical[k] - tr.true_angles[k]) ** 2))
        for k in ("knee_flexion_right", "knee_adduction_right")
    ]
    assert max(rmse) > 1.0, rmse  # degrees


@pytest.mark.parametrize("clip", CLIPS[1:])
def test_rajagopal_markers_on_a_real_clip_give_back_the_true_angles(
    clip: str, shared_data: Path, tmp_path: Path
) -> None:
    """The Rajagopal 2016 set (the shipped ``rajagopal`` map, chosen by the marker names):
    knee, ankle and elbow centres from the static trial's medial markers, carried by the
    thigh, shank and upper-arm clusters; the walk has the lateral markers only."""
    tr = marker_trial(shared_data / clip, "rajagopal")
    t_static = np.arange(tr.static.shape[0]) / tr.rate_hz
    static = write_trc(tmp_path / "static.trc", t_static, tr.names, tr.static)
    walk = write_trc(tmp_path / "walk.trc", tr.t_s, tr.motion_names, tr.motion)
    assert "R.MKnee" in tr.names and "R.MKnee" not in tr.motion_names
    inp = load_input(walk, static=static)  # no --map: chosen by the names
    assert inp.anatomical is not None and "rajagopal" in inp.seq.source
    for j in ("HipLeft", "KneeRight", "AnkleLeft", "ElbowRight"):
        err = np.linalg.norm(inp.seq.positions[:, inp.seq.index(j)] - tr.true_joints[j], axis=-1)
        assert np.nanmax(err) < 1e-3, (j, np.nanmax(err))  # metres
    for k in [f"{a}_{s}" for a in LEGS for s in ("left", "right")] + ["pelvis_obliquity"]:
        d = (inp.anatomical[k] - tr.true_angles[k] + 180.0) % 360.0 - 180.0
        assert np.sqrt(np.nanmean(d**2)) < 0.5, (k, np.sqrt(np.nanmean(d**2)))  # degrees
    for s in ("left", "right"):
        d = inp.anatomical[f"elbow_flexion_{s}"] - tr.true_angles[f"elbow_flexion_{s}"]
        assert np.sqrt(np.nanmean(d**2)) < 2.0


@pytest.mark.parametrize("with_static", [True, False])
@pytest.mark.parametrize("clip", CLIPS[:2])
def test_plug_in_gait_markers_on_a_real_clip_give_back_the_true_centres_and_angles(
    clip: str, with_static: bool, shared_data: Path, tmp_path: Path
) -> None:
    """The shipped ``plug-in-gait`` map (chosen by the marker names): Harrington's hips, the
    chord function's knee and ankle centres (KNE/THI/hip centre, ANK/TIB/knee centre, at the
    map's assumed widths), with a static trial (carried by the clusters) and without one (in
    every frame)."""
    tr = marker_trial(shared_data / clip, "plug-in-gait")
    walk = write_trc(tmp_path / "walk.trc", tr.t_s, tr.motion_names, tr.motion, up="+z")
    kw = {}
    if with_static:
        t_static = np.arange(tr.static.shape[0]) / tr.rate_hz
        kw["static"] = write_trc(tmp_path / "static.trc", t_static, tr.names, tr.static, up="+z")
    inp = load_input(walk, **kw)  # type: ignore[arg-type]
    assert "plug-in-gait" in inp.seq.source
    for j in ("HipLeft", "KneeLeft", "KneeRight", "AnkleLeft", "AnkleRight", "WristLeft"):
        err = np.linalg.norm(inp.seq.positions[:, inp.seq.index(j)] - tr.true_joints[j], axis=-1)
        assert np.nanmax(err) < 1e-3, (j, np.nanmax(err))  # metres
    if not with_static:
        assert inp.anatomical is None
        return
    assert inp.anatomical is not None and inp.anatomical_status is not None
    assert inp.anatomical_status["upper_arm_left"].startswith("skipped")  # two markers only
    for k in [f"{a}_{s}" for a in LEGS for s in ("left", "right")] + ["pelvis_tilt"]:
        d = (inp.anatomical[k] - tr.true_angles[k] + 180.0) % 360.0 - 180.0
        assert np.sqrt(np.nanmean(d**2)) < 0.5, (k, np.sqrt(np.nanmean(d**2)))  # degrees
