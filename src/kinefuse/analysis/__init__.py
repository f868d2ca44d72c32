"""Normalization and parameterization of skeleton motion (paper B, METHODS.md section B).

Pure numpy/scipy: arrays and small frozen dataclasses in, new ones out; no files, no clock.

The chain, for a :class:`SkeletonSequence` ``seq`` (Kinect v2 topology, metres, z up)::

    from kinefuse import analysis as an
    norm = an.normalize(seq)                        # B.1: default pose, body planes, limb frames
    model = an.learn_axes(seq, norm, phase=(0.0, 60.0), method="dj")   # B.2 on the calibration
    ang = an.joint_angles(seq, norm, model)         # angles about the learned axes + twist
    deg = ang.anatomical()                          # {"knee_flexion_left": (T,) degrees, ...}
    rec = an.reconstruct(ang, model, norm)          # forward kinematics back to positions
    flags = an.plausibility(ang, model)             # (T, L) implausible-pose flags per limb

Modules
-------
``sequence``
    :class:`SkeletonSequence` (the shared input type) and :func:`kinect_parents`.
``limbs``
    :data:`LIMBS`, :data:`LIMB_NAMES`: the pelvis (root) and 12 limbs named after the Kinect bone
    they follow (``"upper_arm_left"`` = ShoulderLeft -> ElbowLeft), with parent limb, number of
    movement axes and the neighbour that gives their twist for position-only skeletons.
``normalize``
    :func:`find_default_pose` (frame index), :func:`normalize` -> :class:`Normalization`
    (``frames (T, L, 3, 3)`` limb->world, ``transforms() (T, L, 4, 4)``, ``twist_weight``,
    per-limb ``status`` and ``observable`` DOF).
``parameterize``
    :func:`learn_axes` -> :class:`AxisModel` (per limb: axes in the parent's normalized frame,
    rest position, status ``"ok"`` / ``"no movement"`` / ``"one axis only"`` ...; methods
    ``"dj"`` (Direction Joining, default), ``"pca"``, ``"em"``), :func:`joint_angles` ->
    :class:`Angles`, :func:`reconstruct`, :func:`edit_pose`.
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
"""

from kinefuse.analysis.limbs import LIMB_NAMES, LIMBS, Limb, limb
from kinefuse.analysis.normalize import Normalization, find_default_pose, normalize
from kinefuse.analysis.sequence import SkeletonSequence, kinect_parents

__all__ = [
    "LIMBS",
    "LIMB_NAMES",
    "Limb",
    "Normalization",
    "SkeletonSequence",
    "find_default_pose",
    "kinect_parents",
    "limb",
    "normalize",
]
