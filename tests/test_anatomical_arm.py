"""Issue 20 item 3: the shoulder and elbow anatomical angles (ISB 2005: elevation plane,
elevation, axial rotation; the JCS flexion, adduction, internal rotation; elbow flexion) on a
synthetic arm whose angles are known, both sides, with their documented signs and zeros
(kinefuse.biomech.anatomical.ANATOMICAL_ANGLES; docs/analysis.md)."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.biomech.anatomical import anatomical_angles, frame_from_long_axis, shoulder_yxy

X, Y, Z = np.eye(3)  # ISB trunk frame = the world here: X anterior, Y up, Z right
TRUNK = np.eye(3)[None]


def arm(side: str, humerus_y: np.ndarray, forearm_y: np.ndarray, hint: np.ndarray) -> dict:
    """The angles of an arm whose humerus runs along ``humerus_y`` (elbow -> shoulder) and
    forearm along ``forearm_y`` (wrist -> elbow), both frames' Z from ``hint``."""
    frames = {
        "trunk": TRUNK,
        f"upper_arm_{side}": frame_from_long_axis(humerus_y, hint)[None],
        f"forearm_{side}": frame_from_long_axis(forearm_y, hint)[None],
    }
    return {k: float(v[0]) for k, v in anatomical_angles(frames).items()}


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("side", ["right", "left"])
def test_hanging_arm_is_the_zero(side: str) -> None:
    a = arm(side, Y, Y, Z)
    for k in ("shoulder_flexion", "shoulder_adduction", "shoulder_internal_rotation",
              "elbow_flexion", "shoulder_elevation"):  # fmt: skip
        assert a[f"{k}_{side}"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("deg", [30.0, 90.0, 150.0])
def test_forward_flexion(side: str, deg: float) -> None:
    # the elbow moves forward (anterior) and up: the humerus's Y turns from up towards back
    t = np.radians(deg)
    a = arm(side, unit(np.cos(t) * Y - np.sin(t) * X), unit(np.cos(t) * Y - np.sin(t) * X), Z)
    assert a[f"shoulder_flexion_{side}"] == pytest.approx(deg, abs=1e-6)
    assert a[f"shoulder_adduction_{side}"] == pytest.approx(0.0, abs=1e-6)
    assert a[f"shoulder_elevation_plane_{side}"] == pytest.approx(90.0, abs=1e-6)
    assert a[f"shoulder_elevation_{side}"] == pytest.approx(deg, abs=1e-6)
    assert a[f"elbow_flexion_{side}"] == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize("deg", [20.0, 60.0, 90.0])
def test_abduction_reads_negative_adduction_and_plane_zero(side: str, deg: float) -> None:
    s = 1.0 if side == "right" else -1.0  # lateral is +Z on the right, -Z on the left
    t = np.radians(deg)
    y = unit(np.cos(t) * Y - s * np.sin(t) * Z)  # the elbow goes out to the side
    a = arm(side, y, y, unit(np.cross(X, y)))  # Z in the frontal plane, X stays anterior
    assert a[f"shoulder_adduction_{side}"] == pytest.approx(-deg, abs=1e-6)
    assert a[f"shoulder_flexion_{side}"] == pytest.approx(0.0, abs=1e-6)
    assert a[f"shoulder_elevation_plane_{side}"] == pytest.approx(0.0, abs=1e-6)
    assert a[f"shoulder_elevation_{side}"] == pytest.approx(deg, abs=1e-6)


@pytest.mark.parametrize("side", ["right", "left"])
@pytest.mark.parametrize(("rot", "flex"), [(30.0, 90.0), (-20.0, 60.0), (0.0, 120.0)])
def test_internal_rotation_and_elbow_flexion(side: str, rot: float, flex: float) -> None:
    # arm hanging, elbow flexed, humerus turned internally: the hand moves medially
    s = 1.0 if side == "right" else -1.0
    r = np.radians(rot)
    front = unit(np.cos(r) * X - s * np.sin(r) * Z)  # the humerus's anterior axis
    hint = np.cross(front, Y)  # makes the humerus's X = front
    f = np.radians(flex)
    forearm_dir = unit(-np.cos(f) * Y + np.sin(f) * front)  # elbow -> wrist
    frames = {
        "trunk": TRUNK,
        f"upper_arm_{side}": frame_from_long_axis(Y, hint)[None],
        f"forearm_{side}": frame_from_long_axis(-forearm_dir, hint)[None],
    }
    a = {k: float(v[0]) for k, v in anatomical_angles(frames).items()}
    assert a[f"shoulder_internal_rotation_{side}"] == pytest.approx(rot, abs=1e-6)
    assert a[f"elbow_flexion_{side}"] == pytest.approx(flex, abs=1e-6)
    assert a[f"shoulder_elevation_{side}"] == pytest.approx(0.0, abs=1e-6)


def test_yxy_recovers_known_elevation_plane_and_rotation() -> None:
    """A humerus built as Ry(plane) Rx(-elevation) Ry(rotation) (Wu et al. 2005) reads back
    those three, on the right and (mirrored) on the left."""

    def ry(a: float) -> np.ndarray:
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])

    def rx(a: float) -> np.ndarray:
        c, s = np.cos(a), np.sin(a)
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    m = np.diag([1.0, 1.0, -1.0])
    for plane, elev, rot in [(0.0, 45.0, 10.0), (90.0, 90.0, -30.0), (45.0, 120.0, 25.0),
                             (-30.0, 30.0, 0.0)]:  # fmt: skip
        h = ry(np.radians(plane)) @ rx(-np.radians(elev)) @ ry(np.radians(rot))
        for right, frame in ((True, h), (False, m @ h @ m)):
            p, e, r = shoulder_yxy(TRUNK, frame[None], right)
            assert (float(p[0]), float(e[0]), float(r[0])) == pytest.approx((plane, elev, rot),
                                                                            abs=1e-6)  # fmt: skip
