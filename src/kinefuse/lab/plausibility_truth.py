"""How well the analysis' plausibility flags find large fusion errors (for ``kinefuse evaluate``).

Paper B's third application flags implausible poses from what the calibration phase taught
(:func:`kinefuse.biomech.angle_plausibility.plausibility`: angles beyond the calibrated ranges,
motion off the learned axes, stretched limbs). Here each fused skeleton of an evaluation is
analysed like ``kinefuse analyze`` does (normalization, Direction Joining axes from the
session's range-of-motion phase, angles) and its per-joint flags (a limb's flag marks its distal
joint) are compared with the joints whose fused position is more than ``threshold_m`` from the
truth:

* ``precision``: of the flagged joint-frames, the fraction with a large error;
* ``recall``: of the joint-frames with a large error, the fraction flagged;
* ``base_rate``: the fraction of joint-frames with a large error (a precision above it means
  the flags find errors better than chance).

Counted over the frames after the calibration phase (the motion), on the joints a limb ends in.
A session without a range-of-motion phase is calibrated on its whole motion, and says so.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.limbs import LIMBS
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import KinefuseError
from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]

#: A fused joint this far from the truth counts as a large error, metres.
LARGE_ERROR_M = 0.10


def _scores(flag: NDArray[np.bool_], large: NDArray[np.bool_]) -> dict[str, float | int]:
    tp = int((flag & large).sum())
    nf, nl = int(flag.sum()), int(large.sum())
    return {
        "precision": tp / nf if nf else float("nan"),
        "recall": tp / nl if nl else float("nan"),
        "base_rate": nl / flag.size if flag.size else float("nan"),
        "flagged": nf,
        "large_errors": nl,
        "joint_frames": int(flag.size),
    }


def plausibility_vs_errors(
    store: SessionStore,
    results: dict[str, Any],
    truth: Array,
    *,
    threshold_m: float = LARGE_ERROR_M,
) -> dict[str, Any]:
    """Precision and recall of the plausibility flags against large fusion errors, per method.

    Parameters
    ----------
    store : SessionStore
        The evaluated session (its ``rom_phase_server_s`` metadata, if any).
    results : dict of str to MethodResult
        The fused skeletons of the evaluation.
    truth : (T, 25, 3) float
        The truth on the same frames and in the same world as ``results``.
    threshold_m : float
        Error above which a fused joint counts as a large error, metres.
    """
    from kinefuse.biomech.angle_plausibility import plausibility
    from kinefuse.biomech.kinematics import joint_angles
    from kinefuse.biomech.normalize import normalize
    from kinefuse.biomech.parameterize import learn_axes
    from kinefuse.biomech.sequence import SkeletonSequence

    meta = store.meta()
    phase_meta = meta.get("rom_phase_server_s")
    out: dict[str, Any] = {"threshold_m": threshold_m}
    distal = sorted({lb.distal_index for lb in LIMBS})
    for method, res in results.items():
        t = res.t_server_s
        if isinstance(phase_meta, list) and len(phase_meta) == 2:
            phase = (float(phase_meta[0]), float(phase_meta[1]))
            out["calibration"] = "the session's range-of-motion phase"
        else:
            phase = (float(t[0]), float(t[-1]))
            out["calibration"] = "no range-of-motion phase: calibrated on the whole motion"
        try:
            seq = SkeletonSequence.from_kinect(res.positions, t_s=t, source=f"fused {method}")
            norm = normalize(seq)
            model = learn_axes(seq, norm, phase, method="dj")
            flags = plausibility(joint_angles(seq, norm, model), model).joint_flags()
        except KinefuseError as exc:
            out[method] = {"error": str(exc)}
            continue
        err = np.linalg.norm(res.positions - truth, axis=-1)
        rows = t > phase[1]
        if not rows.any():
            rows = np.ones_like(rows)
        f = flags[rows][:, distal]
        e = err[rows][:, distal]
        ok = np.isfinite(e)
        large = e > threshold_m
        by_joint = {
            JOINTS[j]: _scores(f[:, k][ok[:, k]], large[:, k][ok[:, k]])
            for k, j in enumerate(distal)
        }
        out[method] = {**_scores(f[ok], large[ok]), "by_joint": by_joint}
    return out


def format_plausibility(section: object) -> str:
    """One line per method for ``kinefuse evaluate``'s text report ("" if absent)."""
    if not isinstance(section, dict):
        return ""
    lines = [
        f"\nplausibility flags (paper B) vs fused errors > {100 * section['threshold_m']:.0f} cm "
        f"({section.get('calibration', '')}):"
    ]
    for m, v in section.items():
        if not isinstance(v, dict):
            continue
        if "error" in v:
            lines.append(f"  {m:<10} not computed: {v['error']}")
            continue
        lines.append(
            f"  {m:<10} precision {v['precision']:.2f}, recall {v['recall']:.2f} "
            f"(base rate {v['base_rate']:.2f}, {v['flagged']} of {v['joint_frames']} flagged)"
        )
    return "\n".join(lines)
