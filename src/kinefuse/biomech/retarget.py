"""Retargeting a source skeleton onto the 25 Kinect v2 joints; units, axes, resampling, placement.

Steps (:func:`retarget`):

1. **Map**: a :class:`~kinefuse.biomech.name_maps.NameMap` (given, or the shipped map that covers
   the source best) says which source joints give each Kinect joint. Positions are pivots: Kinect
   ``ElbowLeft`` is the source joint whose rotation is the elbow's (cgspeed ``LeftForeArm``).
2. **Units**: the ``units`` argument, or the unit among m, cm, mm, in and asf that makes the
   subject's stature plausible (1.2-2.1 m). Stature is estimated from the leg (hip to knee to
   ankle), which is 0.491 of the stature (Drillis & Contini 1966: thigh 0.245 H, shank
   0.246 H), so a source whose trunk or neck is shortened by its conversion still scales right.
3. **Axes**: sources are y up; the lab is z up: world x = source x, world y = -source z,
   world z = source y (a proper rotation).
4. **Synthesis** of joints the map leaves out (in metres, the world frame): rules in
   :data:`SYNTHESIS_RULES`, offsets measured on a real Kinect v2 (kinect2-tracking's
   ``walker.json``: wrist-hand 7.5 cm, hand-tip 7.5 cm, wrist-thumb 8.5-9 cm, ankle-foot 10 cm,
   spine and neck proportions), scaled by stature / 1.70 m. Synthesized joints are flagged in
   :attr:`Motion.synthesized`.

Source hips (BVH ``LeftUpLeg``, ASF ``lfemur``) are the hip joint centres: lower and wider than a
Kinect's ``HipLeft``, which sits about level with ``SpineBase``; we keep the anatomical points
(see ``docs/motion.md``).
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.biomech.name_maps import BUILTIN_MAPS, NameMap, NameResolver, normalize_name
from kinefuse.core.frames.motion import Motion
from kinefuse.core.frames.source_motion import Array, SourceMotion
from kinefuse.core.geometry.rotations import rot_z, unit
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, N_JOINTS
from kinefuse.core.toml import toml_str
from kinefuse.errors import InputError, RetargetError

#: Metres per unit for ``units=`` ("asf" is the ASF's ``0.0254 / length``; 0.0254 / 0.45 for BVH).
UNITS_M: Final[dict[str, float | None]] = {
    "m": 1.0,
    "cm": 0.01,
    "mm": 0.001,
    "in": 0.0254,
    "asf": None,
}
#: Stature range the automatic unit choice accepts, metres.
PLAUSIBLE_HEIGHT_M: Final = (1.2, 2.1)
#: Hip-knee-ankle length as a fraction of stature (Drillis & Contini 1966: 0.245 + 0.246).
LEG_FRACTION_OF_HEIGHT: Final = 0.491
#: Stature the synthesis offsets refer to, metres (assumption: the walker of kinect2-tracking).
SYNTH_REFERENCE_HEIGHT_M: Final = 1.70
#: Height of a standing foot joint above the floor after :func:`place`, metres (a Kinect v2
#: FootLeft/Right stands 1-4 cm above its floor plane in walker.json; assumption: 2 cm).
FOOT_JOINT_HEIGHT_M: Final = 0.02

#: Joints no rule can synthesize: every map must give them.
CORE_JOINTS: Final[tuple[str, ...]] = (
    "Head",
    "ShoulderLeft",
    "ElbowLeft",
    "WristLeft",
    "ShoulderRight",
    "ElbowRight",
    "WristRight",
    "HipLeft",
    "KneeLeft",
    "AnkleLeft",
    "HipRight",
    "KneeRight",
    "AnkleRight",
)

#: What each synthesis rule does (documentation; the code is :func:`_synthesize`).
SYNTHESIS_RULES: Final[dict[str, str]] = {
    "SpineBase": "midpoint of HipLeft and HipRight",
    "SpineShoulder": "shoulder midpoint + 0.066 m along SpineBase->shoulder midpoint",
    "SpineMid": "SpineBase + 0.577 (SpineShoulder - SpineBase)",
    "Neck": "SpineShoulder + 0.365 (Head - SpineShoulder)",
    "Hand": "Wrist + 0.075 m along Elbow->Wrist",
    "HandTip": "Hand + 0.075 m along Wrist->Hand",
    "Thumb": "Wrist + 0.045 m along Wrist->Hand + 0.075 m toward the inside of the elbow "
    "(blended with the body's forward direction when the arm is straight)",
    "Foot": "Ankle + 0.09 m forward (body heading, perpendicular to the shank) + 0.04 m along "
    "Knee->Ankle",
}

_JOINT_HINTS: Final[dict[str, tuple[str, str]]] = {
    "SpineBase": ("pelvis / root joint", "Hips"),
    "Head": ("head (centre, or top of the neck)", "Head"),
    "ShoulderLeft": ("left shoulder joint (where the upper arm rotates)", "LeftArm"),
    "ElbowLeft": ("left elbow (where the forearm rotates)", "LeftForeArm"),
    "WristLeft": ("left wrist (where the hand rotates)", "LeftHand"),
    "HipLeft": ("left hip joint (where the thigh rotates)", "LeftUpLeg"),
    "KneeLeft": ("left knee (where the shank rotates)", "LeftLeg"),
    "AnkleLeft": ("left ankle (where the foot rotates)", "LeftFoot"),
    "ShoulderRight": ("right shoulder joint", "RightArm"),
    "ElbowRight": ("right elbow", "RightForeArm"),
    "WristRight": ("right wrist", "RightHand"),
    "HipRight": ("right hip joint", "RightUpLeg"),
    "KneeRight": ("right knee", "RightLeg"),
    "AnkleRight": ("right ankle", "RightFoot"),
}


_SIDE_WORDS = (("left", "l"), ("right", "r"))


def _side(name: str) -> str | None:
    """``"l"``, ``"r"`` or None: the body side a joint name names (``LeftKnee``, ``rknee``,
    ``Knee_R``, ``l_hip``)."""
    import re

    n = normalize_name(name)
    for word, letter in _SIDE_WORDS:
        if word in n or re.search(rf"(^|[^a-z]){letter}([^a-z]|$)|^{letter}(?=[a-z]{{3}})", n):
            return letter
    return None


def _sideless(name: str) -> str:
    """The normalized name without its side word or letter."""
    import re

    n = normalize_name(name)
    n = re.sub(r"left|right", "", n)
    return re.sub(r"(^|[^a-z])[lr]([^a-z]|$)|^[lr](?=[a-z]{3})", r"\1\2", n)


Resolved = dict[str, tuple[tuple[int, float], ...]]


def resolve_map(names: Sequence[str], name_map: NameMap) -> Resolved:
    """For each Kinect joint the map gives and the source has: ``((source_index, weight), ...)``.

    The first alternative whose joints all exist in ``names`` is taken.
    """
    find = NameResolver(names)
    out: Resolved = {}
    for joint, alts in name_map.joints.items():
        for term in alts:
            found = [(find(n), w) for n, w in term]
            if all(i is not None for i, _ in found):
                out[joint] = tuple((int(i), w) for i, w in found if i is not None)
                break
    return out


def _score(resolved: Resolved) -> tuple[int, int, int]:
    core = sum(j in resolved for j in CORE_JOINTS)
    used = len({i for term in resolved.values() for i, _ in term})
    return (core, len(resolved), used)


def select_map(names: Sequence[str]) -> tuple[NameMap, Resolved]:
    """The shipped map that covers a source skeleton best, with its resolution.

    Maps are ranked by how many of the core joints (:data:`CORE_JOINTS`) they find, then how many
    Kinect joints they find, then how many distinct source joints they use.
    """
    best: tuple[tuple[int, int, int], NameMap, Resolved] | None = None
    for m in BUILTIN_MAPS.values():
        r = resolve_map(names, m)
        s = _score(r)
        if best is None or s > best[0]:
            best = (s, m, r)
    if best is None:
        raise RetargetError("no shipped name maps are available")
    return best[1], best[2]


#: The source joints a mapping error lists by name (a skeleton of 1,000 joints is not listed whole).
_LISTED = 80


def _unmappable(
    src: SourceMotion, name_map: NameMap, resolved: Resolved, chosen: bool
) -> RetargetError:
    missing = [j for j in CORE_JOINTS if j not in resolved]
    if "SpineBase" not in resolved and ("HipLeft" in missing or "HipRight" in missing):
        missing.insert(0, "SpineBase")
    real = [n for n in src.names if not n.endswith("/End")]
    lines = [
        f"cannot map the skeleton of {src.path} onto the Kinect v2 joints.",
        (
            f"With the name map {name_map.name!r} ({name_map.origin})"
            if chosen
            else f"The shipped map that fits best, {name_map.name!r},"
        )
        + f" finds {len(resolved)} of {N_JOINTS} Kinect joints.",
        f"Kinect joints it could not map (no rule can synthesize them): {', '.join(missing)}.",
        f"Source joints seen ({len(real)}): {', '.join(real[:_LISTED])}"
        + (f", ... and {len(real) - _LISTED} more." if len(real) > _LISTED else "."),
        "Write a name map (TOML: Kinect joint = source joint) and pass it with "
        "--name-map MAP.toml; docs/motion.md ('Name maps') explains the format. A minimal map:",
        "",
        'name = "my-skeleton"',
        "[joints]",
    ]
    used = {src.names[i] for term in resolved.values() for i, _ in term}
    for j in ("SpineBase", *CORE_JOINTS):
        what, example = _JOINT_HINTS[j]
        if j in resolved:
            lines.append(f"{j} = {_spec_toml([(src.names[i], w) for i, w in resolved[j]])}")
            continue
        known = {example} | {
            n for m in BUILTIN_MAPS.values() for term in m.joints.get(j, ()) for n, _ in term
        }
        # a suggestion must be on the same side and alike in the rest of its name
        # ("RightCollar" is no knee, however much of "RightKnee" it shares)
        scored = [
            (difflib.SequenceMatcher(None, _sideless(k), _sideless(r)).ratio(), r)
            for k in sorted(known)
            for r in real
            if r not in used and _side(k) == _side(r)
        ]
        best = max(scored, default=(0.0, ""))
        hint = f"; perhaps {best[1]!r}?" if best[0] >= 0.6 else ""
        lines.append(f'{j} = "?"  # {what}{hint}')
    lines.append(
        "# hands, hand tips, thumbs, feet, neck and spine points are synthesized when left out"
    )
    return RetargetError("\n".join(lines))


def _spec_toml(term: Sequence[tuple[str, float]]) -> str:
    """A map entry in TOML for a weighted sum of source joints."""
    if len(term) == 1:
        return toml_str(term[0][0])
    weights = {w for _, w in term}
    if len(weights) == 1:
        return "{ mean = [" + ", ".join(toml_str(n) for n, _ in term) + "] }"
    return "{ blend = { " + ", ".join(f"{toml_str(n)} = {w:g}" for n, w in term) + " } }"


def facing_direction(positions: ArrayLike) -> Array:
    """The body's horizontal forward direction, from the hips and shoulders lines.

    Parameters
    ----------
    positions : (..., 25, 3) float
        Kinect joints in the world frame (z up).

    Returns
    -------
    forward : (..., 3) float
        Horizontal unit vectors (z = 0), pointing to the front of the body.
    """
    p = np.asarray(positions, dtype=np.float64)
    if p.shape[-2:] != (N_JOINTS, 3):
        raise InputError(f"positions must have shape (..., {N_JOINTS}, 3), got {p.shape}")
    j = JOINT_INDEX

    def lateral(a: str, b: str) -> Array:
        v = p[..., j[a], :] - p[..., j[b], :]
        v = v * np.array([1.0, 1.0, 0.0])
        return unit(v, zero=0.0)

    lat = lateral("HipLeft", "HipRight") + lateral("ShoulderLeft", "ShoulderRight")
    fwd = np.stack([lat[..., 1], -lat[..., 0], np.zeros(lat.shape[:-1])], axis=-1)
    return unit(fwd, zero=0.0)


def estimate_height_m(positions: ArrayLike) -> float:
    """Stature estimated from the legs: median hip-knee-ankle length / 0.491.

    Parameters
    ----------
    positions : (T, 25, 3) float
        Kinect joints (any unit: the result is in that unit; metres for a :class:`Motion`).

    Returns
    -------
    height : float
    """
    p = np.asarray(positions, dtype=np.float64)
    if p.ndim != 3 or p.shape[1:] != (N_JOINTS, 3):
        raise InputError(f"positions must have shape (T, {N_JOINTS}, 3), got {p.shape}")
    j = JOINT_INDEX
    leg = 0.0
    for side in ("Left", "Right"):
        hip, knee, ankle = (p[:, j[n + side]] for n in ("Hip", "Knee", "Ankle"))
        leg += 0.5 * float(
            np.nanmedian(
                np.linalg.norm(hip - knee, axis=-1) + np.linalg.norm(knee - ankle, axis=-1)
            )
        )
    return leg / LEG_FRACTION_OF_HEIGHT


def _choose_unit(
    src: SourceMotion, height_file: float, units: str | None
) -> tuple[str, float, str]:
    """(unit name, metres per file unit, how it was chosen)."""
    factors = {k: (src.asf_unit_m if v is None else v) for k, v in UNITS_M.items()}
    if units is not None:
        if units not in factors:
            raise InputError(
                f"units must be one of {', '.join(repr(u) for u in UNITS_M)}, got {units!r}"
            )
        return units, factors[units], "given"
    prefer = (
        ["asf", "m", "cm", "mm", "in"] if src.fmt == "asf/amc" else ["m", "cm", "mm", "in", "asf"]
    )
    lo, hi = PLAUSIBLE_HEIGHT_M
    fits = [u for u in prefer if lo <= height_file * factors[u] <= hi]
    if not fits:
        options = ", ".join(f"{height_file * factors[u]:.3g} m in {u}" for u in prefer)
        raise InputError(
            f"{src.path}: cannot tell the length unit. The subject's stature (from its leg "
            f"length) would be {options}; none is between {lo} and {hi} m. Pass the unit "
            "explicitly, e.g. load_motion(path, units='cm'), with units one of "
            f"{', '.join(repr(u) for u in UNITS_M)}."
        )
    return fits[0], factors[fits[0]], f"auto: stature {height_file * factors[fits[0]]:.2f} m"


def _synthesize(p: Array, have: NDArray[np.bool_], height_m: float) -> NDArray[np.bool_]:
    """Fill the joints not in ``have`` (in place, metres, world frame); return which it filled."""
    j = JOINT_INDEX
    s = height_m / SYNTH_REFERENCE_HEIGHT_M
    made = np.zeros(N_JOINTS, dtype=bool)

    def need(name: str) -> bool:
        return not have[j[name]] and not made[j[name]]

    def put(name: str, value: Array) -> None:
        p[:, j[name]] = value
        made[j[name]] = True

    def at(name: str) -> Array:
        return p[:, j[name]]

    if need("SpineBase"):
        put("SpineBase", 0.5 * (at("HipLeft") + at("HipRight")))
    if need("SpineShoulder"):
        mid = 0.5 * (at("ShoulderLeft") + at("ShoulderRight"))
        put("SpineShoulder", mid + 0.066 * s * unit(mid - at("SpineBase"), zero=0.0))
    if need("SpineMid"):
        put("SpineMid", at("SpineBase") + 0.577 * (at("SpineShoulder") - at("SpineBase")))
    if need("Neck"):
        put("Neck", at("SpineShoulder") + 0.365 * (at("Head") - at("SpineShoulder")))
    forward = facing_direction(p)
    for side in ("Left", "Right"):
        wrist, elbow, shoulder = at("Wrist" + side), at("Elbow" + side), at("Shoulder" + side)
        if need("Hand" + side):
            put("Hand" + side, wrist + 0.075 * s * unit(wrist - elbow, zero=0.0))
        hand = at("Hand" + side)
        if need("HandTip" + side):
            put("HandTip" + side, hand + 0.075 * s * unit(hand - wrist, zero=0.0))
        if need("Thumb" + side):
            f = unit(hand - wrist, zero=0.0)
            u = shoulder - elbow
            inside = u - (u * f).sum(-1, keepdims=True) * f
            fwd = forward - (forward * f).sum(-1, keepdims=True) * f
            scale = np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
            d = unit(inside / scale + 0.3 * fwd, zero=0.0)
            put("Thumb" + side, wrist + s * (0.045 * f + 0.075 * d))
        if need("Foot" + side):
            ankle, knee = at("Ankle" + side), at("Knee" + side)
            shank = unit(ankle - knee, zero=0.0)
            fwd = unit(forward - (forward * shank).sum(-1, keepdims=True) * shank, zero=0.0)
            put("Foot" + side, ankle + s * (0.09 * fwd + 0.04 * shank))
    return made


def retarget(
    src: SourceMotion, *, name_map: NameMap | None = None, units: str | None = None
) -> Motion:
    """Turn a source skeleton sequence into the 25 Kinect v2 joints in the lab frame.

    Parameters
    ----------
    src : SourceMotion
        Joint positions in file units, y up (from :func:`~kinefuse.formats.motion.bvh.read_bvh` or
        :func:`~kinefuse.formats.motion.asf_amc.read_amc`).
    name_map : NameMap, optional
        Which source joints give which Kinect joint; default: the shipped map that fits best.
    units : {"m", "cm", "mm", "in", "asf"}, optional
        The file's length unit; default: the one that gives a plausible stature.

    Returns
    -------
    Motion
        Positions ``(T, 25, 3)`` in metres, z up; synthesized joints flagged; ``source`` tells
        the file, the map, the unit and what was dropped or synthesized.

    Raises
    ------
    RetargetError
        The skeleton cannot be mapped (lists the joints and shows a TOML map to write).
    InputError
        The unit cannot be told (lists the stature each unit would give).
    """
    if name_map is None:
        chosen, resolved = select_map(src.names)
        given = False
    else:
        chosen, resolved, given = name_map, resolve_map(src.names, name_map), True
    if any(j not in resolved for j in CORE_JOINTS):
        raise _unmappable(src, chosen, resolved, given)
    t = src.n_frames
    raw = np.full((t, N_JOINTS, 3), np.nan)
    have = np.zeros(N_JOINTS, dtype=bool)
    for joint, term in resolved.items():
        idx = np.array([i for i, _ in term])
        w = np.array([w for _, w in term])
        raw[:, JOINT_INDEX[joint]] = np.einsum("tkc,k->tc", src.positions[:, idx], w)
        have[JOINT_INDEX[joint]] = True
    height_file = estimate_height_m(raw)
    if not np.isfinite(height_file) or height_file <= 0:
        raise InputError(
            f"{src.path}: the legs have no length (hips, knees and ankles coincide); "
            "check the name map"
        )
    unit, metres, how = _choose_unit(src, height_file, units)
    axes = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # world <- source
    pos = (raw * metres) @ axes.T
    made = _synthesize(pos, have, height_file * metres)
    synth_names = [JOINTS[i] for i in np.flatnonzero(made)]
    parts = [
        f"{src.path} [{src.fmt}]",
        f"map {chosen.name} ({chosen.origin})",
        f"units {unit} ({how})",
        *src.notes,
        "synthesized: " + (", ".join(synth_names) if synth_names else "none"),
    ]
    return Motion(positions=pos, rate_hz=src.rate_hz, synthesized=made, source="; ".join(parts))


def resample(motion: Motion, rate_hz: float) -> Motion:
    """Resample a motion to ``rate_hz`` by linear interpolation (any rate, up or down).

    The new frames are at ``k / rate_hz`` for ``k = 0 .. floor(duration * rate_hz)``.

    Returns
    -------
    Motion
    """
    if (
        isinstance(rate_hz, bool)
        or not isinstance(rate_hz, int | float)
        or not (np.isfinite(rate_hz) and rate_hz > 0)
    ):
        raise InputError(f"rate_hz must be a positive number of frames per second, got {rate_hz!r}")
    n = int(np.floor(motion.duration_s * rate_hz + 1e-9)) + 1
    t = np.arange(n) / float(rate_hz)
    return Motion(
        positions=motion.at(t),
        rate_hz=float(rate_hz),
        synthesized=motion.synthesized.copy(),
        source=f"{motion.source}; resampled {motion.rate_hz:g} -> {rate_hz:g} Hz",
    )


#: A foot joint moving slower than this is taken to stand on the floor, m/s.
FOOT_CONTACT_SPEED_M_S: Final = 0.25


def _foot_contact_z(p: Array, rate_hz: float, window_s: float) -> float:
    """Height of the foot joints where they stand on the floor during the first ``window_s``.

    The median height of the FootLeft/FootRight samples slower than
    :data:`FOOT_CONTACT_SPEED_M_S` (stance); with no such sample (a jump, a run), the lowest
    foot or ankle sample.
    """
    n = min(p.shape[0], max(2, int(np.floor(window_s * rate_hz)) + 1))
    feet = p[:n, [JOINT_INDEX["FootLeft"], JOINT_INDEX["FootRight"]]]
    if n >= 2:
        speed = np.linalg.norm(np.gradient(feet, axis=0), axis=-1) * rate_hz
        still = feet[..., 2][speed < FOOT_CONTACT_SPEED_M_S]
        if still.size:
            return float(np.median(still))
    low = [JOINT_INDEX[k] for k in ("FootLeft", "FootRight", "AnkleLeft", "AnkleRight")]
    return float(p[:n, low, 2].min())


def place(
    motion: Motion,
    offset_m: ArrayLike = (0.0, 0.0),
    heading_deg: float = 0.0,
    *,
    floor_window_s: float = 1.0,
) -> Motion:
    """Put the actor in the lab: position, heading, feet on the floor.

    The motion is rotated about the vertical through its SpineBase at frame 0 so that the initial
    facing direction (:func:`facing_direction` at frame 0) is ``heading_deg`` from the world x
    axis (counter-clockwise seen from above), moved horizontally so that SpineBase at frame 0 is
    at ``offset_m``, and moved vertically so that the feet stand on the floor (z = 0) during the
    first ``floor_window_s`` seconds: the foot joints' median height while they stand still
    (slower than :data:`FOOT_CONTACT_SPEED_M_S`) becomes :data:`FOOT_JOINT_HEIGHT_M`; if they
    never stand still then (a jump, a run), the lowest foot/ankle joint does. The median resists
    the few frames where a capture pushes a toe joint through the floor (CMU 02_walk_a frame 0:
    3.7 cm below its stance height).

    Parameters
    ----------
    motion : Motion
    offset_m : (2,) float
        Floor position (x, y) of SpineBase at frame 0, metres.
    heading_deg : float
        Initial facing direction, degrees from the world x axis.
    floor_window_s : float
        Span of the start used to find the floor contact, seconds.

    Returns
    -------
    Motion
    """
    off = np.asarray(offset_m, dtype=np.float64)
    if off.shape != (2,) or not np.isfinite(off).all():
        raise InputError(f"offset_m must be two finite numbers (x, y) in metres, got {offset_m!r}")
    if not np.isfinite(heading_deg):
        raise InputError(f"heading_deg must be a finite number of degrees, got {heading_deg!r}")
    if not floor_window_s > 0:
        raise InputError(f"floor_window_s must be positive, got {floor_window_s!r}")
    p = motion.positions
    f0 = facing_direction(p[0])
    turn = np.radians(heading_deg) - np.arctan2(f0[1], f0[0])
    r = rot_z(float(turn))
    pivot = p[0, JOINT_INDEX["SpineBase"]] * np.array([1.0, 1.0, 0.0])
    q = (p - pivot) @ r.T
    q[..., :2] += off
    q[..., 2] += FOOT_JOINT_HEIGHT_M - _foot_contact_z(q, motion.rate_hz, floor_window_s)
    return Motion(
        positions=q,
        rate_hz=motion.rate_hz,
        synthesized=motion.synthesized.copy(),
        source=f"{motion.source}; placed at ({off[0]:g}, {off[1]:g}) m heading {heading_deg:g} deg",
    )
