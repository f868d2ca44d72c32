"""Anatomical names and ISB signs: the mapping from learned axes to names, checked on motion."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse import biomech as an
from kinefuse.biomech import anatomy
from kinefuse.biomech.rom import make_rom_motion
from kinefuse.core.geometry.rotations import rodrigues
from kinefuse.formats.motion import load_motion


@pytest.fixture(scope="module")
def analysed(shared_data):  # type: ignore[no-untyped-def]
    clip = load_motion(shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh")
    d = an.find_default_pose(an.SkeletonSequence.from_motion(clip))
    motion, truth = make_rom_motion(clip.positions[d], None, np.random.default_rng(5), rate_hz=30.0)
    seq = an.SkeletonSequence.from_motion(motion)
    norm = an.normalize(seq)
    model = an.learn_axes(seq, norm)
    return seq, truth, an.joint_angles(seq, norm, model).anatomical()


def test_assign_axes_orders_signs_and_names(rng) -> None:
    tpl = anatomy.templates("thigh_right")
    a = np.stack([v for _, v in tpl])
    tilt = rodrigues(np.array([0.3, 0.2, 0.93]) / np.linalg.norm([0.3, 0.2, 0.93]), 0.15)
    learned = -(a @ tilt.T)[::-1]  # swapped, flipped, tilted by 8.6°
    axes, names, dev, idx = anatomy.assign_axes("thigh_right", learned)
    assert names == ("hip_flexion_right", "hip_adduction_right")
    assert idx == (0, 1)
    assert (np.einsum("ki,ki->k", axes, a) > 0).all()
    assert np.degrees(dev).max() < 9.0


def test_extra_axis_gets_a_generic_name() -> None:
    learned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    _, names, _, idx = anatomy.assign_axes("shank_left", learned)
    assert names == ("knee_flexion_left", "shank_left_axis1")
    assert idx == (0, -1)


def _during(truth, seq, limb: str, dof: str):  # type: ignore[no-untyped-def]
    spans = [(a, b) for lb, d, a, b in truth.movements if (lb, d) == (limb, dof)]
    a, b = spans[0]
    return (seq.t_s >= a) & (seq.t_s <= b)


@pytest.mark.parametrize(
    ("name", "limb", "dof", "peak_deg"),
    [
        ("hip_flexion_left", "thigh_left", "0", 70.0),
        ("hip_adduction_right", "thigh_right", "1", 15.0),
        ("knee_flexion_right", "shank_right", "0", 100.0),
        ("ankle_dorsiflexion_left", "foot_left", "0", 20.0),
        ("shoulder_flexion_left", "upper_arm_left", "0", 110.0),
        ("shoulder_abduction_right", "upper_arm_right", "1", 100.0),
        ("elbow_flexion_left", "forearm_left", "0", 120.0),
        ("trunk_flexion", "trunk", "0", 40.0),
        ("trunk_lateral_bend", "trunk", "1", 25.0),
        ("shoulder_rotation_left", "upper_arm_left", "twist", 45.0),
        ("hip_rotation_right", "thigh_right", "twist", 30.0),
        ("forearm_pronation_right", "forearm_right", "twist", 60.0),
        ("trunk_rotation", "trunk", "twist", 30.0),
    ],
)
def test_positive_is_the_isb_direction(analysed, name, limb, dof, peak_deg) -> None:  # type: ignore[no-untyped-def]
    seq, truth, deg = analysed
    during = _during(truth, seq, limb, dof)
    # the generator moves to +amplitude first, in the ISB-positive direction of each template
    assert np.nanmax(deg[name][during]) == pytest.approx(peak_deg, abs=3.0)  # degrees


def test_shoulder_elevation_and_plane() -> None:
    d = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    elev, plane = anatomy.shoulder_elevation(d, "left")
    np.testing.assert_allclose(np.degrees(elev), [90, 90, 90, 0], atol=1e-9)
    np.testing.assert_allclose(np.degrees(plane[:3]), [90, 0, 180], atol=1e-9)
    assert np.isnan(plane[3])  # undefined with the arm hanging
    _, plane_r = anatomy.shoulder_elevation(d, "right")
    assert np.degrees(plane_r[2]) == pytest.approx(0.0)  # abduction of the right arm


def test_every_produced_name_is_listed(analysed) -> None:  # type: ignore[no-untyped-def]
    _, _, deg = analysed
    assert set(deg) <= set(anatomy.ANGLE_NAMES)
    assert {"knee_flexion_left", "hip_flexion_right", "forearm_pronation_left"} <= set(deg)
