"""How much worse a sensor measures a joint because of where it sees the body from.

The Kinect v2 tracker is trained on frontal views. Seen from the side it places the trunk, hips
and head worse (the real 90-degree take Study_1: head 9.5 cm, hips 7.3 cm disagreement between
the two sensors, against about half of that at 45 degrees) and the limbs on the far side of the
body worse than the near ones (far arm 10 cm against 5 cm); ``docs/error_model_tracker.md`` and
``docs/realism.md`` give the sources. :func:`view_variance` turns this into extra isotropic
measurement variance per frame, sensor and joint, added by
:func:`kinefuse.capture.fusion.model.world_measurements`:

- a **view term** ``(sigma_view * |sin v|^p)^2`` for the trunk, head, shoulders and hips
  (:data:`VIEW_JOINTS`), ``v`` the angle between the body's facing as the sensor's own
  skeleton reports it (:func:`kinefuse.capture.fusion.model.facing`) and the horizontal direction
  from the body (its trunk) to the sensor: zero seen from the front or the back,
  ``sigma_view^2`` straight from the side;
- a **far-side term** ``(sigma_far * far^q)^2``, ``far`` in [0, 1] how far a joint lies on the
  side of the body away from the sensor: its lateral offset from the trunk along the body's
  left-right axis (in units of :data:`SIDE_SCALE_M`, clipped to [-1, 1]) times ``-sin v``.

Both come from the sensor's own skeleton of the same frame only: causal, no truth, and the
same for a mirrored (left/right swapped) skeleton (the facing and the left-right axis flip
together, ``|sin v|`` and the far-ness do not change), so they do not depend on the swap
correction that runs later. Element-wise arithmetic only, so a frame gets the same bits alone
and in a batch (the replay/push identity of ``best-live``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS

Array = NDArray[np.float64]

_SB, _SS = JOINT_INDEX["SpineBase"], JOINT_INDEX["SpineShoulder"]
_HIP_L, _HIP_R = JOINT_INDEX["HipLeft"], JOINT_INDEX["HipRight"]
_SH_L, _SH_R = JOINT_INDEX["ShoulderLeft"], JOINT_INDEX["ShoulderRight"]
#: lateral offset from the trunk (m) at which a joint counts fully as on one side of the body
#: (about half an adult's hip width; the shoulders and the limbs lie beyond it)
SIDE_SCALE_M = 0.1
#: the joints the view term applies to: the trunk, head, shoulders and hips, whose placement the
#: real side view gets worst (the 88-degree take Study_1 against the 1-degree one, per-joint
#: median disagreement: spine base 7.8 / 2.1 cm, spine mid 5.8 / 1.5, neck 4.0 / 1.3, head
#: 9.5 / 2.6, shoulder 10.3 / 2.2; docs/realism.md). The limbs get the far-side term instead: a
#: side view sees the near limbs' swing across its rays, where it measures best
VIEW_JOINTS = ("SpineBase", "SpineMid", "SpineShoulder", "Neck", "Head", "ShoulderLeft",
               "ShoulderRight", "HipLeft", "HipRight")  # fmt: skip
_VIEW_MASK = np.zeros(N_JOINTS)
_VIEW_MASK[[JOINT_INDEX[n] for n in VIEW_JOINTS]] = 1.0


def _geometry(z: Array, sensor_pos: Array) -> tuple[Array, Array, Array, Array]:
    """``sin v (T, S)``, trunk centre ``(T, S, 2)`` and unit left-right axis ``x, y (T, S)``
    (horizontal components only; call under ``np.errstate``: NaN where undefined)."""
    zx, zy = z[..., 0], z[..., 1]
    lx = (zx[..., _HIP_L] - zx[..., _HIP_R]) + (zx[..., _SH_L] - zx[..., _SH_R])
    ly = (zy[..., _HIP_L] - zy[..., _HIP_R]) + (zy[..., _SH_L] - zy[..., _SH_R])
    nl = np.sqrt(lx * lx + ly * ly)
    inv = np.where(nl > 1e-6, 1.0 / nl, np.nan)
    ux, uy = lx * inv, ly * inv
    a, b = z[..., _SB, :2], z[..., _SS, :2]
    c = 0.5 * (a + b)
    c = np.where(np.isnan(c), np.fmax(a, b), c)  # either one alone if the other is missing
    dx = sensor_pos[:, 0] - c[..., 0]
    dy = sensor_pos[:, 1] - c[..., 1]
    # facing = (u_y, -u_x): sin(facing -> d) = facing x d (z) = u . d
    sin_v = (ux * dx + uy * dy) / np.sqrt(dx * dx + dy * dy)
    return sin_v, c, ux, uy


def side_view(z: Array, sensor_pos: Array) -> tuple[Array, Array, Array]:
    """The view geometry of each sensor's skeleton.

    Parameters
    ----------
    z : (T, S, 25, 3) float
        Each sensor's joints in the world (z up), NaN = none.
    sensor_pos : (S, 3) float
        The sensors' positions in the world.

    Returns
    -------
    sin_view : (T, S) float
        ``sin`` of the angle from the reported facing to the horizontal direction body ->
        sensor (positive: the sensor on the body's left as reported), NaN when the skeleton
        has no facing or no trunk.
    centre : (T, S, 2) float
        Horizontal position of the trunk centre (mean of SpineBase and SpineShoulder, either
        alone if one is missing).
    lr : (T, S, 2) float
        Horizontal unit left-right axis (pointing to the reported left), NaN when none.
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        sin_v, c, ux, uy = _geometry(z, sensor_pos)
    return sin_v, c, np.stack([ux, uy], axis=-1)


def view_variance(
    z: Array,
    sensor_pos: Array,
    view_sigma_m: float,
    view_exponent: float,
    far_sigma_m: float = 0.0,
    far_exponent: float = 2.0,
) -> Array:
    """Extra isotropic measurement variance ``(T, S, 25)`` (m^2) from the view (module docstring).

    Parameters
    ----------
    z : (T, S, 25, 3) float
        Each sensor's joints in the world, NaN = none.
    sensor_pos : (S, 3) float
        The sensors' positions in the world (m).
    view_sigma_m : float
        Standard deviation (m) added to each of :data:`VIEW_JOINTS` seen straight from the side.
    view_exponent : float
        Its growth with the side view, ``|sin v|^view_exponent``.
    far_sigma_m : float
        Standard deviation (m) added to a joint fully on the far side seen from the side.
    far_exponent : float
        Its growth with the far-ness, ``far^far_exponent``.

    A skeleton without a facing or a trunk counts as seen from the side (the worst case).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        sin_v, c, ux, uy = _geometry(z, sensor_pos)
        s = np.abs(sin_v)
        s = np.where(np.isnan(s), 1.0, s)
        sd = view_sigma_m * s**view_exponent
        extra = (sd * sd)[..., None] * _VIEW_MASK
        if far_sigma_m <= 0.0:
            return extra
        lat = (z[..., 0] - c[..., 0, None]) * ux[..., None] + (z[..., 1] - c[..., 1, None]) * uy[
            ..., None
        ]  # (T, S, 25), + left
        side = np.minimum(np.maximum(lat * (1.0 / SIDE_SCALE_M), -1.0), 1.0)
        p = -side * sin_v[..., None]
        far = np.where(p > 0.0, p, 0.0)  # NaN (no joint, no facing): 0
        fd = far_sigma_m * far**far_exponent
        return extra + fd * fd
