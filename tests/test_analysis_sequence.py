"""The analysis input type: validation at the boundary, slicing, subsets of the Kinect joints."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.biomech import SkeletonSequence, kinect_parents
from kinefuse.core.skeleton import JOINTS, PARENTS, standing_pose
from kinefuse.errors import InputError


def _seq(t: int = 10) -> SkeletonSequence:
    return SkeletonSequence.from_kinect(np.repeat(standing_pose()[None], t, axis=0), rate_hz=30.0)


def test_full_kinect_topology_and_time_base() -> None:
    s = _seq(10)
    assert s.parents == PARENTS
    assert s.n_frames == 10 and s.n_joints == 25
    np.testing.assert_allclose(s.t_s, np.arange(10) / 30.0)
    assert s.index("KneeLeft") == JOINTS.index("KneeLeft")


def test_nan_positions_are_masked_and_masked_positions_are_nan() -> None:
    p = np.repeat(standing_pose()[None], 4, axis=0)
    p[1, 5] = np.nan
    mask = np.ones((4, 25), bool)
    mask[2, 7] = False
    s = SkeletonSequence.from_kinect(p, rate_hz=30.0, mask=mask)
    assert not s.mask[1, 5] and not s.mask[2, 7]
    assert np.isnan(s.positions[2, 7]).all()
    assert s.mask.sum() == 4 * 25 - 2


def test_subset_takes_nearest_present_ancestor() -> None:
    names = ["SpineBase", "SpineShoulder", "ShoulderLeft", "WristLeft"]
    assert kinect_parents(names) == (-1, 0, 1, 2)


def test_slice_and_take() -> None:
    s = _seq(30)
    part = s.slice(0.5, 0.6)
    assert part.n_frames == 4  # frames 15..18 at 30 Hz (0.5 .. 0.6 s)
    with pytest.raises(InputError, match="no frame in"):
        s.slice(5.0, 6.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"positions": np.zeros((3, 24, 3))}, "positions must have shape"),
        ({"t_s": np.array([0.0, 0.2, 0.1])}, "strictly increasing"),
        ({"parents": (-1,) * 25}, "one root"),
        ({"rate_hz": 0.0}, "rate_hz must be a positive"),
        ({"orientation_limbs": ("thigh_left",)}, "orientation_limbs given without"),
    ],
)
def test_bad_input_messages(kwargs: dict[str, object], message: str) -> None:
    base: dict[str, object] = {
        "positions": np.zeros((3, 25, 3)),
        "mask": np.ones((3, 25), bool),
        "joint_names": JOINTS,
        "parents": PARENTS,
        "t_s": np.arange(3) / 30.0,
        "rate_hz": 30.0,
    }
    base.update(kwargs)
    with pytest.raises(InputError, match=message):
        SkeletonSequence(**base)  # type: ignore[arg-type]


def test_unknown_joint_name_is_named() -> None:
    with pytest.raises(InputError, match="Elbow_L"):
        SkeletonSequence.from_kinect(np.zeros((2, 1, 3)), rate_hz=30.0, joint_names=["Elbow_L"])
