"""Angles of every frame, their anatomical names, forward kinematics and pose editing (B.2 4-5).

The local frame of a limb in its parent is ``Q = S Q_rest R(long axis, twist)``: the swing ``S``
(the rotations about the learned axes, then the off-axis rest) takes the rest direction to the
limb's direction, ``Q_rest`` is the limb's frame at rest, and the twist is what remains about
the limb's long axis. The twist comes in closed form from the swing-twist decomposition of
``(S Q_rest)^T Q`` (the paper sampled it).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech import anatomy
from kinefuse.biomech._vec import mv, tmm, twist_angle
from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS, LIMBS
from kinefuse.biomech.normalize import Normalization
from kinefuse.biomech.parameterize import (
    AxisModel,
    _swing_matrices,
    limb_samples,
    swing_and_undefined,
)
from kinefuse.biomech.sequence import SkeletonSequence
from kinefuse.core.geometry.rotations import rodrigues, unit
from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS
from kinefuse.errors import InputError

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Angles:
    """The motion as parameters: per limb the angles about its axes, off-axis angle, twist.

    Attributes
    ----------
    t_s : (T,) float
        Seconds.
    angles : dict limb -> (T, k) float
        Radians about the limb's learned axes (JCS order, ISB signs), NaN where missing.
    off_axis : dict limb -> (T,) float
        Radians off the learned axes (one-axis limbs: out of the plane; two-axis limbs: the part
        the two circles cannot reach).
    twist : dict limb -> (T,) float
        Radians about the limb's long axis (proximal -> distal) relative to its rest frame; NaN
        where the twist is not observable.
    twist_weight : dict limb -> (T,) float
        Observability of the twist per frame (0 to 1, from the normalization).
    length_m : dict limb -> (T,) float
        Measured limb length per frame, metres.
    direction : dict limb -> (T, 3) float
        Unit limb direction in the parent's normalized frame (the joint-sphere samples).
    root_position : (T, 3) float
        SpineBase, metres, world.
    root_frame : (T, 3, 3) float
        The pelvis' normalized frame (pelvis -> world).
    axis_names : dict limb -> tuple of str
    undefined : dict limb -> (T, k + 1) bool
        Where each angle about the learned axes (columns) and the twist (last column) is not
        defined (:func:`~kinefuse.biomech.parameterize.undefined_angles`: gimbal lock, and
        for two axes the frames where its two representations are equally near the rest);
        :meth:`anatomical` gives NaN there. The raw values in :attr:`angles` and :attr:`twist`
        are kept (together they still give the limb's frame back exactly).
    refused : frozenset of str
        Limbs the model refused to learn (:attr:`LimbModel.refused`: not seen in the
        calibration phase): :meth:`anatomical` reports none of their angles, not even the
        shoulder's elevation and plane, which need no learned axes.
    """

    t_s: Array
    angles: dict[str, Array]
    off_axis: dict[str, Array]
    twist: dict[str, Array]
    twist_weight: dict[str, Array]
    length_m: dict[str, Array]
    direction: dict[str, Array]
    root_position: Array
    root_frame: Array
    axis_names: dict[str, tuple[str, ...]]
    undefined: dict[str, NDArray[np.bool_]] = field(default_factory=dict)
    refused: frozenset[str] = frozenset()

    def anatomical(self, *, degrees: bool = True) -> dict[str, Array]:
        """Every named angle ``(T,)``: the learned-axis angles, the twists with their ISB sign,
        and the shoulder's ISB elevation and plane of elevation (see
        :mod:`kinefuse.biomech.anatomy`; not for an upper arm in :attr:`refused`). Degrees
        unless ``degrees=False``. NaN where an angle is not defined: missing joints, an
        unobservable twist, and :attr:`undefined`."""
        f = np.degrees if degrees else (lambda x: x)
        out: dict[str, Array] = {}
        for limb, ang in self.angles.items():
            bad = self.undefined.get(limb)
            if bad is None:
                bad = np.zeros((ang.shape[0], ang.shape[1] + 1), dtype=bool)
            for j, name in enumerate(self.axis_names[limb]):
                out[name] = f(np.where(bad[:, j], np.nan, ang[:, j]))
            tw = anatomy.twist_name(limb)
            if tw is not None and limb in self.twist and np.isfinite(self.twist[limb]).any():
                out[tw[0]] = f(tw[1] * np.where(bad[:, -1], np.nan, self.twist[limb]))
        for side in ("left", "right"):
            d = self.direction.get(f"upper_arm_{side}")
            if d is not None and f"upper_arm_{side}" not in self.refused:
                elev, plane = anatomy.shoulder_elevation(d, side)
                out[f"shoulder_elevation_{side}"] = f(elev)
                out[f"shoulder_plane_{side}"] = f(plane)
        return out


def joint_angles(seq: SkeletonSequence, norm: Normalization, model: AxisModel, /) -> Angles:
    """Angles of every frame of ``seq`` about the axes of ``model`` (vectorized over frames)."""
    if norm.frames.shape[0] != seq.n_frames:
        raise InputError(
            f"the normalization has {norm.frames.shape[0]} frames but the sequence "
            f"{seq.n_frames}: normalize this sequence (normalize(seq)) and pass its result"
        )
    p = seq.kinect_positions()
    angles, off, twist, weight, length, direction, names = {}, {}, {}, {}, {}, {}, {}
    undefined = {}
    for name, lm in model.limbs.items():
        i = LIMB_INDEX[name]
        vec = limb_samples(seq, norm, name)
        u = unit(vec)
        length[name] = np.linalg.norm(vec, axis=-1)
        direction[name] = u
        if not lm.usable:
            continue
        ang, o, undefined[name] = swing_and_undefined(lm, u)
        angles[name], off[name], names[name] = ang, o, lm.axis_names
        w = norm.twist_weight[:, i]
        weight[name] = w
        if LIMBS[i].twist_observable or seq.orientation(name) is not None:
            par = LIMB_PARENTS[i]
            q = tmm(norm.frames[:, par], norm.frames[:, i])
            s = _swing_matrices(lm, ang, None, u)
            base = s @ lm.rest_frame
            tw = twist_angle(tmm(base, q), np.broadcast_to(norm.long_axis[i], u.shape))
            twist[name] = np.where(w > 0, tw, np.nan)
    return Angles(
        t_s=seq.t_s.copy(),
        angles=angles,
        off_axis=off,
        twist=twist,
        twist_weight=weight,
        length_m=length,
        direction=direction,
        root_position=p[:, JOINT_INDEX["SpineBase"]].copy(),
        root_frame=norm.frames[:, 0].copy(),
        axis_names=names,
        undefined=undefined,
        refused=frozenset(k for k, v in model.limbs.items() if v.refused),
    )


def reconstruct(
    angles: Angles,
    model: AxisModel,
    norm: Normalization,
    /,
    *,
    off_axis: bool = True,
    measured_lengths: bool = False,
) -> Array:
    """Forward kinematics: joint positions ``(T, 25, 3)`` (metres, world) from the parameters.

    The root (SpineBase position, pelvis frame) is taken as given; every limb's frame is its
    parent's frame times ``S Q_rest R(twist)``; its distal joint lies ``length`` along the long
    axis. Joints of limbs the model could not learn, and joints that are no limb's end (hand,
    hand tip, thumb, SpineMid, Neck), are NaN.

    Parameters
    ----------
    off_axis : bool
        Include the off-axis angle (the full parameterization); ``False`` keeps only the angles
        about the learned axes (the minimal one).
    measured_lengths : bool
        Use each frame's measured limb length instead of the model's median length.
    """
    t = angles.t_s.shape[0]
    pos = np.full((t, N_JOINTS, 3), np.nan)
    frames = np.full((t, len(LIMBS), 3, 3), np.nan)
    frames[:, 0] = angles.root_frame
    pos[:, JOINT_INDEX["SpineBase"]] = angles.root_position
    for i, lb in enumerate(LIMBS):
        par = LIMB_PARENTS[i]
        if par < 0:
            continue  # the root is given
        lm = model.limbs.get(lb.name)
        if lm is None or not lm.usable:
            continue
        fp = frames[:, par]
        prox = pos[:, lb.proximal_index]
        if not np.isfinite(prox).any():
            prox = pos[:, LIMBS[par].proximal_index] + fp @ lm.offset_m
            pos[:, lb.proximal_index] = prox
        ang = angles.angles[lb.name]
        off = angles.off_axis[lb.name] if off_axis else None
        s = _swing_matrices(lm, ang, off, None)
        if off_axis and lm.axes.shape[0] == 2:
            s = _swing_matrices(lm, ang, None, angles.direction[lb.name])
        tw = angles.twist.get(lb.name)
        tw = np.zeros(t) if tw is None else np.nan_to_num(tw)
        ax = np.broadcast_to(norm.long_axis[i], (t, 3))
        local = s @ lm.rest_frame @ rodrigues(ax, tw)
        frames[:, i] = fp @ local
        length = angles.length_m[lb.name] if measured_lengths else lm.length_m
        d = mv(fp, s @ lm.rest)
        pos[:, lb.distal_index] = prox + d * np.asarray(length)[..., None]
    return pos


def reconstruction_error(
    seq: SkeletonSequence, angles: Angles, model: AxisModel, /, *, off_axis: bool = True
) -> dict[str, float]:
    """Deviation of the parameterized limb positions from the measured ones, metres.

    ``"sphere_mean"``/``"sphere_median"``: the paper's measure, each limb's end on its joint
    sphere (the parent frame, the measured radius) against the end the angles give;
    ``"chain_mean"``: joints of the full forward kinematics (model lengths) against the input.
    """
    errs = []
    for name, lm in model.limbs.items():
        if not lm.usable:
            continue
        u = angles.direction[name]
        off = angles.off_axis[name] if off_axis else None
        x = mv(_swing_matrices(lm, angles.angles[name], off, None), lm.rest)
        e = np.linalg.norm(u - x, axis=-1) * angles.length_m[name]
        errs.append(e)
    e_all = np.concatenate(errs) if errs else np.zeros(0)
    e_all = e_all[np.isfinite(e_all)]
    return {
        "sphere_mean": float(e_all.mean()) if e_all.size else float("nan"),
        "sphere_median": float(np.median(e_all)) if e_all.size else float("nan"),
    }


def edit_pose(
    angles: Angles,
    model: AxisModel,
    norm: Normalization,
    /,
    frame: int,
    changes_deg: dict[str, float],
) -> Array:
    """The pose ``(25, 3)`` of ``frame`` with some anatomical angles changed (degrees added).

    ``changes_deg`` maps names of :meth:`Angles.anatomical` (learned-axis angles and twists) to
    increments, e.g. ``{"knee_flexion_left": 30.0}``. Children follow their parents (forward
    kinematics), as when the paper edits a pose by its angles.
    """
    if not 0 <= frame < angles.t_s.shape[0]:
        raise InputError(f"frame must be 0..{angles.t_s.shape[0] - 1}, got {frame}")
    one = _take(angles, frame)
    new_angles = {k: v.copy() for k, v in one.angles.items()}
    new_twist = {k: v.copy() for k, v in one.twist.items()}
    lookup: dict[str, tuple[str, int, float]] = {}
    for limb, nms in one.axis_names.items():
        for j, n in enumerate(nms):
            lookup[n] = (limb, j, 1.0)
        tw = anatomy.twist_name(limb)
        if tw is not None and limb in new_twist:
            lookup[tw[0]] = (limb, -1, tw[1])
    unknown = [n for n in changes_deg if n not in lookup]
    if unknown:
        raise InputError(
            f"cannot edit {', '.join(unknown)}: not an angle of this model; "
            f"editable: {', '.join(sorted(lookup))}"
        )
    for n, dv in changes_deg.items():
        limb, j, sgn = lookup[n]
        if j >= 0:
            new_angles[limb][:, j] += np.radians(dv)
        else:
            new_twist[limb][:] = np.nan_to_num(new_twist[limb]) + sgn * np.radians(dv)
    # the edited limbs' directions follow their new angles; everything downstream by FK
    edited = replace(one, angles=new_angles, twist=new_twist)
    direction = dict(one.direction)
    for limb in {lookup[n][0] for n in changes_deg}:
        lm = model.limbs[limb]
        s = _swing_matrices(lm, new_angles[limb], one.off_axis[limb], None)
        direction[limb] = unit(mv(s, lm.rest))
    edited = replace(edited, direction=direction)
    sub_norm = replace(norm, frames=norm.frames[frame : frame + 1])
    return reconstruct(edited, model, sub_norm)[0]


def _take(angles: Angles, frame: int) -> Angles:
    sl = slice(frame, frame + 1)
    return Angles(
        t_s=angles.t_s[sl],
        angles={k: v[sl] for k, v in angles.angles.items()},
        off_axis={k: v[sl] for k, v in angles.off_axis.items()},
        twist={k: v[sl] for k, v in angles.twist.items()},
        twist_weight={k: v[sl] for k, v in angles.twist_weight.items()},
        length_m={k: v[sl] for k, v in angles.length_m.items()},
        direction={k: v[sl] for k, v in angles.direction.items()},
        root_position=angles.root_position[sl],
        root_frame=angles.root_frame[sl],
        axis_names=angles.axis_names,
        undefined={k: v[sl] for k, v in angles.undefined.items()},
        refused=angles.refused,
    )
