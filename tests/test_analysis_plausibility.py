"""Plausibility flags: poses outside the calibrated ranges, off the learned axes, stretched."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse import analysis as an
from kinefuse.analysis.plausibility import LENGTH, OFF_AXIS, RANGE
from kinefuse.analysis.rom import make_rom_motion
from kinefuse.motion import load_motion


@pytest.fixture(scope="module")
def calibrated(shared_data):  # type: ignore[no-untyped-def]
    clip = load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh")
    d = an.find_default_pose(an.SkeletonSequence.from_motion(clip))
    motion, _ = make_rom_motion(clip.positions[d], None, np.random.default_rng(4), rate_hz=30.0)
    seq = an.SkeletonSequence.from_motion(motion)
    norm = an.normalize(seq)
    return seq, norm, an.learn_axes(seq, norm)


def test_the_calibration_itself_is_plausible(calibrated) -> None:  # type: ignore[no-untyped-def]
    seq, norm, model = calibrated
    flags = an.plausibility(an.joint_angles(seq, norm, model), model)
    assert flags.flags.mean() < 0.01


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
    assert (flags.reasons[g, li["forearm_right"]] & OFF_AXIS).all()
    assert (flags.reasons[s, li["shank_right"]] & LENGTH).all()
    joint = flags.joint_flags()
    assert joint[f, seq.index("AnkleLeft")].all()
    assert not flags.flags[100:150].any()
