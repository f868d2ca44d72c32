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

from kinefuse.formats.angles import read_angles_mot

__all__ = [
    "arm_trunk_failures",
    "compare_angles",
    "compare_with_ik",
    "format_comparison",
    "mirror_ik",
    "mirror_trc_text",
    "threshold_failures",
]


def compare_with_ik(
    ours: str | Path, ik: str | Path, *, mirrored: bool = False
) -> dict[str, dict[str, Any]]:
    """Per shared coordinate: ``r``, ``offset_deg``, ``rms_after_offset_deg``, ``rmse_deg``,
    ``present`` (fraction of the IK frames), ``n`` (frames compared), ``wraps`` (our curve
    steps by more than 180 deg between two written frames). ``mirrored``: the IK of
    the left-right mirrored trial (:func:`mirror_ik`), for ``ours`` of the mirrored markers."""
    t_o, a_o, _ = read_angles_mot(ours)
    t_i, a_i, _ = read_angles_mot(ik)
    if mirrored:
        a_i = mirror_ik(a_i)
    return compare_angles(t_o, a_o, t_i, a_i)


def compare_angles(
    t_o: np.ndarray, a_o: dict[str, np.ndarray], t_i: np.ndarray, a_i: dict[str, np.ndarray]
) -> dict[str, dict[str, Any]]:
    """:func:`compare_with_ik` on arrays (ours at ``t_o``, the reference at ``t_i``)."""
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
            "wraps": bool(np.any(np.abs(np.diff(a_o[name][np.isfinite(a_o[name])])) > 180.0)),
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
        " wraps"
    ]
    for k, v in table.items():
        lines.append(
            f"{k:20s} {100 * v['present']:7.1f}% {v['r']:7.3f} {v['offset_deg']:8.2f} "
            f"{v['rms_after_offset_deg']:8.2f} {v['rmse_deg']:7.2f} "
            f"{'yes' if v.get('wraps') else 'no':>5s}"
        )
    return "\n".join(lines)


#: OpenSim gait-model coordinates whose sign flips when the trial is mirrored left-right
#: (rotations about the vertical and the progression axes of the pelvis and the lumbar joint;
#: the legs' and arms' coordinates are defined per side and only swap sides).
_MIRROR_NEGATED = ("pelvis_list", "pelvis_rotation", "pelvis_tz", "lumbar_bending",
                   "lumbar_rotation")  # fmt: skip


