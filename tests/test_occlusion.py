"""Occlusion detection (2D bone crossings, coverage) and the paper's sensor selection."""

from __future__ import annotations

import json
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.occlusion.segments import (
    crossing_parameters,
    detect_occlusion,
    detect_occlusion_sensors,
    non_adjacent_bone_pairs,
    occlusion_precision_recall,
    segments_intersect,
)
from kinefuse.capture.occlusion.select import select_sensors
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.raycast import ray_capsules
from kinefuse.core.geometry.rotations import rot_y
from kinefuse.core.skeleton import (
    BONES,
    JOINT_INDEX,
    N_JOINTS,
    TrackingState,
    bone_index_array,
    capsule_radii,
)
from kinefuse.errors import InputError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
WALKER = DATA / "kinect" / "kinect2_tracking" / "walker.json"
J = JOINT_INDEX


def load_walker(n_frames: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Real Kinect v2 joints ``(T, 25, 3)`` in the sensor frame (x right, y down) and states."""
    if not WALKER.is_file():
        pytest.skip(f"real Kinect v2 walk not found at {WALKER}")
    frames = json.loads(WALKER.read_text())["bodyFrame"][:n_frames]
    pos, states = [], []
    for f in frames:
        body = next(b for b in f["bodies"] if b.get("tracked"))
        js = sorted(body["joints"], key=lambda q: q["jointType"])
        # Kinect camera space is x left, y up, z forward
        pos.append([[-q["cameraX"], -q["cameraY"], q["cameraZ"]] for q in js])
        states.append([q["trackingState"] for q in js])
    return np.array(pos, dtype=np.float64), np.array(states, dtype=np.int8)


def capsule_visibility(joints: np.ndarray) -> np.ndarray:
    """Ray-cast truth ``(T, 25)``: no capsule that does not contain the joint is hit before it."""
    bones = bone_index_array()
    radii = capsule_radii()
    vis = np.ones(joints.shape[:2], dtype=bool)
    for t, p in enumerate(joints):  # test helper: capsules move with every frame
        a, b = p[bones[:, 0]], p[bones[:, 1]]
        dist = np.linalg.norm(p, axis=1)
        hit = ray_capsules(np.zeros(3), p / dist[:, None], a, b, radii)  # (25, 24)
        ab = b - a
        s = np.einsum("jci,ci->jc", p[:, None] - a[None], ab) / np.einsum("ci,ci->c", ab, ab)
        closest = a[None] + np.clip(s, 0, 1)[..., None] * ab[None]
        inside = np.linalg.norm(p[:, None] - closest, axis=-1) < radii[None]
        vis[t] = ~((hit < dist[:, None]) & ~inside).any(axis=1)
    return vis


# ------------------------------------------------------------------------------ segment tests


@pytest.mark.parametrize(
    ("seg1", "seg2", "expected"),
    [
        (((0, 0), (2, 2)), ((0, 2), (2, 0)), True),  # X
        (((0, 0), (2, 0)), ((1, 0), (1, 3)), True),  # T: touching counts (paper's <= 0)
        (((0, 0), (2, 0)), ((0, 1), (2, 1)), False),  # parallel, apart
        (((0, 0), (2, 0)), ((1, 0), (3, 0)), True),  # collinear, overlapping
        (((0, 0), (1, 0)), ((2, 0), (3, 0)), False),  # collinear, apart (bounding boxes)
        (((0, 0), (1, 1)), ((3, 0), (2, 1)), False),  # the lines cross, the segments do not
        (((0, 0), (np.nan, 1)), ((0, 1), (1, 0)), False),  # NaN end point
    ],
)
def test_segments_intersect_known_cases(seg1, seg2, expected):
    assert bool(segments_intersect(seg1[0], seg1[1], seg2[0], seg2[1])) is expected


def test_segments_intersect_broadcasts_and_matches_brute_force():
    rng = np.random.default_rng(1)
    p = rng.uniform(0, 10, (500, 4, 2))
    hit = segments_intersect(p[:, 0], p[:, 1], p[:, 2], p[:, 3])
    t, u = crossing_parameters(p[:, 0], p[:, 1], p[:, 2], p[:, 3])
    inside = (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    np.testing.assert_array_equal(hit, inside)
    assert hit.shape == (500,) and 50 < hit.sum() < 450


def test_crossing_parameters_known_answer():
    t, u = crossing_parameters((0, 0), (4, 0), (1, -1), (1, 3))
    assert t == pytest.approx(0.25) and u == pytest.approx(0.25)
    t, u = crossing_parameters((0, 0), (1, 0), (0, 1), (1, 1))
    assert np.isnan(t) and np.isnan(u)


def test_segment_inputs_are_validated():
    with pytest.raises(InputError, match=r"p21 must be 2D points with shape \(\.\.\., 2\)"):
        segments_intersect((0, 0), (1, 1), (0, 0, 0), (1, 1))
    with pytest.raises(InputError, match="p11 must be 2D points"):
        crossing_parameters(3.0, (1, 1), (0, 0), (1, 1))


def test_non_adjacent_bone_pairs_is_every_pair_without_a_shared_joint():
    bones = bone_index_array()
    pairs = non_adjacent_bone_pairs()
    expected = {
        (i, k) for i, k in combinations(range(len(bones)), 2) if not set(bones[i]) & set(bones[k])
    }
    assert {tuple(p) for p in pairs.tolist()} == expected
    # 276 pairs of 24 bones minus 29 that meet at a joint (sum over joints of C(degree, 2))
    assert len(pairs) == len(expected) == 247
    with pytest.raises(InputError, match=r"bones must be an integer \(B, 2\) array"):
        non_adjacent_bone_pairs(np.zeros((3, 3), dtype=int))
    with pytest.raises(InputError, match=r"bone joint indices must be 0\.\.24"):
        non_adjacent_bone_pairs(np.array([[0, 30]]))


# ------------------------------------------------------------------------- hand-made poses


def standing_pose(z_m: float = 2.5) -> np.ndarray:
    """A person facing the camera (sensor frame, y down), arms hanging, ``(25, 3)`` metres."""
    p = {
        "SpineBase": (0.0, 0.1, 0.0),
        "SpineMid": (0.0, -0.2, 0.0),
        "SpineShoulder": (0.0, -0.45, 0.0),
        "Neck": (0.0, -0.52, 0.0),
        "Head": (0.0, -0.65, 0.0),
        "ShoulderLeft": (-0.2, -0.42, 0.0),
        "ElbowLeft": (-0.25, -0.15, 0.0),
        "WristLeft": (-0.27, 0.1, 0.0),
        "HandLeft": (-0.28, 0.17, 0.0),
        "HandTipLeft": (-0.28, 0.25, 0.0),
        "ThumbLeft": (-0.24, 0.17, -0.02),
        "ShoulderRight": (0.2, -0.42, 0.0),
        "ElbowRight": (0.25, -0.15, 0.0),
        "WristRight": (0.27, 0.1, 0.0),
        "HandRight": (0.28, 0.17, 0.0),
        "HandTipRight": (0.28, 0.25, 0.0),
        "ThumbRight": (0.24, 0.17, -0.02),
        "HipLeft": (-0.1, 0.12, 0.0),
        "KneeLeft": (-0.11, 0.55, 0.02),
        "AnkleLeft": (-0.12, 0.95, 0.05),
        "FootLeft": (-0.12, 1.0, -0.08),
        "HipRight": (0.1, 0.12, 0.0),
        "KneeRight": (0.11, 0.55, 0.02),
        "AnkleRight": (0.12, 0.95, 0.05),
        "FootRight": (0.12, 1.0, -0.08),
    }
    out = np.array([p[name] for name in sorted(p, key=JOINT_INDEX.__getitem__)], dtype=np.float64)
    out[:, 2] += z_m
    return out


def arm_across(depth_offset_m: float) -> np.ndarray:
    """Right forearm held horizontally across the belly, ``depth_offset_m`` nearer the camera."""
    p = standing_pose()
    p[J["ElbowRight"]] = (0.22, -0.18, 2.5 - depth_offset_m)
    p[J["WristRight"]] = (-0.04, -0.2, 2.5 - depth_offset_m)
    p[J["HandRight"]] = (-0.11, -0.2, 2.5 - depth_offset_m)
    p[J["HandTipRight"]] = (-0.18, -0.2, 2.5 - depth_offset_m)
    p[J["ThumbRight"]] = (-0.1, -0.24, 2.5 - depth_offset_m)
    return p


def test_standing_pose_has_no_crossing():
    res = detect_occlusion(standing_pose()[None], Intrinsics())
    assert res.n_intersections.tolist() == [0]
    assert not res.occluded.any() and not res.bone_occluded.any()


def test_arm_in_front_of_torso_occludes_the_spine():
    res = detect_occlusion(arm_across(0.25)[None], Intrinsics())
    flagged = {name for name, j in JOINT_INDEX.items() if res.occluded[0, j]}
    # the forearm crosses the lower trunk bone 0.02 m above SpineMid
    assert flagged == {"SpineMid"}
    assert res.n_intersections[0] == 1
    rear = {BONES[k] for k in np.flatnonzero(res.bone_occluded[0])}
    assert rear == {("SpineMid", "SpineShoulder")}


def test_arm_behind_the_back_is_the_occluded_one():
    res = detect_occlusion(arm_across(-0.25)[None], Intrinsics())
    flagged = {name for name, j in JOINT_INDEX.items() if res.occluded[0, j]}
    # the crossing is 0.04 m from WristRight; ElbowRight is 0.22 m away, beyond near_m
    assert flagged == {"WristRight"}
    rear = {BONES[k] for k in np.flatnonzero(res.bone_occluded[0])}
    assert rear == {("ElbowRight", "WristRight")}
    wide = detect_occlusion(arm_across(-0.25)[None], Intrinsics(), near_m=0.3)
    assert wide.occluded[0, J["ElbowRight"]] and wide.occluded[0, J["WristRight"]]


def test_coverage_rule_sees_a_hand_hidden_behind_the_trunk_without_a_crossing():
    p = standing_pose()
    # left arm reaching behind the back: its hand sits behind the trunk, crossing no bone
    p[J["WristLeft"]] = (-0.08, -0.05, 2.7)
    p[J["HandLeft"]] = (-0.06, 0.0, 2.7)
    p[J["HandTipLeft"]] = (-0.05, 0.05, 2.7)
    p[J["ThumbLeft"]] = (-0.04, -0.01, 2.68)
    crossing = detect_occlusion(p[None], Intrinsics())
    coverage = detect_occlusion(p[None], Intrinsics(), rule="coverage")
    assert not crossing.occluded[0, J["HandLeft"]]
    assert coverage.occluded[0, J["HandLeft"]] and coverage.occluded[0, J["HandTipLeft"]]
    assert not coverage.occluded[0, J["Head"]] and not coverage.occluded[0, J["HandRight"]]
    # the intersection counts are the crossing test's whatever the joint rule
    np.testing.assert_array_equal(coverage.n_intersections, crossing.n_intersections)


def test_missing_joints_take_no_part():
    p = np.stack([arm_across(0.25), arm_across(0.25)])
    p[1, J["WristRight"]] = np.nan  # the crossing forearm is gone in frame 1
    res = detect_occlusion(p, Intrinsics())
    assert res.n_intersections.tolist() == [1, 0]
    assert not res.occluded[1].any()


def test_detect_occlusion_sensors_stacks_sensors():
    p = np.stack([standing_pose(), arm_across(0.25)])  # (2 sensors, 25, 3)
    res = detect_occlusion_sensors(p[None], [Intrinsics(), Intrinsics(fx=380.0, fy=380.0)])
    assert res.occluded.shape == (1, 2, N_JOINTS)
    assert res.n_intersections.tolist() == [[0, 1]]
    assert res.bone_occluded.shape == (1, 2, 24)
    with pytest.raises(InputError, match="got 1 intrinsics for 2 sensors"):
        detect_occlusion_sensors(p[None], [Intrinsics()])


def test_detect_occlusion_validates_input():
    with pytest.raises(InputError, match=r"joints_sensor must have shape \(T, 25, 3\)"):
        detect_occlusion(np.zeros((4, 24, 3)), Intrinsics())
    must = r"intrinsics must be a kinefuse\.core\.camera\.intrinsics"
    with pytest.raises(InputError, match=must):
        detect_occlusion(np.zeros((1, 25, 3)), "kinect")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="near_m must be a positive distance"):
        detect_occlusion(np.zeros((1, 25, 3)), Intrinsics(), near_m=-1.0)
    with pytest.raises(InputError, match="rule must be 'crossing'"):
        detect_occlusion(np.zeros((1, 25, 3)), Intrinsics(), rule="depth")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="height_m must be the subject's height"):
        detect_occlusion(np.zeros((1, 25, 3)), Intrinsics(), rule="coverage", height_m=7.0)
    with pytest.raises(InputError, match="rule='coverage' uses the capsule radii"):
        detect_occlusion(np.zeros((1, 25, 3)), Intrinsics(), rule="coverage", bones=[[0, 1]])
    with pytest.raises(InputError, match=r"joints_sensor must have shape \(T, S, 25, 3\)"):
        detect_occlusion_sensors(np.zeros((1, 25, 3)), Intrinsics())


# ------------------------------------------------------------------------ real Kinect poses


def test_real_walk_detection_against_ray_cast_and_kinect_states():
    """Real Kinect v2 poses seen from the side (as recorded) and rotated to other views."""
    joints, _ = load_walker(120)
    centre = joints[:, J["SpineBase"]].mean(axis=0)
    scores = {}
    for angle in (0, 90, 180):
        view = (joints - centre) @ rot_y(np.radians(angle)).T + centre
        visible = capsule_visibility(view)
        for rule in ("crossing", "coverage"):
            res = detect_occlusion(view, Intrinsics(), rule=rule)  # type: ignore[arg-type]
            scores[angle, rule] = occlusion_precision_recall(res.occluded, visible)
    for angle in (0, 90, 180):
        crossing, coverage = scores[angle, "crossing"], scores[angle, "coverage"]
        assert crossing.precision > 0.5  # flags are mostly right
        assert coverage.precision > 0.8 and coverage.recall > 0.8
        assert coverage.recall > crossing.recall + 0.4
    # the Kinect's own judgement on the whole real recording: hidden joints are 'inferred'
    # (measured: crossing precision 0.35 recall 0.14, coverage precision 0.44 recall 0.61)
    all_joints, states = load_walker()
    kinect_visible = states != TrackingState.INFERRED
    cross = occlusion_precision_recall(
        detect_occlusion(all_joints, Intrinsics()).occluded, kinect_visible
    )
    cover = occlusion_precision_recall(
        detect_occlusion(all_joints, Intrinsics(), rule="coverage").occluded, kinect_visible
    )
    assert cover.recall > 2 * cross.recall
    assert cover.precision > cross.precision


# ---------------------------------------------------------------------- precision / recall


def test_precision_recall_counts():
    occ = np.array([True, True, False, False, True])
    vis = np.array([False, True, False, True, False])
    pr = occlusion_precision_recall(occ, vis)
    assert (pr.tp, pr.fp, pr.fn, pr.tn) == (2, 1, 1, 1)
    assert pr.precision == pytest.approx(2 / 3) and pr.recall == pytest.approx(2 / 3)
    assert pr.f1 == pytest.approx(2 / 3)
    only = occlusion_precision_recall(occ, vis, valid=np.array([1, 1, 0, 0, 0], dtype=bool))
    assert (only.tp, only.fp, only.fn, only.tn) == (1, 1, 0, 0)
    none = occlusion_precision_recall(np.zeros(3, bool), np.ones(3, bool))
    assert np.isnan(none.precision) and np.isnan(none.recall) and np.isnan(none.f1)


def test_precision_recall_validates_input():
    with pytest.raises(InputError, match="must be bool arrays, got int64 and bool"):
        occlusion_precision_recall(np.zeros(3, dtype=np.int64), np.ones(3, bool))
    with pytest.raises(InputError, match=r"same shape, got \(3,\) and \(4,\)"):
        occlusion_precision_recall(np.zeros(3, bool), np.ones(4, bool))
    with pytest.raises(InputError, match=r"valid must be a bool array of shape \(3,\)"):
        occlusion_precision_recall(np.zeros(3, bool), np.ones(3, bool), valid=np.ones(2, bool))


# ------------------------------------------------------------------------------- selection


def test_selection_keeps_unoccluded_sensors():
    occ = np.zeros((1, 3, N_JOINTS), dtype=bool)
    occ[0, 1, 5] = True
    sel = select_sensors(occ, np.array([[4, 0, 2]]))
    assert sel[0, :, 5].tolist() == [True, False, True]
    assert sel[0, :, 0].tolist() == [True, True, True]


def test_selection_all_occluded_takes_fewest_intersections():
    occ = np.ones((2, 3, N_JOINTS), dtype=bool)
    n_int = np.array([[4, 1, 2], [3, 5, 3]])
    sel = select_sensors(occ, n_int)
    assert (sel.sum(axis=1) == 1).all()
    assert sel[0, 1].all()  # fewest intersections
    assert sel[1, 0].all()  # a tie goes to the lowest index


def test_selection_never_picks_unavailable_sensors():
    occ = np.ones((1, 3, N_JOINTS), dtype=bool)
    avail = np.ones((1, 3, N_JOINTS), dtype=bool)
    avail[0, 1, :] = False  # the sensor with the fewest intersections saw nothing
    avail[0, :, 7] = False  # nobody saw joint 7
    occ[0, 2, 3] = False  # sensor 2 sees joint 3 clearly
    sel = select_sensors(occ, np.array([[3, 0, 5]]), avail)
    assert sel[0, :, 0].tolist() == [True, False, False]
    assert sel[0, :, 3].tolist() == [False, False, True]
    assert not sel[0, :, 7].any()


def test_selection_validates_input():
    occ = np.zeros((2, 3, N_JOINTS), dtype=bool)
    with pytest.raises(InputError, match=r"occluded must be a bool array of shape \(T, S, 25\)"):
        select_sensors(occ.astype(int), np.zeros((2, 3), dtype=int))
    with pytest.raises(
        InputError, match=r"n_intersections must be an integer array of shape \(2, 3\)"
    ):
        select_sensors(occ, np.zeros((2, 2), dtype=int))
    with pytest.raises(InputError, match=r"available must be a bool array of shape \(2, 3, 25\)"):
        select_sensors(occ, np.zeros((2, 3), dtype=int), np.ones((2, 3), bool))


def test_the_default_bone_pairs_are_computed_once_and_give_the_same_flags():
    """detect_occlusion keeps the 24 bones' non-adjacent pairs (a live client calls it per
    frame); the flags are those of the pairs built anew; the kept arrays cannot be changed."""
    from kinefuse.capture.occlusion.segments import _default_bones, detect_occlusion
    from kinefuse.core.skeleton import bone_index_array, standing_pose

    b, pairs = _default_bones()
    assert np.array_equal(b, bone_index_array())
    assert np.array_equal(pairs, non_adjacent_bone_pairs(bone_index_array()))
    assert _default_bones()[1] is pairs and not pairs.flags.writeable
    rng = np.random.default_rng(3)
    j = (standing_pose() - [0.0, -3.0, 0.0])[:, [0, 2, 1]]
    frames = j[None] + rng.normal(0, 0.15, (40, 25, 3))  # limbs thrown about: crossings
    kept = detect_occlusion(frames, Intrinsics())
    anew = detect_occlusion(frames, Intrinsics(), bones=bone_index_array())
    assert np.array_equal(kept.occluded, anew.occluded)
    assert np.array_equal(kept.n_intersections, anew.n_intersections)
    assert kept.n_intersections.sum() > 0
