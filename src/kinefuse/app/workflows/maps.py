"""``kinefuse maps``: the marker sets that ship, a map written for a file, a map checked on one.

* :func:`list_maps`: each shipped map (``kinefuse/data/markermaps/``), its joints and a few of
  its markers.
* :func:`suggest_map`: a marker map for a file no shipped set fits, written with ``tomli_w``:
  per Kinect joint, the first rule of a shipped map (the maps naming most of the file's markers
  first) whose markers the file has, under the file's own names; the pelvis of a hip joint
  centre regression, the ISB axes (``[anatomy]``) and the rigid clusters likewise. A joint the
  closest set has but no rule can be built for is written ``"TODO"``, and the header says what
  the closest set uses for it.
* :func:`check_map`: per joint, which rule and which of the file's markers the map uses, and on
  how much of the take they are all present.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from kinefuse.biomech.marker_maps import (
    JointRule,
    MarkerMap,
    load_marker_map,
    map_coverage,
    map_marker_names,
    resolved_rules,
    rule_points,
    shipped_marker_maps,
)
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError
from kinefuse.formats.markers import MarkerResolver, read_markers

__all__ = ["TODO", "MapCheck", "check_map", "format_check", "list_maps", "suggest_map"]

#: The value :func:`suggest_map` writes for a rule it could not infer.
TODO = "TODO"
#: The first line of a map :func:`suggest_map` wrote.
HEADER = "# marker map written by `kinefuse maps suggest`"


def list_maps() -> list[str]:
    """One line per shipped map: name, joints, description, some of its marker names."""
    maps = shipped_marker_maps()
    width = max(len(n) for n in maps)
    lines = [f"{len(maps)} marker sets ship (kinefuse/data/markermaps/):"]
    for name, m in maps.items():
        some = ", ".join(map_marker_names(m)[:6])
        lines.append(f"  {name:<{width}}  {len(m.joints):2d} joints  {m.description} ({some}, ...)")
    lines.append("A file's set is chosen by its marker names; `maps check` with --map and a "
                 "set's name shows how one applies to a file.")  # fmt: skip
    return lines


def _rule_toml(rule: JointRule, finder: MarkerResolver, names: tuple[str, ...]) -> Any:
    """A rule as TOML data under the file's marker names; None when one is not in the file."""
    if rule.kind == "hjc":
        return {"hip_joint_centre": rule.side}
    cols = [finder(n) for n, _ in rule.markers]
    if any(c is None for c in cols):
        return None
    own = [names[int(c)] for c in cols if c is not None]
    if rule.kind == "chord":
        return None  # its centre is a landmark of the shipped map, not a marker of the file
    weights = [w for _, w in rule.markers]
    if len(own) == 1:
        return own[0]
    if np.allclose(weights, weights[0]):
        return {"mean": own}
    return {"blend": dict(zip(own, weights, strict=True))}


def _describe(rule: JointRule, mmap: MarkerMap) -> str:
    """A rule in words, a landmark with where it comes from."""
    if rule.kind == "hjc":
        return f"hip joint centre from {', '.join(rule.marker_names(mmap.pelvis))}"
    out = []
    for n in rule.marker_names(mmap.pelvis):
        if n in mmap.landmarks:
            lm_rule, cluster = mmap.landmarks[n]
            n += f" = {_describe(lm_rule, mmap)} in the static trial, carried by {cluster}"
        out.append(n)
    return ", ".join(out)


def suggest_map(path: Path, out: Path) -> tuple[Path, list[str], list[str]]:
    """Write a marker map for ``path``'s markers to ``out`` (refusing to replace a file).

    Returns
    -------
    out : Path
    inferred : list of str
        The joints written with a rule.
    todo : list of str
        The joints written ``"TODO"``, each with what the closest shipped set uses for it.
    """
    import tomli_w

    from kinefuse.core.outputs import atomic_write_text, never_replace

    markers = read_markers(path)
    names = markers.names
    finder = MarkerResolver(names)
    ranked = sorted(shipped_marker_maps().values(), key=lambda m: -map_coverage(m, finder))
    closest = ranked[0]
    data: dict[str, Any] = {"name": out.stem, "description": f"written for {path.name}"}
    if closest.up is not None:  # else the up axis is inferred from the markers' spread
        data["up"] = closest.up
    pelvis = next(
        (
            m.pelvis
            for m in ranked
            if m.pelvis is not None and all(finder(n) is not None for n in m.pelvis.marker_names())
        ),
        None,
    )
    if pelvis is not None:
        own = {k: names[int(finder(getattr(pelvis, k)) or 0)] for k in ("rasis", "lasis")}
        back = ("sacrum",) if pelvis.sacrum else ("rpsis", "lpsis")
        own |= {k: names[int(finder(getattr(pelvis, k)) or 0)] for k in back}
        data["pelvis"] = {"method": pelvis.method, **own}
    joints: dict[str, Any] = {}
    todo: list[str] = []
    for joint in JOINTS:
        rule_data = None
        for m in ranked:
            for rule in m.joints.get(joint, ()):
                if rule.kind == "hjc" and pelvis is None:
                    continue
                rule_data = _rule_toml(rule, finder, names)
                if rule_data is not None:
                    break
            if rule_data is not None:
                break
        if rule_data is not None:
            joints[joint] = rule_data
        elif joint in closest.joints:
            joints[joint] = TODO
            uses = " | ".join(_describe(r, closest) for r in closest.joints[joint])
            todo.append(f"{joint} ({closest.name} uses {uses})")
    if "SpineBase" not in joints:
        joints["SpineBase"] = TODO
        todo.append("SpineBase (the root: e.g. the midpoint of the pelvis markers)")
    data["joints"] = joints
    anatomy: dict[str, list[str]] = {}
    clusters: dict[str, list[str]] = {}
    for m in ranked:
        for key, pair in m.anatomy.items():
            cols = [finder(n) for n in pair]
            if key not in anatomy and all(c is not None for c in cols):
                anatomy[key] = [names[int(c)] for c in cols if c is not None]
        for limb, members in m.clusters.items():
            cols = [finder(n) for n in members]
            if limb not in clusters and all(c is not None for c in cols):
                clusters[limb] = [names[int(c)] for c in cols if c is not None]
    if clusters:
        data["clusters"] = clusters
    if anatomy:
        data["anatomy"] = anatomy
    head = [
        HEADER,
        f"# for {path} ({len(names)} markers); closest shipped set: {closest.name}.",
        "# Rules: a marker name, { mean = [...] }, { blend = { M = W, ... } },",
        '# { hip_joint_centre = "left" | "right" } (needs [pelvis]), or a list of these.',
    ]
    if todo:
        head.append(f'# {len(todo)} joints are "{TODO}": replace each with a rule (or delete it):')
        head += [f"#   {t}" for t in todo]
    text = "\n".join(head) + "\n\n" + tomli_w.dumps(data)
    atomic_write_text(out, text, what="marker map", recognizer=never_replace)
    return out, [j for j, v in joints.items() if v != TODO], todo