def mirror_ik(angles: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The IK coordinates of the left-right mirrored trial: ``_r`` and ``_l`` swapped, the
    pelvis's list and rotation (and the lumbar bending and rotation) negated."""
    out: dict[str, np.ndarray] = {}
    for k, v in angles.items():
        if k.endswith("_r"):
            name = k[:-2] + "_l"
        elif k.endswith("_l"):
            name = k[:-2] + "_r"
        else:
            name = k
        out[name] = -v if name in _MIRROR_NEGATED else v
    return out


def mirror_trc_text(text: str, lateral: int = 2) -> str:
    """A TRC file's text mirrored left-right: the coordinate ``lateral`` (0 X, 1 Y, 2 Z; the
    OpenSim files' right is +Z) negated and the marker names' ``R.``/``L.`` (or ``R``/``L``
    Plug-in Gait prefixes before an upper-case name) swapped, so the file is a real trial of
    the mirror-image subject."""
    lines = text.splitlines()
    names = lines[3].split("\t")

    def swap(n: str) -> str:
        for a, b in (("R.", "L."), ("L.", "R."), ("R_", "L_"), ("L_", "R_")):
            if n.startswith(a):
                return b + n[len(a) :]
        return n

    lines[3] = "\t".join(swap(n) for n in names)
    out = lines[:5]
    for ln in lines[5:]:
        cells = ln.split("\t")
        if len(cells) < 3:
            out.append(ln)
            continue
        for k in range(2 + lateral, len(cells), 3):
            c = cells[k].strip()
            if c and c.lower() != "nan":
                cells[k] = repr(-float(c))
        out.append("\t".join(cells))
    return "\n".join(out) + "\n"


def threshold_failures(c: dict[str, dict[str, Any]]) -> list[str]:
    """Issue 20's thresholds against OpenSim IK; the coordinates that miss them, with why."""
    bad = []

    def need(name: str, ok: bool, what: str) -> None:
        if not ok:
            v = c.get(name, {})
            bad.append(f"{name}: {what} (r {v.get('r', float('nan')):.3f}, offset "
                       f"{v.get('offset_deg', float('nan')):.2f}, rms after offset "
                       f"{v.get('rms_after_offset_deg', float('nan')):.2f})")  # fmt: skip

    def get(name: str, key: str) -> float:
        return float(c.get(name, {}).get(key, float("nan")))

    for s in "rl":
        for n in (f"hip_flexion_{s}", f"knee_angle_{s}"):
            need(n, get(n, "r") >= 0.97, "r >= 0.97")
            need(n, abs(get(n, "offset_deg")) <= 5.0, "|offset| <= 5 deg")
            need(n, get(n, "rms_after_offset_deg") <= 4.0, "rms after offset <= 4 deg")
        n = f"ankle_angle_{s}"
        need(n, get(n, "r") >= 0.9, "r >= 0.9")
        need(n, get(n, "rms_after_offset_deg") <= 5.0, "rms after offset <= 5 deg")
        n = f"hip_adduction_{s}"
        need(n, get(n, "present") >= 0.95, "present on >= 95 % of frames")
        need(n, get(n, "r") >= 0.7, "r >= 0.7")
        need(n, get(n, "rms_after_offset_deg") <= 4.0, "rms after offset <= 4 deg")
    for n in ("pelvis_list", "pelvis_rotation"):
        need(n, get(n, "r") >= 0.7, "r >= 0.7")
    return bad


def arm_trunk_failures(c: dict[str, dict[str, Any]]) -> list[str]:
    """The leg, arm and trunk targets against OpenSim IK, on the coordinates the reference
    has: hip and knee r >= 0.97, |offset| <= 5, RMS after offset <= 4 deg; ankle r >= 0.9;
    ``elbow_flex`` r >= 0.95, |offset| <= 5, RMS <= 4; ``arm_flex`` r >= 0.95, |offset| <= 8,
    RMS <= 4; ``arm_add`` r >= 0.7, RMS <= 4; ``lumbar_extension`` |offset| <= 5, r >= 0.8; no
    coordinate wraps.
    Returns the misses, with the values."""
    bad = []
    for name, v in c.items():
        base = name.removesuffix("_r").removesuffix("_l")
        r, off, rms = v["r"], abs(v["offset_deg"]), v["rms_after_offset_deg"]
        need: list[tuple[bool, str]] = [(not v.get("wraps", False), "no wrap")]
        if base in ("hip_flexion", "knee_angle"):
            need += [(r >= 0.97, "r >= 0.97"), (off <= 5.0, "|offset| <= 5"),
                     (rms <= 4.0, "rms after offset <= 4")]  # fmt: skip
        elif base == "ankle_angle":
            need += [(r >= 0.9, "r >= 0.9")]
        elif base == "elbow_flex":
            need += [(r >= 0.95, "r >= 0.95"), (off <= 5.0, "|offset| <= 5"),
                     (rms <= 4.0, "rms after offset <= 4")]  # fmt: skip
        elif base == "arm_flex":
            need += [(r >= 0.95, "r >= 0.95"), (off <= 8.0, "|offset| <= 8"),
                     (rms <= 4.0, "rms after offset <= 4")]  # fmt: skip
        elif base == "arm_add":
            need += [(r >= 0.7, "r >= 0.7"), (rms <= 4.0, "rms after offset <= 4")]
        elif base == "lumbar_extension":
            need += [(off <= 5.0, "|offset| <= 5"), (r >= 0.8, "r >= 0.8")]
        for ok, what in need:
            if not ok:
                bad.append(f"{name}: {what} (r {r:.3f}, offset {v['offset_deg']:.2f}, rms after "
                           f"offset {rms:.2f} deg)")  # fmt: skip
    return bad
