"""Frame assembly as the paper's server does it (METHODS.md A.1/A.2).

At each server frame time ``T``, every client contributes its most recent observation captured in
the window ``(T - window_s, T]``; older data is excluded. This is the paper's baseline way of
bringing unsynchronized sensors together; our fusion interpolates to ``T`` instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]


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
        tc = np.asarray(capture_server_s[s], dtype=np.float64)
        order = np.argsort(tc, kind="stable")
        tc_sorted = tc[order]
        k = np.searchsorted(tc_sorted, t, side="right") - 1
        has = k >= 0
        rows = np.where(has, order[np.maximum(k, 0)], -1)
        a = np.where(has, t - tc_sorted[np.maximum(k, 0)], np.nan)
        ok = has & (a < window_s)
        idx[ok, s] = rows[ok]
        age[ok, s] = a[ok]
        out[ok, s] = joints[s][rows[ok]]
        st[ok, s] = states[s][rows[ok]]
    return AssembledFrames(t_server_s=t, joints=out, states=st, index=idx, age_s=age)