@dataclass(frozen=True)
class MapCheck:
    """What :func:`check_map` found: per joint (rule, markers, fraction of frames present)."""

    map_name: str
    n_frames: int
    joints: dict[str, tuple[str, str, float]]


def check_map(path: Path, map_path: Path | str, static: Path | None = None) -> MapCheck:
    """How a map (a TOML file or a shipped map's name) applies to ``path``'s markers.

    Raises
    ------
    InputError
        A joint is still ``"TODO"`` or names markers the file lacks (each named, and what the
        file has).
    """
    from kinefuse.formats.sequences import resolve_marker_input

    shipped = shipped_marker_maps()
    mmap = shipped[str(map_path)] if str(map_path) in shipped else load_marker_map(map_path)
    todo = [j for j, rules in mmap.joints.items() for r in rules if TODO in r.marker_names(None)]
    if todo:
        raise InputError(
            f"{map_path}: {', '.join(todo)} still {TODO}: write a rule for each (a marker name, "
            "{ mean = [...] }, ...; the header says what the closest set uses) or delete it, "
            f"then run kinefuse maps check {shlex.quote(str(path))} --map "
            f"{shlex.quote(str(map_path))}"
        )
    markers, mmap, _notes, _st = resolve_marker_input(path, marker_map=mmap, static=static)
    chosen, missing = resolved_rules(mmap, markers.names)
    if missing:
        raise InputError(
            f"{path}: the map {mmap.name!r} ({mmap.origin}) names markers the file does not "
            "have: "
            + "; ".join(f"{j}: {' | or | '.join(w)}" for j, w in missing.items())
            + ". Fix those rules (the file's markers: "
            + ", ".join(markers.names[:40])
            + (", ..." if len(markers.names) > 40 else "")
            + ")."
        )
    out: dict[str, tuple[str, str, float]] = {}
    for joint in (j for j in JOINTS if j in chosen):
        rule = chosen[joint]
        alt = mmap.joints[joint].index(rule)
        kind = {"hjc": "hip joint centre", "chord": "chord"}.get(rule.kind, "")
        if not kind:
            kind = "marker" if len(rule.markers) == 1 else "mean" if len(
                {w for _, w in rule.markers}) == 1 else "blend"  # fmt: skip
        label = kind if alt == 0 else f"{kind} (alternative {alt + 1})"
        finder = MarkerResolver(markers.names)
        used = [
            markers.names[c] if (c := finder(n)) is not None else n
            for n in rule.marker_names(mmap.pelvis)
        ]
        pts = rule_points(markers, rule, mmap)
        frac = float(np.isfinite(pts).all(axis=-1).mean()) if pts is not None else 0.0
        out[joint] = (label, ", ".join(used), frac)
    return MapCheck(mmap.name, markers.n_frames, out)


def format_check(
    check: MapCheck, path: Path, map_arg: str, static: Path | None = None
) -> list[str]:
    """The lines ``kinefuse maps check`` prints, ending with the command that analyses."""
    lines = [f"{path}: map {check.map_name!r} builds {len(check.joints)} joints "
             f"({check.n_frames} frames):"]  # fmt: skip
    width = max(len(j) for j in check.joints)
    for joint, (label, used, frac) in check.joints.items():
        lines.append(f"  {joint:<{width}}  {100 * frac:5.1f} % of frames  {label}: {used}")
    st = f" --static {shlex.quote(str(static))}" if static is not None else ""
    lines.append(
        f"next: kinefuse analyze {shlex.quote(str(path))}{st} --map {shlex.quote(map_arg)} "
        "--out results"
    )
    return lines
