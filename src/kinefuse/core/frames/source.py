"""The frame-source contract: what a sensor client plays, whatever delivers it.

Implemented by a stored session, a real log, a simulated sensor
(:mod:`kinefuse.pipeline.frame_sources`, which also opens one from a spec) and by a driver for a
physical sensor.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, runtime_checkable

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import Frame

__all__ = ["FrameSource"]


@runtime_checkable
class FrameSource(Protocol):
    """What a sensor client plays: frames in arrival order (a driver implements this too).

    ``sensor_ids`` names the sensors it delivers; ``intrinsics(sensor_id)`` their depth camera;
    iterating yields :data:`Frame` items, each sensor's in increasing ``seq``.
    """

    @property
    def sensor_ids(self) -> tuple[str, ...]: ...

    def intrinsics(self, sensor_id: str) -> Intrinsics: ...

    def __iter__(self) -> Iterator[Frame]: ...
