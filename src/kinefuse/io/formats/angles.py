"""Joint angles out: ``angles.csv`` (long table) and ``angles.mot`` (OpenSim motion file).

``angles.csv``: a header ``time_s,joint,angle,degrees`` and one row per frame and angle, frames
in time order and angles in the order given; an empty ``degrees`` cell is a missing value.

``angles.mot``: OpenSim's storage format, as ``opensim.Storage`` and ``TimeSeriesTable`` read it::

    Coordinates
    version=1
    nRows=<frames>
    nColumns=<1 + angles>
    inDegrees=yes
    generator=kinefuse <version>
    endheader
    time<TAB>hip_flexion_r<TAB>...
    0.000000<TAB>12.345678<TAB>...

tab-separated, one row per frame; missing values are written ``NaN`` (OpenSim reads it as NaN).
Column names must be OpenSim-safe (letters, digits, ``_``, ``-``, ``.``): no blanks or tabs.

Both writers go through a temporary file and an atomic rename (:mod:`kinefuse.io.outputs`) and
refuse to replace an existing file unless ``overwrite=True``, and even then unless kinefuse wrote
it as that kind of file (the CSV's header line; the ``.mot``'s ``generator=kinefuse`` line).
"""

from __future__ import annotations

import io
import re
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse import __version__
from kinefuse.errors import InputError
from kinefuse.io.outputs import atomic_write_text

#: what each writer's file is, for messages
_WHAT = {".csv": "angles file", ".mot": "OpenSim motion file"}
_CSV_HEADER = "time_s,joint,angle,degrees"
_MOT_GENERATOR = "kinefuse"


def is_angles_csv(path: Path) -> bool:
    """True if ``path`` is an ``angles.csv`` kinefuse wrote (by its header line)."""
    try:
        with Path(path).open(encoding="utf-8") as f:
            return f.readline().rstrip("\r\n") == _CSV_HEADER
    except (OSError, UnicodeDecodeError):
        return False


def is_angles_mot(path: Path) -> bool:
    """True if ``path`` is a ``.mot`` kinefuse wrote (its header's ``generator=kinefuse`` line)."""
    try:
        gen = read_angles_mot(path)[2].get("generator", "")
    except (OSError, UnicodeDecodeError, ValueError, IndexError, InputError):
        return False
    return gen.split(" ", 1)[0] == _MOT_GENERATOR


def _write(
    path: str | Path, text: str, overwrite: bool, recognizer: Callable[[Path], bool]
) -> Path:
    """Atomic write; an existing file is replaced only with ``overwrite`` and only when
    ``recognizer`` says kinefuse wrote it as this kind of file."""
    what = _WHAT.get(Path(path).suffix.lower(), "angles file")
    return atomic_write_text(
        path, text, what=what, recognizer=lambda p: overwrite and recognizer(p)
    )


Array = NDArray[np.float64]

__all__ = [
    "is_angles_csv",
    "is_angles_mot",
    "read_angles_mot",
    "write_angles_csv",
    "write_angles_mot",
]

_SAFE = re.compile(r"^[A-Za-z0-9_.\-]+$")


def _check(t_s: ArrayLike, angles_deg: Mapping[str, ArrayLike]) -> tuple[Array, dict[str, Array]]:
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim != 1 or t.size == 0 or not np.isfinite(t).all():
        raise InputError(f"times must be a finite (T,) array with T >= 1, got shape {t.shape}")
    if t.size > 1 and not (np.diff(t) > 0).all():
        raise InputError("times must be strictly increasing")
    out: dict[str, Array] = {}
    for name, v in angles_deg.items():
        a = np.asarray(v, dtype=np.float64)
        if a.shape != t.shape:
            raise InputError(f"angle {name!r} has shape {a.shape}, expected ({t.size},) like times")
        out[str(name)] = a
    return t, out


