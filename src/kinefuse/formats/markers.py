"""Optical marker files in: TRC (OpenSim's text format) and C3D (via ezc3d).

Both readers return a :class:`MarkerData`: marker trajectories ``(T, M, 3)`` in metres in a
**z-up** world, NaN where a marker is missing. The rules, applied the same way to both formats:

* **Gaps**: a sample is missing when any coordinate is NaN or empty, when all three are exactly
  zero (the usual "no data" value of capture software), or, in C3D, when its residual is
  negative. A single zero coordinate is data (ground-projected virtual markers have y = 0).
* **Units**: the file's own unit (TRC ``Units``, C3D ``POINT:UNITS``) when it reads as ``mm``,
  ``cm`` or ``m`` after stripping blanks and case; otherwise (an empty or malformed field) the
  unit among mm, cm, m that puts the body's vertical extent (median over frames of the spread
  of the markers along the up axis) between 0.5 and 2.5 m. Which rule decided is recorded in
  :attr:`MarkerData.notes`.
* **Axes** to the lab's z-up world: ``up`` (``"+y"``, ``"-z"``, ...) when the caller (a marker
  map) says which file axis points up; otherwise the file axis along which the markers spread
  most within a frame (median over frames: a standing or walking body is taller than it is
  wide), taken as positive. The file axes are then permuted cyclically so that the up axis
  becomes z (``+y`` up: world ``(x, y, z) = (x_f, -z_f, y_f)``, OpenSim's convention; ``+x`` up:
  ``(y_f, z_f, x_f)``), with a half turn about world x for a negative up axis; always a proper
  rotation, so left and right stay left and right.
* **Time**: TRC's ``Time`` column when it is strictly increasing, else ``frame / DataRate``.

Tolerated quirks of real files (both seen in ``../shared/data/markers``): header values
separated by several tabs and padded with blanks (the Rajagopal walk's ``Units`` field reads
``" mm"`` between doubled tabs); rows shorter than the header (trailing gaps left out); a missing
final newline; marker names with a namespace prefix (C3D ``Derrick:LASI``), kept as written
(marker maps match them with or without the prefix).

**Marker names** are matched by :class:`MarkerResolver`: exactly, else by :func:`marker_key`,
which drops a subject prefix (``Name:``), case and separators (space, ``_``, ``.``, ``-``), reads
the side as a prefix or a suffix (``LASI``, ``L_ASIS``, ``ASIS_L``, ``L.ASIS``, ``ASISl``,
``l asis``, ``LeftASIS`` are all ``l:asis``) and turns the names labs give one landmark into one
(:data:`MARKER_SYNONYMS`: ``ASI``, ``ASIS`` and the ISB / Van Sint Jan ``IAS`` are the same).

Malformed files raise :class:`kinefuse.errors.MotionFormatError` with the file and 1-based line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.frames.marker_data import (
    MARKER_SYNONYMS,
    UP_AXES,
    MarkerData,
    MarkerResolver,
    marker_key,
    up_rotation,
)
from kinefuse.core.inputs import read_text
from kinefuse.errors import InputError, MotionFormatError

Array = NDArray[np.float64]

__all__ = [
    "MARKER_SYNONYMS",
    "UNIT_M",
    "MarkerData",
    "MarkerResolver",
    "marker_key",
    "parse_trc",
    "read_c3d",
    "read_markers",
    "read_trc",
    "up_rotation",
]

#: Metres per unit of the length units marker files declare.
UNIT_M: Final[dict[str, float]] = {"mm": 0.001, "cm": 0.01, "m": 1.0}
#: Vertical extent of a body accepted by the unit inference, metres.
BODY_EXTENT_M: Final = (0.5, 2.5)


def _gaps_to_nan(p: Array) -> tuple[Array, int]:
    """Mark all-zero samples as missing (in place); returns the array and how many."""
    zero = (p == 0.0).all(axis=-1)
    p[zero] = np.nan
    p[~np.isfinite(p).all(axis=-1)] = np.nan
    return p, int(zero.sum())


def _frame_extent(p: Array) -> Array:
    """Median over frames of the markers' spread along each file axis ``(3,)`` (file units)."""
    with np.errstate(all="ignore"):
        lo = np.nanmin(np.where(np.isfinite(p), p, np.inf), axis=1)
        hi = np.nanmax(np.where(np.isfinite(p), p, -np.inf), axis=1)
    spread = hi - lo
    spread = spread[np.isfinite(spread).all(axis=1)]
    if spread.size == 0:
        return np.zeros(3)
    return np.asarray(np.median(spread, axis=0), dtype=np.float64)


