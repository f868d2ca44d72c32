"""Marker maps: how optical markers become Kinect v2 joint centres.

A marker map is a TOML file::

    name = "plug-in-gait"            # shown in provenance (default: the file name)
    description = "..."              # optional
    up = "+z"                        # optional: the file axis that points up (default: inferred)

    [pelvis]                         # needed only by hip_joint_centre entries
    method = "harrington2007"        # or "bell1990"
    rasis = "RASI"
    lasis = "LASI"
    rpsis = "RPSI"                   # rpsis + lpsis, or
    lpsis = "LPSI"
    # sacrum = "SACR"                # one sacral marker instead of the two PSIS

    [joints]                         # Kinect v2 joint = rule
    SpineBase = { mean = ["RASI", "LASI", "RPSI", "LPSI"] }
    HipLeft = { hip_joint_centre = "left" }
    KneeLeft = [{ mean = ["LKNE", "LKNM"] }, "LKNE"]   # alternatives: the first the file has
    AnkleLeft = "LANK"                                 # one marker
    SpineMid = { blend = { STRN = 0.5, T10 = 0.5 } }   # weights adding up to 1

    [clusters]                       # optional: rigid marker clusters -> limb orientations
    thigh_left = ["LTH1", "LTH2", "LTH3"]

Rules: a marker name; ``{ mean = [...] }`` (midpoint of several markers); ``{ blend = {...} }``
(weighted sum, weights add up to 1); ``{ hip_joint_centre = "left" | "right" }`` (a regression
from the ``[pelvis]`` markers); or a list of these as alternatives (the first whose markers
are all in the file wins). Every joint of ``[joints]`` is required: when no alternative can be
built, :func:`apply_marker_map` fails naming the missing markers and the file's markers. A
joint is missing in a frame when any marker of its rule is missing there. ``SpineBase`` must be
mapped (it is the root of the Kinect tree); joints a map leaves out are absent from the
sequence. Marker names match exactly, else by landmark
(:class:`kinefuse.formats.markers.MarkerResolver`: ``Derrick:LASI``, ``L_ASIS``, ``ASIS_L``,
``l asis`` and ``L_IAS`` all match ``LASI``).

Hip joint centres (in the pelvis frame of the ISB recommendation, Wu et al. 2002: origin at the
ASIS midpoint, x anterior within the plane of the ASIS and the PSIS midpoint (or sacrum), z from
the left to the right ASIS, y = z x x superior; PW = inter-ASIS distance, PD = distance from the
ASIS midpoint to the PSIS midpoint or sacrum; side s = +1 right, -1 left):

* ``harrington2007``: Harrington, Nathan, Morris & Nokes (2007), "Prediction of the hip joint
  centre in adults, children, and patients with cerebral palsy based on magnetic resonance
  imaging", J. Biomech. 40:595-602, the equations without leg length:
  ``x = -0.24 PD - 9.9 mm``, ``y = -0.30 PW - 10.9 mm``, ``z = s (0.33 PW + 7.3 mm)``.
* ``bell1990``: Bell, Pedersen & Brand (1990), "A comparison of the accuracy of several hip
  center location prediction methods", J. Biomech. 23:617-621:
  ``x = -0.19 PW``, ``y = -0.30 PW``, ``z = s 0.36 PW``.

A ``[clusters]`` entry gives a limb (:data:`kinefuse.biomech.limbs.LIMB_NAMES`) an orientation
per frame from three markers fixed to it (a rigid cluster): ``e1`` from the first to the second
marker, ``e3`` normal to the plane of the three, ``e2 = e3 x e1``; the normalization turns it
into the limb's normalized frame by its constant offset at the default pose (B.1.4), so the
cluster's placement on the limb does not matter. It makes the twist of that limb observable.

The shipped maps (package data ``kinefuse/data/markermaps/``) are listed by
:func:`shipped_marker_maps`; ``docs/maps.md`` says which sets they read and how to write one
(``kinefuse maps suggest``), ``docs/analysis.md`` gives the full format.
"""

from __future__ import annotations

import difflib
import functools
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.name_maps import alternatives, parse_term
from kinefuse.core.frames.marker_data import MarkerData, MarkerResolver, up_rotation
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError

Array = NDArray[np.float64]

