"""Name maps: which source joint(s) give each Kinect v2 joint.

A map is ``{kinect_joint: spec}``. A spec says where the Kinect joint is, in terms of the
positions of the source's joints (pivots; End Sites as ``"X/End"``):

* ``"LeftForeArm"``: that joint's position;
* ``{ end_site = "Head" }``: the End Site under ``Head`` (same as ``"Head/End"``);
* ``{ mean = ["Head", "Head/End"] }``: the midpoint (mean) of several joints;
* ``{ blend = { Spine = 0.3, Neck = 0.7 } }``: a weighted sum; weights must add up to 1 (a weight
  may be negative or above 1 to extrapolate along a bone);
* ``["LeftToeBase", "LeftToe"]``: alternatives, the first that the source has wins.

Kinect joints a map leaves out (or whose joints the source lacks) are synthesized when a rule
exists (hand, hand tip, thumb, foot, neck, spine points: see :mod:`kinefuse.biomech.retarget`),
else retargeting fails listing them.

Source names match exactly first, then ignoring case and any namespace prefix (``mixamorig:``,
``mixamorig1:``...). The shipped maps are in :data:`BUILTIN_MAPS`; a user map is a TOML file
(:func:`load_name_map`; format in ``docs/motion.md``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from kinefuse.core.frames.source_motion import END_SITE_SUFFIX
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError

#: One way to compute a Kinect joint: a weighted sum of source joints ``((name, weight), ...)``.
Term = tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class NameMap:
    """How to build the 25 Kinect joints from a source skeleton's joints.

    Attributes
    ----------
    name : str
        Shown in ``Motion.source``.
    joints : dict of str to tuple of Term
        For each Kinect joint it maps, the alternatives in order of preference; each alternative
        is a weighted sum of source joints ``((source_name, weight), ...)``, weights adding to 1.
    origin : str
        ``"built-in"`` or the TOML file it was read from.
    """

    name: str
    joints: dict[str, tuple[Term, ...]] = field(default_factory=dict)
    origin: str = "built-in"

    def source_names(self) -> set[str]:
        """Every source joint name the map refers to."""
        return {n for alts in self.joints.values() for term in alts for n, _ in term}


def _spec_error(where: str, joint: str, message: str) -> InputError:
    return InputError(
        f"{where}: name map entry for {joint!r}: {message}. An entry is a joint name, "
        "{ end_site = NAME }, { mean = [NAMES] }, { blend = { NAME = WEIGHT, ... } } or a list "
        "of these (alternatives); see docs/motion.md"
    )


def parse_term(
    spec: Any, error: Callable[[str], InputError], *, noun: str = "joint", end_site: bool = True
) -> Term | None:
    """One entry of a name map or a marker map as a weighted sum of names.

    The forms every map shares: ``"NAME"``; ``{ mean = [NAMES] }``; ``{ blend = { NAME = WEIGHT,
    ... } }`` (weights adding up to 1); and, with ``end_site``, ``{ end_site = NAME }`` (the End
    Site under a joint). ``noun`` names what a name is (joint, marker) in the messages.

    Returns
    -------
    Term or None
        None for a one-key table of another form (the caller's own, e.g. a hip joint centre).

    Raises
    ------
    InputError
        Made by ``error(message)``, for a malformed entry of the shared forms.
    """
    if isinstance(spec, str):
        if not spec.strip():
            raise error(f"the {noun} name is empty")
        return ((spec, 1.0),)
    if not isinstance(spec, Mapping):
        raise error(f"cannot read {spec!r}")
    if len(spec) != 1:
        forms = "end_site, mean, blend" if end_site else "mean, blend"
        raise error(f"a table needs exactly one of {forms}; got {sorted(spec)}")
    ((key, val),) = spec.items()
    if key == "end_site" and end_site:
        if not isinstance(val, str) or not val:
            raise error(f"end_site must be a {noun} name, got {val!r}")
        return ((val + END_SITE_SUFFIX, 1.0),)
    if key == "mean":
        if (
            not isinstance(val, Sequence)
            or isinstance(val, str)
            or len(val) < 1
            or not all(isinstance(n, str) and n.strip() for n in val)
        ):
            raise error(f"mean must be a list of {noun} names, got {val!r}")
        return tuple((n, 1.0 / len(val)) for n in val)
    if key == "blend":
        if not isinstance(val, Mapping) or not val:
            raise error(f"blend must be a table {noun.upper()} = WEIGHT, got {val!r}")
        term: list[tuple[str, float]] = []
        for n, w in val.items():
            if isinstance(w, bool) or not isinstance(w, int | float):
                raise error(f"blend weight of {n!r} must be a number, got {w!r}")
            term.append((str(n), float(w)))
        total = sum(w for _, w in term)
        if abs(total - 1.0) > 1e-6:
            raise error(f"blend weights must add up to 1, they add up to {total:g}")
        return tuple(term)
    return None


def alternatives(spec: Any, error: Callable[[str], InputError]) -> list[Any]:
    """A map entry's alternatives: a list of forms, or one form (no nested lists)."""
    alts = spec if isinstance(spec, list) else [spec]
    if not alts:
        raise error("the list of alternatives is empty")
    if any(isinstance(a, list) for a in alts):
        raise error("alternatives cannot be nested lists")
    return alts


def normalize_name(name: str) -> str:
    """A name as found loosely: case-folded, without surrounding spaces or a namespace prefix
    (``mixamorig:LeftArm`` -> ``leftarm``); an End Site keeps its ``/End``."""
    base, sep, end = name.strip().partition(END_SITE_SUFFIX)
    return (base.rsplit(":", 1)[-1].strip() + sep + end).casefold()


class NameResolver:
    """Finds names in a list (a clip's joints, a file's markers): exactly, else by
    :func:`normalize_name` where that is unambiguous. Calling it gives the index or None."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = list(names)
        self.exact = {n: i for i, n in enumerate(self.names)}
        loose: dict[str, list[int]] = {}
        for i, n in enumerate(self.names):
            loose.setdefault(normalize_name(n), []).append(i)
        self.loose = {k: v[0] for k, v in loose.items() if len(v) == 1}

    def __call__(self, name: str) -> int | None:
        if name in self.exact:
            return self.exact[name]
        return self.loose.get(normalize_name(name))


def parse_name_map(
    data: Mapping[str, Any], *, name: str = "user", origin: str = "built-in"
) -> NameMap:
    """Build a :class:`NameMap` from ``{kinect_joint: spec}`` (the ``[joints]`` table of a TOML
    map). See the module docstring for the spec forms.

    Raises
    ------
    InputError
        Unknown Kinect joint names or malformed specs, with what was expected.
    """
    out: dict[str, tuple[Term, ...]] = {}
    for joint, spec in data.items():
        if joint not in JOINTS:
            raise InputError(
                f"{origin}: {joint!r} is not a Kinect v2 joint; the 25 names are: "
                f"{', '.join(JOINTS)}"
            )

        def error(message: str, joint: str = joint) -> InputError:
            return _spec_error(origin, joint, message)

        terms = []
        for a in alternatives(spec, error):
            term = parse_term(a, error)
            if term is None:
                raise error(f"unknown form {a!r}")
            terms.append(term)
        out[joint] = tuple(terms)
    return NameMap(name=name, joints=out, origin=origin)


def _lr(template: Mapping[str, Any]) -> dict[str, Any]:
    """Expand ``{side}`` (Left), ``{s}`` (l), ``{S}`` (L) in keys and values into both sides."""
    out: dict[str, Any] = {}
    subs = (
        {"side": "Left", "s": "l", "S": "L"},
        {"side": "Right", "s": "r", "S": "R"},
    )

    def fill(v: Any, sub: Mapping[str, str]) -> Any:
        if isinstance(v, str):
            return v.format(**sub)
        if isinstance(v, list):
            return [fill(x, sub) for x in v]
        if isinstance(v, dict):
            return {fill(k, sub): fill(x, sub) for k, x in v.items()}
        return v

    for k, v in template.items():
        if "{" in k:
            for sub in subs:
                out[fill(k, sub)] = fill(v, sub)
        else:
            out[k] = v
    return out


# Thumb tips of CMU-derived skeletons are 4.7 cm from the wrist; a Kinect v2 reports its thumb
# about 9 cm from the wrist (median of kinect2-tracking's walker.json), so the thumb bone is
# extended 1.8 times along its own direction.
_CMU_THUMB = 1.8

_SPECS: dict[str, dict[str, Any]] = {
    # CMU converted by cgspeed / fairmotion (01_01.bvh): LHipJoint -> LeftUpLeg (hip joint) ...;
    # LowerBack, Spine, Spine1 (top of the upper back; the thorax bone is missing), Neck (at
    # Spine1), Neck1 (top of the lower neck), Head (top of the neck), Head/End (top of the head).
    "cgspeed": _lr(
        {
            "SpineBase": "Hips",
            "SpineMid": "Spine1",
            "SpineShoulder": "Neck1",
            "Neck": {"mean": ["Neck1", "Head"]},
            "Head": {"mean": ["Head", "Head/End"]},
            "Shoulder{side}": "{side}Arm",
            "Elbow{side}": "{side}ForeArm",
            "Wrist{side}": "{side}Hand",
            "Hand{side}": {"end_site": "{S}Fingers"},
            "Thumb{side}": {"blend": {"{S}Thumb/End": _CMU_THUMB, "{S}Thumb": 1 - _CMU_THUMB}},
            "Hip{side}": "{side}UpLeg",
            "Knee{side}": "{side}Leg",
            "Ankle{side}": "{side}Foot",
            "Foot{side}": "{side}ToeBase",
        }
    ),
    # CMU in the bvh11 naming (131_01_scaled_metres.bvh): LeftHip (hip joint), LeftKnee,
    # LeftAnkle, LeftToe; lowerback, Chest, Chest2, lowerneck (at Chest2), Neck, Head;
    # LeftCollar, LeftShoulder (shoulder joint), LeftElbow, LeftWrist, lhand, LFingers, LThumb.
    "cmu-bvh11": _lr(
        {
            "SpineBase": "Hips",
            "SpineMid": "Chest2",
            "SpineShoulder": "Neck",
            "Neck": {"mean": ["Neck", "Head"]},
            "Head": {"mean": ["Head", "Head/End"]},
            "Shoulder{side}": "{side}Shoulder",
            "Elbow{side}": "{side}Elbow",
            "Wrist{side}": "{side}Wrist",
            "Hand{side}": {"end_site": "{S}Fingers"},
            "Thumb{side}": {"blend": {"{S}Thumb/End": _CMU_THUMB, "{S}Thumb": 1 - _CMU_THUMB}},
            "Hip{side}": "{side}Hip",
            "Knee{side}": "{side}Knee",
            "Ankle{side}": "{side}Ankle",
            "Foot{side}": "{side}Toe",
        }
    ),
    # Acclaim ASF/AMC (CMU): a name is where that bone starts (its pivot).
    "acclaim": _lr(
        {
            "SpineBase": "root",
            "SpineMid": "thorax",
            "SpineShoulder": "upperneck",
            "Neck": {"mean": ["upperneck", "head"]},
            "Head": {"mean": ["head", "head/End"]},
            "Shoulder{side}": "{s}humerus",
            "Elbow{side}": "{s}radius",
            "Wrist{side}": "{s}hand",
            "Hand{side}": {"end_site": "{s}fingers"},
            "Thumb{side}": {"blend": {"{s}thumb/End": _CMU_THUMB, "{s}thumb": 1 - _CMU_THUMB}},
            "Hip{side}": "{s}femur",
            "Knee{side}": "{s}tibia",
            "Ankle{side}": "{s}foot",
            "Foot{side}": "{s}toes",
        }
    ),
    # Mixamo (names with or without the mixamorig: prefix): Hips, Spine, Spine1, Spine2, Neck
    # (base of the neck), Head (top of the neck), HeadTop_End; LeftShoulder (clavicle), LeftArm,
    # LeftForeArm, LeftHand, LeftHandMiddle1..4, LeftHandThumb1..4; LeftUpLeg, LeftLeg,
    # LeftFoot, LeftToeBase, LeftToe_End.
    "mixamo": _lr(
        {
            "SpineBase": "Hips",
            "SpineMid": ["Spine1", "Spine"],
            "SpineShoulder": "Neck",
            "Neck": {"mean": ["Neck", "Head"]},
            "Head": [
                {"mean": ["Head", "HeadTop_End"]},
                {"mean": ["Head", "Head/End"]},
                "Head",
            ],
            "Shoulder{side}": "{side}Arm",
            "Elbow{side}": "{side}ForeArm",
            "Wrist{side}": "{side}Hand",
            "Hand{side}": ["{side}HandMiddle1", "{side}HandIndex1"],
            "HandTip{side}": ["{side}HandMiddle4", "{side}HandMiddle3"],
            "Thumb{side}": ["{side}HandThumb4", "{side}HandThumb3"],
            "Hip{side}": "{side}UpLeg",
            "Knee{side}": "{side}Leg",
            "Ankle{side}": "{side}Foot",
            "Foot{side}": "{side}ToeBase",
        }
    ),
    # Classic Biovision (the 1990s sample files): Hips, LeftHip, LeftKnee, LeftAnkle, Chest,
    # LeftCollar, LeftUpArm, LeftLowArm, LeftHand, Neck, Head. Hands, thumbs and feet are
    # synthesized (the End Sites of such files vary too much to stand for a Kinect joint).
    "biovision": _lr(
        {
            "SpineBase": "Hips",
            "SpineMid": {"blend": {"Hips": 0.42, "Neck": 0.58}},
            "SpineShoulder": "Neck",
            "Neck": {"mean": ["Neck", "Head"]},
            "Head": [{"mean": ["Head", "Head/End"]}, "Head"],
            "Shoulder{side}": "{side}UpArm",
            "Elbow{side}": "{side}LowArm",
            "Wrist{side}": "{side}Hand",
            "Hip{side}": "{side}Hip",
            "Knee{side}": "{side}Knee",
            "Ankle{side}": "{side}Ankle",
        }
    ),
}

#: The shipped maps by name (``"cgspeed"``, ``"cmu-bvh11"``, ``"acclaim"``, ``"mixamo"``,
#: ``"biovision"``).
BUILTIN_MAPS: dict[str, NameMap] = {
    k: parse_name_map(v, name=k, origin="built-in") for k, v in _SPECS.items()
}


def load_name_map(path: str | Path) -> NameMap:
    """Read a name map from a TOML file.

    The file has an optional ``name``, an optional ``extends`` (a shipped map to start from; the
    file's entries replace its entries joint by joint) and a ``[joints]`` table
    ``KinectJoint = spec`` (spec forms in the module docstring and ``docs/motion.md``).

    Returns
    -------
    NameMap

    Raises
    ------
    InputError
        Unreadable file, TOML syntax error, unknown keys, joints or specs.
    """
    from kinefuse.core.toml import read_toml

    p = Path(path)
    data = read_toml(p, "name map")
    unknown = sorted(set(data) - {"name", "extends", "joints"})
    if unknown:
        raise InputError(
            f"{p}: unknown keys {unknown}; a name map has 'name', 'extends' and a [joints] table"
        )
    joints = data.get("joints")
    if not isinstance(joints, dict) or not joints:
        raise InputError(
            f'{p}: no [joints] table; write e.g.\n[joints]\nSpineBase = "Hips"\n'
            "(see docs/motion.md)"
        )
    name = data.get("name", p.stem)
    if not isinstance(name, str):
        raise InputError(f"{p}: 'name' must be a string, got {name!r}")
    user = parse_name_map(joints, name=name, origin=str(p))
    base_name = data.get("extends")
    if base_name is None:
        return user
    if base_name not in BUILTIN_MAPS:
        raise InputError(
            f"{p}: extends = {base_name!r} is not a shipped map; choose one of "
            f"{', '.join(BUILTIN_MAPS)}"
        )
    merged = dict(BUILTIN_MAPS[base_name].joints)
    merged.update(user.joints)
    return NameMap(name=name, joints=merged, origin=str(p))
