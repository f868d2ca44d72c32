"""Clock synchronisation (NTP-style offset and drift, the online estimator, device -> host) and
frame assembly. Pure: clocks injected.

Part of :mod:`kinefuse.capture`: may import :mod:`kinefuse.core` and the rest of capture.
"""

from kinefuse.capture.sync.assembly import AssembledFrames, assemble_latest
from kinefuse.capture.sync.device import (
    DeviceClockEstimate,
    SensorTimebase,
    estimate_device_clock,
    sensor_timebase,
)
from kinefuse.capture.sync.ntp import ClockEstimate, estimate_clock, probe_offsets
from kinefuse.capture.sync.online import OnlineClock, OnlineClockParams, OnlineEstimate, ProbeStatus

__all__ = [
    "AssembledFrames",
    "ClockEstimate",
    "DeviceClockEstimate",
    "OnlineClock",
    "OnlineClockParams",
    "OnlineEstimate",
    "ProbeStatus",
    "SensorTimebase",
    "assemble_latest",
    "estimate_clock",
    "estimate_device_clock",
    "probe_offsets",
    "sensor_timebase",
]
