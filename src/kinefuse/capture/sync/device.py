"""From a sensor's own frame timestamps to server time, as a real client and server can.

A Kinect v2 stamps each frame with its device clock (``RelativeTime``), which is not the clock
of the PC it is plugged into; the PC receives the frame a variable capture-to-host latency later
and can stamp that arrival on its own clock. The server knows the PC's clock through NTP-style
probes (:mod:`kinefuse.capture.sync.ntp`). So, per sensor:

1. **device -> host**: a robust straight-line fit of ``t_receive_host - t_device`` against
   ``t_device`` over every frame (the device clock's offset and drift against the host's, plus
   the mean latency), minus a nominal mean latency (:data:`NOMINAL_LATENCY_S`): the capture time
   on the host clock. What the nominal value misses (a unit's own latency) stays as a time error
   common to all frames of that sensor, as on real hardware;
2. **host -> server**: the probes' clock estimate.

Sessions recorded without host receive times (older stores, or a client that stamps frames
with the probed clock itself) map ``t_device`` through the probes alone. Depth frames carry the
same device timestamps but no arrival times: calibration maps them with the estimate from the
body frames of the same device (a session with depth frames only falls back to the probes).
Pure: arrays in, a small frozen dataclass out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.sync.ntp import ClockEstimate, estimate_clock
from kinefuse.core.affine_clock import AffineClock, OffsetDriftClock
from kinefuse.errors import SyncError

Array = NDArray[np.float64]

#: Mean capture-to-host latency of a Kinect v2 body frame assumed by the sync, seconds: the middle
#: of the 50-90 ms reported from motion to skeleton output (an assumption of the system, the
#: same literature figure the simulator's ClockParams.latency_mean_s uses; measure it once for a
#: real rig, e.g. with a light flash seen by the depth camera).
NOMINAL_LATENCY_S = 0.060


@dataclass(frozen=True)
class DeviceClockEstimate(OffsetDriftClock):
    """One sensor's device clock fitted to its frames' host arrivals: the
    :class:`OffsetDriftClock` map from device time to host capture time (``offset_s``: host time
    of device time 0, minus the nominal latency), with ``residual_s`` (robust spread, 1.4826 MAD,
    of the arrival delays around the fit: the latency jitter) and ``n_frames`` (frames used; 0:
    no host times, the identity map)."""

    residual_s: float
    n_frames: int

    @classmethod
    def identity(cls) -> DeviceClockEstimate:
        """Device time is host time (frames stamped by the probed clock)."""
        return cls(offset_s=0.0, drift_ppm=0.0, residual_s=0.0, n_frames=0)


def estimate_device_clock(
    t_device_s: ArrayLike,
    t_receive_host_s: ArrayLike,
    *,
    latency_s: float = NOMINAL_LATENCY_S,
) -> DeviceClockEstimate:
    """Fit the device clock against the host clock from each frame's two stamps.

    Parameters
    ----------
    t_device_s : (N,) float
        Frame timestamps on the device clock, seconds.
    t_receive_host_s : (N,) float
        Arrival times on the host clock, seconds; NaN where unknown (those frames are skipped).
    latency_s : float
        Assumed mean capture-to-host latency, seconds.

    Returns
    -------
    DeviceClockEstimate
        The identity when no frame has a host time.
    """
    td = np.asarray(t_device_s, dtype=np.float64).reshape(-1)
    th = np.asarray(t_receive_host_s, dtype=np.float64).reshape(-1)
    if td.shape != th.shape:
        raise SyncError(
            f"device and host times must pair up frame by frame, got {td.size} and {th.size}"
        )
    if not (np.isfinite(latency_s) and latency_s >= 0):
        raise SyncError(f"latency_s must be a non-negative number of seconds, got {latency_s}")
    ok = np.isfinite(td) & np.isfinite(th)
    if not ok.any():
        return DeviceClockEstimate.identity()
    td, d = td[ok], th[ok] - td[ok]
    if td.size < 3 or np.ptp(td) < 1.0:
        a, b = float(np.median(d)), 0.0
        r = d - a
    else:
        tc = td - td.mean()
        w = np.ones_like(tc)
        coef = np.array([np.median(d), 0.0])
        for _ in range(5):  # iteratively reweighted least squares (Huber-like)
            m = np.stack([np.ones_like(tc), tc], axis=1) * np.sqrt(w)[:, None]
            coef, *_ = np.linalg.lstsq(m, d * np.sqrt(w), rcond=None)
            r = d - (coef[0] + coef[1] * tc)
            s = 1.4826 * np.median(np.abs(r)) + 1e-7
            w = np.minimum(1.0, 2.0 * s / np.maximum(np.abs(r), 1e-12))
        b = float(coef[1])
        a = float(coef[0] - b * td.mean())
        r = d - (a + b * td)
    # t_host_receive = t_device + a + b t_device = a + (1 + b) t_device; capture = that - latency
    return DeviceClockEstimate(
        offset_s=a - float(latency_s),
        drift_ppm=b * 1e6,
        residual_s=float(1.4826 * np.median(np.abs(r))),
        n_frames=int(td.size),
    )


@dataclass(frozen=True)
class SensorTimebase:
    """Device timestamps to server time for one sensor: device -> host -> server."""

    device: DeviceClockEstimate
    host: ClockEstimate

    @property
    def affine(self) -> AffineClock:
        """Device timestamps -> server capture times: the device fit, then the host clock's
        inverse (server -> client) map."""
        return self.host.affine.inverted().compose(self.device.affine)


def sensor_timebase(
    probes: ArrayLike,
    t_device_s: ArrayLike,
    t_receive_host_s: ArrayLike,
    *,
    latency_s: float = NOMINAL_LATENCY_S,
) -> SensorTimebase:
    """Both steps at once, from what the server has: the probes and each frame's two stamps.

    Parameters
    ----------
    probes : (N, 4) float
        The client's clock probes (:func:`kinefuse.capture.sync.ntp.estimate_clock`).
    t_device_s, t_receive_host_s : (M,) float
        The body frames' device timestamps and host arrival times (NaN where unknown).
    """
    return SensorTimebase(
        device=estimate_device_clock(t_device_s, t_receive_host_s, latency_s=latency_s),
        host=estimate_clock(probes),
    )
