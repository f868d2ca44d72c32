"""How much worse a sensor measures a joint because of where it sees the body from.

The Kinect v2 tracker is trained on frontal views. Seen from the side it places the trunk, hips
and head worse (the real 90-degree take Study_1: head 9.5 cm, hips 7.3 cm disagreement between
the two sensors, against about half of that at 45 degrees) and the limbs on the far side of the
body worse than the near ones (far arm 10 cm against 5 cm); ``docs/error_model_tracker.md`` and
``docs/realism.md`` give the sources. :func:`view_variance` turns this into extra isotropic
measurement variance per frame, sensor and joint, added by
:func:`kinefuse.fusion.model.world_measurements`:

- a **view term** ``(sigma_view * |sin v|^p)^2`` for the trunk, head, shoulders and hips
  (:data:`VIEW_JOINTS`), ``v`` the angle between the body's facing as the sensor's own
  skeleton reports it (:func:`kinefuse.fusion.model.facing`) and the horizontal direction
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

from kinefuse.skeleton import JOINT_INDEX, N_JOINTS

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


def _horizontal_unit(v: Array) -> Array:
    n = np.sqrt(v[..., 0] ** 2 + v[..., 1] ** 2)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(n > 1e-9, v / n, np.nan)
    u[..., 2] = 0.0
    return u


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
    centre : (T, S, 3) float
        The trunk centre (mean of SpineBase and SpineShoulder, either alone if one is missing).
    lr : (T, S, 3) float
        Horizontal unit left-right axis (pointing to the reported left), NaN when none.
    """
    lr = _horizontal_unit(
        (z[..., _HIP_L, :] - z[..., _HIP_R, :]) + (z[..., _SH_L, :] - z[..., _SH_R, :])
    )
    a, b = z[..., _SB, :], z[..., _SS, :]
    fa = np.isfinite(a).all(-1, keepdims=True)
    fb = np.isfinite(b).all(-1, keepdims=True)
    with np.errstate(invalid="ignore"):
        centre = np.where(fa & fb, 0.5 * (a + b), np.where(fa, a, b))
    d = _horizontal_unit(sensor_pos - centre)
    # facing = (lr_y, -lr_x): sin(facing -> d) = facing x d (z) = lr . d
    sin_v = lr[..., 0] * d[..., 0] + lr[..., 1] * d[..., 1]
    return sin_v, centre, lr


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
    sin_v, centre, lr = side_view(z, sensor_pos)
    s = np.abs(np.nan_to_num(sin_v, nan=1.0))
    sd = view_sigma_m * s**view_exponent
    extra = np.broadcast_to((sd * sd)[..., None] * _VIEW_MASK, z.shape[:-1])
    if far_sigma_m <= 0.0:
        return np.array(extra)
    rel = z - centre[..., None, :]
    lat = rel[..., 0] * lr[..., None, 0] + rel[..., 1] * lr[..., None, 1]  # (T, S, 25), + left
    side = np.clip(np.nan_to_num(lat) / SIDE_SCALE_M, -1.0, 1.0)
    far = np.clip(-side * np.nan_to_num(sin_v)[..., None], 0.0, 1.0)
    fd = far_sigma_m * far**far_exponent
    return extra + fd * fd