def _to_world(
    raw: Array, unit_text: str, up: str | None, path: str, fmt: str
) -> tuple[Array, list[str]]:
    """Units and axes (see the module docstring) of positions in file units ``(T, M, 3)``."""
    notes: list[str] = []
    p, n_zero = _gaps_to_nan(raw)
    if n_zero:
        notes.append(f"{n_zero} all-zero marker samples read as gaps")
    extent = _frame_extent(p)
    if up is None:
        axis = int(np.argmax(extent))
        up_key = "+" + "xyz"[axis]
        notes.append(f"up axis {up_key} (largest within-frame spread of the markers)")
    else:
        up_key = up.strip().lower()
        up_rotation(up_key)  # validates
        if up_key[0] not in "+-":
            up_key = "+" + up_key
        notes.append(f"up axis {up_key} (given)")
    unit = unit_text.strip().strip('"').lower()
    if unit in UNIT_M:
        metres = UNIT_M[unit]
        notes.append(f"unit {unit} (from the file)")
    else:
        vertical = float(extent[UP_AXES[up_key]])
        lo, hi = BODY_EXTENT_M
        fits = [u for u in ("mm", "m", "cm") if lo <= vertical * UNIT_M[u] <= hi]
        if not fits:
            raise MotionFormatError(
                f"the length unit {unit_text!r} is not mm, cm or m, and no unit makes the body's "
                f"vertical extent ({vertical:g} file units) between {lo} and {hi} m; fix the "
                "file's unit field",
                path=path,
            )
        metres = UNIT_M[fits[0]]
        notes.append(
            f"unit {fits[0]} (the file says {unit_text!r}; inferred from the body's extent "
            f"{vertical * metres:.2f} m)"
        )
    world = (p * metres) @ up_rotation(up_key).T
    return world, notes


# ------------------------------------------------------------------------------------------ TRC


def _header_fields(line: str) -> list[str]:
    return [f.strip() for f in line.replace("\t", " ").split(" ") if f.strip()]


