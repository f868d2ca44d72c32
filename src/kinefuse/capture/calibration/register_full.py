"""Full 6-DoF registration of every sensor from wand tracks matched in time: a spanning tree of
robust Kabsch fits, then one joint robust least-squares refinement; the world frame from the
floors. Re-exported by :mod:`kinefuse.capture.calibration.register`, whose docstring describes it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.optimize import least_squares

from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.capture.calibration.register_common import Registration, Sightings
from kinefuse.core.geometry.rotations import skew, so3_exp_and_left_jacobian
from kinefuse.core.geometry.transforms import invert_transform, kabsch, make_transform
from kinefuse.errors import CalibrationError, InputError

Array = NDArray[np.float64]


# ---------------------------------------------------------------------------------------------
# Full 6-DoF registration


@dataclass
class _Matched:
    """Wand tracks of all sensors interpolated to a common time grid."""

    t: Array  # (G,)
    p: Array  # (G, S, 3)  NaN where missing
    q: Array  # (G, S)
    ok: NDArray[np.bool_]  # (G, S)
    i0: NDArray[np.intp]  # (G, S) raw indices of the bracketing sightings
    i1: NDArray[np.intp]


def _match_in_time(
    tracks: Sequence[Sightings], rate_hz: float, max_gap_s: float, max_speed: float
) -> _Matched:
    t_lo = min(float(s.t_server_s[0]) for s in tracks)
    t_hi = max(float(s.t_server_s[-1]) for s in tracks)
    grid = np.arange(t_lo, t_hi + 0.5 / rate_hz, 1.0 / rate_hz)
    g, n_s = len(grid), len(tracks)
    p = np.full((g, n_s, 3), np.nan)
    q = np.zeros((g, n_s))
    ok = np.zeros((g, n_s), dtype=bool)
    i0a = np.zeros((g, n_s), dtype=np.intp)
    i1a = np.zeros((g, n_s), dtype=np.intp)
    for k, s in enumerate(tracks):
        ts, ps = s.t_server_s, s.centre_sensor_m
        n = len(ts)
        if n < 2:
            continue
        i1 = np.clip(np.searchsorted(ts, grid, side="right"), 1, n - 1)
        i0 = i1 - 1
        t0, t1 = ts[i0], ts[i1]
        dt = t1 - t0
        inside = (grid >= t0) & (grid <= t1) & (dt > 0) & (dt <= max_gap_s)
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(inside, (grid - t0) / np.where(dt > 0, dt, 1.0), 0.0)
            speed = np.linalg.norm(ps[i1] - ps[i0], axis=1) / np.where(dt > 0, dt, np.inf)
        inside &= speed <= max_speed
        pk = ps[i0] * (1 - w)[:, None] + ps[i1] * w[:, None]
        p[inside, k] = pk[inside]
        q[inside, k] = np.minimum(s.quality[i0], s.quality[i1])[inside]
        ok[:, k] = inside
        i0a[:, k], i1a[:, k] = i0, i1
    return _Matched(grid, p, q, ok, i0a, i1a)


def _robust_kabsch(src: Array, dst: Array, w: Array, what: str, min_spread_m: float) -> Array:
    """Kabsch ``src2dst`` with iterative trimming of outliers; checks the geometry is 3D enough.

    The rotation about a line is not determined by points near that line: the kept points must
    lie at least ``min_spread_m`` (RMS) away from their best-fitting line.
    """
    try:
        t = kabsch(src, dst, w)
        keep = np.ones(len(src), dtype=bool)
        for _ in range(4):
            r = np.linalg.norm(src @ t[:3, :3].T + t[:3, 3] - dst, axis=1)
            thr = max(4.0 * 1.4826 * float(np.median(r)), 0.02)
            new_keep = r < thr
            if new_keep.sum() < 3 or np.array_equal(new_keep, keep):
                break
            keep = new_keep
            t = kabsch(src[keep], dst[keep], w[keep])
    except ValueError as e:
        raise CalibrationError(
            f"{what}: the shared wand positions do not determine a pose ({e}); wave the wand "
            "through a volume (not along a line) where these sensors overlap"
        ) from None
    pts = src[keep]
    sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    spread = float(np.sqrt((sv[1] ** 2 + sv[2] ** 2) / len(pts)))
    if spread < min_spread_m:
        raise CalibrationError(
            f"{what} saw the wand together with the other sensors only near a line "
            f"({spread * 100:.1f} cm RMS across it, need {min_spread_m * 100:.0f} cm; "
            f"{len(pts)} shared sightings): its rotation about that line is not determined. Wave "
            "the wand through a volume (not along a line) where its view overlaps the others'"
        )
    return t


def _spanning_order(
    ids: Sequence[str], shared: NDArray[np.int64], root: int, min_shared: int
) -> list[int]:
    """Prim's order of a maximum spanning tree from ``root``; raises for unreachable sensors."""
    n = len(ids)
    done = np.zeros(n, dtype=bool)
    done[root] = True
    order = [root]
    while not done.all():
        link = np.where(done[None, :], shared, 0).max(axis=1)
        link[done] = -1
        nxt = int(np.argmax(link))
        if link[nxt] < min_shared:
            lonely = [ids[k] for k in range(n) if not done[k]]
            seen = [ids[k] for k in range(n) if done[k]]
            counts = ", ".join(
                f"{ids[k]}: {int(np.where(done, shared[k], 0).max())}"
                for k in range(n)
                if not done[k]
            )
            raise CalibrationError(
                f"sensor(s) {', '.join(lonely)} never saw the wand at the same time as sensor(s) "
                f"{', '.join(seen)} often enough (need {min_shared} shared sightings; best "
                f"counts: {counts}). Wave the wand where their fields of view overlap with the "
                "others' and record the calibration again"
            )
        done[nxt] = True
        order.append(nxt)
    return order


