"""Bringing a sensor's stream onto frame times: the two primitives, and the paper's frame assembly.

* **Latest in a window** (:func:`latest_in_window`, METHODS.md A.1/A.2): at each server frame
  time ``T``, a client contributes its most recent observation captured in the window
  ``(T - window_s, T]``; older data is excluded. This is the paper's baseline way of bringing
  unsynchronized sensors together (:func:`assemble_latest`; ``best`` with ``timestamp=False``).
* **Gap-aware linear interpolation** (:func:`interp_neighbours`, :func:`interpolate`): our fusion
  interpolates each stream to ``T`` instead, between the two observations around it, and gives
  nothing across a gap longer than ``max_gap_s``.

Both take observation times in any order (sorted here, stably) and return rows of the caller's
arrays, so one call serves joints and their covariances alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.errors import InputError

Array = NDArray[np.float64]

#: At either end of a stream, a query within half a 30 Hz frame of the first/last observation
#: takes that observation (instead of NaN).
END_TOLERANCE_S = 1.0 / 60.0


def latest_in_window(
    t_obs_s: ArrayLike, t_query_s: ArrayLike, *, window_s: float
) -> tuple[NDArray[np.intp], Array, NDArray[np.bool_]]:
    """Per query time ``T``, the latest observation captured in ``(T - window_s, T]``.

    Parameters
    ----------
    t_obs_s : (N,) float
        Observation times, seconds, any order (ties keep their order).
    t_query_s : (Q,) float
        Query (frame) times on the same clock, seconds.
    window_s : float
        Observations ``window_s`` or more older than ``T`` are excluded, seconds.

    Returns
    -------
    rows : (Q,) int
        Row of ``t_obs_s`` used, -1 where none is in the window.
    age_s : (Q,) float
        ``T`` minus the observation's time, NaN where none.
    ok : (Q,) bool
        ``rows >= 0``.
    """
    t = np.asarray(t_obs_s, dtype=np.float64)
    q = np.asarray(t_query_s, dtype=np.float64)
    if t.size == 0:
        none = np.zeros(q.shape, dtype=bool)
        return np.full(q.shape, -1, dtype=np.intp), np.full(q.shape, np.nan), none
    order = np.argsort(t, kind="stable")
    ts = t[order]
    k = np.searchsorted(ts, q, side="right") - 1
    kk = np.maximum(k, 0)
    age = np.where(k >= 0, q - ts[kk], np.nan)
    ok = (k >= 0) & (age < window_s)
    rows = np.where(ok, order[kk], -1).astype(np.intp)
    return rows, np.where(ok, age, np.nan), ok


def interp_neighbours(
    t_obs_s: ArrayLike,
    t_query_s: ArrayLike,
    *,
    max_gap_s: float,
    end_tolerance_s: float = END_TOLERANCE_S,
) -> tuple[NDArray[np.intp], NDArray[np.intp], Array, NDArray[np.bool_]]:
    """The two observations around each query time and the linear weight between them.

    A value at ``T`` is ``v[i0] * (1 - w) + v[i1] * w``. Neighbours further apart than
    ``max_gap_s`` give no value; before the first and after the last observation a query within
    ``end_tolerance_s`` takes that observation (``w`` 0 or 1), any other gives no value.

    Parameters
    ----------
    t_obs_s : (N,) float
        Observation times, seconds, any order (ties keep their order), ``N >= 1``.
    t_query_s : (Q,) float
        Query times, seconds.
    max_gap_s : float
        Largest gap between the two neighbours that is interpolated over, seconds.
    end_tolerance_s : float
        How far outside the stream a query still takes the end observation, seconds.

    Returns
    -------
    i0, i1 : (Q,) int
        Rows of ``t_obs_s`` before and after each query (clipped into range where there is none).
    w : (Q,) float
        Weight of ``i1``, in [0, 1] where ``ok``.
    ok : (Q,) bool
        Where a value exists.
    """
    t = np.asarray(t_obs_s, dtype=np.float64)
    q = np.asarray(t_query_s, dtype=np.float64)
    n = t.size
    order = np.argsort(t, kind="stable")
    ts = t[order]
    k = np.searchsorted(ts, q, side="right")
    i0 = np.clip(k - 1, 0, n - 1)
    i1 = np.clip(k, 0, n - 1)
    dt = ts[i1] - ts[i0]
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(dt > 0, (q - ts[i0]) / dt, 0.0)
    inside = (k > 0) & (k < n) & (dt <= max_gap_s)
    at_start = (k == 0) & (ts[0] - q <= end_tolerance_s)
    at_end = (k == n) & (q - ts[-1] <= end_tolerance_s)
    w = np.where(at_start, 0.0, np.where(at_end, 1.0, w))
    return order[i0], order[i1], w, inside | at_start | at_end


def interpolate(
    t_obs_s: ArrayLike, p: ArrayLike, t_query_s: ArrayLike, *, max_gap_s: float = 0.1
) -> Array:
    """Linear interpolation of a stream to query times, NaN across gaps and outside it.

    Parameters
    ----------
    t_obs_s : (N,) float
        Observation times, seconds (any order; sorted here).
    p : (N, ...) float
        Observations (e.g. ``(N, 25, 3)`` joints), NaN = missing.
    t_query_s : (Q,) float
    max_gap_s : float
        Neighbours further apart than this give NaN. At either end a query within half a 30 Hz
        frame of the first/last observation takes that observation (:func:`interp_neighbours`).

    Returns
    -------
    (Q, ...) float
    """
    t = np.asarray(t_obs_s, dtype=np.float64)
    v = np.asarray(p, dtype=np.float64)
    q = np.asarray(t_query_s, dtype=np.float64)
    if t.ndim != 1 or v.ndim < 1 or v.shape[0] != t.size or q.ndim != 1:
        raise InputError(
            f"interpolate expects times (N,), values (N, ...) and query times (Q,), got "
            f"{t.shape}, {v.shape} and {q.shape}"
        )
    out_shape = (q.size, *v.shape[1:])
    if t.size == 0:
        return np.full(out_shape, np.nan)
    i0, i1, w, ok = interp_neighbours(t, q, max_gap_s=max_gap_s)
    extra = (1,) * (v.ndim - 1)
    wv = w.reshape(-1, *extra)
    out = v[i0] * (1.0 - wv) + v[i1] * wv
    return np.where(ok.reshape(-1, *extra), out, np.nan)


@dataclass(frozen=True)
class AssembledFrames:
    """Per frame time, each sensor's latest observation in the window.

    Attributes
    ----------
    t_server_s : (T,) float
        Frame times.
    joints : (T, S, J, 3) float
        Joints in each sensor's frame; NaN where the sensor had nothing in the window.
    states : (T, S, J) int8
    index : (T, S) int
        Row of the observation used in that sensor's stream, -1 if none.
    age_s : (T, S) float
        ``T`` minus the observation's capture time on the server clock (NaN if none).
    """

    t_server_s: Array
    joints: Array
    states: NDArray[np.int8]
    index: NDArray[np.intp]
    age_s: Array


def assemble_latest(
    t_frames_s: ArrayLike,
    capture_server_s: list[Array],
    joints: list[Array],
    states: list[NDArray[np.int8]],
    *,
    window_s: float = 1.0 / 30.0,
) -> AssembledFrames:
    """Assemble frames from S sensor streams.

    Parameters
    ----------
    t_frames_s : (T,) float
        Server frame times.
    capture_server_s : list of (N_s,) float
        Each stream's capture times on the server clock (from the clock estimate).
    joints : list of (N_s, J, 3) float
    states : list of (N_s, J) int8
    window_s : float
        Observations older than this at a frame time are excluded.
    """
    t = np.asarray(t_frames_s, dtype=np.float64)
    n_s = len(capture_server_s)
    if not (len(joints) == len(states) == n_s):
        raise ValueError("capture times, joints and states must list the same sensors")
    if n_s == 0:
        raise ValueError("no sensor streams to assemble")
    n_j = joints[0].shape[1]
    out = np.full((t.size, n_s, n_j, 3), np.nan)
    st = np.zeros((t.size, n_s, n_j), dtype=np.int8)
    idx = np.full((t.size, n_s), -1, dtype=np.intp)
    age = np.full((t.size, n_s), np.nan)
    for s in range(n_s):
        rows, a, ok = latest_in_window(capture_server_s[s], t, window_s=window_s)
        idx[ok, s] = rows[ok]
        age[ok, s] = a[ok]
        out[ok, s] = joints[s][rows[ok]]
        st[ok, s] = states[s][rows[ok]]
    return AssembledFrames(t_server_s=t, joints=out, states=st, index=idx, age_s=age)