__all__ = [
    "HJC_METHODS",
    "JointRule",
    "MarkerMap",
    "PelvisSpec",
    "apply_marker_map",
    "chord_point",
    "cluster_orientations",
    "hip_joint_centres",
    "load_marker_map",
    "map_coverage",
    "map_marker_names",
    "parse_marker_map",
    "resolved_rules",
    "rule_points",
    "select_marker_map",
    "shipped_marker_maps",
    "unbuilt_joints",
]

#: Hip joint centre regressions (see the module docstring for the equations and sources).
HJC_METHODS: Final = ("harrington2007", "bell1990")


@dataclass(frozen=True)
class JointRule:
    """One way to compute a joint: ``kind`` ``"blend"`` (weighted markers), ``"hjc"`` (a hip
    regression) or ``"chord"`` (Plug-in Gait's chord function, :func:`chord_point`)."""

    kind: str
    markers: tuple[tuple[str, float], ...] = ()  # chord: (marker, wand, centre), weights unused
    side: str = ""
    offset_m: float = 0.0  # chord: distance of the centre from the marker

    def marker_names(self, pelvis: PelvisSpec | None) -> tuple[str, ...]:
        if self.kind == "hjc":
            return pelvis.marker_names() if pelvis is not None else ()
        return tuple(n for n, _ in self.markers)


@dataclass(frozen=True)
class PelvisSpec:
    """The pelvis markers of a hip joint centre regression."""

    method: str
    rasis: str
    lasis: str
    rpsis: str = ""
    lpsis: str = ""
    sacrum: str = ""

    def marker_names(self) -> tuple[str, ...]:
        back = (self.sacrum,) if self.sacrum else (self.rpsis, self.lpsis)
        return (self.rasis, self.lasis, *back)


@dataclass(frozen=True)
class MarkerMap:
    """Kinect joint -> alternatives of :class:`JointRule` (see the module docstring)."""

    name: str
    joints: dict[str, tuple[JointRule, ...]] = field(default_factory=dict)
    pelvis: PelvisSpec | None = None
    up: str | None = None
    description: str = ""
    origin: str = "built-in"
    clusters: dict[str, tuple[str, ...]] = field(default_factory=dict)
    landmarks: dict[str, tuple[JointRule, str]] = field(default_factory=dict)
    anatomy: dict[str, tuple[str, str]] = field(default_factory=dict)


def _rule_error(where: str, joint: str, message: str) -> InputError:
    return InputError(
        f"{where}: marker map entry for {joint!r}: {message}. An entry is a marker name, "
        "{ mean = [MARKERS] }, { blend = { MARKER = WEIGHT, ... } }, "
        '{ hip_joint_centre = "left" | "right" } or a list of these (alternatives); see '
        "docs/analysis.md"
    )


def _parse_rule(spec: Any, joint: str, where: str) -> JointRule:
    def error(message: str) -> InputError:
        return _rule_error(where, joint, message)

    term = parse_term(spec, error, noun="marker", end_site=False)
    if term is not None:
        return JointRule("blend", term)
    ((key, val),) = spec.items()
    if key == "hip_joint_centre":
        if val not in ("left", "right"):
            raise error(f'hip_joint_centre must be "left" or "right", got {val!r}')
        return JointRule("hjc", side=str(val))
    if key == "chord":
        want = {"marker", "wand", "centre", "offset_m"}
        if not isinstance(val, Mapping) or set(val) != want:
            raise error(
                "chord needs { marker = M, wand = W, centre = C, offset_m = D } (C: a marker or "
                f"landmark, D in metres), got {val!r}"
            )
        names = [val["marker"], val["wand"], val["centre"]]
        d = val["offset_m"]
        if not all(isinstance(n, str) and n for n in names):
            raise error(f"chord marker, wand and centre must be names, got {names!r}")
        if not isinstance(d, int | float) or not (0.0 < float(d) < 0.2):
            raise error(f"chord offset_m must be a distance in metres (0 to 0.2), got {d!r}")
        return JointRule("chord", tuple((str(n), 0.0) for n in names), offset_m=float(d))
    raise error(f"unknown rule {key!r}")


