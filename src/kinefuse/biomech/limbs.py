"""The limbs analysis parameterizes, as data: joints, parent limb, axes and what is observable.

A limb is named by the Kinect v2 bone it follows (``"upper_arm_left"`` = ShoulderLeft ->
ElbowLeft); the trunk and the head span two Kinect bones each (see :data:`PELVIS`). The root
limb is the pelvis (SpineBase, its frame from the hips and SpineMid); it gets the body
coordinate system. Every other limb rotates about its ``proximal`` joint (the centre of
its joint sphere) relative to its ``parent`` limb's normalized frame.

For position-only skeletons (fused sessions) a limb's orientation about its own long axis (its
*twist*) comes from a neighbour joint, ``twist_ref``: the vector ``twist_ref[1] - twist_ref[0]``
(the elbow plane for the upper arm, the knee plane for the thigh, the thumb for the forearm, the
foot for the shank, the shoulder line for the trunk, the hip line for the pelvis). Limbs without
one (head, foot) have an unobservable twist; their frame is carried from the parent by the
minimal rotation and their twist is reported as not observable.

Body frame (from the body planes of the default pose): ``x`` anterior (frontal-plane normal,
forward), ``y`` to the subject's left (sagittal-plane normal), ``z`` superior (transverse-plane
normal, up). Right-handed: ``x × y = z``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from kinefuse.core.skeleton import JOINT_INDEX


@dataclass(frozen=True)
class Limb:
    """One limb of the analysis skeleton.

    Attributes
    ----------
    name : str
        e.g. ``"thigh_left"``.
    proximal, distal : str
        Kinect joints at the limb's ends; the limb rotates about ``proximal``.
    parent : str or None
        Parent limb (whose normalized frame the samples are expressed in); None for the root.
    n_axes : int
        Movement axes the joint has for its swing (1: hinge such as the knee; 2: ball or saddle
        such as the hip). The calibration phase moves the limb along that many main directions.
    twist_ref : tuple of two str, or ()
        Joints whose difference gives the twist reference for position-only skeletons.
    twist_observable : bool
        Whether the twist is observable from positions alone.
    side : str
        ``"left"``, ``"right"`` or ``""`` (midline).
    body_axis : int
        The body axis (0 x forward, 1 y left, 2 z up) the limb's long axis replaces in its
        normalized frame. The paper takes the axis closest to the limb in the default pose; for
        the foot (forward and down, near 45°) that choice flips between recordings, so every
        limb names its axis: z for the trunk and limbs, x for the foot.
    one_way : bool
        The twist reference is a hinge that bends one way (the thigh's, the knee). A bend read
        the other way (a hyperextended knee: a depth sensor's knee centre a few centimetres
        behind the hip-ankle line of a straight leg) lies in the same plane, so where the bend
        points against the calibrated one the reference's frame is turned by 180° about the limb
        before its twist is measured (:func:`kinefuse.biomech.normalize._reference_twist`).
    """

    name: str
    proximal: str
    distal: str
    parent: str | None
    n_axes: int
    twist_ref: tuple[str, ...]
    side: str = ""
    body_axis: int = 2
    one_way: bool = False

    @property
    def twist_observable(self) -> bool:
        return len(self.twist_ref) == 2

    @property
    def proximal_index(self) -> int:
        return JOINT_INDEX[self.proximal]

    @property
    def distal_index(self) -> int:
        return JOINT_INDEX[self.distal]


def _sided(side: str) -> tuple[Limb, ...]:
    s = side.capitalize()
    return (
        Limb(
            f"upper_arm_{side}",
            f"Shoulder{s}",
            f"Elbow{s}",
            "trunk",
            2,
            (f"Elbow{s}", f"Wrist{s}"),
            side,
        ),
        Limb(
            f"forearm_{side}",
            f"Elbow{s}",
            f"Wrist{s}",
            f"upper_arm_{side}",
            1,
            (f"Hand{s}", f"Thumb{s}"),
            side,
        ),
        Limb(
            f"thigh_{side}",
            f"Hip{s}",
            f"Knee{s}",
            "pelvis",
            2,
            (f"Knee{s}", f"Ankle{s}"),
            side,
            one_way=True,
        ),
        Limb(
            f"shank_{side}",
            f"Knee{s}",
            f"Ankle{s}",
            f"thigh_{side}",
            1,
            (f"Ankle{s}", f"Foot{s}"),
            side,
        ),
        Limb(f"foot_{side}", f"Ankle{s}", f"Foot{s}", f"shank_{side}", 1, (), side, 0),
    )


#: The root limb: origin SpineBase, SpineBase -> SpineMid; its frame's long axis runs from the
#: hips' midpoint to SpineMid (:func:`kinefuse.biomech.normalize.root_long_axis`), its twist from
#: the hip line.
#: The trunk spans SpineBase -> SpineShoulder and the head SpineShoulder -> Head (not the Kinect
#: bones SpineMid -> SpineShoulder and Neck -> Head): the longer baselines halve the effect of
#: the depth sensor's biased spine joints on the frames (SpineMid and Neck are 20 and 7 cm from
#: their neighbours and several cm off in fused data).
PELVIS: Final = Limb("pelvis", "SpineBase", "SpineMid", None, 0, ("HipRight", "HipLeft"))

#: All limbs, parents before children. The pelvis first (root, body frame), then 12 limbs.
LIMBS: Final[tuple[Limb, ...]] = (
    PELVIS,
    Limb("trunk", "SpineBase", "SpineShoulder", "pelvis", 2, ("ShoulderRight", "ShoulderLeft")),
    Limb("head", "SpineShoulder", "Head", "trunk", 2, ()),
    *_sided("left"),
    *_sided("right"),
)
LIMB_NAMES: Final[tuple[str, ...]] = tuple(limb.name for limb in LIMBS)
LIMB_INDEX: Final[dict[str, int]] = {n: i for i, n in enumerate(LIMB_NAMES)}
#: Index of each limb's parent limb in :data:`LIMBS` (-1 for the pelvis).
LIMB_PARENTS: Final[tuple[int, ...]] = tuple(
    -1 if limb.parent is None else LIMB_INDEX[limb.parent] for limb in LIMBS
)


def limb(name: str) -> Limb:
    """The limb called ``name``; a clear error naming the known limbs otherwise."""
    try:
        return LIMBS[LIMB_INDEX[name]]
    except KeyError:
        raise KeyError(f"unknown limb {name!r}; the limbs are: {', '.join(LIMB_NAMES)}") from None