def parse_trc(text: str, *, path: str = "<string>", up: str | None = None) -> MarkerData:
    """Parse the text of a TRC file (see the module docstring for the rules).

    Parameters
    ----------
    text : str
        The whole file.
    path : str
        For messages and provenance.
    up : str, optional
        The file axis that points up (``"+y"`` for OpenSim files); default: inferred.

    Returns
    -------
    MarkerData

    Raises
    ------
    MotionFormatError
        With the line where the file does not follow the TRC layout.
    """
    lines = text.splitlines()
    if len(lines) < 5 or not lines[0].strip().lower().startswith("pathfiletype"):
        raise MotionFormatError(
            "not a TRC file: the first line must start with 'PathFileType' and the header has "
            "five lines (PathFileType, the header keys, their values, marker names, X1 Y1 Z1...)",
            path=path,
            line=1,
        )
    keys = _header_fields(lines[1])
    values = _header_fields(lines[2])
    if len(values) < len(keys):
        # a blank Units or other value collapses; pair what we can and say so
        pass
    header = {k.lower(): v for k, v in zip(keys, values, strict=False)}
    try:
        rate = float(header.get("datarate", header.get("camerarate", "nan")))
    except ValueError:
        rate = float("nan")
    if not (np.isfinite(rate) and rate > 0):
        raise MotionFormatError(
            f"DataRate must be a positive number of frames per second, got "
            f"{header.get('datarate')!r}",
            path=path,
            line=3,
        )
    unit_text = header.get("units", "")
    name_cells = lines[3].split("\t")
    if len(name_cells) < 3 or name_cells[0].strip().lower() not in ("frame#", "frame"):
        raise MotionFormatError(
            "line 4 must be 'Frame#<TAB>Time<TAB>marker names...'", path=path, line=4
        )
    names = tuple(c.strip() for c in name_cells[2:] if c.strip())
    if not names:
        raise MotionFormatError("no marker names on line 4", path=path, line=4)
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise MotionFormatError(f"marker names repeat: {', '.join(dup)}", path=path, line=4)
    m = len(names)
    rows: list[list[float]] = []
    row_lines: list[int] = []
    for no in range(5, len(lines)):
        line = lines[no]
        if not line.strip():
            continue
        cells = line.rstrip("\r\n").split("\t")
        if len(cells) > 2 + 3 * m and any(c.strip() for c in cells[2 + 3 * m :]):
            raise MotionFormatError(
                f"this row has {len(cells) - 2} coordinates, more than the {3 * m} of the "
                f"{m} markers named on line 4",
                path=path,
                line=no + 1,
            )
        vals = np.full(2 + 3 * m, np.nan)
        for i, c in enumerate(cells[: 2 + 3 * m]):
            c = c.strip()
            if not c:
                continue
            try:
                vals[i] = float(c)
            except ValueError:
                what = "the frame number" if i == 0 else "the time" if i == 1 else "a coordinate"
                raise MotionFormatError(
                    f"{what} (column {i + 1}) is {c!r}, not a number", path=path, line=no + 1
                ) from None
        rows.append(vals.tolist())
        row_lines.append(no + 1)
    if not rows:
        raise MotionFormatError("the file has no data rows after the header", path=path)
    data = np.array(rows, dtype=np.float64)
    notes: list[str] = []
    n_declared = header.get("numframes")
    if n_declared is not None and n_declared.isdigit() and int(n_declared) != data.shape[0]:
        notes.append(
            f"header says {n_declared} frames, the file holds {data.shape[0]} rows; the rows "
            "were used (a truncated file?)"
        )
    declared = header.get("nummarkers")
    if declared is not None and declared.isdigit() and int(declared) != m:
        notes.append(f"header says {declared} markers, line 4 names {m}; the names were used")
    t = data[:, 1]
    if np.isfinite(t).all() and (t.size < 2 or (np.diff(t) > 0).all()):
        t_s = t - 0.0
    else:
        t_s = np.arange(data.shape[0]) / rate
        notes.append("Time column missing or not increasing: times are frame / DataRate")
    raw = data[:, 2:].reshape(-1, m, 3)
    pos, more = _to_world(raw, unit_text, up, path, "trc")
    return MarkerData(
        names=names,
        positions=pos,
        t_s=np.asarray(t_s, dtype=np.float64),
        rate_hz=rate,
        path=path,
        fmt="trc",
        notes=tuple(notes + more),
    )


def _trc_first_line(line: str) -> str | None:
    if line.strip().lower().startswith("pathfiletype"):
        return None
    return (
        f"not a TRC file: the first line must start with 'PathFileType', got {line[:40]!r}; "
        "the header has five lines (PathFileType, the header keys, their values, marker names, "
        "X1 Y1 Z1...)"
    )


def read_trc(path: str | Path, *, up: str | None = None) -> MarkerData:
    """Read a TRC file (opened read-only); see :func:`parse_trc`. Its size and first line are
    checked before it is read whole (:func:`kinefuse.core.inputs.read_text`)."""
    p = Path(path)
    text = read_text(
        p,
        what="TRC marker file",
        first_line=_trc_first_line,
        fail=lambda message, line: MotionFormatError(message, path=str(p), line=line),
    )
    return parse_trc(text, path=str(p), up=up)


# ------------------------------------------------------------------------------------------ C3D


