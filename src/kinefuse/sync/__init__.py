"""Clock synchronization (NTP-style offset and drift) and frame assembly. Pure: clocks injected."""

from kinefuse.sync.assembly import AssembledFrames, assemble_latest
from kinefuse.sync.ntp import ClockEstimate, estimate_clock, probe_offsets
from kinefuse.sync.online import OnlineClock, OnlineClockParams, OnlineEstimate, ProbeStatus

__all__ = [
    "AssembledFrames",
    "ClockEstimate",
    "OnlineClock",
    "OnlineClockParams",
    "OnlineEstimate",
    "ProbeStatus",
    "assemble_latest",
    "estimate_clock",
    "probe_offsets",
]
