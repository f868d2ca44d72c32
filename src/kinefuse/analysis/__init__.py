"""Normalization and parameterization of skeleton motion (paper B, METHODS.md section B).

Pure numpy/scipy: arrays and small frozen dataclasses in, new ones out; no files, no clock.

The chain, for a :class:`SkeletonSequence` ``seq`` (Kinect v2 topology, metres, z up)::

    from kinefuse import analysis as an
    norm = an.normalize(seq)                        # B.1: default pose, body planes, limb frames
    model = an.learn_axes(seq, norm, phase=(0.0, 60.0), method="dj")   # B.2 on the calibration
    ang = an.joint_angles(seq, norm, model)         # angles about the learned axes + twist
    deg = ang.anatomical()                          # {"knee_flexion_left": (T,) degrees, ...}
    rec = an.reconstruct(ang, model, norm)          # forward kinematics back to positions
    err = an.reconstruction_error(seq, ang, model)  # {"sphere_mean": m, ...}
    flags = an.plausibility(ang, model).joint_flags()   # (T, 25) implausible-pose flags
    cons = an.normalization_consistency([norm_a, norm_b, norm_c])  # {"mean", "median"} degrees
    rom, truth = an.make_rom_motion(default_pose_25x3, seconds, rng)  # (Motion, RomTruth)
    motion = an.prepend_rom(rom, clip)              # calibration phase, 1 s blend, the clip

The calibration phase of a clip made by ``prepend_rom`` is ``(0, rom.duration_s)`` in motion
time (add the session's wand phase for server time). Against a truth (simulated sessions):
``axis_errors_deg(model, true_axes_in_normalization(truth.axes, true_frames, norm.frames))``,
``angle_rmse_deg(ang.anatomical(), ang_true.anatomical(), frames)``,
``twist_errors_deg(ang.twist, ang_true.twist, ang.twist_weight, frames)`` where ``ang_true``
is the same analysis of the true positions (see ``studies/analysis_accuracy.py accuracy``).

Modules
-------
``sequence``
    :class:`SkeletonSequence` (the shared input type) and :func:`kinect_parents`.
``limbs``
    :data:`LIMBS`, :data:`LIMB_NAMES`: the pelvis (root) and 12 limbs named after the Kinect bone
    they follow (``"upper_arm_left"`` = ShoulderLeft -> ElbowLeft; the trunk spans SpineBase ->
    SpineShoulder and the head SpineShoulder -> Head), with parent limb, number of movement
    axes and the neighbour that gives their twist for position-only skeletons.
``normalize``
    :func:`find_default_pose` (frame index), :func:`normalize` -> :class:`Normalization`
    (``frames (T, L, 3, 3)`` limb->world, ``transforms() (T, L, 4, 4)``, ``twist_weight``,
    per-limb ``status`` and ``observable`` DOF).
``axes``
    Speed-histogram filtering and the three axis extractors on the joint sphere.
``parameterize``
    :func:`learn_axes` -> :class:`AxisModel` (per limb a :class:`LimbModel`: axes in the
    parent's normalized frame, rest position, ranges, status ``"ok"`` / ``"no movement: ..."``
    / ``"one axis only: ..."`` / ``"missing: ..."``; methods ``"dj"`` (Direction Joining,
    default), ``"pca"``, ``"em"``).
``kinematics``
    :func:`joint_angles` -> :class:`Angles` (``angles``, ``twist``, ``off_axis`` per limb;
    ``anatomical()`` -> ISB-named degrees), :func:`reconstruct`, :func:`reconstruction_error`,
    :func:`edit_pose`.
``anatomy``
    Names and ISB signs of the angles (:data:`ANGLE_NAMES`, :func:`anatomical_angles`).
``plausibility``
    :func:`plausibility` flags per frame and limb from calibrated ranges and off-axis motion.
``consistency``
    :func:`normalization_consistency` across takes of one subject.
``rom``
    :func:`make_rom_motion` (a range-of-motion calibration phase on a real subject's default
    pose, with its true axes in :class:`RomTruth`) and :func:`prepend_rom`.

Errors the caller can cause raise :class:`kinefuse.errors.InputError` (a ``ValueError``) with a
message saying what was expected and what to do; per-limb problems that should not stop the
analysis of the other limbs are reported in ``status`` dictionaries instead.

May import: skeleton, geometry, motion, errors (the numerical core: no files, sockets or
clocks).
"""

from kinefuse.analysis.anatomy import ANGLE_NAMES
from kinefuse.analysis.consistency import (
    angle_rmse_deg,
    axis_errors_deg,
    normalization_consistency,
    true_axes_in_normalization,
    twist_errors_deg,
)
from kinefuse.analysis.kinematics import (
    Angles,
    edit_pose,
    joint_angles,
    reconstruct,
    reconstruction_error,
)
from kinefuse.analysis.limbs import LIMB_NAMES, LIMBS, Limb, limb
from kinefuse.analysis.normalize import Normalization, find_default_pose, normalize, propagate
from kinefuse.analysis.parameterize import METHODS, AxisModel, LimbModel, learn_axes
from kinefuse.analysis.plausibility import Plausibility, plausibility
from kinefuse.analysis.rom import RomTruth, make_rom_motion, prepend_rom
from kinefuse.analysis.sequence import SkeletonSequence, kinect_parents

__all__ = [
    "ANGLE_NAMES",
    "LIMBS",
    "LIMB_NAMES",
    "METHODS",
    "Angles",
    "AxisModel",
    "Limb",
    "LimbModel",
    "Normalization",
    "Plausibility",
    "RomTruth",
    "SkeletonSequence",
    "angle_rmse_deg",
    "axis_errors_deg",
    "edit_pose",
    "find_default_pose",
    "joint_angles",
    "kinect_parents",
    "learn_axes",
    "limb",
    "make_rom_motion",
    "normalization_consistency",
    "normalize",
    "plausibility",
    "prepend_rom",
    "propagate",
    "reconstruct",
    "reconstruction_error",
    "true_axes_in_normalization",
    "twist_errors_deg",
]
