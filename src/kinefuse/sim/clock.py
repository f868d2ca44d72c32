"""Sensor clocks: the device's and the client PC's, latency, jitter and NTP-style probes.

The lab's true time is the server's clock (the server is the time reference of a session). A
real Kinect v2 has two clocks that matter, as here:

- the **device clock** stamps every frame (``RelativeTime``; ``Skeleton_Time`` in the
  KinectMultiTrack logs)::

      t_sensor = offset_s + rate * t_true + jitter      (rate: drift_ppm parts per million above 1)

  and the device captures at its nominal rate on that clock with a phase of its own: the sensors
  are not synchronized;
- the **host clock** of the client PC the device is plugged into answers the clock probes
  (:func:`clock_probes`) and stamps the moment each frame arrives from the device, after a
  capture-to-host latency (USB transfer, SDK body tracking) that varies frame to frame and
  between units.

Both stamps are recorded (``t_sensor_s``, ``t_receive_host_s``), as a real client can; the sync
maps device time to host time from them (:mod:`kinefuse.capture.sync.device`) and host time to
server time from the probes. Every parameter is in :class:`ClockParams` with its unit and source.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.affine_clock import OffsetDriftClock
from kinefuse.errors import InputError

if TYPE_CHECKING:
    from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ClockParams:
    """How sensor clocks, capture and transport behave (one config, each value with its source)."""

    frame_rate_hz: float = field(
        default=30.0,
        metadata={"unit": "Hz", "source": "Kinect v2 depth/body stream rate (Microsoft SDK 2.0)"},
    )
    offset_range_s: float = field(
        default=1000.0,
        metadata={
            "unit": "s",
            "source": "assumption: clients' clocks start at arbitrary times; offsets uniform in "
            "[0, offset_range_s)",
        },
    )
    drift_sigma_ppm: float = field(
        default=20.0,
        metadata={
            "unit": "ppm",
            "source": "assumption from typical PC quartz oscillators (+/-20-50 ppm tolerance); "
            "normal, clipped at 3 sigma",
        },
    )
    timestamp_jitter_s: float = field(
        default=0.0002,
        metadata={
            "unit": "s",
            "source": "assumption: Kinect v2 RelativeTime has 100 ns resolution; frame-to-frame "
            "timing jitter of a fraction of a millisecond",
        },
    )
    frame_drop_prob: float = field(
        default=0.003,
        metadata={"unit": "1", "source": "assumption: occasional USB 3 frame drops"},
    )
    latency_mean_s: float = field(
        default=0.060,
        metadata={
            "unit": "s",
            "source": "assumption in the range reported for Kinect v2 body-tracking output "
            "(roughly 50-90 ms from motion to skeleton)",
        },
    )
    latency_sigma_s: float = field(
        default=0.004,
        metadata={
            "unit": "s",
            "source": "assumption: frame-to-frame spread of the capture-to-host latency "
            "(normal, clipped at latency_min_s)",
        },
    )
    latency_unit_sigma_s: float = field(
        default=0.003,
        metadata={
            "unit": "s",
            "source": "assumption: spread of the mean latency between units (host PCs, USB "
            "controllers); a client cannot measure it, so it stays in the sync as a time "
            "offset between sensors",
        },
    )
    latency_min_s: float = field(
        default=0.030,
        metadata={"unit": "s", "source": "assumption: no frame arrives sooner"},
    )
    network_delay_s: float = field(
        default=0.0005,
        metadata={"unit": "s", "source": "assumption: one-way delay on a wired LAN"},
    )
    network_jitter_s: float = field(
        default=0.0005,
        metadata={
            "unit": "s",
            "source": "assumption: exponential queueing delay added to network_delay_s",
        },
    )
    probe_interval_s: float = field(
        default=1.0, metadata={"unit": "s", "source": "design choice: one probe burst a second"}
    )
    probe_burst: int = field(
        default=4, metadata={"unit": "1", "source": "design choice (NTP clock filter practice)"}
    )
    probe_turnaround_s: float = field(
        default=0.0002,
        metadata={"unit": "s", "source": "assumption: client time between receive and reply"},
    )

    def __post_init__(self) -> None:
        if not self.frame_rate_hz > 0:
            raise ValueError(f"frame_rate_hz must be positive, got {self.frame_rate_hz}")
        if not 0 <= self.frame_drop_prob < 1:
            raise ValueError(f"frame_drop_prob must be in [0, 1), got {self.frame_drop_prob}")


@dataclass(frozen=True)
class SensorClock(OffsetDriftClock):
    """One simulated clock: the :class:`OffsetDriftClock` map from true (server) time to the
    clock's time (``offset_s``: its time at true time 0), with ``phase_s`` (its time of the
    first frame grid point modulo the frame period)."""

    phase_s: float

    def to_dict(self) -> dict[str, float]:
        return {"offset_s": self.offset_s, "drift_ppm": self.drift_ppm, "phase_s": self.phase_s}


def draw_clock(rng: np.random.Generator, params: ClockParams = ClockParams()) -> SensorClock:
    """A random sensor clock under ``params``."""
    drift = (
        float(
            np.clip(
                rng.normal(0.0, params.drift_sigma_ppm),
                -3 * params.drift_sigma_ppm,
                3 * params.drift_sigma_ppm,
            )
        )
        if params.drift_sigma_ppm > 0
        else 0.0
    )
    return SensorClock(
        offset_s=float(rng.uniform(0.0, params.offset_range_s)),
        drift_ppm=drift,
        phase_s=float(rng.uniform(0.0, 1.0 / params.frame_rate_hz)),
    )


@dataclass(frozen=True)
class SensorClocks:
    """The clocks of one simulated sensor: its device's and its client PC's.

    Attributes
    ----------
    device : SensorClock
        Stamps the frames and sets their capture grid.
    host : SensorClock
        The client PC's clock: answers clock probes, stamps frame arrivals (its phase is unused).
    latency_offset_s : float
        This unit's mean capture-to-host latency minus ``ClockParams.latency_mean_s``.
    """

    device: SensorClock
    host: SensorClock
    latency_offset_s: float

    def to_dict(self) -> dict[str, float]:
        """Flat: the device clock's keys as :meth:`SensorClock.to_dict`, the host's prefixed."""
        return {
            **self.device.to_dict(),
            "host_offset_s": self.host.offset_s,
            "host_drift_ppm": self.host.drift_ppm,
            "latency_offset_s": self.latency_offset_s,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, float]) -> SensorClocks:
        """The clocks :meth:`to_dict` wrote (a missing unit latency: 0; phases are not kept
        for the host clock: 0)."""
        return cls(
            device=SensorClock(
                offset_s=d["offset_s"], drift_ppm=d["drift_ppm"], phase_s=d.get("phase_s", 0.0)
            ),
            host=SensorClock(
                offset_s=d["host_offset_s"], drift_ppm=d["host_drift_ppm"], phase_s=0.0
            ),
            latency_offset_s=d.get("latency_offset_s", 0.0),
        )


def read_sensor_clocks(store: SessionStore, sensor_id: str) -> SensorClocks:
    """The simulated sensor's true clocks, from the session's truth: the simulator reading back
    what it wrote, to play that sensor live (a ``sim:`` source of ``kinefuse sensor``).

    Raises
    ------
    InputError
        The session has no truth (a live recording), or its clocks lack a key (an old session).
    """
    if not store.has_truth():
        raise InputError(
            f"{store.path} holds no simulator truth (a live recording?): a sim: source must "
            "be a simulated session (kinefuse simulate); replay a recording with "
            "--clock-offset-ms/--clock-drift-ppm given"
        )
    _pose, clock = store.truth().sensor(sensor_id)
    try:
        return SensorClocks.from_dict(clock)
    except KeyError as e:
        raise InputError(
            f"{store.path}: the true clock of sensor {sensor_id!r} has no {e}; simulate the "
            "session again with this kinefuse"
        ) from None


def draw_sensor_clocks(
    rng: np.random.Generator, params: ClockParams = ClockParams()
) -> SensorClocks:
    """A random device clock, host clock and unit latency under ``params``."""
    device = draw_clock(rng, params)
    host = draw_clock(rng, params)
    unit = (
        float(rng.normal(0.0, params.latency_unit_sigma_s)) if params.latency_unit_sigma_s else 0.0
    )
    return SensorClocks(device=device, host=host, latency_offset_s=unit)


@dataclass(frozen=True)
class CaptureTimes:
    """The frames one sensor captured in a time span.

    Attributes
    ----------
    seq : (N,) int64
        Frame sequence numbers on the sensor's frame grid (gaps where frames were dropped).
    t_true_s : (N,) float
        True (server) time of each capture.
    t_sensor_s : (N,) float
        The sensor's timestamp of each capture (its clock, with timestamp jitter).
    t_receive_server_s : (N,) float
        When the server receives the frame's body data (capture + latency + network delay).
    t_receive_host_s : (N,) float
        When the client PC receives the frame from the device, on the host clock.
    """

    seq: NDArray[np.int64]
    t_true_s: Array
    t_sensor_s: Array
    t_receive_server_s: Array
    t_receive_host_s: Array


def capture_times(
    clock: SensorClock,
    t_start_s: float,
    t_end_s: float,
    rng: np.random.Generator,
    params: ClockParams = ClockParams(),
    *,
    host: SensorClock | None = None,
    latency_offset_s: float = 0.0,
) -> CaptureTimes:
    """Frames a sensor captures between true times ``t_start_s`` and ``t_end_s``.

    The frame grid is ``phase_s + k / frame_rate_hz`` on the sensor's (device) clock; ``seq`` is
    ``k``. ``host`` is the client PC's clock that stamps arrivals (default: the device clock
    itself, a sensor whose frames are stamped by the clock that answers probes);
    ``latency_offset_s`` this unit's latency offset (:class:`SensorClocks`).
    """
    if not t_end_s > t_start_s:
        raise ValueError(f"capture span must be positive, got {t_start_s}..{t_end_s} s")
    period = 1.0 / params.frame_rate_hz
    s0, s1 = clock.affine.forward(t_start_s), clock.affine.forward(t_end_s)
    k0 = int(np.ceil((float(s0) - clock.phase_s) / period))
    k1 = int(np.floor((float(s1) - clock.phase_s) / period))
    k = np.arange(k0, k1 + 1, dtype=np.int64)
    keep = rng.random(k.size) >= params.frame_drop_prob
    k = k[keep]
    t_sensor_grid = clock.phase_s + k * period
    t_true = clock.affine.inverse(t_sensor_grid)
    t_sensor = t_sensor_grid + rng.normal(0.0, params.timestamp_jitter_s, k.size)
    mean = params.latency_mean_s + latency_offset_s
    latency = np.maximum(rng.normal(mean, params.latency_sigma_s, k.size), params.latency_min_s)
    net = params.network_delay_s + rng.exponential(params.network_jitter_s, k.size)
    h = clock if host is None else host
    return CaptureTimes(
        seq=k - k0 if k.size else k,
        t_true_s=t_true,
        t_sensor_s=t_sensor,
        t_receive_server_s=t_true + latency + net,
        t_receive_host_s=h.affine.forward(t_true + latency),
    )


def clock_probes(
    clock: SensorClock,
    t_start_s: float,
    t_end_s: float,
    rng: np.random.Generator,
    params: ClockParams = ClockParams(),
) -> Array:
    """Simulated NTP-style exchanges between the server and one sensor's client.

    The server sends at ``t1`` (its clock), the client receives at ``t2`` and replies at ``t3``
    (its clock), the server receives at ``t4``. Delays are asymmetric and random, as on a real
    network, so an estimator has to cope with them.

    Returns
    -------
    probes : (N, 4) float
        Columns ``t1_server_s, t2_client_s, t3_client_s, t4_server_s``.
    """
    starts = np.arange(t_start_s, t_end_s, params.probe_interval_s)
    burst = max(int(params.probe_burst), 1)
    t1 = (starts[:, None] + 0.01 * np.arange(burst)[None, :]).reshape(-1)
    n = t1.size
    up = params.network_delay_s + rng.exponential(params.network_jitter_s, n)
    down = params.network_delay_s + rng.exponential(params.network_jitter_s, n)
    turn = params.probe_turnaround_s * (1.0 + rng.random(n))
    t2 = clock.affine.forward(t1 + up)
    t3 = t2 + turn * clock.rate
    t4 = t1 + up + turn + down
    return np.stack([t1, t2, t3, t4], axis=1)
