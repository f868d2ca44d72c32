"""Which of a recording's sensors the offline commands can use, and why the others are left out.

A live recording holds whatever its authenticated peers sent: a test sensor that never
calibrated, a client whose clock was never set, frames stamped 1e12 s from the rest. None of
that may stop the offline commands from working on the sensors that recorded properly. This
module screens a store's sensors on their time stamps alone (nothing else is read): each
sensor's capture times are put on the server clock as every command does (device -> host ->
server, :func:`kinefuse.capture.sync.sensor_timebase`) and compared with the span the server itself
saw the recording take (its own stamps: the clock probes' send and receive times, the frames'
arrival times, the phases in the metadata). A sensor whose frames lie mostly outside that span is
left out, named with the reason; a usable sensor's few stray frames are dropped and counted.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.sync import sensor_timebase
from kinefuse.errors import KinefuseError
from kinefuse.formats.store.session_store import SessionStore

Array = NDArray[np.float64]

__all__ = ["MARGIN_S", "SensorScreen", "recording_window", "screen_sensors", "server_times"]

#: Capture times (server clock) this far outside the span the server saw are not the recording's:
#: a minute, or a tenth of the span if that is longer (clock estimates err by milliseconds).
MARGIN_S = 60.0
#: Without any stamp of the server's own, a time stamp beyond this (about 300 years) is no
#: clock's.
MAX_ABS_S = 1e10


@dataclass(frozen=True)
class SensorScreen:
    """The verdict on a store's sensors.

    Attributes
    ----------
    usable : tuple of str
        Sensor ids the commands may use, in the store's order.
    left_out : dict
        ``sensor id -> why`` (a plain-language reason) for the others.
    window_server_s : (float, float) or None
        The span (server clock, margin included) capture times must fall in; None when the store
        has no stamps of the server's own (then only absurd stamps, beyond ``MAX_ABS_S``, are
        refused).
    stray_seq : dict
        ``sensor id -> seq`` of a usable sensor's frames stamped outside the window (dropped).
    """

    usable: tuple[str, ...]
    left_out: dict[str, str] = field(default_factory=dict)
    window_server_s: tuple[float, float] | None = None
    stray_seq: dict[str, NDArray[np.int64]] = field(default_factory=dict)

    def notes(self) -> list[str]:
        """One line per sensor left out and per sensor with dropped frames."""
        out = [f"sensor {sid} left out: {why}" for sid, why in self.left_out.items()]
        out += [
            f"sensor {sid}: {len(seq)} frame(s) stamped outside the recording were dropped"
            for sid, seq in self.stray_seq.items()
        ]
        return out

    def without(self, more: dict[str, str]) -> SensorScreen:
        """The same screen with the sensors of ``more`` (id -> why) left out as well."""
        left = {**self.left_out, **{k: v for k, v in more.items() if k not in self.left_out}}
        return SensorScreen(
            usable=tuple(s for s in self.usable if s not in left),
            left_out=left,
            window_server_s=self.window_server_s,
            stray_seq={k: v for k, v in self.stray_seq.items() if k not in left},
        )


def recording_window(store: SessionStore) -> tuple[float, float] | None:
    """The span of the recording on the server clock, from the server's own stamps only (its
    probes' send and receive times, the frames' arrival times, the metadata's phases), widened by
    :data:`MARGIN_S` (or a tenth of the span); None when there are none."""
    lo, hi = np.inf, -np.inf
    meta = store.meta()
    for key in ("calibration_phase_server_s", "motion_phase_server_s"):
        v = meta.get(key)
        if isinstance(v, list) and len(v) == 2 and all(isinstance(x, int | float) for x in v):
            lo, hi = min(lo, float(v[0])), max(hi, float(v[1]))
    for info in store.sensors():
        probes = store.clock_probes(info.id)
        if len(probes):
            lo, hi = min(lo, float(probes[:, 0].min())), max(hi, float(probes[:, 3].max()))
        _seq, _t, t_server, _th = store.observation_times(info.id)
        t_server = t_server[np.isfinite(t_server)]
        if t_server.size:
            lo, hi = min(lo, float(t_server.min())), max(hi, float(t_server.max()))
    if not np.isfinite(lo) or not np.isfinite(hi):
        return None
    margin = max(MARGIN_S, 0.1 * (hi - lo))
    return lo - margin, hi + margin


def server_times(
    probes: Array, t_sensor_s: Array, t_host_s: Array, t_receive_server_s: Array
) -> Array:
    """Capture times on the server clock as the commands compute them: through the sensor's
    clock (its probes) when it has probes, else the server's arrival stamps where there are some,
    else the sensor's own stamps. Raises :class:`KinefuseError` (or a numerical error) when the
    clock cannot be estimated."""
    if len(probes):
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            tb = sensor_timebase(probes, t_sensor_s, t_host_s)
            return np.asarray(tb.affine.forward(t_sensor_s), dtype=np.float64)
    if np.isfinite(t_receive_server_s).any():
        return np.where(np.isfinite(t_receive_server_s), t_receive_server_s, np.nan)
    return t_sensor_s


def _span(t: Array) -> str:
    t = t[np.isfinite(t)]
    if not t.size:
        return "no finite time"
    return f"{t.min():.4g} to {t.max():.4g} s" if t.min() != t.max() else f"{t.min():.4g} s"


def screen_sensors(store: SessionStore, *, need_clock: bool = True) -> SensorScreen:
    """Screen every sensor of ``store`` on its time stamps (see the module's docstring).

    ``need_clock``: a sensor with frames but no clock probes is left out (its stamps cannot be
    put on the server clock: what fusion and calibration need); without it such a sensor is
    judged on the server's arrival stamps or its own (what ``inspect`` shows).
    A sensor without frames is usable (it has nothing to screen; the commands say it saw nothing).
    """
    window = recording_window(store)
    usable: list[str] = []
    left: dict[str, str] = {}
    stray: dict[str, NDArray[np.int64]] = {}
    for info in store.sensors():
        seq, t_dev, t_server_rx, t_host = store.observation_times(info.id)
        n = seq.size
        if n == 0:
            usable.append(info.id)
            continue
        probes = store.clock_probes(info.id)
        if need_clock and not len(probes):
            left[info.id] = (
                f"no clock probes, so its {n} frame(s) cannot be put on the server clock (its "
                f"own stamps: {_span(t_dev)})"
            )
            continue
        try:
            t = server_times(probes, t_dev, t_host, t_server_rx)
        except (KinefuseError, ValueError, ArithmeticError, np.linalg.LinAlgError) as e:
            left[info.id] = f"its clock could not be estimated ({e})"
            continue
        if window is None:
            inside = np.isfinite(t) & (np.abs(t) <= MAX_ABS_S)
            where = f"beyond any clock's range (|t| > {MAX_ABS_S:.0e} s)"
        else:
            inside = np.isfinite(t) & (t >= window[0]) & (t <= window[1])
            where = (
                f"outside the recording (server time {_span(t[~inside])}; the server saw "
                f"{window[0]:.1f} to {window[1]:.1f} s, margin included)"
            )
        n_out = int(n - inside.sum())
        if 2 * n_out > n:
            left[info.id] = (
                f"{n_out} of its {n} frame(s) are stamped {where}: a sensor whose clock was "
                "never set or that sends garbage time stamps"
            )
        else:
            usable.append(info.id)
            if n_out:
                stray[info.id] = seq[~inside]
    return SensorScreen(tuple(usable), left, window, stray)