def parse_marker_map(data: Mapping[str, Any], *, name: str, origin: str) -> MarkerMap:
    """Build a :class:`MarkerMap` from the parsed TOML tables (see the module docstring).

    Raises
    ------
    InputError
        Unknown keys or joints, malformed rules, a hip joint centre without ``[pelvis]``.
    """
    known = {"name", "description", "up", "pelvis", "joints", "clusters", "landmarks", "anatomy"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InputError(
            f"{origin}: unknown keys {unknown}; a marker map has name, description, up, "
            "[pelvis], [joints], [clusters], [landmarks] and [anatomy]"
        )
    clusters: dict[str, tuple[str, ...]] = {}
    from kinefuse.biomech.limbs import LIMB_NAMES

    for limb_name, names in dict(data.get("clusters", {})).items():
        if limb_name not in LIMB_NAMES:
            raise InputError(
                f"{origin}: [clusters] {limb_name!r} is not a limb; the limbs are: "
                f"{', '.join(LIMB_NAMES)}"
            )
        if (
            not isinstance(names, list)
            or len(names) < 3
            or not all(isinstance(n, str) and n for n in names)
        ):
            raise InputError(
                f"{origin}: [clusters] {limb_name} must list three or more marker names, got "
                f"{names!r}"
            )
        clusters[limb_name] = tuple(names)
    landmarks: dict[str, tuple[JointRule, str]] = {}
    for lm_name, spec in dict(data.get("landmarks", {})).items():
        if not isinstance(spec, Mapping) or "cluster" not in spec:
            raise InputError(
                f"{origin}: [landmarks] {lm_name!r} must be a rule with a cluster, e.g. "
                '{ mean = ["R.Knee.Lat", "R.Knee.Med"], cluster = "thigh_right" }'
            )
        rest = {k: v for k, v in spec.items() if k != "cluster"}
        cl = spec["cluster"]
        if cl not in clusters:
            raise InputError(
                f"{origin}: [landmarks] {lm_name!r} is held by cluster {cl!r}, which [clusters] "
                f"does not define (it has: {', '.join(clusters) or 'none'})"
            )
        landmarks[str(lm_name)] = (_parse_rule(rest, str(lm_name), origin), str(cl))
    anatomy: dict[str, tuple[str, str]] = {}
    anat_keys = {
        f"{k}_{side}" for k in ("knee_axis", "ankle_axis", "foot", "elbow_axis", "wrist_axis")
        for side in ("left", "right")
    }  # fmt: skip
    for key, names in dict(data.get("anatomy", {})).items():
        if key not in anat_keys:
            raise InputError(
                f"{origin}: [anatomy] {key!r} is not known; the keys are "
                f"{', '.join(sorted(anat_keys))}"
            )
        if not (
            isinstance(names, list) and len(names) == 2 and all(isinstance(n, str) for n in names)
        ):
            raise InputError(
                f"{origin}: [anatomy] {key} must list two marker names (medial, lateral; for "
                f"the foot heel, toe), got {names!r}"
            )
        anatomy[key] = (names[0], names[1])
    joints_t = data.get("joints")
    if not isinstance(joints_t, Mapping) or not joints_t:
        raise InputError(
            f'{origin}: no [joints] table; write e.g.\n[joints]\nSpineBase = {{ mean = ["RASI", '
            '"LASI", "RPSI", "LPSI"] }\n(see docs/analysis.md)'
        )
    up = data.get("up")
    if up is not None:
        if not isinstance(up, str):
            raise InputError(f'{origin}: up must be a string such as "+y", got {up!r}')
        up_rotation(up)
    pelvis = None
    if "pelvis" in data:
        pt = data["pelvis"]
        if not isinstance(pt, Mapping):
            raise InputError(f"{origin}: [pelvis] must be a table")
        bad = sorted(set(pt) - {"method", "rasis", "lasis", "rpsis", "lpsis", "sacrum"})
        if bad:
            raise InputError(
                f"{origin}: [pelvis] has unknown keys {bad}; it takes method, rasis, lasis and "
                "rpsis + lpsis or sacrum"
            )
        method = pt.get("method", "harrington2007")
        if method not in HJC_METHODS:
            raise InputError(
                f"{origin}: [pelvis] method must be one of {', '.join(HJC_METHODS)}, got {method!r}"
            )
        for k in ("rasis", "lasis"):
            if not isinstance(pt.get(k), str) or not pt[k]:
                raise InputError(f"{origin}: [pelvis] needs {k} = MARKER")
        has_psis = isinstance(pt.get("rpsis"), str) and isinstance(pt.get("lpsis"), str)
        has_sacrum = isinstance(pt.get("sacrum"), str)
        if has_psis == has_sacrum:
            raise InputError(
                f"{origin}: [pelvis] needs either rpsis and lpsis, or sacrum (exactly one of them)"
            )
        pelvis = PelvisSpec(
            method=str(method),
            rasis=pt["rasis"],
            lasis=pt["lasis"],
            rpsis=pt.get("rpsis", ""),
            lpsis=pt.get("lpsis", ""),
            sacrum=pt.get("sacrum", ""),
        )
    joints: dict[str, tuple[JointRule, ...]] = {}
    for joint, spec in joints_t.items():
        if joint not in JOINTS:
            close = difflib.get_close_matches(joint, JOINTS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise InputError(
                f"{origin}: {joint!r} is not a Kinect v2 joint{hint}; the 25 names are: "
                f"{', '.join(JOINTS)}"
            )
        alts = alternatives(spec, functools.partial(_rule_error, origin, joint))
        rules = tuple(_parse_rule(a, joint, origin) for a in alts)
        if any(r.kind == "hjc" for r in rules) and pelvis is None:
            raise _rule_error(origin, joint, "hip_joint_centre needs a [pelvis] table")
        joints[joint] = rules
    if "SpineBase" not in joints:
        raise InputError(
            f"{origin}: the map must give SpineBase (the root of the Kinect tree), e.g. "
            'SpineBase = { mean = ["RASI", "LASI", "RPSI", "LPSI"] }'
        )
    desc = data.get("description", "")
    return MarkerMap(
        name=str(data.get("name", name)),
        joints=joints,
        pelvis=pelvis,
        up=up,
        description=str(desc),
        origin=origin,
        clusters=clusters,
        landmarks=landmarks,
        anatomy=anatomy,
    )


def load_marker_map(path: str | Path) -> MarkerMap:
    """Read a marker map from a TOML file (format in the module docstring).

    Raises
    ------
    InputError
        Unreadable file, TOML syntax error, unknown keys, joints or rules.
    """
    from kinefuse.core.toml import read_toml

    p = Path(path)
    return parse_marker_map(read_toml(p, "marker map"), name=p.stem, origin=str(p))


def shipped_marker_maps() -> dict[str, MarkerMap]:
    """The maps shipped in ``kinefuse/data/markermaps/``, by name."""
    folder = resources.files("kinefuse") / "data" / "markermaps"
    out: dict[str, MarkerMap] = {}
    for entry in sorted(folder.iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".toml"):
            data = tomllib.loads(entry.read_text(encoding="utf-8"))
            m = parse_marker_map(data, name=entry.name[:-5], origin=f"built-in {entry.name}")
            out[m.name] = m
    return out


# ------------------------------------------------------------------------------ resolution


def _resolve(
    mmap: MarkerMap, finder: MarkerResolver, static: MarkerResolver | None = None
) -> tuple[dict[str, JointRule], dict[str, list[str]]]:
    """(joint -> the first buildable rule, joint -> missing markers of each alternative).

    A landmark counts as present when the file has it, or its rule's markers, or (with the
    static trial's names ``static``) the static trial has them and the file its cluster."""
    chosen: dict[str, JointRule] = {}
    missing: dict[str, list[str]] = {}
    for joint, rules in mmap.joints.items():
        why = []
        for rule in rules:
            lack = [n for n in rule.marker_names(mmap.pelvis) if finder(n) is None]
            lack = [n for n in lack if n not in mmap.landmarks]
            for lm in set(rule.marker_names(mmap.pelvis)) & set(mmap.landmarks):
                if finder(lm) is not None:
                    continue
                lm_rule, cluster = mmap.landmarks[lm]
                need = lm_rule.marker_names(mmap.pelvis)
                here = [n for n in need if finder(n) is None]
                if not here:
                    continue
                if static is not None:
                    there = [n for n in need if static(n) is None]
                    carrier = [n for n in mmap.clusters[cluster] if finder(n) is None]
                    if not there and not carrier:
                        continue
                    if carrier and set(carrier) >= set(here) - set(there):
                        lack += here + carrier  # no cluster to carry it: the segment is absent
                    else:
                        lack += [f"{n} (static trial)" for n in there] + carrier
                elif any(finder(n) is None for n in mmap.clusters[cluster]):
                    lack += here  # no cluster to carry it: a static trial would not help
                else:
                    lack += [f"{n} (or a static trial with it)" for n in here]
            if not lack:
                chosen[joint] = rule
                break
            why.append(", ".join(lack))
        else:
            missing[joint] = why
    return chosen, missing


def _partial_ok(chosen: Mapping[str, JointRule], missing: Mapping[str, list[str]]) -> bool:
    """A partial body (:func:`kinefuse.biomech.normalize.partial_body`) whose missing joints
    lack markers the file does not have at all: not landmarks a static trial would give (then
    the error that asks for the static trial stands)."""
    from kinefuse.biomech.normalize import partial_body

    if any("static trial" in w for why in missing.values() for w in why):
        return False
    return partial_body(tuple(chosen)) is not None


def map_marker_names(mmap: MarkerMap) -> tuple[str, ...]:
    """Every marker name a map mentions (joints' alternatives, pelvis, clusters, landmarks'
    rules, anatomy), in order, without its own landmarks."""
    names: list[str] = []
    for rules in mmap.joints.values():
        for r in rules:
            names += r.marker_names(mmap.pelvis)
    if mmap.pelvis is not None:
        names += mmap.pelvis.marker_names()
    for members in mmap.clusters.values():
        names += members
    for rule, _cluster in mmap.landmarks.values():
        names += rule.marker_names(mmap.pelvis)
    for pair in mmap.anatomy.values():
        names += pair
    return tuple(dict.fromkeys(n for n in names if n not in mmap.landmarks))


def map_coverage(mmap: MarkerMap, names: MarkerResolver | tuple[str, ...]) -> int:
    """How many of a file's markers (its names, or their resolver) the map names."""
    finder = names if isinstance(names, MarkerResolver) else MarkerResolver(names)
    return len({c for n in map_marker_names(mmap) if (c := finder(n)) is not None})


def resolved_rules(
    mmap: MarkerMap, names: tuple[str, ...]
) -> tuple[dict[str, JointRule], dict[str, list[str]]]:
    """(joint -> the first rule the markers ``names`` build, joint -> the missing markers of
    each alternative where none is built)."""
    return _resolve(mmap, MarkerResolver(names))


def select_marker_map(markers: MarkerData, static: MarkerData | None = None) -> MarkerMap:
    """The shipped map whose every joint the file's markers (and the static trial's, for the
    map's ``[landmarks]``) can build; of several, the one that names most of the file's markers
    (then the one with most joints). Else the best partial body (upper or lower body only).

    Raises
    ------
    InputError
        No shipped map fits: at most twelve lines with the closest set, per joint what it
        lacks, and the ``kinefuse maps`` commands that write and check a map for the file.
    """
    finder = MarkerResolver(markers.names)
    sf = MarkerResolver(static.names) if static is not None else None
    full: list[tuple[int, int, MarkerMap]] = []
    part: list[tuple[int, int, MarkerMap]] = []
    near: list[tuple[int, int, MarkerMap, dict[str, list[str]]]] = []
    for m in shipped_marker_maps().values():
        chosen, missing = _resolve(m, finder, sf)
        cover = map_coverage(m, finder)
        if not missing:
            full.append((cover, len(chosen), m))
        elif _partial_ok(chosen, missing):
            part.append((len(chosen), cover, m))
        near.append((cover, len(chosen), m, missing))
    for found in (full, part):  # an upper- or lower-body-only capture of a shipped marker set
        if found:
            return max(found, key=lambda f: f[:2])[2]
    raise InputError(_no_fit_message(markers, max(near, key=lambda f: f[:2])))


def _no_fit_message(
    markers: MarkerData, near: tuple[int, int, MarkerMap, dict[str, list[str]]]
) -> str:
    """The error of :func:`select_marker_map`: at most eleven lines (the CLI prints it after
    one ``loading`` line)."""
    import shlex

    cover, built, m, missing = near
    names = markers.names
    shown = ", ".join(names[:8]) + (f", ... ({len(names) - 8} more)" if len(names) > 8 else "")
    lines = [f"{markers.path}: no shipped marker set fits its {len(names)} markers ({shown})."]
    if cover == 0:
        lines.append(
            "No shipped set shares a marker name with it (`kinefuse maps list` shows the sets)."
        )
    else:
        lines.append(
            f"Closest: {m.name!r} ({m.description or m.origin}), {cover} of its markers found; "
            f"it builds {built} of {len(m.joints)} joints and lacks:"
        )
        groups: dict[str, list[str]] = {}
        for joint, why in missing.items():
            groups.setdefault(" | ".join(why), []).append(joint)
        packed: list[str] = []
        left = len(missing)
        for lacks, joints in groups.items():
            item = f"{', '.join(joints)}: {lacks}"
            if packed and len(packed[-1]) + len(item) < 110:
                packed[-1] += f"; {item}"
            elif len(packed) < 5:
                packed.append(f"  {item}")
            else:
                break
            left -= len(joints)
        lines += packed
        if left:
            lines.append(f"  ... and {left} more joints")
        if any("static trial" in w for why in missing.values() for w in why):
            lines.append(
                f"The {m.name} set takes those from the static trial: pass it with --static "
                "(the trial with those markers), or:"
            )
    f = shlex.quote(str(markers.path))
    lines.append(
        f"Write a map for it: kinefuse maps suggest {f} --out my_map.toml (fill the rules "
        "marked TODO),"
    )
    lines.append(
        f"then kinefuse maps check {f} --map my_map.toml, and pass --map my_map.toml "
        "(docs/maps.md)."
    )
    return "\n".join(lines)


def hip_joint_centres(
    rasis: Array, lasis: Array, back: Array, method: str = "harrington2007"
) -> tuple[Array, Array]:
    """Left and right hip joint centres from the pelvis markers, by a published regression.

    Parameters
    ----------
    rasis, lasis : (..., 3) float
        Right and left anterior superior iliac spine markers, metres.
    back : (..., 3) float
        The PSIS midpoint (or the sacral marker), metres.
    method : {"harrington2007", "bell1990"}
        Equations and sources in the module docstring.

    Returns
    -------
    left, right : (..., 3) float
        Hip joint centres, metres, in the markers' frame; NaN where a marker is NaN.
    """
    if method not in HJC_METHODS:
        raise InputError(f"method must be one of {', '.join(HJC_METHODS)}, got {method!r}")
    mid = 0.5 * (rasis + lasis)
    z = rasis - lasis
    pw = np.linalg.norm(z, axis=-1, keepdims=True)
    z = z / np.where(pw > 0, pw, np.nan)
    a = mid - back
    a = a - (a * z).sum(-1, keepdims=True) * z
    x = a / np.linalg.norm(a, axis=-1, keepdims=True)
    y = np.cross(z, x)
    pd = np.linalg.norm(mid - back, axis=-1, keepdims=True)
    if method == "harrington2007":
        cx, cy, cz = -0.24 * pd - 0.0099, -0.30 * pw - 0.0109, 0.33 * pw + 0.0073
    else:
        cx, cy, cz = -0.19 * pw, -0.30 * pw, 0.36 * pw
    base = mid + cx * x + cy * y
    return base - cz * z, base + cz * z


def unbuilt_joints(markers: MarkerData, mmap: MarkerMap) -> dict[str, str]:
    """The map's joints the file's markers cannot build: joint -> the missing markers of each
    alternative (``"LKNE"``, ``"L.Knee, L.MKnee | L.Knee"``), in the map's order; for a map of
    a partial body (an upper- or lower-body marker set), also the body joints it has no rule
    for (``"none: the upper-limb-isb marker set has none"``)."""
    from kinefuse.biomech.normalize import REQUIRED_JOINTS, partial_body

    _, missing = _resolve(mmap, MarkerResolver(markers.names))
    out = {j: " | ".join(w) for j, w in missing.items()}
    if partial_body(tuple(mmap.joints)) is not None:
        for j in REQUIRED_JOINTS:
            if j not in mmap.joints:
                out[j] = f"none: the {mmap.name} marker set has none"
    return out


def chord_point(centre: Array, marker: Array, wand: Array, offset_m: float) -> Array:
    """Plug-in Gait's chord function: the joint centre ``J`` at ``offset_m`` from ``marker``
    (``M``), in the plane of ``centre`` (``P``, the proximal joint centre), ``M`` and ``wand``
    (``W``), with ``P - J`` at right angles to ``M - J``; on the side of the line ``M -> P``
    away from ``W`` (the wand marker is lateral, the centre medial of the marker). Shapes
    ``(..., 3)``; NaN where an input is."""
    u = centre - marker
    length = np.linalg.norm(u, axis=-1, keepdims=True)
    u = u / length
    w = wand - marker
    v = w - (w * u).sum(-1, keepdims=True) * u
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    a = offset_m**2 / length
    b = np.sqrt(np.clip(offset_m**2 - a**2, 0.0, None))
    return np.asarray(marker + a * u - b * v, dtype=np.float64)


def rule_points(markers: MarkerData, rule: JointRule, mmap: MarkerMap) -> Array | None:
    """``(T, 3)`` of one rule on ``markers`` (metres), None when a name is not in the file."""
    f = MarkerResolver(markers.names)
    p = markers.positions
    if rule.kind == "hjc":
        pv = mmap.pelvis
        if pv is None:
            return None
        idx = [f(n) for n in pv.marker_names()]
        if any(i is None for i in idx):
            return None
        ci = [int(i) for i in idx if i is not None]
        back = p[:, ci[2]] if pv.sacrum else 0.5 * (p[:, ci[2]] + p[:, ci[3]])
        left, right = hip_joint_centres(p[:, ci[0]], p[:, ci[1]], back, pv.method)
        return left if rule.side == "left" else right
    idx = [f(n) for n, _ in rule.markers]
    if any(i is None for i in idx):
        return None
    cols = [p[:, int(i)] for i in idx if i is not None]
    if rule.kind == "chord":
        return chord_point(cols[2], cols[0], cols[1], rule.offset_m)
    w = np.array([wt for _, wt in rule.markers], dtype=np.float64)
    return np.asarray(np.einsum("ktc,k->tc", np.stack(cols), w), dtype=np.float64)


def _with_direct_landmarks(markers: MarkerData, mmap: MarkerMap) -> MarkerData:
    """``markers`` with every ``[landmarks]`` entry the file lacks but has its rule's markers
    appended, computed from them (a static trial's landmarks come in already carried by their
    clusters: :func:`kinefuse.biomech.static_trial.with_landmarks`)."""
    from dataclasses import replace

    out = markers
    for lm, (rule, _cluster) in mmap.landmarks.items():  # in order: one may use an earlier one
        if MarkerResolver(out.names)(lm) is not None:
            continue
        pts = rule_points(out, rule, mmap)
        if pts is None:
            continue
        out = replace(out, names=(*out.names, lm),
                      positions=np.concatenate([out.positions, pts[:, None]], axis=1))  # fmt: skip
    return out


def apply_marker_map(
    markers: MarkerData, mmap: MarkerMap, *, partial: bool = False
) -> tuple[Array, tuple[str, ...], tuple[str, ...]]:
    """Joint centres from markers through a map.

    Parameters
    ----------
    markers : MarkerData
    mmap : MarkerMap
    partial : bool
        Accept a partial body: when the joints the file cannot build leave SpineBase and the
        upper body (or the lower body) of
        :func:`kinefuse.biomech.normalize.partial_body`, those joints are left out (absent
        from the result; :func:`unbuilt_joints` says why) instead of failing.

    Returns
    -------
    positions : (T, J, 3) float
        Joint centres, metres, z up; NaN where a marker of the joint's rule is missing.
    joint_names : tuple of str, length J
        The mapped Kinect joints, in :data:`kinefuse.core.skeleton.JOINTS` order.
    notes : tuple of str
        Which alternative each joint used when it was not the first.

    Raises
    ------
    InputError
        A joint of the map cannot be built: names the joint, the missing markers of each
        alternative, the file's markers and close matches.
    """
    markers = _with_direct_landmarks(markers, mmap)
    finder = MarkerResolver(markers.names)
    chosen, missing = _resolve(mmap, finder)
    if missing and not (partial and _partial_ok(chosen, missing)):
        lines = [
            f"{markers.path}: the marker map {mmap.name!r} ({mmap.origin}) names markers the "
            "file does not have:"
        ]
        for joint, why in missing.items():
            wanted = [n for w in why for n in w.split(", ")]
            close = {c for n in wanted for c in difflib.get_close_matches(n, markers.names, n=2)}
            hint = f" (close: {', '.join(sorted(close))})" if close else ""
            lines.append(f"  {joint}: missing {' | or | '.join(why)}{hint}")
        lines.append(f"The file's {len(markers.names)} markers: {', '.join(markers.names)}.")
        if partial:
            lines.append(
                "Nothing can be analysed without them: a partial body needs SpineBase and either "
                "the upper body (SpineMid, SpineShoulder, ShoulderLeft, ShoulderRight) or the "
                "lower body (HipLeft, KneeLeft, AnkleLeft, HipRight, KneeRight, AnkleRight)."
            )
        lines.append("Fix the map (docs/analysis.md, 'Marker maps') or pass another with --map.")
        raise InputError("\n".join(lines))
    p = markers.positions
    names = tuple(j for j in JOINTS if j in chosen)
    out = np.full((p.shape[0], len(names), 3), np.nan)
    hips: tuple[Array, Array] | None = None
    notes = []
    for k, joint in enumerate(names):
        rule = chosen[joint]
        if rule is not mmap.joints[joint][0]:
            alt = mmap.joints[joint].index(rule) + 1
            notes.append(f"{joint} from alternative {alt} ({', '.join(rule.marker_names(None))})")
        if rule.kind == "hjc":
            if hips is None:
                pv = mmap.pelvis
                assert pv is not None  # parse_marker_map checks it
                col = {n: int(finder(n) or 0) for n in pv.marker_names()}
                back = (
                    p[:, col[pv.sacrum]]
                    if pv.sacrum
                    else 0.5 * (p[:, col[pv.rpsis]] + p[:, col[pv.lpsis]])
                )
                hips = hip_joint_centres(p[:, col[pv.rasis]], p[:, col[pv.lasis]], back, pv.method)
            out[:, k] = hips[0] if rule.side == "left" else hips[1]
        else:
            pts = rule_points(markers, rule, mmap)
            assert pts is not None  # all its markers are in the file (_resolve)
            out[:, k] = pts
    return out, names, tuple(notes)


def cluster_orientations(
    markers: MarkerData, mmap: MarkerMap, *, partial: bool = False
) -> tuple[tuple[str, ...], Array | None]:
    """Limb orientations from the map's rigid marker clusters (see the module docstring).

    Returns
    -------
    limbs : tuple of str
    orientations : (T, L, 3, 3) float or None
        Cluster-to-world rotations, NaN where a marker is missing; None without clusters.

    Raises
    ------
    InputError
        A cluster of a map the user gave names markers the file lacks (a shipped map chosen by
        the file's names, or a partial body, leaves such a cluster out: its segment then has
        no cluster orientation, and its status says so).
    """
    if not mmap.clusters:
        return (), None
    finder = MarkerResolver(markers.names)
    lack = {k: [n for n in v if finder(n) is None] for k, v in mmap.clusters.items()}
    lack = {k: v for k, v in lack.items() if v}
    clusters = dict(mmap.clusters)
    if lack and (partial or mmap.origin.startswith("built-in")):
        clusters = {k: v for k, v in clusters.items() if k not in lack}
        if not clusters:
            return (), None
    elif lack:
        raise InputError(
            f"{markers.path}: the marker map {mmap.name!r} ({mmap.origin}) names cluster markers "
            "the file does not have: "
            + "; ".join(f"{k}: {', '.join(v)}" for k, v in lack.items())
            + f". The file's markers: {', '.join(markers.names)}."
        )
    p = markers.positions
    out = []
    for names in clusters.values():
        a, b, c = (p[:, int(finder(n) or 0)] for n in names[:3])  # the first three
        e1 = b - a
        e1 = e1 / np.linalg.norm(e1, axis=-1, keepdims=True)
        e3 = np.cross(e1, c - a)
        e3 = e3 / np.linalg.norm(e3, axis=-1, keepdims=True)
        out.append(np.stack([e1, np.cross(e3, e1), e3], axis=-1))
    return tuple(clusters), np.stack(out, axis=1)