def read_c3d(path: str | Path, *, up: str | None = None) -> MarkerData:
    """Read the 3D points of a C3D file with ezc3d (see the module docstring for the rules).

    Parameters
    ----------
    path : str or Path
    up : str, optional
        The file axis that points up; default: inferred.

    Returns
    -------
    MarkerData

    Raises
    ------
    MotionFormatError
        ezc3d cannot read the file, or it has no 3D points.
    """
    try:
        import ezc3d
    except ImportError:  # pragma: no cover - a dependency; the message helps if it is absent
        raise InputError("reading .c3d needs the ezc3d package: pip install ezc3d") from None
    p = Path(path)
    if not p.is_file():
        raise MotionFormatError("no such file", path=str(p))
    check_c3d_header(p)
    try:
        c3d = ezc3d.c3d(str(p))
    except (RuntimeError, OSError, ValueError) as e:
        raise MotionFormatError(f"ezc3d cannot read it as C3D: {e}", path=str(p)) from None
    params = c3d["parameters"]["POINT"]
    declared = _c3d_header_frames(p)

    def value(key: str) -> list[object]:
        v = params.get(key, {}).get("value", [])
        return list(np.atleast_1d(v))

    labels = [str(x).strip() for x in value("LABELS")]
    k = 2
    while f"LABELS{k}" in params:
        labels += [str(x).strip() for x in value(f"LABELS{k}")]
        k += 1
    pts = np.asarray(c3d["data"]["points"], dtype=np.float64)  # (4, M, T)
    if pts.ndim != 3 or pts.shape[1] == 0 or pts.shape[2] == 0:
        raise MotionFormatError("the file holds no 3D points (POINT section empty)", path=str(p))
    if declared is not None and pts.shape[2] < declared:
        raise MotionFormatError(
            f"the file is truncated: its header declares {declared} frames, the data holds "
            f"{pts.shape[2]}; copy the file again",
            path=str(p),
        )
    m = pts.shape[1]
    labels = labels[:m] + [f"point{i + 1}" for i in range(len(labels), m)]
    rate_v = value("RATE")
    rate = float(rate_v[0]) if rate_v else float("nan")  # type: ignore[arg-type]
    if not (np.isfinite(rate) and rate > 0):
        raise MotionFormatError(f"POINT:RATE must be positive, got {rate_v!r}", path=str(p))
    units = value("UNITS")
    unit_text = str(units[0]) if units else ""
    raw = np.transpose(pts[:3], (2, 1, 0)).copy()  # (T, M, 3)
    notes: list[str] = []
    resid = c3d["data"].get("meta_points", {}).get("residuals")
    if resid is not None:
        r = np.asarray(resid, dtype=np.float64)
        if r.shape[-2:] == (m, raw.shape[0]):
            bad = (r.reshape(-1, m, raw.shape[0])[0] < 0).T
            if bad.any():
                raw[bad] = np.nan
                notes.append(f"{int(bad.sum())} samples with a negative residual read as gaps")
    pos, more = _to_world(raw, unit_text, up, str(p), "c3d")
    first = int(c3d["header"]["points"]["first_frame"])
    t_s = (first + np.arange(raw.shape[0])) / rate
    return MarkerData(
        names=tuple(labels),
        positions=pos,
        t_s=t_s - t_s[0],
        rate_hz=rate,
        path=str(p),
        fmt="c3d",
        notes=tuple(notes + more),
    )


def check_c3d_header(path: Path) -> None:
    """Refuse a file that is not C3D by its first bytes, before ezc3d reads it (ezc3d spends
    minutes on a large file of zeros): every C3D file starts with the number of its parameter
    block (2 or more, inside the file) and the byte 0x50."""
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            head = f.read(2)
    except OSError as e:
        why = e.strerror or str(e)
        raise MotionFormatError(f"cannot read the file: {why}", path=str(path)) from None
    if len(head) < 2 or head[1] != 0x50 or head[0] < 2 or (head[0] - 1) * 512 >= size:
        raise MotionFormatError(
            f"not a C3D file: it starts with {head!r}, where every C3D file starts with its "
            "parameter block's number and the byte 0x50 ('P')",
            path=str(path),
        )


def _c3d_header_frames(path: Path) -> int | None:
    """Frames the C3D header declares (words 4-5, first and last frame; Intel byte order), or
    None when the header cannot say (other byte orders, more than 65535 frames)."""
    import struct

    with path.open("rb") as f:
        head = f.read(12)
    if len(head) < 12 or head[1] != 0x50:  # byte 2 of every C3D file is 0x50
        return None
    first, last = struct.unpack("<hh", head[6:10])
    if not 1 <= first <= last:
        return None
    return last - first + 1


def read_markers(path: str | Path, *, up: str | None = None) -> MarkerData:
    """Read a ``.trc`` or ``.c3d`` marker file (the extension decides)."""
    p = Path(path)
    ext = p.suffix.lower()
    if ext == ".trc":
        return read_trc(p, up=up)
    if ext == ".c3d":
        return read_c3d(p, up=up)
    raise InputError(f"{p}: unknown marker format {ext or '(none)'!r}; kinefuse reads .trc, .c3d")
