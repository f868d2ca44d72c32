"""Plausibility flags: poses outside the calibrated ranges, off the learned axes, stretched."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse import biomech as an
from kinefuse.biomech.angle_plausibility import LENGTH, OFF_AXIS, RANGE
from kinefuse.biomech.rom import make_rom_motion
from kinefuse.formats.motion import load_motion


@pytest.fixture(scope="module")
def calibrated(shared_data):  # type: ignore[no-untyped-def]
    clip = load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh")
    d = an.find_default_pose(an.SkeletonSequence.from_motion(clip))
    motion, _ = make_rom_motion(clip.positions[d], None, np.random.default_rng(4), rate_hz=30.0)
    seq = an.SkeletonSequence.from_motion(motion)
    norm = an.normalize(seq)
    return seq, norm, an.learn_axes(seq, norm)


def _stretched(seq, frames, factor: float):  # type: ignore[no-untyped-def]
    """The take with the right shank ``factor`` times its length in ``frames``."""
    p = seq.positions.copy()
    kr, ar = seq.index("KneeRight"), seq.index("AnkleRight")
    p[frames, ar] = p[frames, kr] + factor * (p[frames, ar] - p[frames, kr])
    return an.SkeletonSequence.from_kinect(p, t_s=seq.t_s)


def test_the_calibration_itself_is_plausible(calibrated) -> None:  # type: ignore[no-untyped-def]
    seq, norm, model = calibrated
    flags = an.plausibility(an.joint_angles(seq, norm, model), model)
    assert flags.flags.mean() < 0.01  # 0 of 4902 frames measured
    assert (flags.flags == (flags.reasons != 0)).all()
    # the flagger is not blind: the same take with 5 stretched frames flags them, and only them
    s = np.arange(1000, 1005)
    broken = an.plausibility(an.joint_angles(_stretched(seq, s, 1.5), norm, model), model)
    li = an.LIMB_NAMES.index("shank_right")
    assert broken.flags[s, li].all()
    new = broken.flags & ~flags.flags
    assert set(np.flatnonzero(new.any(axis=1))) == set(s.tolist())


@pytest.mark.parametrize(
    ("factor", "tolerance", "flagged"),
    [(1.13, 0.15, False), (1.17, 0.15, True), (0.87, 0.15, False), (0.83, 0.15, True),
     (1.13, 0.10, True), (1.17, 0.20, False)],
)  # fmt: skip
def test_a_length_is_flagged_beyond_the_tolerance_and_only_for_length(
    calibrated, factor: float, tolerance: float, flagged: bool
) -> None:  # type: ignore[no-untyped-def]
    """The shank's length off by more than ``length_tolerance`` (15 %), longer or shorter, is
    flagged LENGTH (and nothing else: its direction is unchanged); within it, not at all."""
    seq, norm, model = calibrated
    s = np.arange(600, 610)
    bad = _stretched(seq, s, factor)
    flags = an.plausibility(an.joint_angles(bad, norm, model), model, length_tolerance=tolerance)
    li = an.LIMB_NAMES.index("shank_right")
    assert (flags.reasons[s, li] == (LENGTH if flagged else 0)).all()
    assert flags.flags[s, li].all() == flagged


def test_broken_poses_are_flagged(calibrated) -> None:  # type: ignore[no-untyped-def]
    seq, norm, model = calibrated
    p = seq.positions.copy()
    k, a, h = (seq.index(n) for n in ("KneeLeft", "AnkleLeft", "HipLeft"))
    f = np.arange(200, 230)
    thigh = p[f, k] - p[f, h]
    thigh /= np.linalg.norm(thigh, axis=-1, keepdims=True)
    forward = norm.body2world[:, 0]
    p[f, a] = p[f, k] + 0.3 * (1.2 * forward - thigh)  # the knee bent the wrong way
    g = np.arange(400, 420)
    p[g, seq.index("WristRight")] += 0.12 * norm.body2world[:, 1]  # the elbow bent sideways
    s = np.arange(600, 610)
    kr, ar = seq.index("KneeRight"), seq.index("AnkleRight")
    p[s, ar] = p[s, kr] + 1.6 * (p[s, ar] - p[s, kr])  # the shank stretched by 60 %
    bad = an.SkeletonSequence.from_kinect(p, t_s=seq.t_s)
    flags = an.plausibility(an.joint_angles(bad, norm, model), model)
    li = {n: i for i, n in enumerate(an.LIMB_NAMES)}
    assert (flags.reasons[f, li["shank_left"]] & (RANGE | OFF_AXIS)).all()
    assert not (flags.reasons[f, li["shank_left"]] & LENGTH).any()  # bent, not stretched
    assert (flags.reasons[g, li["forearm_right"]] & OFF_AXIS).all()
    assert (flags.reasons[s, li["shank_right"]] == LENGTH).all()  # stretched along its axis
    joint = flags.joint_flags()
    assert joint[f, seq.index("AnkleLeft")].all()
    assert joint[g, seq.index("WristRight")].all() and joint[s, seq.index("AnkleRight")].all()
    # exactly the broken frames, and in each only the broken limb and the limb hanging from it
    by_window = {
        "f": (f, {"shank_left", "foot_left"}),
        "g": (g, {"forearm_right"}),
        "s": (s, {"shank_right", "foot_right"}),
    }
    for name, (frames, limbs) in by_window.items():
        got = {an.LIMB_NAMES[j] for j in np.flatnonzero(flags.flags[frames].any(axis=0))}
        assert got <= limbs and got & {"shank_left", "forearm_right", "shank_right"}, name
    assert set(np.flatnonzero(flags.flags.any(axis=1))) == set(np.concatenate([f, g, s]).tolist())
