"""The pose tracker's stages after its 2D model (lift, map, gates) on rendered body depth,
against the truth: the simulator's capsule body, 2D landmarks projected from the true joints."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import apply_transform, invert_transform, look_at
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, TrackingState, standing_pose
from kinefuse.devices.pose.gates import check_body
from kinefuse.devices.pose.landmarks import LM
from kinefuse.devices.pose.tracker import body_from_landmarks
from kinefuse.formats.motion.load import load_motion
from kinefuse.lab.pose_lift import DetectorNoise, score_lifting, true_landmarks
from kinefuse.sim.depth import Scene, render_depth
from kinefuse.sim.lab import LabConfig, SensorSimulation
from kinefuse.sim.rig import default_rig, place_actor

#: joints the model has (not derived), whose error bounds are stated in docs/tracker.md
DIRECT = ("Head", "ShoulderLeft", "ShoulderRight", "ElbowLeft", "ElbowRight", "WristLeft",
          "WristRight", "HipLeft", "HipRight", "KneeLeft", "KneeRight", "AnkleLeft",
          "AnkleRight")  # fmt: skip


@pytest.fixture(scope="module")
def sim(shared_data: Path) -> SensorSimulation:
    motion = load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh")
    rig = default_rig(4)
    return SensorSimulation(place_actor(motion, rig), rig, rig.sensors[0].id,
                            LabConfig(seed=3, calibration_s=0.0))  # fmt: skip


def _median_visible(score, names):  # type: ignore[no-untyped-def]
    rows = {r["joint"]: r for r in score.table()}
    return {n: rows[n]["visible_median_m"] for n in names}


def test_exact_landmarks_on_rendered_depth_give_the_joints_within_4_cm(sim) -> None:  # type: ignore[no-untyped-def]
    score = score_lifting(sim, every=8, max_frames=15)
    assert score.refused == ()
    med = _median_visible(score, DIRECT)
    assert all(v < 0.04 for v in med.values()), med


def test_detector_noise_landmarks_stay_within_8_cm(sim) -> None:  # type: ignore[no-untyped-def]
    score = score_lifting(sim, every=8, max_frames=15, noise=DetectorNoise(), seed=1)
    med = _median_visible(score, DIRECT)
    assert all(v < 0.08 for v in med.values()), med
    assert len(score.refused) <= 2  # a person, nearly every frame, despite the noise


def _camera() -> tuple[np.ndarray, Intrinsics]:
    return look_at([3.0, 0.0, 1.1], [0.0, 0.0, 1.0]), Intrinsics()


def test_a_landmark_hidden_behind_a_limb_is_flagged_not_placed_on_the_limb() -> None:
    pose = standing_pose()  # facing +x, the camera on +x looks at it
    j = {n: pose[JOINT_INDEX[n]].copy() for n in JOINTS}
    # the right arm reaches across the chest, its forearm 30 cm in front of the left elbow
    left_elbow = j["ElbowLeft"]
    j["ElbowRight"] = np.array([0.22, -0.05, left_elbow[2] + 0.07])
    j["WristRight"] = np.array([0.30, left_elbow[1] + 0.02, left_elbow[2] + 0.01])
    j["HandRight"] = j["WristRight"] + [0.0, 0.08, 0.0]
    j["HandTipRight"] = j["WristRight"] + [0.0, 0.15, 0.0]
    j["ThumbRight"] = j["WristRight"] + [0.03, 0.08, 0.02]
    joints = np.array([j[n] for n in JOINTS])
    s2w, intr = _camera()
    depth = render_depth(Scene.from_pose(joints), s2w, intr, np.random.default_rng(0), noise=False)
    truth = apply_transform(invert_transform(s2w), joints)
    stages = body_from_landmarks(true_landmarks(truth, intr), depth, intr, intr)
    k = LM["left_elbow"]
    assert stages.lifted.hidden[k]
    assert stages.lifted.states[k] == TrackingState.INFERRED
    forearm_z = truth[JOINT_INDEX["WristRight"], 2]
    elbow = stages.gate.joints_m[JOINT_INDEX["ElbowLeft"]]
    assert elbow[2] > forearm_z + 0.15  # behind the forearm, not on it
    assert np.linalg.norm(elbow - truth[JOINT_INDEX["ElbowLeft"]]) < 0.10
    # the visible joints around it are tracked where they are
    for name in ("ShoulderLeft", "WristRight", "HipLeft"):
        i = JOINT_INDEX[name]
        assert stages.gate.states[i] == TrackingState.TRACKED, name
        assert np.linalg.norm(stages.gate.joints_m[i] - truth[i]) < 0.05, name


def test_a_landmark_on_the_background_takes_the_body_depth_not_the_wall() -> None:
    joints = standing_pose()
    s2w, intr = _camera()
    depth = render_depth(Scene.from_pose(joints), s2w, intr, np.random.default_rng(0), noise=False)
    truth = apply_transform(invert_transform(s2w), joints)
    lm = true_landmarks(truth, intr)
    # the wrist's landmark 4 px outside the arm's silhouette: half its window on the wall
    k = LM["left_wrist"]
    lm.uv_px[k, 0] += 4.0 if lm.uv_px[k, 0] > intr.cx else -4.0
    stages = body_from_landmarks(lm, depth, intr, intr)
    wrist = stages.gate.joints_m[JOINT_INDEX["WristLeft"]]
    assert abs(wrist[2] - truth[JOINT_INDEX["WristLeft"], 2]) < 0.05


def test_gates_refuse_tiny_twisted_and_underground_bodies() -> None:
    states = np.full(25, TrackingState.TRACKED, dtype=np.int8)
    pose = standing_pose()
    floor_z_up = np.array([0.0, 0.0, 1.0, 0.0])  # this pose's frame: z up, feet at z = 0
    assert check_body(pose, states, floor_z_up).refused is None
    tiny = check_body(pose * 0.05, states)
    assert tiny.refused is not None and tiny.refused.startswith("bones of 2 cm")
    twisted = pose.copy()
    for a, b in (("HipLeft", "HipRight"),):
        ia, ib = JOINT_INDEX[a], JOINT_INDEX[b]
        twisted[[ia, ib]] = twisted[[ib, ia]]
    assert "left and right disagree" in str(check_body(twisted, states).refused)
    sunk = check_body(pose - np.array([0.0, 0.0, 1.3]), states, floor_z_up).refused
    assert sunk is not None and sunk.startswith("hips") and "under the floor" in sunk
    through = pose.copy()
    through[JOINT_INDEX["FootLeft"], 2] = -0.4  # one landmark lifted through the floor
    gate = check_body(through, states, floor_z_up)
    assert gate.refused is None and gate.states[JOINT_INDEX["FootLeft"]] == 0
    assert gate.states[JOINT_INDEX["FootRight"]] == TrackingState.TRACKED
    floating = check_body(pose + np.array([0.0, 0.0, 1.5]), states, floor_z_up).refused
    assert floating is not None and "above the floor" in floating


def test_a_limb_longer_than_its_bones_loses_its_end_not_the_body() -> None:
    states = np.full(25, TrackingState.TRACKED, dtype=np.int8)
    pose = standing_pose()
    pose[JOINT_INDEX["WristLeft"]] += [0.0, 0.0, -0.9]  # a wrist landmark on the floor
    gate = check_body(pose, states)
    assert gate.refused is None
    for name in ("WristLeft", "HandLeft", "HandTipLeft"):
        assert gate.states[JOINT_INDEX[name]] == TrackingState.NOT_TRACKED
        assert np.isnan(gate.joints_m[JOINT_INDEX[name]]).all()
    assert gate.states[JOINT_INDEX["WristRight"]] == TrackingState.TRACKED


def test_a_session_tracked_by_the_pose_tracker_fuses_and_evaluates(
    tmp_path: Path, shared_data: Path
) -> None:
    """The whole chain on a simulated session: every sensor's body observations made by the
    pose tracker on its rendered body depth, fused by `best`, scored against the truth."""
    from kinefuse.app.workflows.evaluate import run_evaluate
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.pose_lift import pose_observations
    from kinefuse.sim.lab import simulate_session

    rig = default_rig(2)
    motion = place_actor(load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh"),
                         rig, 1.0)  # fmt: skip
    path = tmp_path / "pose.sqlite"
    cfg = LabConfig(seed=0, calibration_s=0.0, motion_s=1.0)
    simulate_session(motion, rig, path, cfg, observe=pose_observations(DetectorNoise(), 0))
    with SessionStore.open(path, writable=True) as store:
        store.mark_complete()
        assert len(store.sensors()) == 2
    report = run_evaluate(session=path, methods=("best",), out_dir=None, calibration=None,
                          true_calibration=True)  # fmt: skip
    best = report.method("best")
    assert best["coverage"] > 0.9 and best["mae_m"] < 0.08


def test_without_mediapipe_the_tracker_says_what_to_install() -> None:
    """A Python in which MediaPipe cannot be imported (as without the extra): one line naming
    the extra, from the factory, no traceback."""
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['mediapipe'] = None\n"
        "from kinefuse.devices.trackers import TrackerUnavailable, load_tracker\n"
        "try:\n    load_tracker('pose')\nexcept TrackerUnavailable as e:\n    print(e)\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)  # fmt: skip
    assert run.returncode == 0, run.stderr
    line = run.stdout.strip()
    assert "\n" not in line and "pip install 'kinefuse[tracker]'" in line, line


def test_a_body_turned_sideways_has_its_far_shoulder_behind_the_trunk() -> None:
    """Seen from the side, the far shoulder's window shows the near side; it is put behind by
    the body's width and flagged, whether the face or (no face) the model's visibility says
    which side is away."""
    pose = standing_pose()
    turned = pose.copy()
    turned[:, 0], turned[:, 1] = -pose[:, 1], pose[:, 0]  # facing +y: its left side is away
    s2w, intr = _camera()
    depth = render_depth(Scene.from_pose(turned), s2w, intr, np.random.default_rng(0), noise=False)
    truth = apply_transform(invert_transform(s2w), turned)
    far, near = JOINT_INDEX["ShoulderLeft"], JOINT_INDEX["ShoulderRight"]
    assert truth[far, 2] > truth[near, 2] + 0.3
    with_face = true_landmarks(truth, intr)
    no_face = true_landmarks(truth, intr)
    no_face.uv_px[:11] = np.nan
    no_face.visibility[[LM["left_shoulder"], LM["left_hip"]]] = 0.2  # the model sees less of it
    for lm in (with_face, no_face):
        stages = body_from_landmarks(lm, depth, intr, intr)
        assert stages.lifted.hidden[LM["left_shoulder"]]
        assert stages.gate.states[far] == TrackingState.INFERRED
        assert abs(stages.gate.joints_m[far, 2] - truth[far, 2]) < 0.08
        assert stages.gate.states[near] == TrackingState.TRACKED
