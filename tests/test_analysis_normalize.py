"""Normalization (B.1): default pose, body planes, recording independence, propagation."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse import biomech as an
from kinefuse.biomech.normalize import body_frame, propagate
from kinefuse.biomech.rom import make_rom_motion
from kinefuse.core.geometry.rotations import rodrigues
from kinefuse.core.skeleton import standing_pose
from kinefuse.errors import InputError
from kinefuse.formats.motion import load_motion


@pytest.fixture(scope="module")
def rom(shared_data):  # type: ignore[no-untyped-def]
    clip = load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh")
    d = an.find_default_pose(an.SkeletonSequence.from_motion(clip))
    motion, truth = make_rom_motion(clip.positions[d], None, np.random.default_rng(3), rate_hz=30.0)
    return an.SkeletonSequence.from_motion(motion), truth


def _moved(seq: an.SkeletonSequence, yaw_deg: float, shift: tuple[float, float]):  # type: ignore[no-untyped-def]
    r = rodrigues(np.array([0.0, 0.0, 1.0]), np.radians(yaw_deg))
    p = seq.positions @ r.T + np.array([*shift, 0.0])
    return an.SkeletonSequence.from_kinect(p, t_s=seq.t_s)


def test_body_frame_of_the_standing_pose() -> None:
    b = body_frame(standing_pose())  # faces +x, z up
    np.testing.assert_allclose(b[:, 0], [1, 0, 0], atol=0.05)  # forward
    np.testing.assert_allclose(b[:, 1], [0, 1, 0], atol=0.05)  # left
    np.testing.assert_allclose(b[:, 2], [0, 0, 1], atol=0.05)  # up


def test_default_pose_is_a_held_default_pose(rom) -> None:  # type: ignore[no-untyped-def]
    seq, truth = rom
    d = an.find_default_pose(seq)
    dev = np.linalg.norm(seq.positions[d] - truth.default_pose, axis=-1)
    assert dev.max() < 0.08  # metres: the sway along the chains, no movement under way
    assert np.median(dev) < 0.015  # metres


def test_default_pose_ignores_a_turned_trunk(rom) -> None:  # type: ignore[no-untyped-def]
    seq, truth = rom
    d = an.find_default_pose(seq)
    trunk_twist = [
        (a, b) for limb, dof, a, b in truth.movements if (limb, dof) == ("trunk", "twist")
    ]
    t = seq.t_s[d]
    assert not any(a <= t <= b for a, b in trunk_twist)


def test_limb_frames_do_not_depend_on_where_the_person_stood(rom) -> None:  # type: ignore[no-untyped-def]
    seq, _ = rom
    a = an.normalize(seq)
    b = an.normalize(_moved(seq, 137.0, (2.0, -1.5)))
    cons = an.normalization_consistency([a, b])
    assert cons["max"] < 1e-4  # degrees: the same body gives the same frames
    assert a.default_frame == b.default_frame


def test_consistency_grows_with_noise(rom, rng) -> None:  # type: ignore[no-untyped-def]
    """Three takes of one body, moved: noise-free they agree to numerical precision; joint noise
    of 2 mm and 4 mm (the same draws, scaled) gives a deviation that grows about in proportion,
    to about 3 degrees at 4 mm (1.8 deg at 2 mm; 6.5 deg at 8 mm with this seed)."""
    seq, _ = rom
    moved = [_moved(seq, 60.0 * k, (0.5 * k, 0.0)) for k in range(3)]
    unit = [rng.normal(size=m.positions.shape) for m in moved]

    def consistency(sigma_m: float) -> dict:  # type: ignore[type-arg]
        takes = [
            an.normalize(an.SkeletonSequence.from_kinect(m.positions + sigma_m * u, t_s=seq.t_s))
            for m, u in zip(moved, unit, strict=True)
        ]
        return an.normalization_consistency(takes)

    clean, two, four = consistency(0.0), consistency(0.002), consistency(0.004)
    assert clean["pairs"] == two["pairs"] == four["pairs"] == 3
    assert clean["max"] < 1e-4  # degrees: without noise the takes give the same frames
    assert two["median"] > 1e4 * clean["max"]  # the noise, not the moving, makes the deviation
    assert 1.3 < four["median"] / two["median"] < 2.6  # grows about linearly with the noise
    assert 2.0 < four["median"] < 4.5  # degrees with 4 mm of joint noise
    assert four["mean"] > two["mean"] and four["max"] > clean["max"]


def test_frames_are_rotations_and_follow_the_limbs(rom) -> None:  # type: ignore[no-untyped-def]
    seq, _ = rom
    norm = an.normalize(seq)
    f = norm.frames.reshape(-1, 3, 3)
    f = f[np.isfinite(f).all(axis=(1, 2))]
    np.testing.assert_allclose(
        f @ np.swapaxes(f, 1, 2), np.broadcast_to(np.eye(3), f.shape), atol=1e-9
    )
    p = seq.kinect_positions()
    body_rel = np.einsum("ji,jk->ik", norm.body2world, norm.frames[norm.default_frame, 0])
    np.testing.assert_allclose(body_rel, np.eye(3), atol=0.02)  # the root carries the body frame
    for i, lb in enumerate(an.LIMBS[1:], start=1):
        u = p[:, lb.distal_index] - p[:, lb.proximal_index]
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        along = np.einsum("tij,j->ti", norm.frames[:, i], norm.long_axis[i])
        np.testing.assert_allclose(along, u, atol=1e-9, err_msg=lb.name)


def _tilt_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle (degrees) between frames ``a`` and ``b`` ``(T, 3, 3)``."""
    c = (np.trace(np.swapaxes(a, 1, 2) @ b, axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def test_pelvis_frame_holds_when_a_back_view_moves_the_spine_joints(rom) -> None:  # type: ignore[no-untyped-def]
    # a sensor that sees the body from behind fits a body it believes turned around: its
    # SpineMid lands several cm in front, its SpineBase behind (fused: +4.5 / -1.2 cm while that
    # sensor took part). SpineBase -> SpineMid (17 cm) tilted the pelvis by 18 deg with it, and
    # every trunk and thigh angle and axis; the long axis from the hips' midpoint does not use
    # SpineBase and is longer
    full, _ = rom
    seq = an.SkeletonSequence.from_kinect(full.kinect_positions(), t_s=full.t_s)  # positions only
    ref = an.normalize(seq)
    p = seq.positions
    # the frames away from the default pose's (which sets the constants)
    half = np.abs(np.arange(p.shape[0]) - ref.default_frame) > seq.rate_hz
    fwd = ref.frames[:, 0, :, 0]  # the pelvis's forward axis, world
    sb, sm = (seq.joint_names.index(j) for j in ("SpineBase", "SpineMid"))
    moved = p.copy()

    def frames(q: np.ndarray) -> np.ndarray:
        s = an.SkeletonSequence.from_kinect(q, t_s=seq.t_s)
        return an.normalize(s, default_frame=ref.default_frame).frames[:, 0]

    moved[half, sb] -= 0.03 * fwd[half]
    got = frames(moved)
    np.testing.assert_allclose(got, ref.frames[:, 0], atol=1e-9)  # SpineBase alone
    moved[half, sm] += 0.045 * fwd[half]
    moved[half, sb] += 0.018 * fwd[half]  # -1.2 cm in all
    got = frames(moved)
    tilt = _tilt_deg(got[half], ref.frames[half, 0])
    assert np.nanmax(tilt) < 10.0  # degrees (18 from SpineBase -> SpineMid)
    np.testing.assert_allclose(got[~half], ref.frames[~half, 0], atol=1e-9)


def test_propagate_gives_the_same_frames_for_new_data(rom) -> None:  # type: ignore[no-untyped-def]
    seq, _ = rom
    norm = an.normalize(seq)
    frames, weight = propagate(norm, seq.kinect_positions()[500:600])
    np.testing.assert_allclose(frames, norm.frames[500:600], atol=1e-12)
    np.testing.assert_allclose(weight, norm.twist_weight[500:600])


def test_observable_dof_are_stated(rom) -> None:  # type: ignore[no-untyped-def]
    seq, _ = rom
    norm = an.normalize(seq)
    assert norm.observable["head"]["twist"] == "not observable"
    assert norm.observable["forearm_left"]["twist"] in ("observable", "when bent")
    assert norm.observable["thigh_left"]["swing_axes"] == 2
    assert norm.status["foot_left"] == "twist not observable from positions"


def _without(names_out: set[str]) -> an.SkeletonSequence:
    p = np.repeat(standing_pose()[None], 5, axis=0)
    all_names = an.SkeletonSequence.from_kinect(p, rate_hz=30).joint_names
    keep = [i for i, n in enumerate(all_names) if n not in names_out]
    names = [all_names[i] for i in keep]
    return an.SkeletonSequence.from_kinect(p[:, keep], rate_hz=30.0, joint_names=names)


def test_missing_body_joint_is_a_clear_error() -> None:
    # too little for the whole body and for either half: the error says what each needs
    seq = _without({"KneeLeft", "ShoulderLeft"})
    with pytest.raises(InputError, match="needs the body joints ShoulderLeft, KneeLeft") as e:
        an.normalize(seq)
    assert "upper-body-only input needs" in str(e.value)
    assert "(missing: ShoulderLeft)" in str(e.value)


def test_a_body_missing_a_leg_joint_is_normalized_as_an_upper_body() -> None:
    # the analysis then skips the legs with that reason (tests/test_partial_bodies.py)
    seq = _without({"KneeLeft"})
    assert an.normalize(seq) is not None


def test_a_default_frame_outside_the_sequence_is_a_clear_error() -> None:
    p = np.repeat(standing_pose()[None], 5, axis=0)
    with pytest.raises(InputError, match="default_frame must be a frame index"):
        an.normalize(an.SkeletonSequence.from_kinect(p, rate_hz=30.0), default_frame=9)
