"""Exporters of fused skeletons behind a registry keyed by file extension.

Every exporter takes frame times ``(T,)`` seconds and joint positions ``(T, 25, 3)`` in the world
frame (metres, z up, NaN = missing) and writes one file. Units at the edge: CSV in metres, TRC
and C3D in millimetres (their usual unit, declared in the file).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError
from kinefuse.skeleton import JOINTS, N_JOINTS

Array = NDArray[np.float64]


def _check(t_s: Array, positions: Array) -> tuple[Array, Array]:
    t = np.asarray(t_s, dtype=np.float64)
    p = np.asarray(positions, dtype=np.float64)
    if t.ndim != 1 or p.shape != (t.size, N_JOINTS, 3):
        raise InputError(
            f"export needs times (T,) and positions (T, {N_JOINTS}, 3), got {t.shape} and {p.shape}"
        )
    if t.size < 2:
        raise InputError("export needs at least 2 frames")
    return t, p


def _rate(t: Array) -> float:
    return float(1.0 / np.median(np.diff(t)))


def export_csv(path: Path, t_s: Array, positions: Array) -> None:
    """CSV: ``time_s`` then ``<Joint>_x_m, <Joint>_y_m, <Joint>_z_m`` per joint; empty = missing."""
    t, p = _check(t_s, positions)
    header = ["time_s"] + [f"{j}_{a}_m" for j in JOINTS for a in "xyz"]
    flat = np.concatenate([t[:, None], p.reshape(t.size, -1)], axis=1)
    with path.open("w") as f:
        f.write(",".join(header) + "\n")
        for row in flat:
            f.write(",".join("" if not np.isfinite(v) else f"{v:.6f}" for v in row) + "\n")


def export_trc(path: Path, t_s: Array, positions: Array) -> None:
    """OpenSim TRC (tab-separated, millimetres); missing markers are left empty."""
    t, p = _check(t_s, positions)
    rate = _rate(t)
    mm = p * 1000.0
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame"
        "\tOrigNumFrames",
        f"{rate:.6g}\t{rate:.6g}\t{t.size}\t{N_JOINTS}\tmm\t{rate:.6g}\t1\t{t.size}",
        "Frame#\tTime\t" + "\t\t\t".join(JOINTS) + "\t\t",
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(N_JOINTS)),
        "",
    ]
    for k in range(t.size):
        vals = "\t".join("" if not np.isfinite(v) else f"{v:.3f}" for v in mm[k].reshape(-1))
        lines.append(f"{k + 1}\t{t[k] - t[0]:.6f}\t{vals}")
    path.write_text("\n".join(lines) + "\n")


def export_c3d(path: Path, t_s: Array, positions: Array) -> None:
    """C3D via ezc3d (millimetres); missing points are NaN with residual -1, as C3D marks them."""
    try:
        import ezc3d
    except ImportError:  # pragma: no cover - ezc3d is a dependency; the message helps if absent
        raise InputError("writing .c3d needs the ezc3d package: pip install ezc3d") from None
    t, p = _check(t_s, positions)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [_rate(t)]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = list(JOINTS)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    pts = np.ones((4, N_JOINTS, t.size))
    pts[:3] = np.transpose(p * 1000.0, (2, 1, 0))
    c3d["data"]["points"] = pts
    c3d["data"]["meta_points"] = {
        "residuals": np.where(np.isfinite(p).all(-1), 0.0, -1.0).T[None, :, :],
        "camera_masks": np.zeros((7, N_JOINTS, t.size), dtype=bool),
    }
    c3d.write(str(path))


EXPORTERS: dict[str, Callable[[Path, Array, Array], None]] = {
    ".csv": export_csv,
    ".trc": export_trc,
    ".c3d": export_c3d,
}


def export_skeleton(path: str | Path, t_s: Array, positions: Array) -> Path:
    """Write a fused skeleton; the extension picks the format (``.csv``, ``.trc``, ``.c3d``)."""
    p = Path(path)
    fn = EXPORTERS.get(p.suffix.lower())
    if fn is None:
        raise InputError(
            f"{p}: unknown output format {p.suffix or '(none)'!r}; use one of "
            + ", ".join(sorted(EXPORTERS))
        )
    p.parent.mkdir(parents=True, exist_ok=True)
    fn(p, t_s, positions)
    return p
