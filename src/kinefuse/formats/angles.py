"""Joint angles out: ``angles.csv`` (long table) and ``angles.mot`` (OpenSim motion file).

``angles.csv``: a header ``time_s,joint,angle,method,degrees,filled,status`` and one row per
frame and angle, frames in time order and angles in the order given; ``method`` is
``functional`` (paper B's learned axes) or ``anatomical`` (ISB joint coordinate systems from a
static trial); an empty ``degrees`` cell is a missing value; ``filled`` is 1 where a short gap
was filled by interpolation (:mod:`kinefuse.biomech.gaps`), else 0; ``status`` is the angle's
plausibility over the whole take (:func:`kinefuse.biomech.angle_plausibility.angle_status`: ``ok``,
``implausible``, or ``no data``; the same on every row of the angle; the reasons are in
``analysis.json``).

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

tab-separated, one row per written frame. ``opensim.Storage`` stops reading a row at the first
value it cannot parse (``NaN``: a file with any NaN loads as one or two rows), so the file never
holds one (:func:`plan_mot`): gaps of at most 0.1 s are filled by linear interpolation
(:func:`kinefuse.biomech.gaps.fill_short_gaps`); a column with no value, or missing on more than
half the frames after that, is left out; then every frame still missing a value in a kept column
is left out (``nRows`` counts the written rows; the time column shows the holes). What was
filled and left out is returned by :func:`plan_mot` for the report.
Column names must be OpenSim-safe (letters, digits, ``_``, ``-``, ``.``): no blanks or tabs.

Both writers go through a temporary file and an atomic rename (:mod:`kinefuse.core.outputs`) and
refuse to replace an existing file unless ``overwrite=True``, and even then unless kinefuse wrote
it as that kind of file (the CSV's header line; the ``.mot``'s ``generator=kinefuse`` line).
"""

from __future__ import annotations

import io
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse import __version__
from kinefuse.biomech.gaps import MAX_GAP_S, fill_short_gaps, missing_runs
from kinefuse.core.inputs import LINE_LIMIT, read_text
from kinefuse.core.outputs import atomic_write_lines, atomic_write_text
from kinefuse.errors import InputError

#: what each writer's file is, for messages
_WHAT = {".csv": "angles file", ".mot": "OpenSim motion file"}
_CSV_HEADER = "time_s,joint,angle,method,degrees,filled,status"
#: this one and the earlier ones
_CSV_HEADERS_OURS = (_CSV_HEADER, "time_s,joint,angle,method,degrees,filled",
                     "time_s,joint,angle,degrees")  # fmt: skip
_MOT_GENERATOR = "kinefuse"


