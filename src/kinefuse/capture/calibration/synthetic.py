"""Synthetic calibration data with known truth, for tests, benchmarks and documentation.

What the clients of a rig would send to the server during a calibration phase, without rendering
depth frames (for those, use the simulator: ``kinefuse.sim.depth.render_depth``): a rig of
pitched and rolled sensors (:func:`make_rig`), a wand trajectory that follows the paper's protocol
and then waves through the volume (:func:`wand_waving`), and the wand centres each sensor reports
at its own 30 Hz frame times (unsynchronized phases, times on the server clock with a residual
sync error) with detection noise growing with distance, dropouts and a few gross outliers
(:func:`simulate_sightings`).

Nothing here is used by the calibration itself.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.calibration.register import Sightings
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand
from kinefuse.core.geometry.transforms import invert_transform, look_at

Array = NDArray[np.float64]

# ---------------------------------------------------------------------------------------------
# Rigs, wand trajectories and the sightings the clients would send


def make_rig(
    n_sensors: int,
    rng: np.random.Generator,
    *,
    distance_m: tuple[float, float] = (2.0, 4.0),
    pitch_deg: float = 20.0,
    roll_deg: float = 5.0,
    centre_m: ArrayLike = (0.0, 0.0, 1.1),
    aim_jitter_m: float = 0.2,
    height_limits_m: tuple[float, float] = (0.3, 2.6),
    level: bool = False,
) -> Array:
    """Sensors around a capture area, each looking at it with a random tilt and roll.

    Sensor ``i`` stands at azimuth ``2 pi i / n`` (+- 0.2 rad) and a random horizontal distance
    from the centre; it aims at the centre (moved up or down by up to ``aim_jitter_m``) with a
    random pitch in ``[-pitch_deg, pitch_deg]`` from the horizontal (its height follows, within
    ``height_limits_m``), then rolls by a random angle in ``[-roll_deg, roll_deg]``.

    Parameters
    ----------
    n_sensors : int
    rng : numpy Generator
    distance_m : (min, max)
        Horizontal distance from the centre.
    pitch_deg, roll_deg : float
        Maximum absolute pitch (tilt of the optical axis from the horizontal) and roll.
    centre_m : (3,)
        Centre of the capture volume.
    aim_jitter_m : float
        Random vertical offset of the aim point.
    height_limits_m : (min, max)
        Sensor heights are clipped to this range (the pitch then follows from the aim).
    level : bool
        Every sensor level (no pitch, no roll), as the paper's method assumes.

    Returns
    -------
    sensor2world : (S, 4, 4) float
    """
    c = np.asarray(centre_m, dtype=np.float64)
    out = np.empty((n_sensors, 4, 4))
    az0 = rng.uniform(0, 2 * np.pi)
    for i in range(n_sensors):
        az = az0 + 2 * np.pi * i / n_sensors + rng.uniform(-0.2, 0.2)
        dist = rng.uniform(*distance_m)
        aim = c + np.array([0.0, 0.0, rng.uniform(-aim_jitter_m, aim_jitter_m)])
        pitch = 0.0 if level else np.radians(rng.uniform(-pitch_deg, pitch_deg))
        height = float(np.clip(aim[2] - dist * np.tan(pitch), *height_limits_m))
        pos = np.array([c[0] + dist * np.cos(az), c[1] + dist * np.sin(az), height])
        if level:
            aim[2] = height
        roll = 0.0 if level else np.radians(rng.uniform(-roll_deg, roll_deg))
        out[i] = look_at(pos, aim, roll_rad=roll)
    return out


def wand_waving(
    duration_s: float,
    rng: np.random.Generator,
    *,
    rate_hz: float = 240.0,
    centre_m: ArrayLike = (0.0, 0.0, 1.1),
    extent_m: ArrayLike = (0.8, 0.8, 0.45),
    max_freq_hz: float = 0.45,
    hold_s: float = 1.0,
    first_move_m: ArrayLike = (0.0, 1.0, 0.0),
) -> tuple[Array, Array]:
    """A smooth random wand trajectory: held still at the start, moved, then waved in 3D.

    The first ``hold_s`` seconds the wand rests at ``centre_m`` (the paper's "wand at the
    origin"), then it moves by ``first_move_m`` and rests again for ``hold_s`` (the paper's second
    position), then it is waved as a sum of sinusoids within ``extent_m`` of the centre.

    Returns
    -------
    t_s : (T,) float
    position_m : (T, 3) float
        World positions of the wand centre.
    """
    c = np.asarray(centre_m, dtype=np.float64)
    ext = np.asarray(extent_m, dtype=np.float64)
    mv = np.asarray(first_move_m, dtype=np.float64)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    k = 4
    freq = rng.uniform(0.08, max_freq_hz, size=(k, 3))
    phase = rng.uniform(0, 2 * np.pi, size=(k, 3))
    amp = rng.uniform(0.5, 1.0, size=(k, 3))
    amp /= amp.sum(axis=0)

    def smoothstep(x: Array) -> Array:
        x = np.clip(x, 0.0, 1.0)
        return np.asarray(x * x * (3 - 2 * x))

    move = smoothstep((t - hold_s) / 1.0)[:, None] * mv
    start_wave = 2 * hold_s + 1.0
    blend = smoothstep((t - start_wave) / 1.5)[:, None]
    tshift = np.maximum(t - start_wave, 0.0)[:, None, None]
    wave = (amp * np.sin(2 * np.pi * freq * tshift + phase)).sum(axis=1) * ext
    wave -= (amp * np.sin(phase)).sum(axis=0) * ext
    return t, c + (1.0 - blend) * move + blend * wave


def simulate_sightings(
    sensor2world: ArrayLike,
    intrinsics: Intrinsics,
    t_s: ArrayLike,
    wand_world_m: ArrayLike,
    rng: np.random.Generator,
    *,
    sensor_ids: Sequence[str] | None = None,
    rate_hz: float = 30.0,
    noise_m: tuple[float, float] = (0.001, 0.00025),
    sync_error_s: float = 0.001,
    dropout: float = 0.05,
    outlier_rate: float = 0.01,
    wand: Wand | None = None,
    visible: NDArray[np.bool_] | None = None,
) -> dict[str, Sightings]:
    """Wand centres each sensor would report, on the server clock, with realistic errors.

    Each sensor captures at ``rate_hz`` with its own random phase; a capture at true time ``t``
    carries the server time ``t + e`` with ``e ~ N(0, sync_error_s)``. The wand is seen when its
    whole silhouette is in the image and its centre within range. Detection noise per axis is
    ``noise_m[0] + noise_m[1] * z^2`` (z in metres); a fraction ``dropout`` of frames is lost and
    ``outlier_rate`` of the reports are gross errors (0.1-0.5 m off).

    Parameters
    ----------
    sensor2world : (S, 4, 4) float
    intrinsics : Intrinsics
    t_s : (T,) float
        Times of the true trajectory.
    wand_world_m : (T, 3) float
        True wand centre in the world.
    rng : numpy Generator
    visible : (S, T) bool, optional
        Extra visibility mask (e.g. to build a chain of sensors); sightings are kept only where
        it is True at the nearest trajectory sample.

    Returns
    -------
    dict sensor id -> Sightings
    """
    poses = np.asarray(sensor2world, dtype=np.float64)
    tt = np.asarray(t_s, dtype=np.float64)
    pw = np.asarray(wand_world_m, dtype=np.float64)
    wnd = Wand() if wand is None else wand
    ids = [f"k{i}" for i in range(len(poses))] if sensor_ids is None else list(sensor_ids)
    out: dict[str, Sightings] = {}
    f = 0.5 * (intrinsics.fx + intrinsics.fy)
    for i, s2w in enumerate(poses):
        phase = rng.uniform(0, 1.0 / rate_hz)
        tk = np.arange(tt[0] + phase, tt[-1], 1.0 / rate_hz)
        p = np.stack([np.interp(tk, tt, pw[:, j]) for j in range(3)], -1)
        w2s = invert_transform(s2w)
        ps = p @ w2s[:3, :3].T + w2s[:3, 3]
        rho = f * wnd.radius_m / np.maximum(ps[:, 2], 0.2)
        seen = intrinsics.in_view(ps, margin_px=0.0) & (ps[:, 2] > wnd.radius_m)
        uv = intrinsics.project(ps)
        with np.errstate(invalid="ignore"):
            seen &= (uv[:, 0] > rho) & (uv[:, 0] < intrinsics.width - 1 - rho)
            seen &= (uv[:, 1] > rho) & (uv[:, 1] < intrinsics.height - 1 - rho)
        if visible is not None:
            idx = np.clip(np.searchsorted(tt, tk), 0, len(tt) - 1)
            seen &= np.asarray(visible, dtype=bool)[i, idx]
        seen &= rng.random(len(tk)) >= dropout
        sig = noise_m[0] + noise_m[1] * ps[:, 2] ** 2
        meas = ps + rng.standard_normal(ps.shape) * sig[:, None]
        out_mask = rng.random(len(tk)) < outlier_rate
        off = rng.standard_normal((len(tk), 3))
        off *= (rng.uniform(0.1, 0.5, len(tk)) / np.linalg.norm(off, axis=1))[:, None]
        meas = np.where(out_mask[:, None], meas + off, meas)
        t_server = tk + rng.standard_normal(len(tk)) * sync_error_s
        q = np.clip(1.0 - 0.1 * ps[:, 2], 0.2, 1.0)
        out[ids[i]] = Sightings(
            t_server_s=t_server[seen], centre_sensor_m=meas[seen], quality=q[seen]
        )
    return out


def true_wand_in_sensor(
    sensor2world: ArrayLike, t_s: ArrayLike, wand_world_m: ArrayLike, t_query_s: ArrayLike
) -> Array:
    """True wand centre in one sensor's frame at times ``t_query_s``: ``(N, 3)`` metres."""
    tt = np.asarray(t_s, dtype=np.float64)
    pw = np.asarray(wand_world_m, dtype=np.float64)
    tq = np.asarray(t_query_s, dtype=np.float64)
    p = np.stack([np.interp(tq, tt, pw[:, j]) for j in range(3)], -1)
    w2s = invert_transform(np.asarray(sensor2world, dtype=np.float64))
    return np.asarray(p @ w2s[:3, :3].T + w2s[:3, 3])


__all__ = [
    "make_rig",
    "simulate_sightings",
    "true_wand_in_sensor",
    "wand_waving",
]
