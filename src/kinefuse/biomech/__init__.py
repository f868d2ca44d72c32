"""Biomechanics: a joint series -> anatomy, axes, joint angles, range of motion (paper B).

Pure numpy/scipy: arrays and small frozen dataclasses in, new ones out; no files, no clock.

The chain, for a :class:`SkeletonSequence` ``seq`` (Kinect v2 topology, metres, z up)::

    from kinefuse import biomech as an
    norm = an.normalize(seq)                        # B.1: default pose, body planes, limb frames
    model = an.learn_axes(seq, norm, phase=(0.0, 60.0), method="dj")   # B.2 on the calibration
    ang = an.joint_angles(seq, norm, model)         # angles about the learned axes + twist
    deg = ang.anatomical()                          # {"knee_flexion_left": (T,) degrees, ...}
    rec = an.reconstruct(ang, model, norm)          # forward kinematics back to positions
    err = an.reconstruction_error(seq, ang, model)  # {"sphere_mean": m, ...}
    flags = an.plausibility(ang, model).joint_flags()   # (T, 25) implausible-pose flags
    rom, truth = an.make_rom_motion(default_pose_25x3, seconds, rng)  # (Motion, RomTruth)
    motion = an.prepend_rom(rom, clip)              # calibration phase, 1 s blend, the clip

Where the joint series comes from, also here: ``marker_maps.py`` (marker trajectories -> the
25 joints, hip-joint-centre regressions), ``static_trial.py`` (anatomical frames from a static
trial, the ISB frame maths), ``name_maps.py`` and ``retarget.py`` (a motion file's own joints
-> the 25 joints). ``rom.py`` builds the simulated standing and range-of-motion phases.

Errors the caller can cause raise :class:`kinefuse.errors.InputError` with a message saying
what was expected and what to do; per-limb problems are reported in ``status`` dictionaries.

May import :mod:`kinefuse.core`, :mod:`kinefuse.capture` and :mod:`kinefuse.errors`; never a
reader or writer (those are in :mod:`kinefuse.formats`, above).
"""

from kinefuse.biomech.anatomy import ANGLE_NAMES
from kinefuse.biomech.angle_plausibility import Plausibility, plausibility
from kinefuse.biomech.kinematics import (
    Angles,
    edit_pose,
    joint_angles,
    reconstruct,
    reconstruction_error,
)
from kinefuse.biomech.limbs import LIMB_NAMES, LIMBS, Limb, limb
from kinefuse.biomech.normalize import Normalization, find_default_pose, normalize, propagate
from kinefuse.biomech.parameterize import METHODS, AxisModel, LimbModel, learn_axes
from kinefuse.biomech.rom import RomTruth, make_rom_motion, prepend_rom
from kinefuse.biomech.sequence import SkeletonSequence, kinect_parents
from kinefuse.biomech.side_consistency import (
    angle_rmse_deg,
    axis_errors_deg,
    normalization_consistency,
    true_axes_in_normalization,
    twist_errors_deg,
)

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
