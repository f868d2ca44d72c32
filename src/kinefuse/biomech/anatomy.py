"""Anatomical names and signs of the learned angles (ISB, Wu et al. 2002 and 2005).

Every limb's learned movement axes are matched to *templates*: the anatomical axis each movement
is expected to turn about, given in the parent limb's normalized frame (x forward, y to the
subject's left, z up in the default pose, see :mod:`kinefuse.biomech.limbs`) and signed so that
the right-hand rotation about it is the positive ISB direction. A learned axis is assigned to the
template it is closest to (smallest angle, each template used once) and flipped to point the
same way, so the angle about it has the ISB sign. The first axis of a two-axis limb is the fixed
(proximal) axis of the joint coordinate system, the second the floating one: the limb direction
is ``p = R(axis0, angle0) R(axis1, angle1) rest``.

Sign conventions (angle 0 = the limb's rest position in the calibration phase):

============================  ======================================================  ==========
angle                         positive                                                 axis
============================  ======================================================  ==========
trunk_flexion                 trunk bends forward (relative to the pelvis)             +y
trunk_lateral_bend            bends to the subject's right                             +x
trunk_rotation                turns to the subject's left (seen from above: ccw)       long axis
head_flexion                  head bends forward (relative to the trunk)               +y
head_lateral_bend             bends to the right                                       +x
shoulder_flexion_S            arm swings forward                                       -y
shoulder_abduction_S          arm lifts sideways, away from the body                   ±x
shoulder_rotation_S           internal rotation                                        long axis
shoulder_elevation_S          ISB humerus elevation: angle of the arm from hanging     (direct)
shoulder_plane_S              ISB plane of elevation: 0 abduction, 90 forward flexion  (direct)
elbow_flexion_S               forearm bends toward the upper arm                       -y
forearm_pronation_S           pronation                                                long axis
hip_flexion_S                 thigh swings forward                                     -y
hip_adduction_S               thigh moves toward the midline                           ±x
hip_rotation_S                internal rotation                                        long axis
knee_flexion_S                shank bends backward                                     +y
knee_rotation_S               internal rotation of the shank (from the foot; mixes     long axis
                              tibial rotation and foot ab/adduction)
ankle_dorsiflexion_S          toes up (plantar flexion negative)                       -y
============================  ======================================================  ==========

``S`` is ``left`` or ``right``; ``±x`` is ``+x`` on the left and ``-x`` on the right (mirror).
Twists are about the limb's proximal-to-distal axis, negated on the right side for the rotations
that ISB defines per side (internal rotation, pronation), so that both sides read the same way.
The shoulder's elevation and plane of elevation are computed directly from the upper arm's
direction in the trunk frame (ISB's Y-X-Y sequence without the gimbal-prone third angle); the
plane is NaN below :data:`PLANE_MIN_ELEVATION_DEG` (10°) of elevation: it is the arm's
longitude about the hanging direction, undefined at it and ill-conditioned near it (a direction
error ``e`` moves it by ``e / sin(elevation)``: 5.8 e at 10°, 2.9 e at 20°; a hanging arm is
at 10-20° most of a walk, so the threshold stays where ISB's definition allows it).

Angles that small input errors would throw about are NaN rather than noise
(:attr:`~kinefuse.biomech.kinematics.Angles.undefined`): in gimbal lock (a limb within 20° of
its fixed axis, e.g. the arm abducted 70-110°) the angle about the fixed axis and the twist; for
a two-axis limb where its two representations are about equally near the rest (high elevations
between abduction 90° and overhead) all its angles; and a position-derived twist more uncertain
than 10° per frame throughout, with the limb's status saying so
(:data:`~kinefuse.biomech.normalize.TWIST_NOISE_MAX_DEG`).
"""

from __future__ import annotations

import itertools
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.geometry.rotations import unit

Array = NDArray[np.float64]

X, Y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
#: Below this elevation (degrees) the shoulder's plane of elevation is not defined (NaN).
PLANE_MIN_ELEVATION_DEG = 10.0


def _side_sign(limb: str) -> float:
    return -1.0 if limb.endswith("_right") else 1.0


def _templates(limb: str) -> tuple[tuple[str, Array], ...]:
    s = _side_sign(limb)
    side = limb.rsplit("_", 1)[-1]
    kind = limb.removesuffix("_left").removesuffix("_right")
    table: dict[str, tuple[tuple[str, Array], ...]] = {
        "trunk": (("trunk_flexion", Y), ("trunk_lateral_bend", X)),
        "head": (("head_flexion", Y), ("head_lateral_bend", X)),
        "upper_arm": ((f"shoulder_flexion_{side}", -Y), (f"shoulder_abduction_{side}", s * X)),
        "forearm": ((f"elbow_flexion_{side}", -Y),),
        "thigh": ((f"hip_flexion_{side}", -Y), (f"hip_adduction_{side}", -s * X)),
        "shank": ((f"knee_flexion_{side}", Y),),
        "foot": ((f"ankle_dorsiflexion_{side}", -Y),),
    }
    return table.get(kind, ())


