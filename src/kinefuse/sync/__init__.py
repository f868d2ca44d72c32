"""Clock synchronization (NTP-style offset and drift) and frame assembly. Pure: clocks injected."""

from kinefuse.sync.assembly import AssembledFrames, assemble_latest
from kinefuse.sync.ntp import ClockEstimate, estimate_clock, probe_offsets

__all__ = ["AssembledFrames", "ClockEstimate", "assemble_latest", "estimate_clock", "probe_offsets"]
