"""How recording-independent the results are: normalized axes across takes, errors vs truth.

:func:`normalization_consistency` is the paper's normalization experiment: several takes of one
subject (different rigs, headings, sessions), each normalized at its own default pose; for every
limb and each of its three normalized axes, the angle between the takes (every pair). The
frames are compared *relative to each take's body frame* (the world differs between takes: the
sensors stood elsewhere and the person faced another way), so what is measured is whether the
normalization gives the same limb frames on the same body.

The other functions compare results with a known truth (simulation, or the analysis of the
true motion); they are for evaluation and take plain arrays, never a store.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech._vec import wrap
from kinefuse.biomech.limbs import LIMB_NAMES
from kinefuse.biomech.normalize import Normalization
from kinefuse.biomech.parameterize import AxisModel
from kinefuse.errors import InputError

Array = NDArray[np.float64]


def body_relative_frames(norm: Normalization, /) -> Array:
    """Limb frames at the default pose relative to the body frame ``(L, 3, 3)``."""
    return np.einsum("ji,ljk->lik", norm.body2world, norm.frames[norm.default_frame])


def normalization_consistency(takes: Sequence[Normalization], /) -> dict[str, object]:
    """Deviation of the normalized limb axes between takes, degrees.

    Returns ``{"mean", "median", "max", "by_limb": {limb: mean}, "n_takes", "pairs"}``; every
    (pair, limb, axis) is one value.
    """
    if len(takes) < 2:
        raise InputError(f"consistency needs at least two takes, got {len(takes)}")
    rel = [body_relative_frames(n) for n in takes]
    vals = []
    by_limb: dict[str, list[float]] = {n: [] for n in LIMB_NAMES}
    for a, b in combinations(range(len(rel)), 2):
        cos = np.einsum("lik,lik->lk", rel[a], rel[b])  # per limb, per axis (column)
        ang = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        for li, name in enumerate(LIMB_NAMES):
            if np.isfinite(ang[li]).all():
                by_limb[name].extend(ang[li].tolist())
                vals.extend(ang[li].tolist())
    if not vals:
        raise InputError("no limb has a normalized frame in every take; nothing to compare")
    v = np.array(vals)
    return {
        "mean": float(v.mean()),
        "median": float(np.median(v)),
        "max": float(v.max()),
        "by_limb": {k: float(np.mean(x)) for k, x in by_limb.items() if x},
        "n_takes": len(takes),
        "pairs": len(rel) * (len(rel) - 1) // 2,
    }


def axis_errors_deg(model: AxisModel, true_axes: dict[str, Array], /) -> dict[str, object]:
    """Angle between learned and true axes (both in the parent's normalized frame), degrees.

    Axes are compared as lines (an axis and its opposite describe the same plane); a limb with
    more learned axes than true ones is scored on its first (template-matched) ones; limbs with
    fewer are listed under ``"skipped"`` with their
    status. Returns ``{"median", "mean", "by_limb": {limb: [deg, ...]}, "skipped": {...}}``.
    """
    by_limb: dict[str, list[float]] = {}
    skipped: dict[str, str] = {}
    for name, a_true in true_axes.items():
        lm = model.limbs.get(name)
        if lm is None or lm.axes.shape[0] < a_true.shape[0] or a_true.shape[0] == 0:
            skipped[name] = "not learned" if lm is None else lm.status
            continue
        # a one-axis limb given a second axis for its off-plane motion: its hinge (first) axis
        cos = np.abs(np.einsum("ki,ki->k", lm.axes[: a_true.shape[0]], a_true))
        by_limb[name] = np.degrees(np.arccos(np.clip(cos, 0.0, 1.0))).tolist()
    v = np.array([x for xs in by_limb.values() for x in xs])
    return {
        "median": float(np.median(v)) if v.size else float("nan"),
        "mean": float(v.mean()) if v.size else float("nan"),
        "by_limb": by_limb,
        "skipped": skipped,
    }


def angle_rmse_deg(
    estimate: dict[str, Array], truth: dict[str, Array], /, frames: Array | None = None
) -> dict[str, float]:
    """RMSE per angle name (degrees in, degrees out) over ``frames`` where both are finite.

    Differences are wrapped to (-180, 180] degrees.
    """
    out = {}
    for name, e in estimate.items():
        t = truth.get(name)
        if t is None:
            continue
        d = np.degrees(wrap(np.radians(e - t)))
        if frames is not None:
            d = d[frames]
        d = d[np.isfinite(d)]
        if d.size:
            out[name] = float(np.sqrt(np.mean(d**2)))
    return out


def twist_errors_deg(
    estimate: dict[str, Array],
    truth: dict[str, Array],
    weight: dict[str, Array],
    /,
    frames: Array | None = None,
) -> dict[str, object]:
    """Absolute twist error (radians in, degrees out) over frames with full twist weight."""
    vals = []
    by_limb = {}
    for name, e in estimate.items():
        t = truth.get(name)
        if t is None:
            continue
        d = np.abs(np.degrees(wrap(e - t)))
        ok = np.isfinite(d) & (weight[name] >= 1.0)
        if frames is not None:
            keep = np.zeros_like(ok)
            keep[frames] = True
            ok &= keep
        if ok.any():
            vals.append(d[ok])
            by_limb[name] = float(np.median(d[ok]))
    v = np.concatenate(vals) if vals else np.zeros(0)
    return {
        "median": float(np.median(v)) if v.size else float("nan"),
        "mean": float(v.mean()) if v.size else float("nan"),
        "by_limb": by_limb,
    }


def true_axes_in_normalization(
    true_axes: dict[str, Array], true_frames: Array, norm_frames: Array, /
) -> dict[str, Array]:
    """True axes ``(k, 3)`` (in the true parent frames) expressed in a normalization's frames.

    ``true_frames`` and ``norm_frames`` are ``(T, L, 3, 3)`` limb-to-world rotations at the same
    ``T`` instants (e.g. the calibration phase) in the same world. Both are attached to the same
    limbs, so the mean rotation between them over the frames maps one onto the other; a
    constant offset of the normalization is left out of the axis error (it is what the
    consistency across takes and the angles measure).
    """
    from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS
    from kinefuse.core.geometry.rotations import chordal_mean

    out = {}
    for name, a in true_axes.items():
        par = LIMB_PARENTS[LIMB_INDEX[name]]
        r = np.einsum("tji,tjk->tik", norm_frames[:, par], true_frames[:, par])
        r = r[np.isfinite(r).all(axis=(1, 2))]
        if r.shape[0]:
            out[name] = (chordal_mean(r) @ np.asarray(a).T).T
    return out