def _initial_poses(
    m: _Matched, ids: Sequence[str], order: Sequence[int], min_spread_m: float
) -> tuple[Array, Array]:
    """Poses in the frame of ``order[0]``: each sensor in turn by a robust Kabsch fit of its wand
    centres onto the wand positions the already registered sensors agree on."""
    n_s = len(ids)
    rot = np.tile(np.eye(3), (n_s, 1, 1))
    trans = np.zeros((n_s, 3))
    done = np.zeros(n_s, dtype=bool)
    done[order[0]] = True
    for k in order[1:]:
        reg = m.ok & done[None, :]
        both = m.ok[:, k] & reg.any(axis=1)
        pw = np.einsum("sij,gsj->gsi", rot, np.nan_to_num(m.p)) + trans[None]
        wq = np.where(reg, m.q, 0.0)
        target = (pw * wq[..., None]).sum(1)[both] / wq.sum(1)[both][:, None]
        t = _robust_kabsch(m.p[both, k], target, m.q[both, k], f"sensor {ids[k]}", min_spread_m)
        rot[k], trans[k] = t[:3, :3], t[:3, 3]
        done[k] = True
    return rot, trans


@dataclass
class _Refined:
    sensor2ref: Array  # (S, 4, 4)
    wand: Array  # (E, 3) refined wand positions of the events
    g_idx: NDArray[np.intp]  # (O,) event of each observation
    s_idx: NDArray[np.intp]  # (O,) sensor of each observation
    residual: Array  # (O, 3) unweighted residuals, metres


