"""Movement filtering and axis extraction on the joint sphere (METHODS.md B.2 steps 1-2).

Samples are a limb's directions in its parent's normalized frame, unit vectors ``(n, 3)`` in
time order (the joint centre ``o`` is the origin). Three extractors are kept side by side so that
the paper's comparison can be rerun: stratified PCA, EM started from PCA, and the paper's
Direction Joining (DJ). All return axes through ``o`` (the normals of the *axis planes*).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.geometry.rotations import unit
from kinefuse.core.geometry.transforms import fit_plane

Array = NDArray[np.float64]

#: Width of a stratification cell on the unit joint sphere, radians (about 3°).
CELL_RAD = np.radians(3.0)
#: Direction Joining's similarity threshold (the paper's delta), radians.
DELTA_RAD = np.radians(15.0)
#: The least sweep of a quick stroke that crosses the speed threshold only briefly
#: (:func:`movement_mask`), radians.
MIN_STROKE_RAD = np.radians(10.0)


def speed_threshold(speed: Array, bins: int = 100) -> float:
    """The paper's speed threshold: the valley after the low-speed (stationary) peak.

    A histogram of ``bins`` uniform bins over the speeds, smoothed over 5 bins (ours); small
    bars are eliminated by keeping
    the two most *prominent* peaks (a bar's prominence is how far it stands above the higher of
    the two valleys that separate it from higher bars; eliminating the lowest bars one by one
    would keep two bumps of one noisy mode); the threshold is the upper edge of the lowest bin
    between them. With one peak only, returns the upper edge of the first empty bin after it
    (or infinity: no stationary phase can be told apart).

    The threshold is lowered to where the stationary peak's upper flank ends, if that comes
    first (:func:`_stationary_end`, ours): a movement whose speeds spread over a decade (slow
    and fast strokes, cosine profiles) makes no second peak, only a low plateau of a few samples
    per bin, so the "second peak" is a bump of that plateau and the lowest bin before it is
    anywhere in it (issue 24: on fused data the valley fell at 77-90 deg/s, above every sample
    of a thigh's ab-/adduction at 65-75 deg/s median, and the thigh was learned with one axis).
    """
    return _threshold_and_mode(speed, bins)[0]


def _threshold_and_mode(speed: Array, bins: int = 100) -> tuple[float, float]:
    """:func:`speed_threshold` and the speed at the stationary peak (the histogram's mode
    below the threshold; NaN where there is none)."""
    v = speed[np.isfinite(speed)]
    if v.size < 3 or not v.max() > v.min():
        return float("inf"), float("nan")
    h, edges = np.histogram(v, bins=bins, range=(float(v.min()), float(v.max())))
    # a 5-bin moving average first: a noisy mode has bumps more prominent than a small peak
    h = np.convolve(h.astype(float), np.ones(5) / 5.0, mode="same")
    peaks, prom = _prominent_peaks(h)
    if peaks.size == 0:
        return float("inf"), float("nan")
    if peaks.size == 1:
        p0 = int(peaks[0])
        empty = np.flatnonzero(h[p0:] == 0)
        valley_edge = float(edges[p0 + empty[0]]) if empty.size else float("inf")
        mode = 0.5 * float(edges[p0] + edges[p0 + 1])
        return min(valley_edge, _stationary_end(h, edges, p0)), mode
    top = np.sort(peaks[np.argsort(-prom)[:2]])
    p0, p1 = int(top[0]), int(top[1])
    valley = p0 + int(np.argmin(h[p0 : p1 + 1]))
    mode = 0.5 * float(edges[p0] + edges[p0 + 1])
    return min(float(edges[valley + 1]), _stationary_end(h, edges, p0)), mode


def _stationary_end(h: Array, edges: Array, p0: int) -> float:
    """Where the stationary peak ``p0`` of the histogram ``h`` ends: the lower edge of the first
    bin above it holding more than twice the count of its mirror image below the peak (ours).

    Below the stationary peak there are hardly any movement samples (only a stroke's turning
    points are that slow), so the stationary samples' upper flank is taken as the mirror of
    their lower one. A
    bin above the peak holding more than twice its mirror's count holds more movement than
    stationary samples: the equal-density (Bayes) boundary between the two. On the logarithm of
    the speed of pure noise the flank is longer below the peak than above it, so the mirror
    errs towards keeping stationary samples out. Infinity where no bin qualifies."""
    for i in range(p0 + 1, h.size):
        j = 2 * p0 - i
        if h[i] > 2.0 * (h[j] if j >= 0 else 0.0):
            return float(edges[i])
    return float("inf")


def _prominent_peaks(h: Array) -> tuple[NDArray[np.intp], Array]:
    """Local maxima of ``h`` (plateaus count once) and their prominences."""
    n = h.size
    left = np.concatenate([[-np.inf], h[:-1]])
    right = np.concatenate([h[1:], [-np.inf]])
    peaks = np.flatnonzero((h > left) & (h >= right) & (h > 0))
    # a plateau counts once: keep the first bar of a run of equal maxima
    peaks = np.array(
        [p for p in peaks if p + 1 >= n or h[p + 1] < h[p] or _plateau_peak(h, int(p))]
    )
    prom = np.empty(peaks.size)
    for k, p in enumerate(peaks):
        hi_l = np.flatnonzero(h[:p] > h[p])
        hi_r = np.flatnonzero(h[p + 1 :] > h[p])
        lo_l = h[hi_l[-1] : p].min() if hi_l.size else h[: p + 1].min()
        lo_r = h[p : p + 1 + hi_r[0] + 1].min() if hi_r.size else h[p:].min()
        prom[k] = h[p] - max(lo_l, lo_r)
    return peaks.astype(np.intp), prom


def _plateau_peak(h: Array, p: int) -> bool:
    q = p
    while q + 1 < h.size and h[q + 1] == h[p]:
        q += 1
    return q + 1 >= h.size or h[q + 1] < h[p]


def movement_mask(
    samples: Array, rate_hz: float, smooth_s: float = 0.1, min_run_s: float = 0.2
) -> tuple[NDArray[np.bool_], Array]:
    """Split time-ordered unit samples ``(n, 3)`` into movement (True) and stationary samples.

    Speeds are angle steps between subsequent samples after a centred moving average of
    ``smooth_s`` seconds. The paper's histogram valley (:func:`speed_threshold`) is found on the
    *logarithm* of the speeds (ours): depth-sensor noise spreads the stationary peak over a
    decade of small speeds, so on a linear axis it swallows the valley; on a log axis noise and
    movement are two peaks. Movement runs shorter than ``min_run_s`` are noise spikes and are
    dropped, unless they are part of a quick stroke (see the code; ours). Returns the mask
    ``(n,)`` and the speeds ``(n,)`` (rad per frame, NaN at the first sample and at gaps).
    """
    s = smooth(samples, max(round(smooth_s * rate_hz), 0))
    # the displacement over 0.1 s either side (ours): a per-frame step of a 30 Hz depth sensor
    # is mostly its noise; over a longer lag the movement grows and the noise does not
    lag = max(round(0.1 * rate_hz), 1)
    step = np.full(s.shape[0], np.nan)
    if s.shape[0] > 2 * lag:
        step[lag:-lag] = np.linalg.norm(s[2 * lag :] - s[: -2 * lag], axis=-1) / (2 * lag)
    ok = np.isfinite(step) & (step > 0)
    if ok.sum() < 3:
        return np.zeros(s.shape[0], dtype=bool), step
    log = np.full(step.shape, np.nan)
    log[ok] = np.log10(step[ok])
    thr, mode = _threshold_and_mode(log)
    seed: NDArray[np.bool_] = np.asarray(np.where(ok, log > thr, False), dtype=bool)
    moving = seed.copy()
    min_run = max(round(min_run_s * rate_hz), 1)
    # a quick stroke (ours): on fused data a threshold set high by the noise's glitches is
    # crossed by a quick stroke for fewer frames than min_run, and the stroke was dropped whole
    # as a noise spike (issue 24: both thighs' ab-/adduction of 131_01 on a 3-sensor arc, peaks
    # of 100 deg/s over a 73 deg/s threshold for 4-5 frames a half-stroke, so the thighs were
    # learned with one axis). A short run above the threshold is kept where, extended to either
    # side while the speed stays above half-way (on the log axis) between the still peak and
    # the threshold, it lasts min_run, sweeps the limb over MIN_STROKE_RAD (those strokes'
    # halves sweep 20-30 deg; the noise runs a low threshold lets through 1-4 deg) and holds no
    # run above the threshold that is kept anyway (the stroke is then in the samples already;
    # its fragments added moved a head's second axis by 14 deg on a sweep session)
    low = min(0.5 * (thr + mode), thr) if np.isfinite(thr) and np.isfinite(mode) else thr
    weak = np.where(ok, log > low, False)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], seed.astype(np.int8), [0]])))
    wedges = np.flatnonzero(np.diff(np.concatenate([[0], weak.astype(np.int8), [0]])))
    wrun = np.zeros(s.shape[0], dtype=np.intp)  # the weak run each sample is in
    for k, (a, b) in enumerate(zip(wedges[::2], wedges[1::2], strict=True)):
        wrun[a:b] = k
    runs = list(zip(edges[::2], edges[1::2], strict=True))
    # a stroke that a long run above the threshold already stands for keeps only that run
    held = {int(wrun[a]) for a, b in runs if b - a >= min_run}
    for a, b in runs:
        if b - a >= min_run:
            continue
        k = int(wrun[a])
        wa, wb = int(wedges[2 * k]), int(wedges[2 * k + 1])
        if k in held or wb - wa < min_run or _sweep(s[wa:wb]) < MIN_STROKE_RAD:
            moving[a:b] = False
    return moving, step


def _sweep(u: Array) -> float:
    """How far the unit samples ``u (n, 3)`` reach: the largest angle from the first or the last
    sample, radians."""
    u = u[np.isfinite(u).all(axis=-1)]
    if u.shape[0] < 2:
        return 0.0
    c = np.clip(np.concatenate([u @ u[0], u @ u[-1]]), -1.0, 1.0)
    return float(np.arccos(c.min()))


def smooth(samples: Array, half: int) -> Array:
    """Centred moving average over ``2 half + 1`` samples, NaN-aware, re-normalized to unit."""
    if half <= 0:
        return samples.copy()
    ok: NDArray[np.bool_] = np.asarray(np.isfinite(samples).all(axis=-1))
    x = np.where(ok[:, None], samples, 0.0)
    c = np.concatenate([np.zeros((1, 3)), np.cumsum(x, axis=0)])
    n = np.concatenate([[0], np.cumsum(ok)])
    idx = np.arange(samples.shape[0])
    lo = np.clip(idx - half, 0, samples.shape[0])
    hi = np.clip(idx + half + 1, 0, samples.shape[0])
    cnt = (n[hi] - n[lo]).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = (c[hi] - c[lo]) / cnt[:, None]
    out = unit(m)
    out[~ok] = np.nan
    return out


def _cells(u: Array, cell: float) -> NDArray[np.int64]:
    return np.floor(u / cell).astype(np.int64)


def stratify(u: Array, cell: float = CELL_RAD) -> Array:
    """Global stratification: one representative (the normalized mean) per occupied cell."""
    keys = _cells(u, cell)
    _, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    sums = np.zeros((int(inv.max()) + 1, 3))
    np.add.at(sums, inv, u)
    return unit(sums)


def stratify_windowed(
    u: Array, segment: NDArray[np.int64], cell: float = CELL_RAD
) -> tuple[Array, NDArray[np.int64], NDArray[np.int64]]:
    """Windowed stratification: one representative per run of consecutive samples in one cell.

    ``segment (n,)`` labels contiguous runs of movement samples; a run never spans two
    segments. Returns the representatives ``(m, 3)``, their segment ``(m,)`` and, per sample,
    the index of its representative ``(n,)``.
    """
    keys = _cells(u, cell)
    change = np.ones(u.shape[0], dtype=bool)
    change[1:] = (keys[1:] != keys[:-1]).any(axis=1) | (segment[1:] != segment[:-1])
    run = np.cumsum(change) - 1
    sums = np.zeros((int(run[-1]) + 1, 3))
    np.add.at(sums, run, u)
    return unit(sums), segment[change], run


def plane_fit(u: Array, weights: Array | None = None) -> Array:
    """Unit normal of the plane through the origin best fitting ``u (n, 3)`` (least squares)."""
    return fit_plane(u, weights, through_origin=True)[1]


def pca_axes(u: Array, n_axes: int, cell: float = CELL_RAD) -> Array:
    """Stratified PCA: the ``n_axes`` largest principal directions ``d`` at the centre ``c`` of
    the representatives give the axes ``c × d``. Returns ``(n_axes, 3)``."""
    r = stratify(u, cell)
    c = r.mean(axis=0)
    cov = np.cov((r - c).T) if r.shape[0] > 1 else np.eye(3)
    _, vec = np.linalg.eigh(cov)
    d = vec[:, ::-1][:, :n_axes].T
    return unit(np.cross(unit(c), d))


def em_axes(
    u: Array,
    n_axes: int,
    cell: float = CELL_RAD,
    iterations: int = 50,
    start: Array | None = None,
) -> Array:
    """EM: assign the stratified representatives to the nearest axis plane, refit the planes,
    until the assignment stops changing. Starts from the PCA axes unless ``start`` is given."""
    r = stratify(u, cell)
    if n_axes == 1:
        return plane_fit(r)[None]
    a = pca_axes(u, n_axes, cell) if start is None else np.array(start, dtype=np.float64)
    lab = np.full(r.shape[0], -1)
    for _ in range(iterations):
        new = np.argmin(np.abs(r @ a.T), axis=1)
        if (new == lab).all():
            break
        lab = new
        for k in range(n_axes):
            if (lab == k).sum() >= 3:
                a[k] = plane_fit(r[lab == k])
    return a


def dj_axes(
    u: Array,
    segment: NDArray[np.int64],
    n_axes: int,
    delta: float = DELTA_RAD,
    cell: float = CELL_RAD,
) -> tuple[Array, Array]:
    """Direction Joining: group consecutive movement steps by their axis planes, merge groups,
    keep the largest clusters.

    Parameters
    ----------
    u : (n, 3) float
        Time-ordered unit movement samples.
    segment : (n,) int
        Contiguous-run label of each sample (steps across runs are not movements).
    n_axes : int
        Number of main directions to return.

    Returns
    -------
    axes : (k, 3) float
        ``k <= n_axes`` axes, largest cluster first, each refitted to its cluster's samples;
        a cluster within ``2 delta`` of a larger one is passed over (the same direction).
    weights : (k,) float
        The clusters' sizes (summed step arc length, radians), same order.
    """
    reps, seg, run = stratify_windowed(u, segment, cell)
    if reps.shape[0] < 3:
        return np.zeros((0, 3)), np.zeros(0)
    v = reps[1:] - reps[:-1]
    c = 0.5 * (reps[1:] + reps[:-1])
    valid = seg[1:] == seg[:-1]
    normal = np.cross(c, v)  # (c - o) x d, length ~ arc length of the step
    length = np.linalg.norm(v, axis=-1)
    n_steps = v.shape[0]
    group = np.full(n_steps, -1)
    cos_d = np.cos(delta)
    g_sum: list[Array] = []
    cur = -1
    acc = np.zeros(3)
    for i in range(n_steps):
        if not valid[i] or length[i] <= 0:
            cur = -1
            continue
        ni = normal[i] / np.linalg.norm(normal[i])
        if cur >= 0:
            gn = acc / np.linalg.norm(acc)
            cdot = float(ni @ gn)
            if abs(cdot) >= cos_d:
                acc = acc + np.sign(cdot) * normal[i]
                g_sum[cur] = acc
                group[i] = cur
                continue
        cur = len(g_sum)
        acc = normal[i].copy()
        g_sum.append(acc)
        group[i] = cur
    if not g_sum:
        return np.zeros((0, 3)), np.zeros(0)
    sums = np.array(g_sum)
    weight = np.linalg.norm(sums, axis=-1)  # ~ arc length covered along the plane
    cluster = _merge(sums, weight, cos_d)
    n_cl = int(cluster.max()) + 1
    cw = np.bincount(cluster, weights=weight, minlength=n_cl)
    order = np.argsort(-cw)
    axes: list[Array] = []
    ws = []
    for k in order:
        if len(axes) == n_axes:
            break
        steps = np.flatnonzero((group >= 0) & (cluster[np.maximum(group, 0)] == k))
        members = np.unique(np.concatenate([steps, steps + 1]))  # representatives of the steps
        pts = u[np.isin(run, members)]
        if pts.shape[0] < 3:
            continue
        a = plane_fit(pts)
        # a cluster within 2 delta of a heavier one is that main direction split in two (a
        # distorted swing whose halves differ by just over delta; seen in fused data), not a
        # second main direction: skip it (ours)
        if any(abs(float(a @ b)) > np.cos(2.0 * delta) for b in axes):
            continue
        axes.append(a)
        ws.append(cw[k])
    if not axes:
        return np.zeros((0, 3)), np.zeros(0)
    return np.stack(axes), np.array(ws)


def _merge(sums: Array, weight: Array, cos_d: float) -> NDArray[np.int64]:
    """Cluster groups whose axis planes are within delta: heaviest first, each group joins the
    most similar cluster within delta (the cluster's summed normal updated) or starts one; the
    clusters are merged the same way again until a pass changes nothing."""
    label = np.arange(sums.shape[0])
    vec, w = sums, weight
    while True:
        order = np.argsort(-w)
        c_vec: list[Array] = []
        c_w: list[float] = []
        assign = np.empty(vec.shape[0], dtype=np.int64)
        for g in order:
            n = vec[g] / max(float(np.linalg.norm(vec[g])), 1e-300)
            if c_vec:
                cv = np.array(c_vec)
                cos = cv @ n / np.linalg.norm(cv, axis=1)
                k = int(np.argmax(np.abs(cos)))
                if abs(cos[k]) >= cos_d:
                    c_vec[k] = c_vec[k] + np.sign(cos[k]) * vec[g]
                    c_w[k] += float(w[g])
                    assign[g] = k
                    continue
            c_vec.append(vec[g].copy())
            c_w.append(float(w[g]))
            assign[g] = len(c_vec) - 1
        label = assign[label]
        if len(c_vec) == vec.shape[0]:
            return label
        vec, w = np.array(c_vec), np.array(c_w)
