"""kinefuse's angles against OpenSim's inverse kinematics, coordinate by coordinate.

:func:`compare_with_ik` puts an ``angles.mot`` written with ``--names opensim`` beside an
OpenSim IK result (``*_ik.mot``) of the same trial: the kinefuse curve is interpolated
(linearly) at the IK's times, over the frames where both exist, and for every coordinate both
have it gives the correlation ``r``, the mean offset (kinefuse minus OpenSim), the RMS after
removing that offset, the raw RMSE (degrees) and the fraction of the IK's frames kinefuse has.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from kinefuse.io.formats.angles import read_angles_mot

__all__ = ["compare_with_ik", "format_comparison"]


def compare_with_ik(ours: str | Path, ik: str | Path) -> dict[str, dict[str, Any]]:
    """Per shared coordinate: ``r``, ``offset_deg``, ``rms_after_offset_deg``, ``rmse_deg``,
    ``present`` (fraction of the IK frames), ``n`` (frames compared)."""
    t_o, a_o, _ = read_angles_mot(ours)
    t_i, a_i, _ = read_angles_mot(ik)
    out: dict[str, dict[str, Any]] = {}
    for name, ref in a_i.items():
        if name not in a_o or t_o.size < 2:
            continue
        v = np.interp(t_i, t_o, a_o[name], left=np.nan, right=np.nan)
        # frames the .mot left out (long gaps) are not interpolated across
        dt = float(np.median(np.diff(t_o)))
        k = np.clip(np.searchsorted(t_o, t_i), 1, t_o.size - 1)
        v[(t_o[k] - t_o[k - 1]) > 1.5 * dt] = np.nan
        ok = np.isfinite(v) & np.isfinite(ref)
        a, b = v[ok], ref[ok]
        off = float(np.mean(a - b)) if a.size else float("nan")
        out[name] = {
            "n": int(ok.sum()),
            "present": float(ok.mean()),
            "r": float(np.corrcoef(a, b)[0, 1]) if a.size > 2 and a.std() > 0 else float("nan"),
            "offset_deg": off,
            "rms_after_offset_deg": float(np.sqrt(np.mean((a - b - off) ** 2))) if a.size else
            float("nan"),
            "rmse_deg": float(np.sqrt(np.mean((a - b) ** 2))) if a.size else float("nan"),
        }  # fmt: skip
    return out


def format_comparison(table: dict[str, dict[str, Any]]) -> str:
    """The comparison as a text table (degrees)."""
    lines = [
        f"{'coordinate':20s} {'present':>8s} {'r':>7s} {'offset':>8s} {'rms-off':>8s} {'rmse':>7s}"
    ]
    for k, v in table.items():
        lines.append(
            f"{k:20s} {100 * v['present']:7.1f}% {v['r']:7.3f} {v['offset_deg']:8.2f} "
            f"{v['rms_after_offset_deg']:8.2f} {v['rmse_deg']:7.2f}"
        )
    return "\n".join(lines)