def _refine(
    m: _Matched,
    ev: NDArray[np.intp],
    rot: Array,
    trans: Array,
    root: int,
    loss: str,
    loss_scale_m: float,
) -> _Refined:
    """One robust least-squares refinement of all poses (but ``root``'s) and all wand positions.

    Parameters: per free sensor a rotation vector ``phi`` (applied on the left of its initial
    rotation) and its translation, then the wand position of every event. Residual block order:
    observation o = (event e, sensor s), components x, y, z of ``w (R_s p + t_s - X_e)``.
    """
    n_s = rot.shape[0]
    g_idx, s_idx = np.nonzero(m.ok[ev])
    obs_p = m.p[ev][g_idx, s_idx]
    obs_w = np.sqrt(np.clip(m.q[ev][g_idx, s_idx], 0.05, 1.0))
    n_e, n_o = len(ev), len(g_idx)
    free = [k for k in range(n_s) if k != root]
    slot = np.full(n_s, -1)
    slot[free] = np.arange(len(free))
    n_pose = 6 * len(free)
    pw0 = np.einsum("oij,oj->oi", rot[s_idx], obs_p) + trans[s_idx]
    x_ev = np.zeros((n_e, 3))
    np.add.at(x_ev, g_idx, pw0 * obs_w[:, None] ** 2)
    wsum = np.zeros(n_e)
    np.add.at(wsum, g_idx, obs_w**2)
    x_ev /= wsum[:, None]
    pose0 = np.zeros((len(free), 6))
    pose0[:, 3:] = trans[free]  # rotation increments start at 0 around the initial rotations
    x0 = np.concatenate([pose0.ravel(), x_ev.ravel()])
    o_slot = slot[s_idx]
    fo = np.flatnonzero(o_slot >= 0)  # observations by free sensors

    # sparse structure: wand block -I (diagonal), rotation block 3x3, translation block I
    rows_x = (3 * np.arange(n_o)[:, None] + np.arange(3)).ravel()
    cols_x = (n_pose + 3 * g_idx[:, None] + np.arange(3)).ravel()
    rows_r = np.repeat(3 * fo[:, None] + np.arange(3), 3, axis=1).ravel()
    cols_r = np.tile(6 * o_slot[fo][:, None] + np.arange(3), (1, 3)).ravel()
    rows_t = (3 * fo[:, None] + np.arange(3)).ravel()
    cols_t = (6 * o_slot[fo][:, None] + 3 + np.arange(3)).ravel()
    rows_all = np.concatenate([rows_x, rows_r, rows_t])
    cols_all = np.concatenate([cols_x, cols_r, cols_t])
    shape = (3 * n_o, n_pose + 3 * n_e)

    def unpack(x: Array) -> tuple[Array, Array, Array, Array]:
        r_all = rot.copy()
        t_all = trans.copy()
        jl = np.tile(np.eye(3), (n_s, 1, 1))
        if free:
            pose = x[:n_pose].reshape(-1, 6)
            r_exp, j_left = so3_exp_and_left_jacobian(pose[:, :3])
            r_all[free] = r_exp @ rot[free]
            t_all[free] = pose[:, 3:]
            jl[free] = j_left
        return r_all, t_all, jl, x[n_pose:].reshape(-1, 3)

    def fun(x: Array) -> Array:
        r_all, t_all, _, xe = unpack(x)
        q = np.einsum("oij,oj->oi", r_all[s_idx], obs_p) + t_all[s_idx]
        return np.asarray(((q - xe[g_idx]) * obs_w[:, None]).ravel())

    def jac(x: Array) -> sparse.csr_matrix:
        r_all, _, jl, _ = unpack(x)
        q = np.einsum("oij,oj->oi", r_all[s_idx[fo]], obs_p[fo])
        blk = -skew(q) @ jl[s_idx[fo]] * obs_w[fo, None, None]
        data = np.concatenate([np.repeat(-obs_w, 3), blk.reshape(-1), np.repeat(obs_w[fo], 3)])
        return sparse.csr_matrix((data, (rows_all, cols_all)), shape=shape)

    sol = least_squares(
        fun,
        x0,
        jac=jac,
        method="trf",
        loss=loss,
        f_scale=loss_scale_m,
        x_scale="jac",
        tr_solver="lsmr",
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=100,
    )
    r_all, t_all, _, xe = unpack(sol.x)
    res = np.einsum("oij,oj->oi", r_all[s_idx], obs_p) + t_all[s_idx] - xe[g_idx]
    return _Refined(make_transform(r_all, t_all), xe, g_idx, s_idx, res)