def is_angles_csv(path: Path) -> bool:
    """True if ``path`` is an ``angles.csv`` kinefuse wrote (by its header line)."""
    try:
        with Path(path).open(encoding="utf-8") as f:
            return f.readline(LINE_LIMIT).rstrip("\r\n") in _CSV_HEADERS_OURS
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
    "MotPlan",
    "is_angles_csv",
    "is_angles_mot",
    "plan_mot",
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
    methods: Mapping[str, str] | None = None,
    filled: Mapping[str, ArrayLike] | None = None,
    labels: Mapping[str, str] | None = None,
    status: Mapping[str, str] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write ``angles.csv``: ``time_s,joint,angle,method,degrees,filled,status``, one row per
    frame and angle.

    Parameters
    ----------
    path : str or Path
    t_s : (T,) float
        Frame times, seconds.
    angles_deg : mapping of str to (T,) float
        Angle name -> degrees per frame, NaN where missing.
    joints : mapping of str to str
        Angle name -> the joint (or limb) it belongs to.
    methods : mapping of str to str, optional
        Angle name -> ``"functional"`` or ``"anatomical"`` (default ``"functional"``).
    filled : mapping of str to (T,) bool, optional
        Angle name -> frames whose value was interpolated over a short gap.
    labels : mapping of str to str, optional
        Key -> the angle name written (default: the key); lets one name appear under two
        methods.
    status : mapping of str to str, optional
        Angle name -> its plausibility (``ok``, ``implausible``, ``no data``; default empty).
    overwrite : bool
        Replace an existing file, only one kinefuse wrote as this kind of file.

    Returns
    -------
    Path
    """
    t, ang = _check(t_s, angles_deg)
    meth = {n: (methods or {}).get(n, "functional") for n in ang}
    fl = {
        n: np.asarray((filled or {}).get(n, np.zeros(t.shape, bool)), dtype=bool).reshape(t.shape)
        for n in ang
    }
    missing = [n for n in ang if n not in joints]
    if missing:
        raise InputError(f"no joint given for angle(s) {', '.join(missing)}")
    label = {n: (labels or {}).get(n, n) for n in ang}
    stat = {n: (status or {}).get(n, "") for n in ang}
    for n in [*label.values(), *joints.values(), *meth.values(), *stat.values()]:
        if any(c in n for c in ',"\n\r'):
            raise InputError(f"angle and joint names cannot hold commas, quotes or newlines: {n!r}")
    names = list(ang)

    def lines() -> Iterator[str]:
        yield _CSV_HEADER + "\n"
        if not names:
            return
        vals = np.stack([ang[n] for n in names], axis=1)  # (T, A)
        flags = np.stack([fl[n] for n in names], axis=1)
        heads = [f"{joints[n]},{label[n]},{meth[n]}" for n in names]
        tails = [stat[n] for n in names]
        for k in range(t.size):
            tk = f"{t[k]:.6f}"
            for i, head in enumerate(heads):
                v = vals[k, i]
                cell = "" if not np.isfinite(v) else f"{v:.4f}"
                yield f"{tk},{head},{cell},{int(flags[k, i])},{tails[i]}\n"

    what = _WHAT.get(Path(path).suffix.lower(), "angles file")
    return atomic_write_lines(
        path, lines(), what=what, recognizer=lambda p: overwrite and is_angles_csv(p)
    )


@dataclass(frozen=True, eq=False)
class MotPlan:
    """What an ``angles.mot`` holds: the rows and columns without a missing value.

    Attributes
    ----------
    t_s : (R,) float
        Times of the written rows, seconds.
    columns : dict of str to (R,) float
        The written columns (short gaps filled), degrees.
    rows_left_out : list of (float, float)
        Time intervals (first and last left-out frame, seconds) of the frames left out.
    columns_left_out : dict of str to str
        Column -> why it was left out.
    filled : dict of str to int
        Column -> number of frames filled by interpolation.
    frames : int
        Frames given.
    """

    t_s: Array
    columns: dict[str, Array]
    rows_left_out: list[tuple[float, float]] = field(default_factory=list)
    columns_left_out: dict[str, str] = field(default_factory=dict)
    filled: dict[str, int] = field(default_factory=dict)
    frames: int = 0

    def summary(self) -> dict[str, object]:
        """JSON-able summary for the report."""
        return {
            "rows": int(self.t_s.size),
            "frames": self.frames,
            "rows_left_out_s": [[a, b] for a, b in self.rows_left_out],
            "columns_left_out": dict(self.columns_left_out),
            "filled_frames": {k: v for k, v in self.filled.items() if v},
            "rule": f"gaps up to {MAX_GAP_S:g} s filled by linear interpolation; columns "
            "missing on more than half the frames left out; then frames still missing a value "
            "left out (opensim.Storage cannot read NaN)",
        }


def plan_mot(
    t_s: ArrayLike, angles_deg: Mapping[str, ArrayLike], *, max_gap_s: float = MAX_GAP_S
) -> MotPlan:
    """Rows and columns of a ``.mot`` without missing values (rules in the module docstring).

    Parameters
    ----------
    t_s : (T,) float
        Frame times, seconds, strictly increasing.
    angles_deg : mapping of str to (T,) float
        Column name -> degrees per frame, NaN where missing.
    max_gap_s : float
        Longest gap filled by interpolation, seconds.

    Returns
    -------
    MotPlan
    """
    t, ang = _check(t_s, angles_deg)
    cols: dict[str, Array] = {}
    left: dict[str, str] = {}
    filled: dict[str, int] = {}
    for n, v in ang.items():
        f, flag = fill_short_gaps(t, v, max_gap_s=max_gap_s)
        ok = np.isfinite(f)
        if not ok.any():
            left[n] = "no value in any frame"
        elif ok.mean() < 0.5:
            left[n] = f"missing on {100 * (1 - ok.mean()):.0f} % of the frames"
        else:
            cols[n] = f
            filled[n] = int(flag.sum())
    keep = np.ones(t.shape, dtype=bool)
    for v in cols.values():
        keep &= np.isfinite(v)
    runs = [(float(t[a]), float(t[b - 1])) for a, b in missing_runs(keep)]
    return MotPlan(
        t_s=t[keep],
        columns={n: v[keep] for n, v in cols.items()},
        rows_left_out=runs,
        columns_left_out=left,
        filled=filled,
        frames=int(t.size),
    )


def write_angles_mot(
    path: str | Path,
    t_s: ArrayLike,
    angles_deg: Mapping[str, ArrayLike],
    *,
    name: str = "Coordinates",
    overwrite: bool = False,
    plan: MotPlan | None = None,
) -> Path:
    """Write an OpenSim ``.mot`` file of angles in degrees (layout in the module docstring).

    The file holds no missing value, so ``opensim.Storage`` reads every row: short gaps are
    filled, long ones left out (:func:`plan_mot`; pass its result as ``plan`` to report it).

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
    plan : MotPlan, optional
        :func:`plan_mot` of the same data (computed here when not given).

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
    pl = plan if plan is not None else plan_mot(t, ang)
    names = list(pl.columns)
    buf = io.StringIO()
    buf.write(
        f"{name}\nversion=1\nnRows={pl.t_s.size}\nnColumns={len(names) + 1}\ninDegrees=yes\n"
        f"generator={_MOT_GENERATOR} {__version__}\nendheader\n"
    )
    buf.write("\t".join(["time", *names]) + "\n")
    cols = np.stack([pl.t_s, *(pl.columns[n] for n in names)], axis=1)
    for row in cols:
        buf.write("\t".join([f"{v:.6f}" for v in row.tolist()]) + "\n")
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
    lines = read_text(p, what="OpenSim .mot file").splitlines()
    try:
        end = next(i for i, ln in enumerate(lines) if ln.strip().lower() == "endheader")
    except StopIteration:
        raise InputError(f"{p}: no 'endheader' line: not an OpenSim .mot file") from None
    header = {
        k.strip(): v.strip() for k, _, v in (ln.partition("=") for ln in lines[1:end]) if _ == "="
    }
    if end + 1 >= len(lines):
        raise InputError(f"{p}: no column names after 'endheader': the file is truncated")
    cols = lines[end + 1].split("\t")
    try:
        data = np.array(
            [[float(x) for x in ln.split("\t")] for ln in lines[end + 2 :] if ln.strip()],
            dtype=np.float64,
        ).reshape(-1, len(cols))
    except ValueError:
        raise InputError(
            f"{p}: the rows after line {end + 2} are not {len(cols)} tab-separated numbers each "
            "(one per column name): not an OpenSim .mot file, or a damaged one"
        ) from None
    return data[:, 0].copy(), {c: data[:, i].copy() for i, c in enumerate(cols) if i}, header
