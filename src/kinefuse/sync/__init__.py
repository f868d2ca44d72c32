"""Clock synchronization (NTP-style offset and drift) and frame assembly. Pure: clocks injected.

May import: errors, io (base), skeleton, geometry, camera, frames, protocol, motion.
"""

from kinefuse.sync.assembly import AssembledFrames, assemble_latest
from kinefuse.sync.device import (
    DeviceClockEstimate,
    SensorTimebase,
    estimate_device_clock,
    sensor_timebase,
)
from kinefuse.sync.ntp import ClockEstimate, estimate_clock, probe_offsets
from kinefuse.sync.online import OnlineClock, OnlineClockParams, OnlineEstimate, ProbeStatus

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