def register_full(
    sightings: Mapping[str, Sightings],
    *,
    floors: Mapping[str, FloorPlane] | None = None,
    origin: Literal["wand", "sensor"] = "wand",
    pin_sensor: str | None = None,
    rate_hz: float = 30.0,
    max_gap_s: float = 0.05,
    max_speed_m_s: float = 1.5,
    min_shared: int = 10,
    loss: str = "soft_l1",
    loss_scale_m: float = 0.01,
    min_move_m: float = 0.2,
    origin_window_s: float = 0.3,
    move_axis: Literal["x", "y"] = "y",
    min_spread_m: float = 0.05,
) -> Registration:
    """Six-degree-of-freedom registration of 2 or more sensors from wand sightings.

    Parameters
    ----------
    sightings : mapping sensor id -> Sightings
        Each sensor's wand centres (sensor frame, metres) with server-clock times.
    floors : mapping sensor id -> FloorPlane, optional
        Floor planes (sensor frame) of the sensors that see the floor; they give gravity and
        z = 0. Sensors without a floor may be left out.
    origin : {"wand", "sensor"}
        ``"wand"`` (needs ``floors``): origin at the wand's first position projected on the
        floor, ``move_axis`` along its first horizontal move (at least ``min_move_m``), z up.
        ``"sensor"``: the world is pinned to ``pin_sensor``: its frame itself without floors;
        with floors, z up, origin on the floor below it and x along its optical axis projected
        on the floor.
    pin_sensor : str, optional
        Sensor held fixed during the refinement and used by ``origin="sensor"`` (default: the
        sensor that shares the most sightings with the others).
    rate_hz : float
        Rate of the common time grid the tracks are interpolated to.
    max_gap_s : float
        Interpolate only between sightings at most this far apart.
    max_speed_m_s : float
        Skip instants where the wand moved faster than this (the sensors are not synchronized,
        so a clock error of dt shifts a moving wand by speed * dt).
    min_shared : int
        Sensors are linked when they saw the wand together at least this many times.
    loss, loss_scale_m : str, float
        Robust loss of the joint refinement (``scipy.optimize.least_squares``) and its scale.
    origin_window_s : float
        The wand's first position is the median over this long a start.
    move_axis : {"y", "x"}
        World axis along the wand's first move: ``"y"`` as in the paper (the wand is shown at the
        origin, then moved along the y axis), ``"x"`` if the operator moves it along x.
    min_spread_m : float
        A sensor's shared wand positions must lie at least this far (RMS) from a line, else its
        rotation is not determined (error naming it).

    Returns
    -------
    Registration

    Raises
    ------
    CalibrationError
        Fewer than 2 sensors, a sensor without sightings, sensors that never saw the wand together
        with the others (named, with what to do), wand positions that do not determine the poses,
        ``origin="wand"`` without any floor.
    """
    ids = tuple(sightings)
    if len(ids) < 2:
        raise CalibrationError(
            f"calibration needs at least 2 sensors that saw the wand, got {len(ids)} "
            f"({', '.join(ids) or 'none'}); record a calibration phase in which every sensor sees "
            "the wand"
        )
    for sid in ids:
        if not isinstance(sightings[sid], Sightings):
            raise InputError(
                f"sightings[{sid!r}] must be a Sightings, got {type(sightings[sid]).__name__}"
            )
    empty = [sid for sid in ids if len(sightings[sid]) == 0]
    if empty:
        raise CalibrationError(
            f"sensor(s) {', '.join(empty)} have no wand sightings; make sure the wand is waved "
            "in their field of view during the calibration phase (or leave them out)"
        )
    if move_axis not in ("x", "y"):
        raise InputError(f"move_axis must be 'x' or 'y', got {move_axis!r}")
    if origin not in ("wand", "sensor"):
        raise InputError(f"origin must be 'wand' or 'sensor', got {origin!r}")
    if pin_sensor is not None and pin_sensor not in ids:
        raise InputError(f"pin_sensor {pin_sensor!r} is not one of the sensors: {', '.join(ids)}")
    floors = dict(floors or {})
    unknown = sorted(set(floors) - set(ids))
    if unknown:
        raise InputError(f"floors given for unknown sensor(s): {', '.join(unknown)}")
    if origin == "wand" and not floors:
        raise CalibrationError(
            "origin='wand' needs the floor plane of at least one sensor (gravity and z = 0); "
            "pass floors=... (see fit_floor_plane) or use origin='sensor'"
        )
    tracks = [sightings[sid] for sid in ids]
    m = _match_in_time(tracks, rate_hz, max_gap_s, max_speed_m_s)
    multi = m.ok.sum(axis=1) >= 2
    okm = m.ok[multi]
    shared = okm.T.astype(np.int64) @ okm.astype(np.int64)
    np.fill_diagonal(shared, 0)
    root = ids.index(pin_sensor) if pin_sensor is not None else int(np.argmax(shared.sum(1)))
    order = _spanning_order(ids, shared, root, min_shared)

    rot, trans = _initial_poses(m, ids, order, min_spread_m)
    ev = np.flatnonzero(multi)
    ref = _refine(m, ev, rot, trans, root, loss, loss_scale_m)
    rn = np.linalg.norm(ref.residual, axis=1)
    inlier = rn < max(3.0 * loss_scale_m, 4.0 * 1.4826 * float(np.median(rn)))
    n_s = len(ids)
    resid = np.zeros(n_s)
    n_used = np.zeros(n_s, dtype=np.int64)
    for k in range(n_s):
        sel = inlier & (ref.s_idx == k)
        resid[k] = float(np.sqrt(np.mean(rn[sel] ** 2))) if sel.any() else np.nan
        raw = np.concatenate([m.i0[ev[ref.g_idx[sel]], k], m.i1[ev[ref.g_idx[sel]], k]])
        n_used[k] = len(np.unique(raw))
    rms = float(np.sqrt(np.mean(rn[inlier] ** 2))) if inlier.any() else float("nan")
    s2r, xe, g_idx = ref.sensor2ref, ref.wand, ref.g_idx

    # --- world frame
    root2world, world = _world_frame(
        ids,
        s2r,
        floors,
        origin,
        order[0],
        m.t[ev],
        xe,
        inlier,
        g_idx,
        min_move_m,
        origin_window_s,
        move_axis,
    )
    poses = np.einsum("ij,sjk->sik", root2world, s2r)
    return Registration(
        method="full",
        sensor_ids=ids,
        sensor2world=poses,
        residual_m=resid,
        n_sightings=n_used,
        rms_m=rms,
        world=world,
    )