def write_angles_csv(
    path: str | Path,
    t_s: ArrayLike,
    angles_deg: Mapping[str, ArrayLike],
    joints: Mapping[str, str],
    *,
    overwrite: bool = False,
) -> Path:
    """Write ``angles.csv``: ``time_s,joint,angle,degrees``, one row per frame and angle.

    Parameters
    ----------
    path : str or Path
    t_s : (T,) float
        Frame times, seconds.
    angles_deg : mapping of str to (T,) float
        Angle name -> degrees per frame, NaN where missing.
    joints : mapping of str to str
        Angle name -> the joint (or limb) it belongs to.
    overwrite : bool
        Replace an existing file, only one kinefuse wrote as this kind of file.

    Returns
    -------
    Path
    """
    t, ang = _check(t_s, angles_deg)
    missing = [n for n in ang if n not in joints]
    if missing:
        raise InputError(f"no joint given for angle(s) {', '.join(missing)}")
    for n in [*ang, *joints.values()]:
        if any(c in n for c in ',"\n\r'):
            raise InputError(f"angle and joint names cannot hold commas, quotes or newlines: {n!r}")
    buf = io.StringIO()
    buf.write(_CSV_HEADER + "\n")
    names = list(ang)
    if names:
        vals = np.stack([ang[n] for n in names], axis=1)  # (T, A)
        for k in range(t.size):
            tk = f"{t[k]:.6f}"
            for i, n in enumerate(names):
                v = vals[k, i]
                buf.write(f"{tk},{joints[n]},{n},{'' if not np.isfinite(v) else f'{v:.4f}'}\n")
    return _write(path, buf.getvalue(), overwrite, is_angles_csv)


def write_angles_mot(
    path: str | Path,
    t_s: ArrayLike,
    angles_deg: Mapping[str, ArrayLike],
    *,
    name: str = "Coordinates",
    overwrite: bool = False,
) -> Path:
    """Write an OpenSim ``.mot`` file of angles in degrees (layout in the module docstring).

    Parameters
    ----------
    path : str or Path
    t_s : (T,) float
        Frame times, seconds, strictly increasing.
    angles_deg : mapping of str to (T,) float
        Column name -> degrees per frame, NaN where missing.
    name : str
        The first header line (OpenSim's name of the storage).
    overwrite : bool
        Replace an existing file, only one kinefuse wrote as this kind of file.

    Returns
    -------
    Path
    """
    t, ang = _check(t_s, angles_deg)
    bad = [n for n in [name, *ang] if not _SAFE.match(n) or n.lower() == "time"]
    if bad:
        raise InputError(
            f"OpenSim column names must be letters, digits, '_', '-', '.' (and not 'time'); "
            f"got {bad}"
        )
    names = list(ang)
    buf = io.StringIO()
    buf.write(
        f"{name}\nversion=1\nnRows={t.size}\nnColumns={len(names) + 1}\ninDegrees=yes\n"
        f"generator={_MOT_GENERATOR} {__version__}\nendheader\n"
    )
    buf.write("\t".join(["time", *names]) + "\n")
    cols = np.stack([t, *(ang[n] for n in names)], axis=1)
    for row in cols:
        buf.write(
            "\t".join(["NaN" if not np.isfinite(v) else f"{v:.6f}" for v in row.tolist()]) + "\n"
        )
    return _write(path, buf.getvalue(), overwrite, is_angles_mot)


def read_angles_mot(path: str | Path) -> tuple[Array, dict[str, Array], dict[str, str]]:
    """Read a ``.mot`` written by :func:`write_angles_mot` (or a similar OpenSim file).

    Returns
    -------
    t_s : (T,) float
    angles : dict of str to (T,) float
    header : dict of str to str
        The ``key=value`` lines of the header.
    """
    p = Path(path)
    lines = p.read_text(encoding="utf-8").splitlines()
    try:
        end = next(i for i, ln in enumerate(lines) if ln.strip().lower() == "endheader")
    except StopIteration:
        raise InputError(f"{p}: no 'endheader' line: not an OpenSim .mot file") from None
    header = {
        k.strip(): v.strip() for k, _, v in (ln.partition("=") for ln in lines[1:end]) if _ == "="
    }
    cols = lines[end + 1].split("\t")
    data = np.array(
        [[float(x) for x in ln.split("\t")] for ln in lines[end + 2 :] if ln.strip()],
        dtype=np.float64,
    ).reshape(-1, len(cols))
    return data[:, 0].copy(), {c: data[:, i].copy() for i, c in enumerate(cols) if i}, header
