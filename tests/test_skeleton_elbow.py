"""Issue 20: a skeleton's elbow flexion is its hinge angle. From joint centres the forearm's
frame takes its twist from the thumb beside the hand; with the standing frame level that twist
(pronation and supination) read as elbow flexion. A forearm that only pronates, the elbow held
bent, must read no flexion change; a forearm that flexes must read that flexion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse import biomech as an
from kinefuse.core.skeleton import JOINT_INDEX
from kinefuse.formats.motion import load_motion
from kinefuse.pipeline.analysis_chain import hinge_angle_deg, skeleton_anatomy

RATE = 30.0
STAND_S = 3.0
HAND = ("HandLeft", "HandTipLeft", "ThumbLeft")


def _rot(axis: np.ndarray, deg: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = np.radians(deg)
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * (k @ k)


def _turn(pose: np.ndarray, joints: tuple[str, ...], centre: str, rot: np.ndarray) -> None:
    c = pose[JOINT_INDEX[centre]].copy()
    for j in joints:
        pose[JOINT_INDEX[j]] = c + rot @ (pose[JOINT_INDEX[j]] - c)


@pytest.fixture(scope="module")
def standing(shared_data: Path) -> np.ndarray:
    """A real standing pose (CMU 02's default pose) with the left elbow bent 40°."""
    clip = load_motion(shared_data / "motion" / "cmu" / "02_walk_a.amc")
    pose = clip.positions[an.find_default_pose(an.SkeletonSequence.from_motion(clip))].copy()
    right = pose[JOINT_INDEX["HipRight"]] - pose[JOINT_INDEX["HipLeft"]]
    _turn(pose, ("WristLeft", *HAND), "ElbowLeft", _rot(right, 40.0))  # forearm forward
    return pose


def _sequence(pose: np.ndarray, forearm: str, amplitude_deg: float) -> an.SkeletonSequence:
    """Stand still for STAND_S, then move the left forearm: ``"pronate"`` turns the hand about
    the forearm's long axis, ``"flex"`` bends the elbow further, by up to ``amplitude_deg``."""
    n = int(8.0 * RATE)
    t = np.arange(n) / RATE
    out = np.repeat(pose[None], n, axis=0)
    right = pose[JOINT_INDEX["HipRight"]] - pose[JOINT_INDEX["HipLeft"]]
    for i in np.flatnonzero(t > STAND_S):
        deg = amplitude_deg * np.sin(np.pi * (t[i] - STAND_S) / 2.5)
        if forearm == "pronate":
            axis = out[i, JOINT_INDEX["WristLeft"]] - out[i, JOINT_INDEX["ElbowLeft"]]
            _turn(out[i], HAND, "WristLeft", _rot(axis, deg))
        else:
            _turn(out[i], ("WristLeft", *HAND), "ElbowLeft", _rot(right, deg))
    return an.SkeletonSequence.from_kinect(out, t_s=t, source=f"elbow {forearm}")


def test_pronation_is_not_elbow_flexion(standing: np.ndarray) -> None:
    seq = _sequence(standing, "pronate", 70.0)
    angles, _ = skeleton_anatomy(seq, an.normalize(seq), (0.0, STAND_S))
    elbow = angles["elbow_flexion_left"]
    assert np.isfinite(elbow).all()
    assert np.abs(elbow).max() < 0.5  # the elbow never moved


def test_flexion_is_the_elbow_bending_from_the_standing_pose(standing: np.ndarray) -> None:
    seq = _sequence(standing, "flex", 50.0)
    angles, _ = skeleton_anatomy(seq, an.normalize(seq), (0.0, STAND_S))
    t = seq.t_s
    expected = np.where(t > STAND_S, 50.0 * np.sin(np.pi * (t - STAND_S) / 2.5), 0.0)
    np.testing.assert_allclose(angles["elbow_flexion_left"], expected, atol=0.5)
    # the geometry zero reads the elbow's own angle: as bent as it stands (over 40°), plus that
    stands = hinge_angle_deg(seq.kinect_positions()[:1], "ShoulderLeft", "ElbowLeft", "WristLeft")
    assert stands[0] > 40.0
    geo, _ = skeleton_anatomy(seq, an.normalize(seq), (0.0, STAND_S), zero="geometry")
    np.testing.assert_allclose(geo["elbow_flexion_left"], stands[0] + expected, atol=0.5)


def test_hinge_angle_is_nan_where_a_joint_is_missing(standing: np.ndarray) -> None:
    p = np.repeat(standing[None], 3, axis=0)
    p[1, JOINT_INDEX["WristLeft"]] = np.nan
    a = hinge_angle_deg(p, "ShoulderLeft", "ElbowLeft", "WristLeft")
    assert np.isnan(a[1]) and np.isfinite(a[[0, 2]]).all()