def _world_frame(
    ids: Sequence[str],
    s2r: Array,
    floors: Mapping[str, FloorPlane],
    origin: str,
    pin: int,
    t_ev: Array,
    xe: Array,
    inlier: NDArray[np.bool_],
    g_idx: NDArray[np.intp],
    min_move_m: float,
    origin_window_s: float,
    move_axis: str = "y",
) -> tuple[Array, str]:
    """``root2world`` from the floors and the wand's first positions (or the pinned sensor)."""
    if not floors:
        return invert_transform(s2r[pin]), f"pinned: the frame of sensor {ids[pin]} (no gravity)"
    normals, heights, weights = [], [], []
    for sid, fl in floors.items():
        k = ids.index(sid)
        n_r = s2r[k, :3, :3] @ fl.normal
        d_r = fl.offset_m - n_r @ s2r[k, :3, 3]
        normals.append(n_r)
        heights.append(-d_r)  # floor: n . x = -d
        weights.append(max(fl.n_inliers, 1))
    nrm = np.array(normals)
    w = np.array(weights, dtype=np.float64)
    up = (w[:, None] * nrm).sum(0)
    up /= np.linalg.norm(up)
    if len(nrm) >= 3:  # drop floors that disagree (e.g. a table taken for the floor)
        ang = np.degrees(np.arccos(np.clip(nrm @ up, -1, 1)))
        good = ang < max(3.0, 3.0 * float(np.median(ang)))
        if good.sum() >= 2:
            up = (w[good, None] * nrm[good]).sum(0)
            up /= np.linalg.norm(up)
            w = np.where(good, w, 0.0)
    floor_h = float(np.sum(w * np.array(heights)) / w.sum())  # floor: up . x = floor_h
    used = [sid for sid, wk in zip(floors, w, strict=True) if wk > 0]
    if origin == "sensor":
        o = s2r[pin, :3, 3]
        xdir = s2r[pin, :3, 2]
        what = f"pinned to sensor {ids[pin]}: origin on the floor below it, x along its view"
    else:
        ev_ok = np.zeros(len(xe), dtype=bool)
        ev_ok[g_idx[inlier]] = True
        te, pe = t_ev[ev_ok], xe[ev_ok]
        first = pe[te <= te[0] + origin_window_s]
        o = np.median(first, axis=0)
        hv = (pe - o) - np.outer((pe - o) @ up, up)
        far = np.flatnonzero(np.linalg.norm(hv, axis=1) >= min_move_m)
        if far.size == 0:
            raise CalibrationError(
                f"the wand never moved {min_move_m} m horizontally from its first position; "
                "the x axis is not defined (move the wand, or use origin='sensor')"
            )
        xdir = hv[far[0]]
        what = f"wand: origin below the wand's first position, {move_axis} along its first move"
    xdir = xdir - (xdir @ up) * up
    if np.linalg.norm(xdir) < 1e-6:
        raise CalibrationError("the heading direction is vertical; cannot define the world axes")
    xdir /= np.linalg.norm(xdir)
    if origin != "sensor" and move_axis == "y":  # the move is y; x = y cross z
        ydir = xdir
        xdir = np.cross(ydir, up)
    else:
        ydir = np.cross(up, xdir)
    o_floor = o - (o @ up - floor_h) * up
    r_w = np.stack([xdir, ydir, up])  # rows: world axes in the root frame
    root2world = make_transform(r_w, -r_w @ o_floor)
    return root2world, f"{what}; z up from the floor seen by {', '.join(used)}"
