"""A knee whose static trial's epicondyle markers give an axis far from the one the knee flexes
about in the motion gets its axis and centre from the motion (the hinge's axis, through the
lateral knee marker), and its status says so. Shown on the Gait2354 set placed on a real CMU
walk with one medial knee marker moved behind the knee (the truth known), and on the shared
Rajagopal walk, whose left medial knee marker is such a marker (docs/analysis.md), against
OpenSim's IK of it, as it is and mirrored left to right."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.workflows.analyze import load_input
from kinefuse.biomech import static_trial
from kinefuse.biomech.anatomical import rigid_fit
from kinefuse.biomech.static_trial import functional_hinge_axis
from kinefuse.lab.marker_placement import gait2354_trial, write_trc

WALK = "motion/cmu/02_walk_a.amc"
RAJ = "markers/opensim/Pipelines_Rajagopal_"


def _rms(d: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(d**2)))


def _placed_walk(shared_data: Path, tmp_path: Path, medial_back_m: float) -> tuple[Path, Path]:
    """The Gait2354 set on the CMU walk, its static trial's left medial knee marker moved
    ``medial_back_m`` towards the back of the thigh (its frame's -X)."""
    tr = gait2354_trial(shared_data / WALK)
    st = tr.static.copy()
    k = tr.names.index("L.Knee.Med")
    lat, med = st[:, tr.names.index("L.Knee.Lat")], st[:, k]
    y = np.array([0.0, 0.0, 1.0])  # standing: the thigh's long axis is about vertical
    back = np.cross(y, lat - med)  # up x the left knee's medial-to-lateral: backwards
    back /= np.linalg.norm(back, axis=-1, keepdims=True)
    st[:, k] += medial_back_m * back
    t_static = np.arange(st.shape[0]) / tr.rate_hz
    static = write_trc(tmp_path / "static.trc", t_static, tr.names, st)
    walk = write_trc(tmp_path / "walk.trc", tr.t_s, tr.motion_names, tr.motion)
    return walk, static


def test_a_misplaced_medial_knee_marker_is_found_and_the_knee_read_about_its_hinge(
    shared_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """6 cm behind the knee (the epicondyle axis then 28 deg from the hinge): the status
    says so; knee flexion and hip flexion come back within 2 deg RMS of the clip's, where the
    epicondyle axis (kept regardless, below) is off by several degrees."""
    tr = gait2354_trial(shared_data / WALK)
    walk, static = _placed_walk(shared_data, tmp_path, 0.06)
    inp = load_input(walk, marker_map="gait2354", static=static)
    assert inp.anatomical is not None and inp.anatomical_status is not None
    note = inp.anatomical_status["thigh_left"]
    assert note.startswith("ok: the static trial's knee markers give an axis"), note
    assert inp.anatomical_status["thigh_right"] == "ok"
    fixed = {}
    for k in ("knee_flexion_left", "hip_flexion_left", "knee_adduction_left"):
        fixed[k] = _rms(inp.anatomical[k] - tr.true_angles[k])
    assert fixed["knee_flexion_left"] < 2.0 and fixed["hip_flexion_left"] < 2.0, fixed
    assert fixed["knee_adduction_left"] < 3.0, fixed
    monkeypatch.setattr(static_trial, "MAX_KNEE_AXIS_DISAGREEMENT_DEG", 180.0)
    isb = load_input(walk, marker_map="gait2354", static=static)
    assert isb.anatomical is not None and isb.anatomical_status is not None
    assert isb.anatomical_status["thigh_left"] == "ok"
    k = "knee_flexion_left"
    assert _rms(isb.anatomical[k] - tr.true_angles[k]) > 2 * fixed[k] + 2.0


def test_correctly_placed_knee_markers_are_kept(shared_data: Path, tmp_path: Path) -> None:
    """The same walk with the marker where it belongs: both knees keep their epicondyle axes."""
    walk, static = _placed_walk(shared_data, tmp_path, 0.0)
    inp = load_input(walk, marker_map="gait2354", static=static)
    assert inp.anatomical_status is not None
    assert inp.anatomical_status["thigh_left"] == "ok"
    assert inp.anatomical_status["thigh_right"] == "ok"


def test_the_hinge_axis_of_a_known_turn(rng: np.random.Generator) -> None:
    """Clusters turned about a known axis by 0..60 deg, with 1 mm of marker noise: the axis
    comes back within 1 deg and the range within 1 deg."""
    axis = np.array([0.2, 0.1, 1.0])
    axis /= np.linalg.norm(axis)
    ang = np.radians(np.linspace(0.0, 60.0, 120))
    kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    turn = (
        np.eye(3) + np.sin(ang)[:, None, None] * kx + (1 - np.cos(ang))[:, None, None] * (kx @ kx)
    )
    thigh = np.array([[0.05, 0.2, 0.08], [-0.04, 0.15, 0.07], [0.0, 0.3, 0.09]])
    shank = np.array([[0.05, -0.2, 0.06], [-0.04, -0.15, 0.05], [0.0, -0.3, 0.07]])
    still = np.repeat(thigh[None], ang.size, 0) + rng.normal(0, 0.001, (ang.size, 3, 3))
    moved = np.einsum("tij,mj->tmi", turn, shank) + rng.normal(0, 0.001, (ang.size, 3, 3))
    rt, _ = rigid_fit(thigh, still)
    rs, _ = rigid_fit(shank, moved)
    found = functional_hinge_axis(rt, rs)
    assert found is not None
    got, span = found
    assert np.degrees(np.arccos(abs(got @ axis))) < 1.0
    assert span == pytest.approx(60.0, abs=1.0)


@pytest.mark.parametrize("how", ["as is", "mirrored"])
def test_the_rajagopal_walks_legs_meet_the_targets(
    how: str, shared_data: Path, tmp_path: Path
) -> None:
    """The shared Rajagopal walk: its left knee's static markers give an axis 29 deg from its
    hinge (the right's: within 15 deg); read about the hinge, hip and knee meet issue 43's
    targets on both sides against OpenSim's IK, and so does the mirrored walk (the misplaced
    marker then on the right)."""
    from kinefuse.app.workflows.analyze import run_analyze
    from kinefuse.lab.opensim_ik import compare_with_ik, mirror_trc_text

    walk = shared_data / f"{RAJ}ExpData_motion_capture_walk.trc"
    static = shared_data / f"{RAJ}ExpData_static_walk_1.trc"
    if how == "mirrored":
        (tmp_path / "w.trc").write_text(mirror_trc_text(walk.read_text()))
        (tmp_path / "s.trc").write_text(mirror_trc_text(static.read_text()))
        walk, static = tmp_path / "w.trc", tmp_path / "s.trc"
    inp = load_input(walk, static=static)
    assert inp.anatomical_status is not None
    bad, good = ("thigh_left", "thigh_right") if how == "as is" else ("thigh_right", "thigh_left")
    assert inp.anatomical_status[bad].startswith("ok: the static trial's knee markers give an")
    assert inp.anatomical_status[good] == "ok"
    out = tmp_path / "out"
    run_analyze([walk], out=out, static=static, names="opensim:rajagopal", plots=False)
    c = compare_with_ik(out / "angles.mot", shared_data / f"{RAJ}OpenSimIK_walk.mot",
                        mirrored=how == "mirrored")  # fmt: skip
    for s in "rl":
        for k in ("hip_flexion", "knee_angle", "ankle_angle"):
            v = c[f"{k}_{s}"]
            assert v["r"] >= (0.9 if k == "ankle_angle" else 0.97), (k, s, v)
            assert abs(v["offset_deg"]) <= 5.0 and v["rms_after_offset_deg"] <= 4.0, (k, s, v)