#: Per limb: the twist's anatomical name and its sign relative to the proximal->distal axis.
def twist_name(limb: str) -> tuple[str, float] | None:
    """Name and sign of a limb's twist angle, or None if it has no anatomical name."""
    s = _side_sign(limb)
    side = limb.rsplit("_", 1)[-1]
    kind = limb.removesuffix("_left").removesuffix("_right")
    names = {
        "trunk": ("trunk_rotation", 1.0),
        "upper_arm": (f"shoulder_rotation_{side}", s),
        "forearm": (f"forearm_pronation_{side}", s),
        "thigh": (f"hip_rotation_{side}", s),
        "shank": (f"knee_rotation_{side}", s),
    }
    return names.get(kind)


def templates(limb: str) -> tuple[tuple[str, Array], ...]:
    """The anatomical (name, axis) templates of a limb, in JCS order (fixed axis first)."""
    return _templates(limb)


def assign_axes(limb: str, axes: Array) -> tuple[Array, tuple[str, ...], Array, tuple[int, ...]]:
    """Order, sign and name learned axes ``(k, 3)`` of ``limb`` by its templates.

    Returns
    -------
    axes : (k, 3) float
        The axes in template order (fixed axis first), each flipped to agree with its template.
    names : tuple of str
        The anatomical name of the angle about each axis.
    deviation_rad : (k,) float
        Angle between each axis and its template.
    template_index : tuple of int
        Which template each returned axis matched.
    """
    tpl = _templates(limb)
    a = unit(np.asarray(axes, dtype=np.float64).reshape(-1, 3))
    k = a.shape[0]
    if not tpl or k == 0:
        return a, tuple(f"{limb}_axis{i}" for i in range(k)), np.zeros(k), tuple(range(k))
    t = np.stack([v for _, v in tpl])
    cos = np.abs(a @ t.T)  # (k, n_templates)
    best: list[tuple[int, int]] = []
    best_score = -1.0
    for perm in itertools.permutations(range(max(k, t.shape[0])), k):
        pairs = [(i, j) for i, j in enumerate(perm) if j < t.shape[0]]
        score = sum(cos[i, j] for i, j in pairs) + 1e-3 * len(pairs)
        if score > best_score:
            best, best_score = pairs, score
    matched = {i: j for i, j in best}
    # matched axes in template order, unmatched (more axes than templates) after them
    order = sorted(matched, key=lambda i: matched[i]) + [i for i in range(k) if i not in matched]
    out, names, dev, idx = [], [], [], []
    for i in order:
        if i in matched:
            j = matched[i]
            c = float(a[i] @ t[j])
            out.append(a[i] * (1.0 if c >= 0 else -1.0))
            names.append(tpl[j][0])
            dev.append(float(np.arccos(min(abs(c), 1.0))))
            idx.append(j)
        else:
            out.append(a[i])
            names.append(f"{limb}_axis{len(names)}")
            dev.append(float("nan"))
            idx.append(-1)
    return np.stack(out), tuple(names), np.array(dev), tuple(idx)


def shoulder_elevation(direction_trunk: Array, side: str) -> tuple[Array, Array]:
    """ISB elevation and plane of elevation ``(T,)`` rad from the upper arm's direction in the
    trunk's normalized frame ``(T, 3)``. The plane is NaN below
    :data:`PLANE_MIN_ELEVATION_DEG` of elevation."""
    v = unit(direction_trunk)
    elev = np.arccos(np.clip(-v[..., 2], -1.0, 1.0))
    lateral = v[..., 1] * (1.0 if side == "left" else -1.0)
    plane = np.arctan2(v[..., 0], lateral)
    plane = np.where(elev > np.radians(PLANE_MIN_ELEVATION_DEG), plane, np.nan)
    return elev, plane


#: Every anatomical angle name analysis can produce (per side where it applies).
ANGLE_NAMES: Final[tuple[str, ...]] = (
    "trunk_flexion",
    "trunk_lateral_bend",
    "trunk_rotation",
    "head_flexion",
    "head_lateral_bend",
    *(
        f"{n}_{s}"
        for s in ("left", "right")
        for n in (
            "shoulder_flexion",
            "shoulder_abduction",
            "shoulder_rotation",
            "shoulder_elevation",
            "shoulder_plane",
            "elbow_flexion",
            "forearm_pronation",
            "hip_flexion",
            "hip_adduction",
            "hip_rotation",
            "knee_flexion",
            "knee_rotation",
            "ankle_dorsiflexion",
        )
    ),
)
