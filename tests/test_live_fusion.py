"""Causal fusion (best-live): frame by frame, nothing from the future, honest status (issue 10)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.capture.fusion.live import LiveFusion, LiveOptions, replay
from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.core.geometry.transforms import invert_transform, look_at
from kinefuse.core.skeleton import JOINT_INDEX, MIRROR_INDEX, N_JOINTS, TrackingState, standing_pose
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method

J = JOINT_INDEX
TRACKED = np.full(N_JOINTS, TrackingState.TRACKED, dtype=np.int8)


def rig(n: int = 4) -> np.ndarray:
    a = 2 * np.pi * np.arange(n) / n
    return np.stack([look_at([3 * np.cos(x), 3 * np.sin(x), 1.0 + 0.05 * i], [0, 0, 1.0])
                     for i, x in enumerate(a)])  # fmt: skip


def seen_by(pose_world: np.ndarray, s2w: np.ndarray) -> np.ndarray:
    w2s = invert_transform(s2w)
    return pose_world @ w2s[:3, :3].T + w2s[:3, 3]


@pytest.fixture(scope="module")
def session(tmp_path_factory, shared_data) -> Path:
    out = tmp_path_factory.mktemp("live") / "walk.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--calibration-seconds", "0", "--seed", "4",
                 "--out", str(out)]) == 0  # fmt: skip
    return out


@pytest.fixture(scope="module")
def sensors(session):
    with SessionStore.open(session) as st:
        poses = {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()}
        return load_sensors(st, poses)


def _replay(sensors, grid, cut_s: float = np.inf):
    keep = [s.t_server_s <= cut_s for s in sensors]
    return replay(
        [s.t_server_s[k] for s, k in zip(sensors, keep, strict=True)],
        [s.observations.joints_m[k] for s, k in zip(sensors, keep, strict=True)],
        [s.observations.states[k] for s, k in zip(sensors, keep, strict=True)],
        np.stack([s.sensor2world for s in sensors]),
        grid,
        occluded=[s.occluded[k] for s, k in zip(sensors, keep, strict=True)],
    )


def test_a_prefix_fuses_bit_identically(sensors) -> None:
    grid = frame_grid(sensors)
    full = _replay(sensors, grid)
    rng = np.random.default_rng(7)
    latency = LiveOptions().latency_s
    for cut in rng.uniform(grid[3], grid[-3], 5):
        part_grid = grid[grid + latency <= cut]
        part = _replay(sensors, part_grid, cut)
        n = part_grid.size
        for a, b in zip(part, full, strict=True):
            np.testing.assert_array_equal(a, b[:n])  # bit for bit, NaN where NaN


def test_replay_equals_pushing_and_fusing_frame_by_frame(sensors) -> None:
    """The replay prepares every frame's measurements in batches; a live server pushes and
    fuses one frame at a time. Same numbers, bit for bit (two seconds of the walk, with its
    swaps, gaps and held observations)."""
    grid = frame_grid(sensors)[:60]
    pos, var, status, used = _replay(sensors, grid)
    opt = LiveOptions()
    fusion = LiveFusion(np.stack([s.sensor2world for s in sensors]), opt)
    events = sorted((float(t), i, k) for i, s in enumerate(sensors)
                    for k, t in enumerate(s.t_server_s))  # fmt: skip
    e = 0
    for f, t in enumerate(grid):
        while e < len(events) and events[e][0] <= t + opt.latency_s:
            _, i, k = events[e]
            o = sensors[i].observations
            fusion.push(i, events[e][0], o.joints_m[k], o.states[k], sensors[i].occluded[k])
            e += 1
        fr = fusion.fuse(float(t))
        np.testing.assert_array_equal(fr.positions, pos[f])
        np.testing.assert_array_equal(fr.variance_m2, var[f])
        np.testing.assert_array_equal(fr.status, status[f])
        np.testing.assert_array_equal(fr.n_sensors, used[f])


def test_one_frame_bone_sweep_equals_the_batched_one() -> None:
    """A live frame is projected onto the bone lengths with plain floats, a replay's frames in
    numpy batches: the same bits (random skeletons, with bones that may not move, coincident
    joints, missing joints, signed zeros and lopsided shares)."""
    from kinefuse.capture.fusion.model import project_bones

    rng = np.random.default_rng(11)
    n_t, n_b = 400, 24
    pos = standing_pose() + rng.normal(0, 0.05, (n_t, N_JOINTS, 3))
    pos[rng.random((n_t, N_JOINTS)) < 0.05] = np.nan
    pos[rng.random((n_t, N_JOINTS, 3)) < 0.05] = -0.0
    pos[::7, J["ElbowLeft"]] = pos[::7, J["ShoulderLeft"]]  # a bone of length 0
    movable = rng.random((n_t, n_b)) < 0.8
    target = rng.uniform(0.02, 0.5, (n_t, n_b))
    w_child = np.where(rng.random((n_t, n_b)) < 0.1, rng.choice([0.0, 1.0], (n_t, n_b)),
                       rng.random((n_t, n_b)))  # fmt: skip
    batch = project_bones(pos, movable, target, w_child, 1.0 - w_child)
    assert not np.allclose(batch, pos, equal_nan=True)  # the sweep moved joints
    for k in range(n_t):
        one = project_bones(pos[k : k + 1], movable[k : k + 1], target[k : k + 1],
                            w_child[k : k + 1], 1.0 - w_child[k : k + 1])  # fmt: skip
        assert one.tobytes() == batch[k : k + 1].tobytes(), k  # bit for bit, signed zeros too


def test_best_live_is_close_to_offline_best_and_far_below_paper(session, sensors) -> None:
    from kinefuse.lab.fusion_truth import truth_at
    from kinefuse.lab.metrics import position_errors

    grid = frame_grid(sensors)
    with SessionStore.open(session) as st:
        truth = truth_at(st, grid)
    mae = {m: position_errors(run_method(sensors, grid, m).positions, truth)["mae_m"]
           for m in ("paper", "best", "best-live")}  # fmt: skip
    assert mae["best-live"] <= 1.15 * mae["best"]
    assert mae["best-live"] < 0.5 * mae["paper"]


def test_status_says_how_each_joint_was_obtained() -> None:
    poses = rig(2)
    pose = standing_pose()
    fusion = LiveFusion(poses)
    inferred = TRACKED.copy()
    inferred[J["HandLeft"]] = TrackingState.INFERRED
    t = 0.0
    for k in range(40):  # both sensors see the body; one of them misses the left foot
        t = k / 30
        for i in range(2):
            joints = seen_by(pose, poses[i])
            states = inferred.copy()
            if i == 1:
                joints[J["FootLeft"]] = np.nan
                states[J["FootLeft"]] = TrackingState.NOT_TRACKED
            fusion.push(i, t, joints, states)
        fr = fusion.fuse(t)
    assert fr.status[J["SpineBase"]] == FusionStatus.OK
    assert fr.status[J["FootLeft"]] == FusionStatus.SINGLE_SENSOR
    assert fr.status[J["HandLeft"]] == FusionStatus.INFERRED_ONLY
    np.testing.assert_allclose(fr.positions, pose, atol=1e-3)  # 1 mm: noise-free measurements
    assert (fr.variance_m2 > 0).all()
    # the sensors stop: predictions for max_predict_s, then nothing
    fr = fusion.fuse(t + 0.2)
    assert (fr.status == FusionStatus.PREDICTED).all() and np.isfinite(fr.positions).all()
    fr = fusion.fuse(t + 0.7)
    assert (fr.status == FusionStatus.NO_DATA).all() and np.isnan(fr.positions).all()


def test_late_observations_count_as_if_on_time() -> None:
    poses = rig(3)
    rng = np.random.default_rng(0)
    walk = np.array([0.5, 0.0, 0.0])  # m/s: a moving body, so the order of samples matters
    # each sensor at 60 Hz: two observations of a sensor reach every 30 Hz frame
    obs = []
    for k in range(60):
        for i in range(3):
            pose = standing_pose() + walk * k / 60 + rng.normal(0, 0.01, (25, 3))
            obs.append((k / 60 + 0.004 * i, i, seen_by(pose, poses[i])))
    a, b = LiveFusion(poses), LiveFusion(poses)
    frames_a, frames_b = [], []
    for k in range(30):
        t = k / 30
        lo = t if k else -np.inf  # each observation arrives once, up to a frame late
        batch = [o for o in obs if lo < o[0] <= t + 1 / 30]
        for o in batch:
            a.push(o[1], o[0], o[2], TRACKED)
        for o in reversed(batch):  # the same observations, each sensor's arriving out of order
            b.push(o[1], o[0], o[2], TRACKED)
        frames_a.append(a.fuse(t).positions)
        frames_b.append(b.fuse(t).positions)
    np.testing.assert_array_equal(np.array(frames_a), np.array(frames_b))


def test_a_sensor_behind_the_body_is_unswapped() -> None:
    poses = rig(4)  # the body faces +x (sensor 0); sensor 2 sees it from behind
    pose = standing_pose()
    fusion = LiveFusion(poses)
    for k in range(30):
        t = k / 30
        for i in range(4):
            joints = seen_by(pose, poses[i])
            if i == 2:
                joints = joints[np.asarray(MIRROR_INDEX)]  # the tracker's left/right confusion
            fusion.push(i, t, joints, TRACKED)
        fr = fusion.fuse(t)
    np.testing.assert_allclose(fr.positions, pose, atol=1e-3)
    assert (fr.status == FusionStatus.OK).all()


def test_bad_input_is_refused_clearly() -> None:
    from kinefuse.errors import FusionError

    fusion = LiveFusion(rig(2))
    with pytest.raises(FusionError, match="unknown sensor index 5"):
        fusion.push(5, 0.0, np.zeros((25, 3)), TRACKED)
    with pytest.raises(FusionError, match="capture time must be finite"):
        fusion.push(0, float("nan"), np.zeros((25, 3)), TRACKED)
    with pytest.raises(FusionError, match=r"\(S, 4, 4\)"):
        LiveFusion(np.eye(4))


def test_fuse_and_evaluate_part_of_a_take(session, tmp_path, capsys) -> None:
    import json

    out = tmp_path / "part.csv"
    assert main(["fuse", str(session), "--true-calibration", "--method", "best-live",
                 "--start", "0.5", "--end", "1.5", "--out", str(out), "--json"]) == 0  # fmt: skip
    info = json.loads(capsys.readouterr().out)
    t = np.loadtxt(out, delimiter=",", skiprows=1, usecols=0)
    assert info["frames"] == t.size == 31 and t[0] == pytest.approx(0.5) and t[-1] <= 1.5
    assert main(["evaluate", str(session), "--true-calibration", "--methods", "best,best-live",
                 "--start", "0.5", "--end", "1.5", "--json"]) == 0  # fmt: skip
    report = json.loads(capsys.readouterr().out)
    assert report["frames"] == 31
    by_status = report["best-live"]["by_status"]
    assert sum(v["fraction"] for v in by_status.values()) == pytest.approx(1.0)
    assert by_status["OK"]["mae_m"] < 0.15  # the trusted joints are the accurate ones
    assert main(["fuse", str(session), "--true-calibration", "--start", "50"]) == 2
    assert "no frames between --start 50" in capsys.readouterr().err


def test_the_clients_own_occlusion_flags_are_used_when_recorded(session, tmp_path) -> None:
    from kinefuse.core.camera.intrinsics import Intrinsics

    with SessionStore.open(session) as st:
        o = st.observations("k0")
        probes = st.clock_probes("k0")
    out = tmp_path / "flags.sqlite"
    flags = np.zeros(o.states.shape, dtype=bool)
    flags[:, J["HandLeft"]] = True  # what this client says, whatever the server would compute
    with SessionStore.create(out) as st:
        st.add_sensor("k0", "S0", Intrinsics())
        st.append_clock_probes("k0", *probes.T)
        st.append_observations("k0", o.seq, o.t_device_s, o.joints_m, o.states,
                               t_receive_host_s=o.t_host_s, occluded=flags,
                               n_crossings=np.full(o.n_frames, 3))  # fmt: skip
        (data,) = load_sensors(st, {"k0": np.eye(4)})
    np.testing.assert_array_equal(data.occluded, flags)
    assert (data.n_intersections == 3).all()
