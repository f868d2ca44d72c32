"""Acclaim ASF (skeleton) + AMC (motion) reader with forward kinematics.

Acclaim's convention, as read here (column vectors):

* Every bone has an ``axis a b c ORDER``: the orientation ``C`` of its local frame, the product of
  the elementary rotations in ``ORDER`` with the first letter applied first (``XYZ`` gives
  ``C = Rz(c) @ Ry(b) @ Rx(a)``).
* The AMC values of a bone are its ``dof`` angles in the listed order; their rotation ``M`` is
  composed the same way (first listed applied first). The bone's world rotation is
  ``G = G_parent @ C @ M @ C^-1``; it ends at ``start + length * G @ direction`` (``direction``
  and ``length`` from the ASF, in the world frame of the rest pose), and its children start there.
* The root's AMC line holds the values named by ``:root order`` (``TX TY TZ RX RY RZ``); its
  rotation is ``C_root @ M_root @ C_root^-1`` with ``C_root`` from ``orientation`` and ``axis``.
  The root's position is the translation values.
* Angles follow ``:DEGREES``/``:RADIANS`` in the AMC (else the ASF's ``:units angle``, else
  degrees). Lengths stay in file units; ``:units length L`` says the file unit is ``1/L`` inch
  (CMU: ``L = 0.45``), which :attr:`SourceMotion.asf_unit_m` records as ``0.0254 / L`` metres.

Joint naming follows the BVH pivot semantics: the position named ``X`` is where bone ``X`` starts
(where it rotates), ``"root"`` is the root, and the end of a leaf bone ``X`` is ``"X/End"``.
Translation and length dofs (``tx ty tz l``) on bones are not read; such a file raises
:class:`kinefuse.errors.MotionFormatError`, as does any malformed line (with its line number).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kinefuse.core.frames.source_motion import (
    END_SITE_SUFFIX,
    Array,
    SourceMotion,
    read_motion_text,
)
from kinefuse.core.geometry.rotations import euler_rotations
from kinefuse.errors import MotionFormatError

_AXES = {"x": 0, "y": 1, "z": 2}


@dataclass
class _Bone:
    name: str
    line: int
    direction: Array = field(default_factory=lambda: np.zeros(3))
    length: float = 0.0
    axis_deg: Array = field(default_factory=lambda: np.zeros(3))
    axis_order: str = "XYZ"
    dof: list[str] = field(default_factory=list)
    parent: str | None = None
    children: list[str] = field(default_factory=list)


@dataclass
class AsfSkeleton:
    """An Acclaim skeleton as read from an ASF file (lengths in file units).

    Attributes
    ----------
    path : str
    length_mult : float
        ``:units length`` (file unit = ``1 / length_mult`` inch).
    angle_unit : str
        ``"deg"`` or ``"rad"``: the unit of ``axis``/``orientation`` angles (and of AMC values
        unless the AMC says otherwise).
    root_order : list of str
        The root's AMC value order, e.g. ``["tx", "ty", "tz", "rx", "ry", "rz"]``.
    root_axis : str
    root_orientation : (3,) float
    bones : dict of str to bone
        In hierarchy order (parents first).
    """

    path: str
    length_mult: float = 1.0
    angle_unit: str = "deg"
    root_order: list[str] = field(default_factory=lambda: ["tx", "ty", "tz", "rx", "ry", "rz"])
    root_axis: str = "XYZ"
    root_orientation: Array = field(default_factory=lambda: np.zeros(3))
    bones: dict[str, _Bone] = field(default_factory=dict)


def _clean(line: str) -> str:
    return line.split("#", 1)[0].strip()


def _floats(parts: list[str], n: int, what: str, path: str, line: int) -> Array:
    if len(parts) < n:
        raise MotionFormatError(f"{what} needs {n} numbers, got {len(parts)}", path=path, line=line)
    try:
        return np.array([float(x) for x in parts[:n]])
    except ValueError:
        raise MotionFormatError(
            f"{what} needs {n} numbers, got {' '.join(parts[:n])!r}", path=path, line=line
        ) from None


def _order(text: str, path: str, line: int) -> str:
    t = text.upper()
    if len(t) != 3 or sorted(t) != ["X", "Y", "Z"]:
        raise MotionFormatError(
            f"an axis order must be a permutation of XYZ, got {text!r}", path=path, line=line
        )
    return t


def parse_asf(text: str, *, path: str = "<string>") -> AsfSkeleton:
    """Parse ASF text (``:units``, ``:root``, ``:bonedata``, ``:hierarchy``).

    Raises
    ------
    MotionFormatError
        With the file and the 1-based line of the problem.
    """
    sk = AsfSkeleton(path=path)
    section = ""
    bone: _Bone | None = None
    bones: dict[str, _Bone] = {}
    hierarchy_open = False
    edges: list[tuple[str, str, int]] = []
    seen_sections: set[str] = set()
    for no, raw in enumerate(text.splitlines(), start=1):
        line = _clean(raw)
        if not line:
            continue
        parts = line.split()
        key = parts[0].lower()
        if key.startswith(":"):
            section = key
            seen_sections.add(section)
            if bone is not None:
                raise MotionFormatError(
                    f"bone {bone.name!r} (line {bone.line}) has no 'end'", path=path, line=no
                )
            continue
        if section == ":units":
            if key == "length":
                v = float(_floats(parts[1:], 1, "units length", path, no)[0])
                if not v > 0:
                    raise MotionFormatError(
                        f"units length must be positive, got {v:g}", path=path, line=no
                    )
                sk.length_mult = v
            elif key == "angle":
                unit = parts[1].lower() if len(parts) > 1 else ""
                if unit not in ("deg", "rad"):
                    raise MotionFormatError(
                        f"units angle must be 'deg' or 'rad', got {unit!r}", path=path, line=no
                    )
                sk.angle_unit = unit
        elif section == ":root":
            if key == "order":
                order = [p.lower() for p in parts[1:]]
                bad = [p for p in order if p not in ("tx", "ty", "tz", "rx", "ry", "rz")]
                if bad or not order:
                    raise MotionFormatError(
                        f"root order must list TX TY TZ RX RY RZ, got {' '.join(parts[1:])!r}",
                        path=path,
                        line=no,
                    )
                sk.root_order = order
            elif key == "axis":
                sk.root_axis = _order(parts[1] if len(parts) > 1 else "", path, no)
            elif key == "orientation":
                sk.root_orientation = _floats(parts[1:], 3, "root orientation", path, no)
        elif section == ":bonedata":
            if key == "begin":
                bone = _Bone(name="", line=no)
            elif key == "end":
                if bone is None:
                    raise MotionFormatError("'end' without 'begin'", path=path, line=no)
                if not bone.name:
                    raise MotionFormatError(
                        f"the bone that begins at line {bone.line} has no name", path=path, line=no
                    )
                if bone.name in bones or bone.name == "root":
                    raise MotionFormatError(
                        f"bone name {bone.name!r} is used twice", path=path, line=no
                    )
                bones[bone.name] = bone
                bone = None
            elif bone is None:
                raise MotionFormatError(
                    f"{parts[0]!r} outside a begin/end bone block", path=path, line=no
                )
            elif key == "name":
                bone.name = parts[1] if len(parts) > 1 else ""
            elif key == "direction":
                bone.direction = _floats(parts[1:], 3, "direction", path, no)
            elif key == "length":
                bone.length = float(_floats(parts[1:], 1, "length", path, no)[0])
            elif key == "axis":
                bone.axis_deg = _floats(parts[1:], 3, "axis", path, no)
                bone.axis_order = _order(parts[4] if len(parts) > 4 else "XYZ", path, no)
            elif key == "dof":
                dof = [p.lower() for p in parts[1:]]
                unsupported = [d for d in dof if d not in ("rx", "ry", "rz")]
                if unsupported:
                    raise MotionFormatError(
                        f"bone {bone.name!r}: dof {' '.join(unsupported)} not supported (only "
                        "rx ry rz on bones; translations only on the root)",
                        path=path,
                        line=no,
                    )
                bone.dof = dof
        elif section == ":hierarchy":
            if key == "begin":
                hierarchy_open = True
            elif key == "end":
                hierarchy_open = False
            elif hierarchy_open:
                for child in parts[1:]:
                    edges.append((parts[0], child, no))
    if bone is not None:
        raise MotionFormatError(
            f"bone {bone.name!r} (line {bone.line}) has no 'end'", path=path, line=bone.line
        )
    for needed in (":bonedata", ":hierarchy"):
        if needed not in seen_sections:
            raise MotionFormatError(f"no {needed} section: is this an ASF file?", path=path)
    for parent, child, no in edges:
        if child not in bones:
            raise MotionFormatError(
                f"hierarchy names bone {child!r}, which :bonedata does not define",
                path=path,
                line=no,
            )
        if parent != "root" and parent not in bones:
            raise MotionFormatError(
                f"hierarchy names bone {parent!r}, which :bonedata does not define",
                path=path,
                line=no,
            )
        if bones[child].parent is not None:
            raise MotionFormatError(
                f"bone {child!r} has two parents in the hierarchy", path=path, line=no
            )
        bones[child].parent = parent
        if parent != "root":
            bones[parent].children.append(child)
    orphans = [b for b in bones.values() if b.parent is None]
    if orphans:
        raise MotionFormatError(
            f"bones not reached from the root in :hierarchy: {', '.join(b.name for b in orphans)}",
            path=path,
            line=orphans[0].line,
        )
    # order parents first
    ordered: dict[str, _Bone] = {}
    frontier = [b.name for b in bones.values() if b.parent == "root"]
    while frontier:
        name = frontier.pop(0)
        ordered[name] = bones[name]
        frontier.extend(bones[name].children)
    if len(ordered) != len(bones):
        cyc = sorted(set(bones) - set(ordered))
        raise MotionFormatError(f"the hierarchy has a cycle through {', '.join(cyc)}", path=path)
    sk.bones = ordered
    return sk


def read_asf(path: str | Path) -> AsfSkeleton:
    """Read an ASF file; see :func:`parse_asf`."""
    p = Path(path)
    text = read_motion_text(p)
    return parse_asf(text, path=str(p))


def _rotation(order: str, angles_rad: Array) -> Array:
    """``(T, 3, 3)``: elementary rotations in ``order`` (e.g. ``"XYZ"``), first applied first.

    ``angles_rad`` is ``(T, 3)`` indexed by axis x, y, z.
    """
    axes = [_AXES[c.lower()] for c in reversed(order)]
    return euler_rotations(axes, [angles_rad[:, a] for a in axes], angles_rad.shape[0])


def parse_amc(
    text: str, skeleton: AsfSkeleton, *, path: str = "<string>", rate_hz: float = 120.0
) -> SourceMotion:
    """Parse AMC text against its skeleton and run forward kinematics.

    Parameters
    ----------
    text : str
        The AMC file.
    skeleton : AsfSkeleton
        From :func:`read_asf`.
    path : str
        Shown in errors and provenance.
    rate_hz : float
        The capture rate (AMC files do not carry it; CMU captured at 120 Hz).

    Returns
    -------
    SourceMotion
        Positions ``(T, J, 3)`` of the root, the start of every bone and the end of every leaf
        bone, in ASF file units, y up.
    """
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be a positive number, got {rate_hz!r}")
    bones = skeleton.bones
    ndof = {"root": len(skeleton.root_order)}
    ndof.update({n: len(b.dof) for n, b in bones.items() if b.dof})
    values: dict[str, list[list[str]]] = {n: [] for n in ndof}
    value_lines: dict[str, list[int]] = {n: [] for n in ndof}
    degrees = skeleton.angle_unit == "deg"
    frame_lines: list[int] = []
    seen: set[str] = set()

    def close_frame(end_line: int) -> None:
        if frame_lines and len(seen) != len(ndof):
            missing = sorted(set(ndof) - seen)
            raise MotionFormatError(
                f"frame {len(frame_lines)} (starting at line {frame_lines[-1]}) lacks "
                f"{', '.join(missing)}",
                path=path,
                line=end_line,
            )
        seen.clear()

    lines = text.splitlines()
    for no, raw in enumerate(lines, start=1):
        line = _clean(raw)
        if not line:
            continue
        if line.startswith(":"):
            word = line.split()[0].upper()
            if word == ":DEGREES":
                degrees = True
            elif word == ":RADIANS":
                degrees = False
            continue
        parts = line.split()
        if len(parts) == 1 and parts[0].isdigit():
            close_frame(no)
            frame_lines.append(no)
            continue
        name = parts[0]
        if not frame_lines:
            raise MotionFormatError(f"{name!r} before the first frame number", path=path, line=no)
        if name not in ndof:
            known = "root, " + ", ".join(n for n in ndof if n != "root")
            why = "has no dof in the ASF" if name in bones else "is not a bone of the ASF"
            raise MotionFormatError(
                f"{name!r} {why} ({skeleton.path}); bones with values: {known}",
                path=path,
                line=no,
            )
        if name in seen:
            raise MotionFormatError(
                f"{name!r} appears twice in frame {len(frame_lines)}", path=path, line=no
            )
        if len(parts) - 1 != ndof[name]:
            raise MotionFormatError(
                f"{name!r} needs {ndof[name]} values, got {len(parts) - 1}", path=path, line=no
            )
        seen.add(name)
        values[name].append(parts[1:])
        value_lines[name].append(no)
    if not frame_lines:
        raise MotionFormatError(
            "no frames (no frame number lines): is this an AMC file?", path=path
        )
    close_frame(len(lines) + 1)
    arrays: dict[str, Array] = {}
    for name, rows in values.items():
        try:
            a = np.array(rows, dtype=np.float64)
        except ValueError:
            for row, no in zip(rows, value_lines[name], strict=True):
                for tok in row:
                    try:
                        float(tok)
                    except ValueError:
                        raise MotionFormatError(
                            f"{tok!r} is not a number", path=path, line=no
                        ) from None
            raise
        if not np.isfinite(a).all():
            r = int(np.argwhere(~np.isfinite(a))[0][0])
            raise MotionFormatError("a value is not finite", path=path, line=value_lines[name][r])
        arrays[name] = a
    return _amc_kinematics(skeleton, arrays, len(frame_lines), degrees, path, rate_hz)


def _amc_kinematics(
    sk: AsfSkeleton,
    arrays: dict[str, Array],
    t: int,
    degrees: bool,
    path: str,
    rate_hz: float,
) -> SourceMotion:
    to_rad = np.pi / 180.0 if degrees else 1.0
    axis_to_rad = np.pi / 180.0 if sk.angle_unit == "deg" else 1.0
    root = arrays["root"]
    trans = np.zeros((t, 3))
    rot_angles: list[tuple[int, Array]] = []
    for k, name in enumerate(sk.root_order):
        if name[0] == "t":
            trans[:, _AXES[name[1]]] = root[:, k]
        else:
            rot_angles.append((_AXES[name[1]], root[:, k] * to_rad))
    m_root = euler_rotations(
        [a for a, _ in reversed(rot_angles)], [v for _, v in reversed(rot_angles)], t
    )
    c_root = _rotation(sk.root_axis, (sk.root_orientation * axis_to_rad)[None, :])[0]
    g: dict[str, Array] = {"root": c_root @ m_root @ c_root.T}
    start: dict[str, Array] = {}
    end: dict[str, Array] = {"root": trans}
    names = ["root"]
    parents = [-1]
    index = {"root": 0}
    positions = [trans]
    rotations = [g["root"] @ c_root]
    for name, b in sk.bones.items():
        parent = b.parent or "root"
        c = _rotation(b.axis_order, (b.axis_deg * axis_to_rad)[None, :])[0]
        if b.dof:
            vals = arrays[name] * to_rad
            order = "".join(d[1] for d in b.dof)
            axes = [_AXES[ch] for ch in reversed(order)]
            cols = {d[1]: k for k, d in enumerate(b.dof)}
            m = euler_rotations(axes, [vals[:, cols["xyz"[a]]] for a in axes], t)
        else:
            m = np.broadcast_to(np.eye(3), (t, 3, 3))
        g[name] = g[parent] @ (c @ m @ c.T)
        start[name] = end[parent]
        end[name] = start[name] + b.length * np.einsum("tij,j->ti", g[name], b.direction)
        index[name] = len(names)
        names.append(name)
        parents.append(index[parent])
        positions.append(start[name])
        rotations.append(g[name] @ c)
    for name, b in sk.bones.items():
        if not b.children:
            names.append(name + END_SITE_SUFFIX)
            parents.append(index[name])
            positions.append(end[name])
            rotations.append(rotations[index[name]])
    return SourceMotion(
        names=tuple(names),
        parents=tuple(parents),
        positions=np.stack(positions, axis=1),
        rate_hz=float(rate_hz),
        path=path,
        fmt="asf/amc",
        asf_unit_m=0.0254 / sk.length_mult,
        rotations=np.stack(np.broadcast_arrays(*rotations), axis=1),
    )


def read_amc(amc_path: str | Path, asf_path: str | Path, *, rate_hz: float = 120.0) -> SourceMotion:
    """Read an AMC clip with its ASF skeleton into joint positions (file units, y up)."""
    sk = read_asf(asf_path)
    p = Path(amc_path)
    text = read_motion_text(p)
    motion = parse_amc(text, sk, path=str(p), rate_hz=rate_hz)
    return SourceMotion(
        names=motion.names,
        parents=motion.parents,
        positions=motion.positions,
        rate_hz=motion.rate_hz,
        path=f"{p} (skeleton {Path(asf_path)})",
        fmt=motion.fmt,
        asf_unit_m=motion.asf_unit_m,
        notes=motion.notes,
        rotations=motion.rotations,
    )
