"""The view-dependent measurement noise (kinefuse.capture.fusion.view_noise): a side view weighs
less."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
from kinefuse.capture.fusion.best import BestOptions
from kinefuse.capture.fusion.live import LiveFusion, LiveOptions, replay
from kinefuse.capture.fusion.model import world_measurements
from kinefuse.capture.fusion.view_noise import VIEW_JOINTS, side_view, view_variance
from kinefuse.core.geometry.transforms import invert_transform, look_at
from kinefuse.core.skeleton import JOINT_INDEX, MIRROR_INDEX, N_JOINTS, TrackingState, standing_pose
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors

J = JOINT_INDEX
BODY = [J[n] for n in VIEW_JOINTS]
LIMBS = [j for j in range(N_JOINTS) if j not in BODY]
TRACKED = np.full(N_JOINTS, TrackingState.TRACKED, dtype=np.int8)
TRUNK = [J[n] for n in ("SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head", "HipLeft",
                        "HipRight", "ShoulderLeft", "ShoulderRight")]  # fmt: skip
#: the standing pose faces +x: a frontal sensor on +x, one on the body's left (+y)
FRONT = look_at([3.0, 0.0, 1.0], [0.0, 0.0, 1.0])
LEFT = look_at([0.0, 3.0, 1.1], [0.0, 0.0, 1.0])


def seen_by(pose_world: np.ndarray, s2w: np.ndarray) -> np.ndarray:
    w2s = invert_transform(s2w)
    return pose_world @ w2s[:3, :3].T + w2s[:3, 3]


def _var(z: np.ndarray, pos: np.ndarray, **kw: float) -> np.ndarray:
    p = {"view_sigma_m": 0.1, "view_exponent": 2.0, "far_sigma_m": 0.0, "far_exponent": 2.0}
    p.update(kw)
    return view_variance(z, pos, p["view_sigma_m"], p["view_exponent"], p["far_sigma_m"],
                         p["far_exponent"])  # fmt: skip


def test_the_view_term_is_zero_seen_from_the_front_or_back_and_full_from_the_side() -> None:
    pose = standing_pose()
    pos = np.array([[3.0, 0.0, 1.0], [-3.0, 0.0, 1.2], [0.0, 3.0, 1.1], [3.0, 3.0, 1.0]])
    z = np.broadcast_to(pose, (1, 4, N_JOINTS, 3))
    v = _var(z, pos)
    np.testing.assert_allclose(v[0, :2], 0.0, atol=1e-12)  # front and back: nothing (m^2)
    np.testing.assert_allclose(v[0, 2, BODY], 0.1**2, rtol=1e-9)  # the side: sigma^2
    np.testing.assert_allclose(v[0, 3, BODY], (0.1 * 0.5) ** 2, rtol=1e-6)  # 45 deg: sigma sin^2
    np.testing.assert_allclose(v[0, :, LIMBS], 0.0, atol=1e-12)  # limbs: the far term only
    assert {"SpineBase", "Head", "HipLeft", "ShoulderRight"} <= set(VIEW_JOINTS)
    sin_v, _, lr = side_view(z, pos)
    assert sin_v[0, 2] == pytest.approx(1.0)  # the sensor on the body's left: positive
    np.testing.assert_allclose(lr[0, 0], [0.0, 1.0], atol=1e-12)


def test_a_mirrored_skeleton_gets_the_same_variance() -> None:
    """The tracker's left/right swaps come before the swap correction: the term must not
    depend on them."""
    pose = standing_pose()
    pose[J["KneeLeft"], 1] += 0.05  # not symmetric
    pos = np.array([[2.0, 2.5, 1.0]])
    z = pose[None, None]
    zm = pose[np.asarray(MIRROR_INDEX)][None, None]
    a = _var(z, pos, far_sigma_m=0.07)
    b = _var(zm, pos, far_sigma_m=0.07)
    np.testing.assert_allclose(b[0, 0], a[0, 0][np.asarray(MIRROR_INDEX)], atol=1e-15)
    assert a[0, 0, J["KneeRight"]] > a[0, 0, J["KneeLeft"]]  # the far knee


def test_the_far_side_term_is_on_the_limbs_away_from_the_sensor() -> None:
    pose = standing_pose()
    z = pose[None, None]
    v = _var(z, np.array([[0.0, 3.0, 1.1]]), view_sigma_m=0.0, far_sigma_m=0.1)[0, 0]
    for side in ("Shoulder", "Elbow", "Wrist", "Hip", "Knee", "Ankle"):
        assert v[J[side + "Left"]] == pytest.approx(0.0, abs=1e-12), side  # near (m^2)
        assert v[J[side + "Right"]] > 0.2 * 0.1**2, side  # far: at least half the sigma
    for mid in ("SpineBase", "SpineMid", "Neck", "Head"):
        assert v[J[mid]] < 1e-4, mid  # the midline: under 1 cm
    front = _var(z, np.array([[3.0, 0.0, 1.0]]), view_sigma_m=0.0, far_sigma_m=0.1)
    np.testing.assert_allclose(front, 0.0, atol=1e-12)


def test_no_facing_counts_as_a_side_view_and_off_adds_nothing() -> None:
    pose = standing_pose()
    pose[[J["HipLeft"], J["HipRight"], J["ShoulderLeft"], J["ShoulderRight"]]] = np.nan
    z = pose[None, None]
    v = _var(z, np.array([[3.0, 0.0, 1.0]]), far_sigma_m=0.1)
    np.testing.assert_allclose(v[0, 0, BODY], 0.1**2)
    np.testing.assert_allclose(v[0, 0, LIMBS], 0.0)  # no left-right axis: no far side
    frames = np.broadcast_to(seen_by(standing_pose(), LEFT), (1, 1, N_JOINTS, 3))
    common = dict(lateral_m=np.full(N_JOINTS, 0.015), axial_m=np.full(N_JOINTS, 0.025),
                  inferred_inflation=4.0, occluded_inflation=2.0)  # fmt: skip
    args = (frames, TRACKED[None, None], np.zeros((1, 1, N_JOINTS), bool), np.zeros((1, 1)),
            LEFT[None])  # fmt: skip
    _, c0 = world_measurements(*args, **common)
    _, c1 = world_measurements(*args, **common, view=(0.1, 2.0, 0.0, 2.0))
    expect = np.zeros(c0.shape)
    expect[..., BODY, :, :] = 0.1**2 * np.eye(3)
    np.testing.assert_allclose(c1 - c0, expect, atol=1e-9)  # m^2


def _fuse_two(view_sigma_m: float) -> np.ndarray:
    """A frontal and a side sensor; the side one places the trunk 5 cm off in x (the frontal
    sensor's depth axis, where it measures worst)."""
    pose = standing_pose()
    off = pose.copy()
    off[TRUNK, 0] += 0.05
    best = BestOptions(temporal="filter", view_sigma_m=view_sigma_m, far_sigma_m=0.0)
    opt = LiveOptions(best=best)
    fusion = LiveFusion(np.stack([FRONT, LEFT]), opt)
    for k in range(30):
        t = k / 30
        fusion.push(0, t, seen_by(pose, FRONT), TRACKED)
        fusion.push(1, t, seen_by(off, LEFT), TRACKED)
        fr = fusion.fuse(t)
    return np.linalg.norm(fr.positions[TRUNK] - pose[TRUNK], axis=-1)


def test_the_fused_trunk_follows_the_frontal_sensor() -> None:
    old = _fuse_two(0.0)
    new = _fuse_two(0.1)
    assert old.mean() > 0.025  # without the term the side sensor's lateral precision wins
    assert new.mean() < 0.01, new  # with it the trunk stays within 1 cm of the frontal view
    assert (new < 0.5 * old).all()


def test_bad_view_options_are_refused() -> None:
    with pytest.raises(ValueError, match="view_sigma_m"):
        BestOptions(view_sigma_m=-0.1)
    with pytest.raises(ValueError, match="exponent"):
        BestOptions(far_exponent=0.0)
    assert BestOptions(view_sigma_m=0.2) != BestOptions(view_sigma_m=0.1)
    assert hash(BestOptions(view_sigma_m=0.2)) == hash(BestOptions(view_sigma_m=0.2))


@pytest.fixture(scope="module")
def sensors(tmp_path_factory):
    out = tmp_path_factory.mktemp("view") / "s.sqlite"
    run_simulate(clip=demo_clip_path(), out=out, sensors=3, seconds=3.0, calibration_s=0.0)
    with SessionStore.open(out) as st:
        poses = {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()}
        return load_sensors(st, poses)


def test_the_view_term_is_on_by_default_and_changes_the_fusion(sensors) -> None:
    """The default options carry the view term, so the replay-equals-push-and-fuse test of
    tests/test_live_fusion.py (default options) checks it bit for bit; here: it is on and it
    changes the result."""
    d = BestOptions()
    assert d.view_sigma_m > 0 and d.far_sigma_m > 0
    grid = frame_grid(sensors)[:45]
    poses = np.stack([s.sensor2world for s in sensors])

    def run(opt: LiveOptions):  # type: ignore[no-untyped-def]
        return replay([s.t_server_s for s in sensors], [s.observations.joints_m for s in sensors],
                      [s.observations.states for s in sensors], poses, grid, opt,
                      occluded=[s.occluded for s in sensors])  # fmt: skip

    # each joint on its own (limb_correlation 0), so that each joint's fused variance reads its
    # own measurement terms: solved with its limb, a joint's variance also moves with its
    # neighbours' (a noisier correlated neighbour can even tell more about the shared error)
    base = BestOptions(temporal="filter", limb_correlation=0.0)
    on = run(LiveOptions(best=base))
    off = run(LiveOptions(best=replace(base, view_sigma_m=0.0, far_sigma_m=0.0)))
    view = run(LiveOptions(best=replace(base, far_sigma_m=0.0)))
    ok = np.isfinite(on[1]) & np.isfinite(off[1])
    assert ok.mean() > 0.9
    # the term only adds measurement noise: no fused variance shrinks ...
    assert (on[1][ok] >= off[1][ok] * (1 - 1e-9)).all()
    # ... the trunk's (the view term) about doubles (2.3x measured; 0.1 m at a side view) ...
    ratio = np.nanmean(on[1][:, BODY]) / np.nanmean(off[1][:, BODY])
    assert 1.5 < ratio < 4.0, ratio
    np.testing.assert_allclose(view[1][:, BODY], on[1][:, BODY], rtol=0.05)  # not the far term
    # ... the limbs' grows with the far-side term alone, on the far limbs (+28 % at most
    # measured: 5 cm at exponent 4 is small), and the view term leaves them
    far = np.nanmean(on[1][:, LIMBS], axis=0) / np.nanmean(view[1][:, LIMBS], axis=0)
    assert 1.15 < far.max() < 3.0 and np.median(far) < 1.1, far
    np.testing.assert_allclose(view[1][:, LIMBS], off[1][:, LIMBS], rtol=0.05)
    # the positions move by millimetres (9 mm measured), not a different skeleton
    shift = np.linalg.norm(on[0] - off[0], axis=-1)
    assert 0.002 < np.nanmean(shift) < 0.025, np.nanmean(shift)
    assert np.nanmax(shift) < 0.1
