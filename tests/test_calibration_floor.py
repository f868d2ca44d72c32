"""The floor plane (gravity and height) from one simulated depth frame."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.capture.calibration.floor import FloorPlane, fit_floor_plane
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import invert_transform, look_at
from kinefuse.errors import CalibrationError, InputError
from kinefuse.sim.depth import DepthNoiseParams, Scene, render_depth

INTR = Intrinsics()
NO_OFFSET = DepthNoiseParams(
    offset_at_1m_mm=0.0, offset_slope_mm_per_m=0.0, wiggle_amplitude_mm=0.0, multipath_max_mm=0.0
)


def _true_floor(s2w: np.ndarray) -> tuple[np.ndarray, float]:
    """Up direction in the sensor frame and the sensor's height."""
    return invert_transform(s2w)[:3, :3] @ np.array([0.0, 0.0, 1.0]), float(s2w[2, 3])


@pytest.mark.parametrize(
    ("position", "target", "roll_deg"),
    [
        ([0.0, -3.0, 1.1], [0.0, 0.0, 1.1], 0.0),  # level
        ([2.5, -1.0, 2.2], [0.0, 0.0, 0.9], 5.0),  # pitched down ~27 deg, rolled
        ([-2.0, 2.0, 0.6], [0.0, 0.0, 1.2], -5.0),  # pitched up ~12 deg, rolled
    ],
)
def test_floor_normal_and_height(
    position: list[float], target: list[float], roll_deg: float
) -> None:
    rng = np.random.default_rng(51)
    s2w = look_at(position, target, roll_rad=np.radians(roll_deg))
    up, height = _true_floor(s2w)
    fl = fit_floor_plane(render_depth(Scene(), s2w, INTR, rng, NO_OFFSET), INTR)
    angle = np.degrees(np.arccos(np.clip(fl.normal @ up, -1.0, 1.0)))
    assert angle < 0.1  # deg
    assert abs(fl.offset_m - height) < 0.003  # 3 mm
    assert fl.n_inliers > 1000
    assert fl.residual_m < 0.02
    # the full error model (systematic range offset, multipath at the walls) costs little
    fl = fit_floor_plane(render_depth(Scene(), s2w, INTR, rng), INTR)
    assert np.degrees(np.arccos(np.clip(fl.normal @ up, -1.0, 1.0))) < 0.3  # deg
    assert abs(fl.offset_m - height) < 0.015  # 15 mm


def test_floor_is_found_with_a_person_in_front() -> None:
    rng = np.random.default_rng(52)
    s2w = look_at([0.0, -3.0, 1.2], [0.0, 0.0, 0.9])
    a = np.array([[0.0, -1.5, 0.1], [0.0, -1.5, 1.0]])
    b = np.array([[0.0, -1.5, 1.0], [0.0, -1.5, 1.6]])
    person = Scene(a=a, b=b, radius=np.array([0.15, 0.15]))
    up, height = _true_floor(s2w)
    fl = fit_floor_plane(render_depth(person, s2w, INTR, rng, NO_OFFSET), INTR)
    assert np.degrees(np.arccos(fl.normal @ up)) < 0.1
    assert abs(fl.offset_m - height) < 0.003  # 3 mm
    np.testing.assert_allclose(fl.distance(np.zeros(3)), fl.offset_m)


def test_no_floor_in_view_is_a_clear_error() -> None:
    rng = np.random.default_rng(53)
    up_looking = look_at([0.0, -2.0, 1.0], [0.0, 0.0, 2.8])  # pitched up 42 deg: walls only
    with pytest.raises(CalibrationError, match=r"k3: .*no floor visible"):
        fit_floor_plane(render_depth(Scene(), up_looking, INTR, rng), INTR, name="k3")
    with pytest.raises(CalibrationError, match="only 0 valid depth samples"):
        fit_floor_plane(np.zeros((424, 512), dtype=np.uint16), INTR)


def test_floor_bad_inputs() -> None:
    d = np.full((424, 512), np.nan)
    with pytest.raises(InputError, match="sensor k1 contains 217088 NaN"):
        fit_floor_plane(d, INTR, name="sensor k1")
    with pytest.raises(InputError, match=r"shape \(10, 10\)"):
        fit_floor_plane(np.zeros((10, 10)), INTR)
    with pytest.raises(CalibrationError, match="finite non-zero 3-vector"):
        FloorPlane(np.zeros(3), 1.0)
    with pytest.raises(CalibrationError, match="offset must be finite"):
        FloorPlane(np.array([0.0, -1.0, 0.0]), float("nan"))
    fl = FloorPlane(np.array([0.0, -2.0, 0.0]), 1.0)
    np.testing.assert_allclose(fl.normal, [0.0, -1.0, 0.0])  # normalized
