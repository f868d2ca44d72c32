"""Biovision Hierarchy (BVH) reader: hierarchy, any channel order, forward kinematics.

Conventions of the format as read here:

* A joint's world transform is ``parent @ T(translation) @ R``, where ``R`` is the product of the
  joint's rotation channels in the order they are listed (``Zrotation Yrotation Xrotation``
  gives ``Rz @ Ry @ Rx``: the last listed rotation is applied to vectors first), angles in degrees.
* ``translation`` is the joint's ``OFFSET``; a position channel (``Xposition`` ...), on the root or
  on any other joint, replaces the matching component of the offset (as Blender and MotionBuilder
  read it).
* The position of joint ``X`` is where ``X`` pivots; an End Site under ``X`` is named ``"X/End"``.
* Values are read as float64. A frame time within 0.01 % of a whole rate (``0.0083333`` s) is
  read as that rate (120 Hz). Frame 0 of some files (e.g. CMU conversions) is an inserted T-pose;
  it is detected (:func:`kinefuse.core.frames.source_motion.leading_outlier_frames`, or all
  rotations zero at frame 0 while the next frame is not, with a jump to frame 1) and dropped, and
  the drop is recorded in :attr:`SourceMotion.notes`.

Errors name the file and the 1-based line: :class:`kinefuse.errors.MotionFormatError`.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kinefuse.core.frames.source_motion import (
    END_SITE_SUFFIX,
    Array,
    SourceMotion,
    leading_outlier_frames,
    read_motion_text,
)
from kinefuse.core.geometry.rotations import euler_rotations
from kinefuse.errors import MotionFormatError

_CHANNELS = {
    "xposition": ("pos", 0),
    "yposition": ("pos", 1),
    "zposition": ("pos", 2),
    "xrotation": ("rot", 0),
    "yrotation": ("rot", 1),
    "zrotation": ("rot", 2),
}
_TOKEN = re.compile(r"[{}]|[^\s{}]+")


@dataclass
class _Joint:
    name: str
    parent: int
    line: int
    offset: Array = field(default_factory=lambda: np.zeros(3))
    channels: list[tuple[str, int]] = field(default_factory=list)
    first_channel: int = 0
    end_site: bool = False


class _Tokens:
    """Hierarchy tokens with their 1-based line numbers."""

    def __init__(self, lines: list[str], path: str) -> None:
        self.path = path
        self.items: list[tuple[str, int]] = []
        self.motion_line = 0
        for no, line in enumerate(lines, start=1):
            toks = _TOKEN.findall(line)
            if toks and toks[0].upper() == "MOTION":
                self.motion_line = no
                break
            self.items.extend((t, no) for t in toks)
        self.pos = 0
        self.last_line = len(lines)

    def fail(self, message: str, line: int | None = None) -> MotionFormatError:
        if line is None:
            line = self.items[self.pos][1] if self.pos < len(self.items) else self.end_line()
        return MotionFormatError(message, path=self.path, line=line)

    def end_line(self) -> int:
        return self.motion_line if self.motion_line else max(1, self.last_line)

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            where = "the MOTION section" if self.motion_line else "the end of the file"
            raise self.fail(f"expected {what}, reached {where}")
        tok = self.items[self.pos]
        self.pos += 1
        return tok

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok.upper() != word.upper():
            raise self.fail(f"expected {word!r}, got {tok!r}", line)
        return line

    def number(self, what: str) -> float:
        tok, line = self.next(what)
        try:
            v = float(tok)
        except ValueError:
            raise self.fail(f"expected {what} (a number), got {tok!r}", line) from None
        if not np.isfinite(v):
            raise self.fail(f"expected {what} (a finite number), got {tok!r}", line)
        return v


def _parse_root(tk: _Tokens, joints: list[_Joint], name: str, line: int) -> None:
    """Parse a ROOT's ``{ OFFSET ... CHANNELS ... children }`` (its name already read) and every
    joint under it. An explicit stack of the open joints, not recursion: a hierarchy of any
    depth is read (a file 1,000 levels deep would exhaust Python's call stack)."""
    open_joints: list[tuple[int, int]] = []  # (index in joints, line of its '{')

    def open_joint(name: str, parent: int, line: int) -> None:
        joints.append(_Joint(name=name, parent=parent, line=line))
        open_joints.append((len(joints) - 1, tk.expect("{")))

    open_joint(name, -1, line)
    while open_joints:
        me, open_line = open_joints[-1]
        joint = joints[me]
        name = joint.name
        if tk.peek() is None:
            where = "the MOTION section" if tk.motion_line else "the end of the file"
            raise tk.fail(
                f"joint {name!r} opened at line {open_line} is not closed: a '}}' is missing "
                f"before {where}"
            )
        tok, tline = tk.next("'}'")
        key = tok.upper()
        if key == "}":
            open_joints.pop()
        elif key == "OFFSET":
            joint.offset = np.array([tk.number(f"OFFSET {c} of {name!r}") for c in "xyz"])
        elif key == "CHANNELS":
            n = tk.number(f"the channel count of {name!r}")
            if n != int(n) or not 0 <= n <= 6:
                raise tk.fail(f"CHANNELS count of {name!r} must be 0 to 6, got {n:g}", tline)
            for _ in range(int(n)):
                ch, cline = tk.next(f"a channel name of {name!r}")
                if ch.lower() not in _CHANNELS:
                    raise tk.fail(
                        f"unknown channel {ch!r} of joint {name!r} (CHANNELS {int(n)} needs "
                        f"{int(n)} names among Xposition Yposition Zposition Xrotation "
                        "Yrotation Zrotation)",
                        cline,
                    )
                joint.channels.append(_CHANNELS[ch.lower()])
        elif key == "JOINT":
            child, cline = tk.next("a joint name after JOINT")
            if child in ("{", "}"):
                raise tk.fail(f"JOINT needs a name, got {child!r}", cline)
            open_joint(child, me, cline)
        elif key == "END":
            tk.expect("Site")
            site = _Joint(name=name + END_SITE_SUFFIX, parent=me, line=tline, end_site=True)
            joints.append(site)
            tk.expect("{")
            tk.expect("OFFSET")
            site.offset = np.array([tk.number(f"End Site OFFSET {c} of {name!r}") for c in "xyz"])
            tk.expect("}")
        else:
            raise tk.fail(
                f"unexpected {tok!r} inside joint {name!r} (expected OFFSET, CHANNELS, JOINT, "
                "End Site or '}')",
                tline,
            )


def _parse_hierarchy(tk: _Tokens) -> list[_Joint]:
    tk.expect("HIERARCHY")
    joints: list[_Joint] = []
    while tk.peek() is not None:
        tok, line = tk.next("ROOT")
        if tok.upper() != "ROOT":
            raise tk.fail(f"expected ROOT, got {tok!r}", line)
        name, nline = tk.next("a root name")
        _parse_root(tk, joints, name, nline)
    if not joints:
        raise tk.fail("the hierarchy has no ROOT joint")
    if not tk.motion_line:
        raise tk.fail("no MOTION section after the hierarchy", tk.last_line)
    names = [j.name for j in joints]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise tk.fail(f"joint names must be unique; repeated: {', '.join(dup)}", 1)
    return joints


def _header_value(lines: list[str], no: int, label: str, path: str) -> str:
    """The value after ``label`` (e.g. ``Frames:``) on 1-based line ``no``."""
    if no > len(lines):
        raise MotionFormatError(
            f"expected '{label} ...' after MOTION, reached the end of the file", path=path, line=no
        )
    text = lines[no - 1].strip()
    if not text.lower().replace(" ", "").startswith(label.lower().replace(" ", "")):
        raise MotionFormatError(f"expected '{label} ...', got {text[:60]!r}", path=path, line=no)
    return text.split(":", 1)[1].strip() if ":" in text else ""


def _read_frames(lines: list[str], start: int, n_channels: int, path: str) -> tuple[Array, float]:
    """Parse ``Frames:``/``Frame Time:`` at 1-based line ``start`` and the frame lines after."""
    no = start
    while no <= len(lines) and not lines[no - 1].strip():
        no += 1
    frames_text = _header_value(lines, no, "Frames:", path)
    try:
        n_frames = int(frames_text)
    except ValueError:
        raise MotionFormatError(
            f"'Frames:' needs a whole number, got {frames_text!r}", path=path, line=no
        ) from None
    if n_frames < 1:
        raise MotionFormatError(f"'Frames:' must be at least 1, got {n_frames}", path=path, line=no)
    frames_line = no
    no += 1
    dt_text = _header_value(lines, no, "Frame Time:", path)
    try:
        dt = float(dt_text)
    except ValueError:
        raise MotionFormatError(
            f"'Frame Time:' needs a number of seconds, got {dt_text!r}", path=path, line=no
        ) from None
    if not (np.isfinite(dt) and dt > 0):
        raise MotionFormatError(
            f"'Frame Time:' must be a positive number of seconds, got {dt_text!r}",
            path=path,
            line=no,
        )
    rows: list[list[str]] = []
    row_lines: list[int] = []
    for k in range(no, len(lines)):
        parts = lines[k].split()
        if not parts:
            continue
        if len(rows) == n_frames:
            raise MotionFormatError(
                f"more frame lines than 'Frames: {n_frames}' (line {frames_line}) declares; "
                "fix the count or remove the extra lines",
                path=path,
                line=k + 1,
            )
        if len(parts) != n_channels:
            raise MotionFormatError(
                f"frame {len(rows) + 1} has {len(parts)} values, expected {n_channels} (the sum "
                "of the hierarchy's CHANNELS); the line is truncated or the hierarchy does not "
                "match the data",
                path=path,
                line=k + 1,
            )
        rows.append(parts)
        row_lines.append(k + 1)
    if len(rows) < n_frames:
        raise MotionFormatError(
            f"'Frames: {n_frames}' (line {frames_line}) but only {len(rows)} frame lines were "
            "found: the file is truncated",
            path=path,
            line=len(lines) + 1,
        )
    try:
        data = np.array(rows, dtype=np.float64).reshape(n_frames, n_channels)
    except ValueError:
        for parts, line in zip(rows, row_lines, strict=True):
            for i, tok in enumerate(parts):
                try:
                    float(tok)
                except ValueError:
                    raise MotionFormatError(
                        f"value {i + 1} of this frame, {tok!r}, is not a number",
                        path=path,
                        line=line,
                    ) from None
        raise
    bad = ~np.isfinite(data)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise MotionFormatError(
            f"value {c + 1} of this frame is not finite ({rows[r][c]!r})",
            path=path,
            line=row_lines[r],
        )
    return data, dt


def _forward_kinematics(joints: list[_Joint], data: Array) -> tuple[Array, Array]:
    """Positions ``(T, J, 3)`` and global rotations ``(T, J, 3, 3)`` of every joint and End Site
    (an End Site has no channels: its parent's rotation); loop over joints, not frames."""
    t = data.shape[0]
    n = len(joints)
    pos = np.zeros((t, n, 3))
    rot = np.zeros((t, n, 3, 3))
    for i, j in enumerate(joints):
        trans = np.broadcast_to(j.offset, (t, 3)).copy()
        axes: list[int] = []
        angles: list[Array] = []
        for k, (kind, ax) in enumerate(j.channels):
            col = data[:, j.first_channel + k]
            if kind == "pos":
                trans[:, ax] = col
            else:
                axes.append(ax)
                angles.append(np.radians(col))
        local = euler_rotations(axes, angles, t)
        if j.parent < 0:
            pos[:, i] = trans
            rot[:, i] = local
        else:
            pr = rot[:, j.parent]
            pos[:, i] = pos[:, j.parent] + np.einsum("tij,tj->ti", pr, trans)
            rot[:, i] = pr @ local
    return pos, rot


def parse_bvh(text: str, *, path: str = "<string>", drop_tpose: bool = True) -> SourceMotion:
    """Parse BVH text into joint positions (file units and axes).

    Parameters
    ----------
    text : str
        The whole file.
    path : str
        Shown in error messages and provenance.
    drop_tpose : bool
        Detect and drop leading inserted T-pose frames (see the module docstring).

    Returns
    -------
    SourceMotion
        Positions ``(T, J, 3)`` of every joint and End Site, in file units, y up, and their
        global rotations (:attr:`SourceMotion.rotations`).

    Raises
    ------
    MotionFormatError
        With the file and the 1-based line where parsing failed.
    """
    lines = text.splitlines()
    tk = _Tokens(lines, path)
    joints = _parse_hierarchy(tk)
    n_channels = 0
    for j in joints:
        j.first_channel = n_channels
        n_channels += len(j.channels)
    data, dt = _read_frames(lines, tk.motion_line + 1, n_channels, path)
    pos, rot = _forward_kinematics(joints, data)
    notes: list[str] = []
    if drop_tpose:
        roots = [i for i, j in enumerate(joints) if j.parent < 0]
        k = leading_outlier_frames(pos, roots)
        if k == 0 and data.shape[0] > 2:
            rot_cols = [
                j.first_channel + c
                for j in joints
                for c, (kind, _) in enumerate(j.channels)
                if kind == "rot"
            ]
            rel = pos - pos[:, roots[0] : roots[0] + 1]
            step = np.sqrt(((rel[1:] - rel[:-1]) ** 2).sum(-1)).mean(-1)
            if (
                rot_cols
                and not data[0, rot_cols].any()
                and data[1, rot_cols].any()
                and step[0] > 5.0 * float(np.median(step[1:]))
            ):
                k = 1
        if k:
            pos = pos[k:]
            rot = rot[k:]
            notes.append(
                f"dropped leading frame(s) {', '.join(str(i) for i in range(k))} "
                "(an inserted T-pose)"
            )
    rate_hz = 1.0 / dt
    if abs(rate_hz - round(rate_hz)) < 1e-4 * rate_hz:
        rate_hz = float(round(rate_hz))  # 'Frame Time: .0083333' means 120 Hz
    return SourceMotion(
        names=tuple(j.name for j in joints),
        parents=tuple(j.parent for j in joints),
        positions=pos,
        rate_hz=rate_hz,
        path=path,
        fmt="bvh",
        notes=tuple(notes),
        rotations=rot,
    )


def read_bvh(path: str | Path, *, drop_tpose: bool = True) -> SourceMotion:
    """Read a BVH file into joint positions (file units and axes); see :func:`parse_bvh`."""
    p = Path(path)
    text = read_motion_text(p)
    return parse_bvh(text, path=str(p), drop_tpose=drop_tpose)
