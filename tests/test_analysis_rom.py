"""The range-of-motion generator: its truth is self-consistent, its schedule as documented."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse import biomech as an
from kinefuse.biomech.rom import MOVEMENTS, make_rom_motion, prepend_rom, standing_pose
from kinefuse.core.skeleton import JOINT_INDEX, bone_index_array
from kinefuse.errors import InputError
from kinefuse.formats.motion import facing_direction, load_motion


@pytest.fixture(scope="module")
def clip(shared_data):  # type: ignore[no-untyped-def]
    return load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh")


def test_rom_keeps_the_subject_and_its_schedule(clip) -> None:  # type: ignore[no-untyped-def]
    d = an.find_default_pose(an.SkeletonSequence.from_motion(clip))
    pose = clip.positions[d]
    motion, truth = make_rom_motion(pose, 90.0, np.random.default_rng(1), rate_hz=30.0)
    assert motion.duration_s == pytest.approx(90.0, abs=0.1)
    assert [(m[0], m[1]) for m in truth.movements] == [
        (lb, str(dof)) for lb, dof, _, _ in MOVEMENTS
    ]
    starts = [m[2] for m in truth.movements]
    assert starts == sorted(starts)
    # bone lengths are the subject's throughout (rigid limbs)
    for lb in an.LIMBS:
        ln = np.linalg.norm(
            motion.positions[:, lb.distal_index] - motion.positions[:, lb.proximal_index], axis=-1
        )
        ref = np.linalg.norm(pose[lb.distal_index] - pose[lb.proximal_index])
        np.testing.assert_allclose(ln, ref, atol=1e-9, err_msg=lb.name)
    # true axes are unit, orthogonal to the rest direction, within the tilt of the templates
    for name, a in truth.axes.items():
        np.testing.assert_allclose(np.linalg.norm(a, axis=-1), 1.0, atol=1e-12)
        np.testing.assert_allclose(a @ truth.rest[name], 0.0, atol=1e-9)


def test_speeds_are_realistic(clip) -> None:  # type: ignore[no-untyped-def]
    _motion, truth = make_rom_motion(
        clip.positions[0], None, np.random.default_rng(2), rate_hz=60.0
    )
    for limb, ang in truth.angles.items():
        if ang.shape[1]:
            peak = np.degrees(np.abs(np.diff(ang, axis=0)).max()) * 60.0
            assert 20.0 < peak < 200.0, limb  # degrees per second


def test_prepend_blends_into_the_clip(clip) -> None:  # type: ignore[no-untyped-def]
    rom, _ = make_rom_motion(clip.positions[0], None, np.random.default_rng(3))
    both = prepend_rom(rom, clip, blend_s=1.0)
    n_rom = int(np.floor(rom.duration_s * clip.rate_hz)) + 1
    n_blend = int(clip.rate_hz)
    assert both.n_frames == n_rom + n_blend + clip.n_frames
    np.testing.assert_allclose(both.positions[-clip.n_frames :], clip.positions)
    seams = both.positions[n_rom - 5 : n_rom + n_blend + 5]
    step = np.linalg.norm(np.diff(seams, axis=0), axis=-1).max()
    assert step < 0.03  # metres per frame at 120 Hz (3.6 m/s): no jump at the seams


def test_bad_input(clip) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(InputError, match="default_pose must be the 25 Kinect joints"):
        make_rom_motion(np.zeros((24, 3)))
    with pytest.raises(InputError, match="would move limbs at"):
        make_rom_motion(clip.positions[0], 5.0)


def test_standing_pose_is_upright_on_the_same_body(clip) -> None:  # type: ignore[no-untyped-def]
    """A static trial's stance from a pose mid-stride (this clip's default pose has both knees
    near 40°): legs straight below the hips, arms hanging, every bone and the trunk kept."""
    pose = clip.positions[an.find_default_pose(an.SkeletonSequence.from_motion(clip))]
    got = standing_pose(pose)
    j = JOINT_INDEX
    bones = bone_index_array()
    length = lambda p: np.linalg.norm(p[bones[:, 1]] - p[bones[:, 0]], axis=-1)  # noqa: E731
    np.testing.assert_allclose(length(got), length(pose), atol=1e-9)
    trunk = [j[n] for n in ("SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head",
                            "HipLeft", "HipRight", "ShoulderLeft", "ShoulderRight")]  # fmt: skip
    lift = got[trunk] - pose[trunk]
    np.testing.assert_allclose(lift[:, :2], 0.0, atol=1e-12)  # the trunk only rises, rigidly
    np.testing.assert_allclose(lift[:, 2], lift[0, 2], atol=1e-12)
    assert lift[0, 2] > 0.01  # straightened legs are longer than bent ones
    fwd = facing_direction(pose)
    for s in ("Left", "Right"):
        for a, b in (("Hip", "Knee"), ("Knee", "Ankle"), ("Shoulder", "Wrist")):
            v = got[j[f"{b}{s}"]] - got[j[f"{a}{s}"]]
            np.testing.assert_allclose(v[:2], 0.0, atol=1e-9, err_msg=f"{a}-{b} {s}")
            assert v[2] < 0
        foot = got[j[f"Foot{s}"]] - got[j[f"Ankle{s}"]]
        assert foot[:2] @ fwd[:2] > 0.8 * np.linalg.norm(foot[:2])  # the foot points ahead
    feet = [j[f"{n}{s}"] for n in ("Ankle", "Foot") for s in ("Left", "Right")]
    assert got[feet, 2].min() == pytest.approx(pose[feet, 2].min(), abs=1e-12)
    with pytest.raises(InputError, match="25 finite Kinect joints"):
        standing_pose(np.where(np.arange(25)[:, None] == 3, np.nan, pose))
