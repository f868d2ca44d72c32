"""Exporters of fused skeletons behind a registry keyed by file extension.

Every exporter takes frame times ``(T,)`` and joint positions ``(T, 25, 3)`` in the world frame
(metres, z up, NaN = missing) and writes one file, atomically (a temporary file renamed into
place) and only over a file of the same kind that kinefuse wrote (see :mod:`kinefuse.core.outputs`).

One time base for all formats: the frame times are seconds on the server clock from the start
of the session, on a uniform grid ``t_k = (k0 + k) / rate`` (``kinefuse fuse`` puts its frames
on multiples of the frame period). CSV and TRC write these times in their time column; C3D
writes ``k0 + 1`` as its (1-based) first frame number, so frame ``n`` is at ``(n - 1) / rate``.

Axes and units (``docs/formats.md``): CSV in metres in the world frame (z up); C3D in
millimetres in the world frame (z up, the usual lab convention of C3D files); TRC in
millimetres and, by default, OpenSim's axes (Y up: ``X = x, Y = z, Z = -y``), or the world
frame with ``trc_axes="z-up"``; BVH in metres on those same Y-up axes, as joint rotations on
the Kinect v2 rig (:mod:`kinefuse.formats.motion.bvh_pose`; no time column: frame 0 is ``t_0``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse import __version__
from kinefuse.core.inputs import LINE_LIMIT
from kinefuse.core.outputs import atomic_file
from kinefuse.core.skeleton import JOINTS, N_JOINTS
from kinefuse.errors import InputError

Array = NDArray[np.float64]

TRC_AXES = ("y-up", "z-up")
#: world (z up) -> OpenSim (y up): X = x, Y = z, Z = -y (a rotation of -90 deg about x).
ZUP_TO_YUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: Largest residual a C3D point can carry at 1 mm resolution (POINT:SCALE -1), millimetres.
C3D_MAX_RESIDUAL_MM = 255.0
_SOFTWARE = f"kinefuse {__version__}"
_CSV_HEADER = ",".join(["time_s"] + [f"{j}_{a}_m" for j in JOINTS for a in "xyz"])


def _check(t_s: Array, positions: Array) -> tuple[Array, Array, float, int]:
    """Validated times and positions, the frame rate and ``k0`` of the uniform grid."""
    t = np.asarray(t_s, dtype=np.float64)
    p = np.asarray(positions, dtype=np.float64)
    if t.ndim != 1 or p.shape != (t.size, N_JOINTS, 3):
        raise InputError(
            f"export needs times (T,) and positions (T, {N_JOINTS}, 3), got {t.shape} and {p.shape}"
        )
    if t.size < 2:
        raise InputError("export needs at least 2 frames")
    if not np.isfinite(t).all():
        raise InputError("export needs finite frame times")
    dt = np.diff(t)
    step = float(np.median(dt))
    if not step > 0 or np.abs(dt - step).max() > 1e-6 * max(step, 1.0):
        raise InputError(
            "export needs frames on a uniform time grid (TRC and C3D have one frame rate); "
            f"intervals range from {dt.min():.6g} to {dt.max():.6g} s"
        )
    rate = 1.0 / step
    return t, p, rate, round(t[0] * rate)


def _write_csv(path: Path, t_s: Array, positions: Array, **_: object) -> None:
    """CSV: ``time_s`` then ``<Joint>_x_m, <Joint>_y_m, <Joint>_z_m`` per joint; empty = missing."""
    t, p, _rate, _k0 = _check(t_s, positions)
    flat = np.concatenate([t[:, None], p.reshape(t.size, -1)], axis=1)
    with path.open("w", encoding="utf-8") as f:
        f.write(_CSV_HEADER + "\n")
        for row in flat:
            f.write(",".join("" if not np.isfinite(v) else f"{v:.6f}" for v in row) + "\n")


def is_csv_export(path: Path) -> bool:
    try:
        with path.open(encoding="utf-8") as f:
            return f.readline(LINE_LIMIT).rstrip("\r\n") == _CSV_HEADER
    except (OSError, UnicodeDecodeError):
        return False


def _trc_header(name: str, rate: float, n_frames: int) -> list[str]:
    return [
        f"PathFileType\t4\t(X/Y/Z)\t{name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame"
        "\tOrigNumFrames",
        f"{rate:.6g}\t{rate:.6g}\t{n_frames}\t{N_JOINTS}\tmm\t{rate:.6g}\t1\t{n_frames}",
        "Frame#\tTime\t" + "\t\t\t".join(JOINTS) + "\t\t",
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(N_JOINTS)),
        "",
    ]


def _write_trc(
    path: Path,
    t_s: Array,
    positions: Array,
    *,
    name: str | None = None,
    trc_axes: str = "y-up",
    **_: object,
) -> None:
    """OpenSim TRC (tab-separated, millimetres); missing markers are written as ``NaN``, which
    OpenSim's reader takes as missing (empty fields break its column count)."""
    if trc_axes not in TRC_AXES:
        raise InputError(f"trc_axes must be one of {', '.join(TRC_AXES)}, got {trc_axes!r}")
    t, p, rate, _k0 = _check(t_s, positions)
    mm = p * 1000.0
    if trc_axes == "y-up":
        mm = mm @ ZUP_TO_YUP.T
    lines = _trc_header(name or path.name, rate, t.size)
    for k in range(t.size):
        vals = "\t".join("NaN" if not np.isfinite(v) else f"{v:.3f}" for v in mm[k].reshape(-1))
        lines.append(f"{k + 1}\t{t[k]:.6f}\t{vals}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def is_trc_export(path: Path) -> bool:
    try:
        with path.open(encoding="utf-8") as f:
            head = [f.readline(LINE_LIMIT).rstrip("\r\n") for _ in range(4)]
    except (OSError, UnicodeDecodeError):
        return False
    return head[0].startswith("PathFileType\t4\t(X/Y/Z)") and head[3] == _trc_header("", 1, 1)[3]


def _write_c3d(
    path: Path, t_s: Array, positions: Array, *, residual_m: Array | None = None, **_: object
) -> None:
    """C3D via ezc3d (millimetres, world frame z up).

    Each point's residual follows the C3D convention: -1 where the point is missing, else its
    fusion residual (``residual_m``, per frame and joint; 0 where none was computed) in
    millimetres at 1 mm resolution, capped at :data:`C3D_MAX_RESIDUAL_MM`.
    """
    try:
        import ezc3d
    except ImportError:  # pragma: no cover - ezc3d is a dependency; the message helps if absent
        raise InputError("writing .c3d needs the ezc3d package: pip install ezc3d") from None
    t, p, rate, k0 = _check(t_s, positions)
    present = np.isfinite(p).all(-1)  # (T, 25)
    if residual_m is None:
        res_mm = np.zeros(present.shape)
    else:
        r = np.asarray(residual_m, dtype=np.float64)
        if r.shape != present.shape:
            raise InputError(f"residual_m must have shape {present.shape}, got {r.shape}")
        res_mm = np.clip(np.nan_to_num(r * 1000.0, nan=0.0), 0.0, C3D_MAX_RESIDUAL_MM)
    res_mm = np.where(present, res_mm, -1.0)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = list(JOINTS)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["parameters"]["POINT"]["SCALE"]["value"] = [-1.0]
    c3d.add_parameter("TRIAL", "ACTUAL_START_FIELD", [k0 + 1, 0])
    c3d.add_parameter("MANUFACTURER", "SOFTWARE", _SOFTWARE)
    c3d["header"]["points"]["first_frame"] = k0  # ezc3d counts from 0; the file holds k0 + 1
    pts = np.ones((4, N_JOINTS, t.size))
    pts[:3] = np.transpose(p * 1000.0, (2, 1, 0))
    c3d["data"]["points"] = pts
    c3d["data"]["meta_points"] = {
        "residuals": res_mm.T[None, :, :],
        "camera_masks": np.zeros((7, N_JOINTS, t.size), dtype=bool),
    }
    c3d.write(str(path))


def is_c3d_export(path: Path) -> bool:
    try:
        import ezc3d

        from kinefuse.formats.markers import check_c3d_header

        check_c3d_header(path)  # ezc3d spends minutes on a large file that is no C3D
        c = ezc3d.c3d(str(path))
        soft = c["parameters"]["MANUFACTURER"]["SOFTWARE"]["value"]
        return bool(soft) and str(soft[0]).startswith("kinefuse")
    except Exception:  # ezc3d raises plain RuntimeError/KeyError on foreign files
        return False


def _write_bvh(
    path: Path, t_s: Array, positions: Array, *, notes: list[str] | None = None, **_: object
) -> None:
    """BVH (``docs/formats.md``, "BVH export"): the Kinect v2 rig with the session's bone
    lengths, rotations solved per frame (:func:`kinefuse.formats.motion.bvh_pose.solve_pose`),
    metres, Y up; the frame time from the grid's rate. What was held is appended to ``notes``."""
    from kinefuse.formats.bvh_export import bvh_text
    from kinefuse.formats.motion.bvh_pose import solve_pose

    _t, p, rate, _k0 = _check(t_s, positions)
    if not np.isfinite(p).all(axis=-1).any():
        raise InputError("a BVH export needs at least one joint position; every frame is empty")
    pose = solve_pose(p)
    if notes is not None:
        notes.extend(pose.notes)
    path.write_text(bvh_text(pose, 1.0 / rate), encoding="utf-8")


def _is_bvh_export(path: Path) -> bool:
    from kinefuse.formats.bvh_export import is_bvh_export

    return is_bvh_export(path)


Exporter = Callable[..., None]

#: extension -> (writer of a new file, recognizer of a file of that kind written by kinefuse);
#: the writers write in place: every public writer calls them through :func:`_export`
EXPORTERS: dict[str, tuple[Exporter, Callable[[Path], bool]]] = {
    ".csv": (_write_csv, is_csv_export),
    ".trc": (_write_trc, is_trc_export),
    ".c3d": (_write_c3d, is_c3d_export),
    ".bvh": (_write_bvh, _is_bvh_export),
}


def _export(path: str | Path, kind: str, t_s: Array, positions: Array, **kw: object) -> Path:
    """Write format ``kind`` (".csv", ".trc", ".c3d") to ``path`` through
    :func:`kinefuse.core.outputs.atomic_file`: a temporary file renamed into place, and an
    existing file replaced only if it is a kinefuse export of that format."""
    p = Path(path)
    writer, recognizer = EXPORTERS[kind]
    what = f"{kind[1:].upper()} export"
    with atomic_file(p, what=what, recognizer=recognizer, suffix=kind) as tmp:
        writer(tmp, t_s, positions, name=p.name, **kw)
    return p


def export_csv(path: str | Path, t_s: Array, positions: Array, **kw: object) -> Path:
    """Write a CSV export (layout: :func:`_write_csv`), safely (:func:`_export`)."""
    return _export(path, ".csv", t_s, positions, **kw)


def export_trc(path: str | Path, t_s: Array, positions: Array, **kw: object) -> Path:
    """Write an OpenSim TRC export (layout: :func:`_write_trc`), safely (:func:`_export`)."""
    return _export(path, ".trc", t_s, positions, **kw)


def export_c3d(path: str | Path, t_s: Array, positions: Array, **kw: object) -> Path:
    """Write a C3D export (layout: :func:`_write_c3d`), safely (:func:`_export`)."""
    return _export(path, ".c3d", t_s, positions, **kw)


def check_export_path(path: str | Path) -> Path:
    """The path as a :class:`Path`, or an :class:`InputError` for an unknown extension."""
    p = Path(path)
    if p.suffix.lower() not in EXPORTERS:
        raise InputError(
            f"{p}: unknown output format {p.suffix or '(none)'!r}; use one of "
            + ", ".join(sorted(EXPORTERS))
        )
    return p


def export_skeleton(
    path: str | Path,
    t_s: Array,
    positions: Array,
    *,
    residual_m: Array | None = None,
    trc_axes: str = "y-up",
    notes: list[str] | None = None,
) -> Path:
    """Write a fused skeleton; the extension picks the format (``.csv``, ``.trc``, ``.c3d``,
    ``.bvh``). A writer appends what the reader should know (a BVH's held rotations) to
    ``notes``.

    Raises
    ------
    InputError
        Unknown extension, or data that the format cannot hold.
    OutputError
        The file exists and is not a kinefuse export of that format, or it could not be written
        (missing or read-only folder, disk full...). An old file is left untouched.
    """
    p = check_export_path(path)
    return _export(
        p, p.suffix.lower(), t_s, positions, residual_m=residual_m, trc_axes=trc_axes, notes=notes
    )


def export_bvh(path: str | Path, t_s: Array, positions: Array, **kw: object) -> Path:
    """Write a BVH export (layout: :func:`_write_bvh`), safely (:func:`_export`)."""
    return _export(path, ".bvh", t_s, positions, **kw)
