"""Anatomical joint angles: ISB segment frames from a static trial, joint coordinate systems.

This is the layer gait labs compare with, beside paper B's functional axes
(:mod:`kinefuse.biomech.parameterize`), which stay as they are.

Segment frames (ISB: Wu et al. 2002 for the pelvis, hip, knee, ankle and spine; Wu et al. 2005
for the shoulder and elbow). Every frame is a rotation ``(3, 3)`` whose columns are the
segment's axes in world coordinates, in the ISB convention: ``X`` anterior, ``Y`` superior (along
the segment, proximal), ``Z`` to the subject's **right** (on both sides; the left side's angles
are mirrored by their signs, as ISB and OpenSim do):

* pelvis: origin between the ASIS; ``Z`` from the left to the right ASIS; ``X`` anterior, in the
  plane of the two ASIS and the PSIS midpoint (or sacral marker), perpendicular to ``Z``;
  ``Y = Z x X``. From a skeleton (no ASIS): ``Z`` from the left to the right hip centre, ``Y``
  from their midpoint towards the spine joint above, ``X = Y x Z``.
* thigh (femur): ``Y`` from the knee centre to the hip centre; ``Z`` perpendicular to it in the
  plane of ``Y`` and the epicondyles (lateral minus medial on the right, the reverse on the
  left), so pointing right; ``X = Y x Z``. Without epicondyles: ``Z`` from the pelvis frame.
* shank (tibia/fibula): ``Y`` from the ankle centre to the knee centre; ``Z`` from the malleoli
  like the thigh's; ``X = Y x Z``. Without malleoli: ``Z`` from the thigh frame.
* foot: ``X`` from the heel to the toe, projected onto the floor in the static trial (the foot
  is taken as flat when standing, as Plug-in Gait's "foot flat" option does), ``Y`` up, ``Z``
  ``= X x Y``. Dorsiflexion is 0 when that line is perpendicular to the shank's ``Y``.
* trunk (thorax): ``Y`` from the lumbar joint (:func:`lumbar_joint_centre`, the OpenSim gait
  models' ``back`` joint; without ASIS markers the spine base) to the shoulder midpoint
  (or the spine joint between the shoulders); ``Z`` along the shoulder line (left to right),
  perpendicular to ``Y``; ``X = Y x Z``. (ISB's thorax uses C7, T8, IJ and PX; marker sets
  without them, and skeletons, get this approximation.) The shoulder markers slide with the
  shoulder girdle, so in a marker file's motion the trunk frame is built in every frame from
  the lumbar joint the pelvis carries and the shoulder markers, not carried as a rigid cluster.
* upper arm (humerus): ``Y`` from the elbow centre to the shoulder (glenohumeral) centre; ``Z``
  from the epicondyles like the thigh (ISB 2005, first option); without them from the trunk.
* forearm: ``Y`` from the wrist centre to the elbow centre; ``Z`` from the styloids (radial
  minus ulnar on the right); without them from the upper arm.

In the static trial each frame is built from these landmarks and expressed in the segment's
*tracking frame* (a rigid marker cluster fitted by least squares, or, for skeletons, a frame
built from the segment's joints); during the motion the tracking frame carries it
(:func:`carry`). So landmarks only the static trial has (medial knee and ankle markers) define
the frames of a motion that lacks them (the CAST idea, Cappozzo et al. 1995).

Joint angles (Grood & Suntay 1983, ISB order): the rotation of the distal frame relative to the
proximal one, ``R = Rp^T Rd``, decomposed ``R = Rz(a) Rx(b) Ry(c)``: ``a`` about the proximal
segment's ``Z`` (flexion axis), ``b`` about the floating axis, ``c`` about the distal
segment's ``Y`` (long axis). Pelvis angles use the lab frame as the proximal one: ``X`` the lab
axis of progression (:func:`lab_frame`), ``Y`` up, ``Z`` to the right of progression. Names,
signs and zeros: :data:`ANATOMICAL_ANGLES` (the zero of every angle is the pose in which the
two frames coincide: standing upright with the feet flat for the frames above). The shoulder
also gets ISB's elevation plane, elevation and axial rotation (``Y-X-Y``, Wu et al. 2005).
A capture without a pelvis (an upper-limb set) has no trunk-to-pelvis angles; its thorax is
measured relative to the lab instead, as ISB's upper-limb recommendation does (thorax relative
to the global frame, the same ``Z-X-Y`` sequence: ``thorax_extension``,
``thorax_lateral_bend``, ``thorax_rotation``), with the lab's ``X`` the thorax's horizontal
heading at the start of the motion.

Pure numpy; arrays in, arrays out.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.geometry.rotations import frames_from_vectors, unit
from kinefuse.core.geometry.transforms import rigid_fit
from kinefuse.errors import InputError

Array = NDArray[np.float64]

__all__ = [
    "ANATOMICAL_ANGLES",
    "MAX_SKELETON_STATIC_MOTION_M",
    "OPENSIM_MODELS",
    "OPENSIM_NAMES",
    "AnatomicalAngle",
    "OpenSimModel",
    "SkeletonAnatomy",
    "anatomical_angles",
    "blend",
    "carry",
    "frame_from_long_axis",
    "hinge_axis",
    "humerus_from_forearm",
    "jcs_zxy",
    "lab_frame",
    "model_body_offsets",
    "opensim_angles",
    "opensim_model",
    "pelvis_frame",
    "pelvis_frame_from_hips",
    "progression_axis",
    "rigid_fit",
    "segment_poses",
    "shoulder_yxy",
    "skeleton_anatomical_frames",
]


def frame_from_long_axis(y_axis: ArrayLike, z_hint: ArrayLike) -> Array:
    """ISB segment frame from its long axis ``Y`` and a right-pointing hint for ``Z``.

    Parameters
    ----------
    y_axis : (..., 3) float
        Direction of the segment's ``Y`` (distal to proximal).
    z_hint : (..., 3) float
        A direction roughly to the subject's right (an epicondyle line, a parent's ``Z``).

    Returns
    -------
    (..., 3, 3) float
        Columns ``X = Y x Z`` (anterior), ``Y``, ``Z`` (``Z`` is the hint made perpendicular to
        ``Y``); NaN where an input is NaN or the two are parallel.
    """
    return frames_from_vectors(y_axis, z_hint)[..., [2, 0, 1]]  # (Y, Z, Y x Z = X) -> (X, Y, Z)


#: Elbow flexion (degrees) below which the humerus keeps its carried second axis, and above
#: which it takes the one from the forearm's plane (:func:`humerus_from_forearm`); between the
#: two the axes are blended.
ELBOW_PLANE_DEG: Final = (10.0, 25.0)


def hinge_axis(
    humerus_y: ArrayLike, forearm_y: ArrayLike, carrying_rad: float = 0.0
) -> tuple[Array, Array]:
    """The elbow's flexion axis from the two long axes, for a hinge with a constant carrying
    angle.

    A hinge about the humerus's ``Z`` with the forearm ``carrying_rad`` out of the humerus's
    ``X-Y`` plane (the ``b`` of :func:`jcs_zxy`) keeps ``Z . Yf = sin(b)``; with ``Z``
    perpendicular to ``Yh`` that fixes ``Z`` from ``Yh`` and ``Yf`` alone where the elbow is
    bent (``b = 0``: the normal of their plane, ISB 2005's second humerus definition).

    Parameters
    ----------
    humerus_y, forearm_y : (..., 3) float
        The long axes (elbow to shoulder, wrist to elbow).
    carrying_rad : float
        ``b``, radians (from the static trial's epicondyle frames).

    Returns
    -------
    axis : (..., 3) float
        Unit ``Z`` (to the right for a bent elbow), NaN where undefined.
    weight : (..., 1) float
        How far the elbow is bent for the axis to hold: 0 straighter than the first of
        :data:`ELBOW_PLANE_DEG` (beyond the carrying angle), 1 beyond the second.
    """
    yh = unit(np.asarray(humerus_y, dtype=np.float64))
    yf = unit(np.asarray(forearm_y, dtype=np.float64))
    n = np.cross(yh, yf)
    beta = np.linalg.norm(n, axis=-1, keepdims=True)  # sine of the angle between the axes
    u = unit(yf - (yf * yh).sum(-1, keepdims=True) * yh)
    with np.errstate(invalid="ignore", divide="ignore"):
        sphi = np.clip(np.sin(carrying_rad) / beta, -1.0, 1.0)
    axis = np.sqrt(1.0 - sphi**2) * unit(n) + sphi * u
    lo, hi = np.sin(np.radians(ELBOW_PLANE_DEG) + abs(carrying_rad))
    w = np.nan_to_num(np.clip((beta - lo) / (hi - lo), 0.0, 1.0))
    return axis, w


def humerus_from_forearm(
    humerus: ArrayLike, forearm_y: ArrayLike, carrying_rad: float = 0.0
) -> Array:
    """The humerus frame whose ``Z`` is the elbow's hinge axis (:func:`hinge_axis`) where the
    elbow is bent enough for it to be defined.

    The elbow is a hinge: its flexion turns the forearm about this axis, so elbow flexion
    reads the hinge's own angle (0 at full extension, never wrapping) and the humerus's
    rotation about its long axis is read from the forearm rather than from markers over the
    biceps. With the elbow straighter than :data:`ELBOW_PLANE_DEG` the given (carried,
    epicondyle) ``Z`` is kept; in between the two are blended.

    Parameters
    ----------
    humerus : (..., 3, 3) float
        The humerus frame (``Y`` its long axis, ``Z`` from the epicondyles, carried).
    forearm_y : (..., 3) float
        The forearm's long axis (wrist to elbow centre).
    carrying_rad : float
        The elbow's carrying angle ``b`` in the static trial, radians.

    Returns
    -------
    (..., 3, 3) float
    """
    h = np.asarray(humerus, dtype=np.float64)
    yh, zh = h[..., 1], h[..., 2]
    axis, w = hinge_axis(yh, forearm_y, carrying_rad)
    return frame_from_long_axis(yh, blend(axis, zh, w))


def blend(a: ArrayLike, b: ArrayLike, w: ArrayLike) -> Array:
    """``w * a + (1 - w) * b`` per row: ``a`` where ``w >= 1``, ``b`` where ``w <= 0``, and in
    between the other side where one is NaN (a NaN with no weight does not spread)."""
    a_, b_, w_ = (np.asarray(x, dtype=np.float64) for x in (a, b, w))
    with np.errstate(invalid="ignore"):
        mixed = w_ * a_ + (1 - w_) * b_
    mixed = np.where(np.isnan(a_), b_, np.where(np.isnan(b_), a_, mixed))
    out: Array = np.where(w_ >= 1, a_, np.where(w_ <= 0, b_, mixed))
    return out


def pelvis_frame(rasis: ArrayLike, lasis: ArrayLike, back: ArrayLike) -> tuple[Array, Array]:
    """ISB pelvis frame from the ASIS and the PSIS midpoint (or sacral marker).

    Parameters
    ----------
    rasis, lasis, back : (..., 3) float
        Metres, world.

    Returns
    -------
    frame : (..., 3, 3) float
    origin : (..., 3) float
        The ASIS midpoint.
    """
    r, ll, b = (np.asarray(a, dtype=np.float64) for a in (rasis, lasis, back))
    mid = 0.5 * (r + ll)
    return frames_from_vectors(r - ll, mid - b)[..., [1, 2, 0]], mid  # (Z, X, Y) -> (X, Y, Z)


def pelvis_frame_from_hips(hip_right: ArrayLike, hip_left: ArrayLike, up: ArrayLike) -> Array:
    """Pelvis frame of a skeleton: ``Z`` left to right hip, ``Y`` towards ``up`` (the spine
    joint above the hips, as a point), ``X = Y x Z``. Shapes ``(..., 3)`` -> ``(..., 3, 3)``."""
    hr, hl, u = (np.asarray(a, dtype=np.float64) for a in (hip_right, hip_left, up))
    f = frames_from_vectors(hr - hl, u - 0.5 * (hr + hl))  # (Z, Y, Z x Y = -X)
    return np.stack([-f[..., 2], f[..., 1], f[..., 0]], axis=-1)


#: The lumbar (``back``) joint of the OpenSim gait models relative to the ASIS midpoint, in the
#: pelvis frame, metres, for the generic model's ASIS width :data:`MODEL_ASIS_WIDTH_M`. From
#: Rajagopal2016.osim (the same ``back`` joint as gait2392 and Hamner 2010): the joint's
#: ``pelvis_offset`` at ``(-0.1007, 0.0815, 0)`` in the pelvis frame, the ASIS markers of the
#: model's Rajagopal pipeline marker set at ``(0.013, 0.030, ±0.128)`` (its
#: ``subject_scaled_walk_markerset.xml`` divided by the pelvis scale factors of its
#: ``scaleSet_applied_walk.xml``). The same marker set puts both acromion markers straight above
#: this joint (``x = 0`` in the torso frame), so the torso's long axis runs from it to the
#: middle of the acromions.
MODEL_LUMBAR_FROM_ASIS_M: Final = np.array([-0.1137, 0.0515, 0.0])
MODEL_ASIS_WIDTH_M: Final = 0.256
#: The generic model's pelvis depth, the distance from the ASIS midpoint to the PSIS midpoint,
#: metres: Rajagopal2016.osim's RASI/RPSI markers at ``(0.0095, 0.0181, ±0.1285)`` and
#: ``(-0.155, 0.035, ±0.045)``. OpenSim's Scale tool scales the pelvis along its X (depth) by
#: the subject's MidASIS-MidPSIS distance over this one (the Rajagopal pipeline's
#: ``scale_setup_walk`` measurement ``PelvisX``), and along Z by the widths, not all by the width.
MODEL_PELVIS_DEPTH_M: Final = 0.1654


def lumbar_joint_centre(
    pelvis: ArrayLike, asis_mid: ArrayLike, asis_width_m: float, depth_m: float | None = None
) -> Array:
    """The lumbar joint centre (L5/S1, where the gait models' torso turns on the pelvis).

    Parameters
    ----------
    pelvis : (..., 3, 3) float
        ISB pelvis frame (:func:`pelvis_frame`).
    asis_mid : (..., 3) float
        The ASIS midpoint, metres.
    asis_width_m : float
        Distance between the ASIS markers, metres (scales the model's offset).
    depth_m : float, optional
        Distance from the ASIS midpoint to the PSIS midpoint, metres: scales the offset's
        anterior component (``X``) instead, as OpenSim's Scale tool scales the pelvis's depth
        (:data:`MODEL_PELVIS_DEPTH_M`). Without PSIS markers (a sacral marker only) the width
        scales all of it.

    Returns
    -------
    (..., 3) float
        ``asis_mid + pelvis @ MODEL_LUMBAR_FROM_ASIS_M * asis_width_m / MODEL_ASIS_WIDTH_M``,
        its ``X`` scaled by ``depth_m / MODEL_PELVIS_DEPTH_M`` when given.
    """
    off = MODEL_LUMBAR_FROM_ASIS_M * (asis_width_m / MODEL_ASIS_WIDTH_M)
    if depth_m is not None:
        off[0] = MODEL_LUMBAR_FROM_ASIS_M[0] * (depth_m / MODEL_PELVIS_DEPTH_M)
    out: Array = np.asarray(asis_mid, float) + np.asarray(pelvis, float) @ off
    return out


def lab_frame(forward: ArrayLike) -> Array:
    """The lab frame pelvis angles are measured in: ``X`` = ``forward`` made horizontal, ``Y`` up
    (world ``+z``), ``Z = X x Y`` (to the right of progression). ``(3,)`` -> ``(3, 3)``."""
    f = np.asarray(forward, dtype=np.float64).copy()
    f[2] = 0.0
    return frames_from_vectors(f, np.array([0.0, 0.0, 1.0]))  # Y: up is horizontal's normal


def progression_axis(displacement: ArrayLike, facing: ArrayLike) -> Array:
    """The world horizontal axis (``±x`` or ``±y``) closest to the direction of progression.

    ``displacement`` (the pelvis's travel over the trial) decides when it is at least 0.5 m,
    else ``facing`` (the pelvis's mean forward direction), as Plug-in Gait does. ``(3,)``."""
    d = np.asarray(displacement, dtype=np.float64)
    v = d if np.hypot(d[0], d[1]) >= 0.5 else np.asarray(facing, dtype=np.float64)
    if not np.isfinite(v[:2]).all() or np.hypot(v[0], v[1]) == 0:
        return np.array([1.0, 0.0, 0.0])
    k = int(np.argmax(np.abs(v[:2])))
    out = np.zeros(3)
    out[k] = np.sign(v[k])
    return out


def carry(static_frame: ArrayLike, static_tracking: ArrayLike, tracking: ArrayLike) -> Array:
    """An anatomical frame defined in the static trial, carried by the tracking frame.

    Parameters
    ----------
    static_frame : (3, 3) float
        The anatomical frame in the static trial (world).
    static_tracking : (3, 3) float
        The tracking frame in the static trial (world); the identity when ``tracking`` is a
        rotation from the static pose (:func:`rigid_fit`).
    tracking : (T, 3, 3) float
        The tracking frame during the motion.

    Returns
    -------
    (T, 3, 3) float
        ``tracking @ static_tracking^T @ static_frame``.
    """
    offset = np.asarray(static_tracking, dtype=np.float64).T @ np.asarray(static_frame, float)
    return np.asarray(tracking, dtype=np.float64) @ offset


def jcs_zxy(proximal: ArrayLike, distal: ArrayLike) -> tuple[Array, Array, Array]:
    """Joint coordinate system angles: ``Rp^T Rd = Rz(a) Rx(b) Ry(c)``, radians.

    Parameters
    ----------
    proximal, distal : (..., 3, 3) float
        Segment frames (columns X anterior, Y superior, Z right), world.

    Returns
    -------
    a, b, c : (...) float
        About the proximal ``Z`` (flexion axis), the floating axis, the distal ``Y``.
    """
    pr, di = np.asarray(proximal, float), np.asarray(distal, float)

    def rt(i: int, k: int) -> Array:  # (Rp^T Rd)[i, k]: the five entries the angles need
        out: Array = (pr[..., :, i] * di[..., :, k]).sum(-1)
        return out

    b = np.arcsin(np.clip(rt(2, 1), -1.0, 1.0))
    a = np.arctan2(-rt(0, 1), rt(1, 1))
    c = np.arctan2(-rt(2, 0), rt(2, 2))
    return a, b, c


def shoulder_yxy(thorax: ArrayLike, humerus: ArrayLike, right: bool) -> tuple[Array, Array, Array]:
    """ISB shoulder angles (Wu et al. 2005, humerus relative to thorax), degrees.

    ``Rp^T Rd = Ry(p) Rx(-e) Ry(r)`` on the right; the left side is mirrored through the
    sagittal plane first (``M R M``, ``M = diag(1, 1, -1)``), so both sides read alike.

    Returns
    -------
    plane, elevation, rotation : (...) float
        The plane of elevation ``p`` (0 lifting out to the side, 90 forward), the elevation
        ``e >= 0`` (0 hanging), the axial rotation ``r`` (positive internal).
    """
    r = np.swapaxes(np.asarray(thorax, float), -1, -2) @ np.asarray(humerus, float)
    if not right:
        m = np.array([1.0, 1.0, -1.0])
        r = r * m[:, None] * m[None, :]
    e = np.arccos(np.clip(r[..., 1, 1], -1.0, 1.0))
    p = np.arctan2(-r[..., 0, 1], -r[..., 2, 1])
    rot = np.arctan2(-r[..., 1, 0], r[..., 1, 2])
    return np.degrees(p), np.degrees(e), np.degrees(rot)


@dataclass(frozen=True)
class AnatomicalAngle:
    """One anatomical angle: ``sign * component`` of ``jcs_zxy(proximal, distal)``."""

    name: str
    proximal: str  # segment ("lab" for the pelvis)
    distal: str
    component: int  # 0 a (Z), 1 b (floating), 2 c (Y)
    sign: float
    meaning: str  # the sign and zero in words


def _side_table() -> tuple[AnatomicalAngle, ...]:
    out: list[AnatomicalAngle] = [
        AnatomicalAngle("pelvis_tilt", "lab", "pelvis", 0, -1.0,
                        "positive anterior tilt (the ASIS down); 0 with the ASIS-PSIS plane "
                        "level"),
        AnatomicalAngle("pelvis_obliquity", "lab", "pelvis", 1, -1.0,
                        "positive when the right side is up; 0 level"),
        AnatomicalAngle("pelvis_rotation", "lab", "pelvis", 2, 1.0,
                        "positive when the pelvis turns to the left (counterclockwise seen from "
                        "above); 0 facing the direction of progression"),
        AnatomicalAngle("trunk_extension", "pelvis", "trunk", 0, 1.0,
                        "trunk relative to pelvis, positive extension (leaning back)"),
        AnatomicalAngle("trunk_lateral_bend", "pelvis", "trunk", 1, 1.0,
                        "positive bending to the right"),
        AnatomicalAngle("trunk_rotation", "pelvis", "trunk", 2, 1.0,
                        "positive turning to the left"),
        AnatomicalAngle("thorax_extension", "lab", "trunk", 0, 1.0,
                        "thorax relative to the lab (captures without a pelvis only): positive "
                        "extension (leaning back); 0 with the thorax's long axis vertical"),
        AnatomicalAngle("thorax_lateral_bend", "lab", "trunk", 1, 1.0,
                        "positive bending to the right; 0 with the thorax's long axis vertical"),
        AnatomicalAngle("thorax_rotation", "lab", "trunk", 2, 1.0,
                        "positive turning to the left; 0 facing the lab frame's X (the "
                        "thorax's heading at the start of the motion)"),
    ]  # fmt: skip
    for side, s in (("right", 1.0), ("left", -1.0)):
        out += [
            AnatomicalAngle(f"hip_flexion_{side}", "pelvis", f"thigh_{side}", 0, 1.0,
                            "positive flexion (knee forward); 0 thigh along the pelvis's Y"),
            AnatomicalAngle(f"hip_adduction_{side}", "pelvis", f"thigh_{side}", 1, s,
                            "positive adduction (knee towards the midline)"),
            AnatomicalAngle(f"hip_internal_rotation_{side}", "pelvis", f"thigh_{side}", 2, s,
                            "positive internal rotation"),
            AnatomicalAngle(f"knee_flexion_{side}", f"thigh_{side}", f"shank_{side}", 0, -1.0,
                            "positive flexion; 0 with thigh and shank long axes aligned"),
            AnatomicalAngle(f"knee_adduction_{side}", f"thigh_{side}", f"shank_{side}", 1, s,
                            "positive adduction (varus)"),
            AnatomicalAngle(f"knee_internal_rotation_{side}", f"thigh_{side}", f"shank_{side}",
                            2, s, "positive internal rotation of the shank"),
            AnatomicalAngle(f"ankle_dorsiflexion_{side}", f"shank_{side}", f"foot_{side}", 0,
                            1.0, "positive dorsiflexion; 0 with the heel-toe line at right "
                            "angles to the shank"),
            AnatomicalAngle(f"ankle_inversion_{side}", f"shank_{side}", f"foot_{side}", 1, s,
                            "positive inversion"),
            AnatomicalAngle(f"shoulder_flexion_{side}", "trunk", f"upper_arm_{side}", 0, 1.0,
                            "Z-X-Y like the hip: positive flexion (arm forward)"),
            AnatomicalAngle(f"shoulder_adduction_{side}", "trunk", f"upper_arm_{side}", 1, s,
                            "positive adduction (negative: abduction)"),
            AnatomicalAngle(f"shoulder_internal_rotation_{side}", "trunk",
                            f"upper_arm_{side}", 2, s, "positive internal rotation"),
            AnatomicalAngle(f"elbow_flexion_{side}", f"upper_arm_{side}", f"forearm_{side}", 0,
                            1.0, "positive flexion; 0 straight"),
            AnatomicalAngle(f"elbow_adduction_{side}", f"upper_arm_{side}", f"forearm_{side}", 1,
                            s, "positive adduction (varus); the carrying angle reads negative"),
            AnatomicalAngle(f"forearm_pronation_{side}", f"upper_arm_{side}", f"forearm_{side}",
                            2, s, "positive pronation; 0 in the anatomical position (palm "
                            "forward); only where the forearm has two styloid markers"),
        ]  # fmt: skip
    return tuple(out)


#: Every anatomical angle: name, segments, component, sign and meaning (zero and sign).
ANATOMICAL_ANGLES: Final[tuple[AnatomicalAngle, ...]] = _side_table()

#: kinefuse anatomical name -> (OpenSim coordinate, sign factor), for the gait models whose
#: knee is negative in flexion. Every coordinate is a rotation of the distal body relative to
#: the proximal one about the axes above, as the models' joints define them: ``hip_r``,
#: ``acromial_r`` (``arm_flex`` about Z, ``arm_add`` about X, ``arm_rot`` about Y, body-fixed)
#: and ``back`` (``lumbar_extension``, ``lumbar_bending``, ``lumbar_rotation``, torso relative
#: to pelvis) are Z-X-Y sequences, the left side's X and Y axes mirrored; ``knee_angle`` and
#: ``elbow_flex`` turn about the flexion axis (zero straight), ``ankle_angle`` about the ankle
#: axis; ``pelvis_tilt`` is a rotation about the lab's Z (positive: the pelvis's front up).
OPENSIM_NAMES: Final[dict[str, tuple[str, float]]] = {
    "pelvis_tilt": ("pelvis_tilt", -1.0),
    "pelvis_obliquity": ("pelvis_list", -1.0),
    "pelvis_rotation": ("pelvis_rotation", 1.0),
    "trunk_extension": ("lumbar_extension", 1.0),
    "trunk_lateral_bend": ("lumbar_bending", 1.0),
    "trunk_rotation": ("lumbar_rotation", 1.0),
    **{
        f"{k}_{side}": (f"{v}_{side[0]}", f)
        for side in ("right", "left")
        for k, (v, f) in {
            "hip_flexion": ("hip_flexion", 1.0),
            "hip_adduction": ("hip_adduction", 1.0),
            "hip_internal_rotation": ("hip_rotation", 1.0),
            "knee_flexion": ("knee_angle", -1.0),
            "ankle_dorsiflexion": ("ankle_angle", 1.0),
            "shoulder_flexion": ("arm_flex", 1.0),
            "shoulder_adduction": ("arm_add", 1.0),
            "shoulder_internal_rotation": ("arm_rot", 1.0),
            "elbow_flexion": ("elbow_flex", 1.0),
        }.items()
    },
}


@dataclass(frozen=True)
class OpenSimModel:
    """An OpenSim model's coordinate conventions where they differ between models."""

    name: str
    knee_sign: float  # +1: knee_angle positive in flexion (Rajagopal 2016); -1: negative
    arms: bool  # the model has arm coordinates (arm_flex/add/rot, elbow_flex)
    source: str  # the model file the convention was read from
    #: segment (``pelvis``, ``trunk``) -> marker -> its location in the model body's frame
    #: (metres; X anterior, Y up, Z right): the marker template of the model's example marker
    #: set, from which the body's own frame is found in the static trial
    #: (:func:`model_body_offsets`); empty: the ISB frames stand for the bodies
    templates: Mapping[str, Mapping[str, tuple[float, float, float]]] = field(default_factory=dict)


#: The Gait2354 example's marker template on the model's ``pelvis`` and ``torso`` bodies
#: (metres, body frames): its scale marker set as the pipeline's scale step leaves it, scaled
#: but not yet moved onto a subject's markers (opensim-models
#: ``Pipelines/Gait2354_Simbody/OutputReference/subject01_scaledOnly.osim``). The model's
#: ``pelvis`` frame is not the ISB one: its ASIS markers sit 10 mm below the sacral marker
#: (3.2 deg); its ``torso`` Y axis runs from the ``back`` joint in front of the acromion
#: markers (3.9 deg).
GAIT2354_TEMPLATES: Final[dict[str, dict[str, tuple[float, float, float]]]] = {
    "pelvis": {
        "R.ASIS": (0.0204915, 0.0307373, 0.131146),
        "L.ASIS": (0.0204915, 0.0307373, -0.131146),
        "V.Sacral": (-0.163932, 0.0409831, 0.0),
    },
    "trunk": {
        "Sternum": (0.0755804, 0.323916, 0.0),
        "R.Acromium": (-0.0323916, 0.475077, 0.161958),
        "L.Acromium": (-0.0323916, 0.475077, -0.161958),
        "Top.Head": (0.000906965, 0.709376, 0.0),
    },
}

#: The models ``--names opensim:MODEL`` knows (``--names opensim``: :data:`DEFAULT_OPENSIM`).
#: Their knee is a ``CustomJoint`` whose flexion coordinate turns the tibia about the femur's
#: Z axis: negative in flexion in gait2354, gait2392 and Hamner 2010 (``knee_angle`` range
#: -120..10 deg), positive in Rajagopal 2016 (``knee_angle_r`` range 0..120 deg, the axis
#: reversed). gait2354/gait2392 have a single torso with fixed arms; Hamner 2010 and Rajagopal
#: 2016 have the ``acromial``, ``elbow`` and ``radioulnar`` joints.
OPENSIM_MODELS: Final[dict[str, OpenSimModel]] = {
    m.name: m
    for m in (
        OpenSimModel(
            "gait2354",
            -1.0,
            False,
            "Models/Gait2354_Simbody/gait2354_simbody.osim",
            GAIT2354_TEMPLATES,
        ),
        OpenSimModel("gait2392", -1.0, False, "Models/Gait2392_Simbody/gait2392_simbody.osim"),
        OpenSimModel("hamner", -1.0, True, "Models/Hamner/FullBodyModel_Hamner2010_v2_0.osim"),
        OpenSimModel("rajagopal", 1.0, True, "Models/Rajagopal/Rajagopal2016.osim"),
    )
}
#: ``--names opensim`` alone: the gait-model knee (negative in flexion) with Hamner's arms.
DEFAULT_OPENSIM: Final = "hamner"


def _rotation_about(template: Array, points: Array) -> Array:
    """The rotation ``R`` minimising ``sum |R @ template_i - points_i|^2`` (no translation:
    both are relative to the same pivot), ``(M, 3)`` each -> ``(3, 3)``."""
    u, _, vt = np.linalg.svd(template.T @ points)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    out: Array = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return out


def model_body_offsets(
    static_frames: Mapping[str, Array],
    markers: Mapping[str, Array],
    templates: Mapping[str, Mapping[str, tuple[float, float, float]]],
    lumbar: ArrayLike | None = None,
) -> dict[str, Array]:
    """Where an OpenSim model's own bodies sit in kinefuse's ISB frames, from the static trial.

    OpenSim's IK places a body by its markers as the model's marker set puts them on it; its
    coordinates relate those bodies, not ISB frames. Here the model's marker template of each
    segment is fitted to the static trial's markers (least squares, every template marker the
    same weight): the pelvis as a free rigid body, the torso turning about the lumbar joint
    (``lumbar``, the model's ``back`` joint, where the torso's frame has its origin).

    Parameters
    ----------
    static_frames : mapping of str to (3, 3) float
        ISB frames in the static trial (``pelvis``, ``trunk``), world.
    markers : mapping of str to (3,) float
        The static trial's marker positions (medians), metres, world.
    templates : mapping
        :attr:`OpenSimModel.templates`.
    lumbar : (3,) float, optional
        The lumbar joint in the static trial; without it the trunk is fitted as a free body.

    Returns
    -------
    dict of str to (3, 3) float
        Segment -> ``static_frame^T @ model_body``: the model body's frame in the ISB frame, so
        ``isb_frames @ offset`` carries it through the motion. Segments whose frame or template
        markers the static trial lacks are left out.
    """
    out: dict[str, Array] = {}
    for seg, tmpl in templates.items():
        if seg not in static_frames or not set(tmpl) <= set(markers):
            continue
        a = np.array([tmpl[k] for k in tmpl], dtype=np.float64)
        b = np.array([markers[k] for k in tmpl], dtype=np.float64)
        if not np.isfinite(b).all():
            continue
        if seg == "trunk" and lumbar is not None:
            body = _rotation_about(a, b - np.asarray(lumbar, dtype=np.float64))
        else:
            body = _rotation_about(a - a.mean(0), b - b.mean(0))
        out[seg] = np.asarray(static_frames[seg], dtype=np.float64).T @ body
    return out


def opensim_model(names: str) -> OpenSimModel | None:
    """The model of a ``--names`` value: ``kinefuse`` -> None, ``opensim`` ->
    :data:`DEFAULT_OPENSIM`, ``opensim:MODEL`` -> that model (case-insensitive; also
    ``rajagopal2016``); :class:`~kinefuse.errors.InputError` for anything else."""
    text = names.strip().lower()
    if text == "kinefuse":
        return None
    head, _, model = text.partition(":")
    model = (model or DEFAULT_OPENSIM).removesuffix("2016").removesuffix("2010")
    if head != "opensim" or model not in OPENSIM_MODELS:
        raise InputError(
            f"--names {names!r}: give kinefuse, opensim or opensim:MODEL with MODEL one of "
            f"{', '.join(OPENSIM_MODELS)}"
        )
    return OPENSIM_MODELS[model]


def anatomical_angles(
    frames: Mapping[str, Array], lab: ArrayLike | None = None, skip: Sequence[str] = ()
) -> dict[str, Array]:
    """Every angle of :data:`ANATOMICAL_ANGLES` whose two frames are given, degrees.

    Parameters
    ----------
    frames : mapping of str to (T, 3, 3) float
        Segment name (``pelvis``, ``trunk``, ``thigh_left``, ``shank_left``, ``foot_left``,
        ``upper_arm_left``, ``forearm_left``, and the right side) -> its anatomical frame.
    lab : (3, 3) float, optional
        The lab frame of the pelvis angles (:func:`lab_frame`), and of the thorax angles
        (``thorax_*``) of a capture without a pelvis; without it no angle relative to the lab.
    skip : sequence of str
        Angles not to give (their frames cannot define them, e.g. ``forearm_pronation_left``
        without styloid markers).

    Returns
    -------
    dict of str to (T,) float
        Degrees, NaN where a frame is NaN. Also ``shoulder_elevation_plane_<side>``,
        ``shoulder_elevation_<side>``, ``shoulder_axial_rotation_<side>`` (ISB ``Y-X-Y``).
    """
    have = dict(frames)
    if lab is not None:
        some = next(iter(have.values()), None)
        if some is None:
            raise InputError("anatomical_angles needs at least one segment frame")
        have["lab"] = np.broadcast_to(np.asarray(lab, dtype=np.float64), some.shape)
    out: dict[str, Array] = {}
    cache: dict[tuple[str, str], tuple[Array, Array, Array]] = {}
    for ang in ANATOMICAL_ANGLES:
        if ang.proximal not in have or ang.distal not in have or ang.name in skip:
            continue
        if ang.name.startswith("thorax_") and "pelvis" in have:
            continue  # with a pelvis the trunk is measured relative to it (trunk_*)
        key = (ang.proximal, ang.distal)
        if key not in cache:
            cache[key] = jcs_zxy(have[ang.proximal], have[ang.distal])
        out[ang.name] = ang.sign * np.degrees(cache[key][ang.component])
    for side in ("right", "left"):
        if "trunk" in have and f"upper_arm_{side}" in have:
            p, e, r = shoulder_yxy(have["trunk"], have[f"upper_arm_{side}"], side == "right")
            out[f"shoulder_elevation_plane_{side}"] = p
            out[f"shoulder_elevation_{side}"] = e
            out[f"shoulder_axial_rotation_{side}"] = r
    return out


def opensim_angles(
    angles: Mapping[str, Array], model: str | OpenSimModel = DEFAULT_OPENSIM
) -> dict[str, Array]:
    """Anatomical angles under an OpenSim model's coordinate names and signs (degrees).

    ``model``: a name of :data:`OPENSIM_MODELS` or one of its entries. Angles the model does
    not have are left out (the arms for gait2354 and gait2392)."""
    m = model if isinstance(model, OpenSimModel) else opensim_model(f"opensim:{model}")
    assert m is not None
    arm = ("arm_", "elbow_")
    out = {}
    for k, v in angles.items():
        if k not in OPENSIM_NAMES:
            continue
        name, sign = OPENSIM_NAMES[k]
        if name.startswith(arm) and not m.arms:
            continue
        if name.startswith("knee_angle"):
            sign = m.knee_sign
        out[name] = sign * np.asarray(v)
    return out


def segment_poses(
    templates: Mapping[str, Array],
    moving: Mapping[str, Array],
    joints: Sequence[tuple[str, str, Array]] = (),
) -> dict[str, tuple[Array, Array]]:
    """Rigid poses of marker clusters, each held to the joint centres its neighbours carry.

    First every segment is fitted to its own markers (:func:`rigid_fit`). Then each segment is
    fitted again to its markers **plus** every joint centre it shares with a neighbour, as that
    neighbour's first fit carries it (the hip centre as the thigh sees it joins the pelvis's
    markers; the knee centre as the shank sees it joins the thigh's): a joint stays one point for
    both segments, as a ball joint does in a kinematic model, with the same weight as a marker.

    Parameters
    ----------
    templates : mapping of str to (M, 3) float
        Segment -> its markers in the static trial, metres.
    moving : mapping of str to (T, M, 3) float
        Segment -> the same markers during the motion (NaN where missing).
    joints : sequence of (str, str, (3,) float)
        ``(segment_a, segment_b, centre in the static trial)`` for each joint two segments share.

    Returns
    -------
    dict of str to ((T, 3, 3), (T, 3))
        Segment -> rotation and translation from the static trial to each frame.
    """
    first = {k: rigid_fit(templates[k], moving[k]) for k in templates}
    out: dict[str, tuple[Array, Array]] = {}
    for seg in templates:
        tm = [np.asarray(templates[seg], dtype=np.float64)]
        mv = [np.asarray(moving[seg], dtype=np.float64)]
        for a, b, c in joints:
            other = b if a == seg else a if b == seg else None
            if other is None or other not in first:
                continue
            r, p = first[other]
            tm.append(np.asarray(c, dtype=np.float64)[None])
            mv.append((r @ c + p)[:, None])
        out[seg] = (
            rigid_fit(np.concatenate(tm), np.concatenate(mv, axis=1)) if len(tm) > 1 else first[seg]
        )
    return out


#: A skeleton's static window is refused when its still joints' 90th-percentile distances from
#: their median positions over the window have a median (over the joints) above this, metres,
#: or one of them is above twice this. Larger than the marker files' 30 mm: a fused
#: depth-sensor skeleton jitters about 1 cm per axis while standing still, and one joint (an
#: ankle the other leg hides, a hip seen from the side) can wander 6 cm while the body stands
#: (fused standing phases of ``studies/analysis_accuracy.py accuracy`` and
#: ``studies/analysis_sweep.py --static``).
MAX_SKELETON_STATIC_MOTION_M = 0.05

#: The joints whose stillness a skeleton's static window is checked on (the hands and feet
#: tips of a depth-sensor skeleton jump even when the subject stands still).
_STILL_JOINTS = ("SpineBase", "HipLeft", "HipRight", "KneeLeft", "KneeRight", "AnkleLeft",
                 "AnkleRight", "SpineShoulder", "ShoulderLeft", "ShoulderRight")  # fmt: skip


@dataclass(frozen=True, eq=False)
class SkeletonAnatomy:
    """ISB frames of a skeleton's segments over the sequence, from a static window."""

    frames: dict[str, Array]  # segment -> (T, 3, 3)
    lab: Array  # (3, 3)
    status: dict[str, str]  # segment -> "ok" or why it was skipped
    static_motion_m: dict[str, float]  # joint -> 90th-percentile distance from its median


def skeleton_anatomical_frames(
    positions: ArrayLike,
    joint_names: Sequence[str],
    t_s: ArrayLike,
    limb_frames: Mapping[str, Array],
    window: tuple[float, float],
    zero: str = "standing",
    static_frames: Mapping[str, Array] | None = None,
) -> SkeletonAnatomy:
    """ISB segment frames of a skeleton (joint centres, no markers), from a static window.

    In the window (the subject standing still) each segment's anatomical frame is built from
    the median joint centres (module docstring: pelvis from the hips and ``SpineMid``, trunk
    from ``SpineBase``/``SpineShoulder`` and the shoulders, thigh ``Y`` hip minus knee with
    ``Z`` from the pelvis, shank from the thigh, foot ``X`` ankle to ``Foot`` made horizontal,
    upper arm from the trunk, forearm from the upper arm) and expressed in the segment's
    tracking frame there (``limb_frames``: the normalized limb frames of paper B, built from the
    segment's joints, their twist from the child limb where it is observable); the tracking
    frame carries it through the sequence (:func:`carry`). So the standing trial sets each
    segment's rotation zero, as a static trial does for marker clusters.

    Parameters
    ----------
    positions : (T, J, 3) float
        Joint centres, metres, world (z up); NaN where missing.
    joint_names : sequence of str
        Kinect v2 joint names of the columns.
    t_s : (T,) float
    limb_frames : mapping of str to (T, 3, 3) float
        Limb name (:data:`kinefuse.biomech.limbs.LIMB_NAMES`) -> limb-to-world rotation.
    window : (float, float)
        The static window, seconds on ``t_s``.
    zero : {"standing", "geometry"}
        ``"standing"``: every segment's anatomical frame in the window is the standing frame
        (``X`` the pelvis's forward made horizontal, ``Y`` up, ``Z`` right), so every angle
        reads 0 in the standing posture (the neutral posture defines the zeros, as a
        neutral-pose calibration does). ``"geometry"``: the frames are built from the joint
        centres as above, so the standing posture reads its own angles; a depth sensor's joint
        centres are not anatomical landmarks, and their joint-definition offsets (centimetres,
        shared by every sensor) then read as constant angle offsets.
    static_frames : mapping of str to (T, 3, 3) float, optional
        Limb name -> the tracking frames to express the static frame in, where they differ
        from ``limb_frames`` (a limb whose twist reference is weak in standing:
        :func:`kinefuse.pipeline.analysis_chain.skeleton_anatomy` gives the frame carried from the
        parent of each limb whose twist weight is under 1 there, e.g. a thigh over a nearly
        straight knee).

    Raises
    ------
    InputError
        The window holds fewer than 2 frames, or the subject moves in it (the joints of
        ``_STILL_JOINTS`` farther than :data:`MAX_SKELETON_STATIC_MOTION_M` from their medians
        at the 90th percentile, in the median over the joints, or one of them farther than
        twice that; the worst joint and the distances are named).
    """
    from kinefuse.core.geometry.rotations import chordal_mean

    p = np.asarray(positions, dtype=np.float64)
    t = np.asarray(t_s, dtype=np.float64)
    lo, hi = window
    sel = (t >= lo) & (t <= hi)
    if int(sel.sum()) < 2:
        raise InputError(
            f"the static window {lo:g}:{hi:g} s holds {int(sel.sum())} frame(s) (the input runs "
            f"{t[0]:.2f} to {t[-1]:.2f} s); give START:END of the standing phase inside it"
        )
    idx = {n: i for i, n in enumerate(joint_names)}
    jp: dict[str, Array] = {}
    motion: dict[str, float] = {}
    for n, i in idx.items():
        w = p[sel, i]
        if not np.isfinite(w).all(-1).any():
            continue
        med = np.nanmedian(w, axis=0)
        jp[n] = med
        if n in _STILL_JOINTS:
            motion[n] = float(np.nanpercentile(np.linalg.norm(w - med, axis=-1), 90))
    if motion:
        worst = max(motion, key=lambda k: motion[k])
        typical = float(np.median(list(motion.values())))
        if (
            typical > MAX_SKELETON_STATIC_MOTION_M
            or motion[worst] > 2 * MAX_SKELETON_STATIC_MOTION_M
        ):
            raise InputError(
                f"the subject moves during the static window {lo:g}:{hi:g} s: {worst} is "
                f"{1e3 * motion[worst]:.0f} mm from its median position in 10 % of the frames "
                f"(at most {2e3 * MAX_SKELETON_STATIC_MOTION_M:.0f} mm allowed), the still "
                f"joints {1e3 * typical:.0f} mm in the median (at most "
                f"{1e3 * MAX_SKELETON_STATIC_MOTION_M:.0f} mm). Give the window of the standing "
                "phase (--static-window START:END, or auto for a session made with simulate "
                "--static)"
            )
    status: dict[str, str] = {}
    static: dict[str, Array] = {}
    if {"HipLeft", "HipRight", "SpineMid"} <= set(jp):
        static["pelvis"] = pelvis_frame_from_hips(jp["HipRight"], jp["HipLeft"], jp["SpineMid"])
    else:
        status["pelvis"] = "skipped: no HipLeft, HipRight and SpineMid in the static window"
    if {"SpineBase", "SpineShoulder", "ShoulderLeft", "ShoulderRight"} <= set(jp):
        static["trunk"] = frame_from_long_axis(
            jp["SpineShoulder"] - jp["SpineBase"], jp["ShoulderRight"] - jp["ShoulderLeft"]
        )
    else:
        status["trunk"] = "skipped: no SpineBase, SpineShoulder and shoulders in the static window"
    up = np.array([0.0, 0.0, 1.0])
    for side in ("right", "left"):
        cap = side.capitalize()
        for segment, proximal, distal, parent in (
            ("thigh", "Hip", "Knee", "pelvis"),
            ("shank", "Knee", "Ankle", f"thigh_{side}"),
            ("upper_arm", "Shoulder", "Elbow", "trunk"),
            ("forearm", "Elbow", "Wrist", f"upper_arm_{side}"),
        ):
            seg = f"{segment}_{side}"
            a, b = jp.get(f"{proximal}{cap}"), jp.get(f"{distal}{cap}")
            if a is None or b is None or parent not in static:
                status[seg] = f"skipped: no {proximal}{cap}/{distal}{cap} or no {parent} frame"
                continue
            static[seg] = frame_from_long_axis(a - b, static[parent][:, 2])
        a, b = jp.get(f"Ankle{cap}"), jp.get(f"Foot{cap}")
        if a is not None and b is not None:
            x = (b - a) * np.array([1.0, 1.0, 0.0])
            x = x / np.linalg.norm(x)
            static[f"foot_{side}"] = np.stack([x, up, np.cross(x, up)], axis=-1)
        else:
            status[f"foot_{side}"] = f"skipped: no Ankle{cap}/Foot{cap}"
    if zero not in ("standing", "geometry"):
        raise InputError(f"zero must be 'standing' or 'geometry', got {zero!r}")
    if zero == "standing" and "pelvis" in static:
        level = lab_frame(static["pelvis"][:, 0])
        static = {k: level for k in static}
    frames: dict[str, Array] = {}
    for seg, a_static in static.items():
        tr = limb_frames.get(seg)
        if tr is None or not np.isfinite(tr[sel]).all((-2, -1)).any():
            status[seg] = "skipped: the limb has no frame in the static window"
            continue
        held = tr if static_frames is None else static_frames.get(seg, tr)
        frames[seg] = carry(a_static, chordal_mean(held[sel]), tr)
        status[seg] = "ok"
    if "SpineBase" in idx:
        sb = p[:, idx["SpineBase"]]
        ok = np.flatnonzero(np.isfinite(sb).all(-1))
        disp = sb[ok[-1]] - sb[ok[0]] if ok.size else np.zeros(3)
    else:
        disp = np.zeros(3)
    # as for marker clusters (kinefuse.biomech.static_trial): the pelvis's mean facing
    facing = (np.nanmean(frames["pelvis"][:, :, 0], axis=0) if "pelvis" in frames
              else np.array([1.0, 0.0, 0.0]))  # fmt: skip
    lab = lab_frame(progression_axis(disp, facing))
    return SkeletonAnatomy(frames=frames, lab=lab, status=status, static_motion_m=motion)
