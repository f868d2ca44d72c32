"""What the server publishes, and the one small interface it publishes through.

The server produces two kinds of items: a :class:`FusedFrame` every fused frame (30 Hz) and a
:class:`Status` snapshot about once a second. Anything that wants them (the recorder, the
live viewer, a test) calls :meth:`Publisher.subscribe` and iterates its :class:`Subscription`.

:meth:`Publisher.publish` never blocks and never awaits, so a slow subscriber cannot stall the
fusion loop: a *lossy* subscription (the viewer's) keeps only the newest ``maxsize`` items and
counts what it dropped; a *lossless* one (the recorder's) keeps everything and its owner must keep
up. All of it runs on one asyncio event loop (publish from the loop's thread).
"""

from __future__ import annotations

import asyncio
from collections import deque
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinefuse.live.protocol.messages import SensorInfo, Status

__all__ = ["FusedFrame", "Item", "Publisher", "SensorInfo", "Status", "Subscription"]

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class FusedFrame:
    """One fused skeleton as the server published it.

    Attributes
    ----------
    seq : int
        The server's fused-frame counter (0, 1, 2, ... at 30 Hz).
    t_server_s : float
        Frame time on the server clock, seconds since the server started.
    positions_m : (25, 3) float
        World frame (z up), metres; NaN where ``status`` is ``NO_DATA``.
    variance_m2 : (25,) float
        Position variance per axis, m^2 (NaN with the positions).
    status : (25,) int8
        :class:`~kinefuse.capture.fusion.status.FusionStatus` codes.
    latency_s : float
        Client host receive time (mapped onto the server clock) of the newest observation used
        -> this frame published, on the server clock, seconds; NaN if no observation was used.
    raw_m : mapping of sensor id -> (25, 3) float
        Each calibrated sensor's latest raw skeleton in the world frame (NaN where untracked),
        for the viewer's per-sensor toggle.
    subject : int
        The person ``positions_m`` is (the subject the server gives by default).
    people_m : mapping of person id -> (25, 3) float
        Every person's fused skeleton (the subject's included), world frame; a one-person
        session has one, person 0.
    people_status : mapping of person id -> (25,) int8
        Every person's status codes (as ``status`` for the subject).
    """

    seq: int
    t_server_s: float
    positions_m: Array
    variance_m2: Array
    status: NDArray[np.int8]
    latency_s: float
    raw_m: Mapping[str, Array] = field(default_factory=dict)
    subject: int = 0
    people_m: Mapping[int, Array] = field(default_factory=dict)
    people_status: Mapping[int, NDArray[np.int8]] = field(default_factory=dict)


Item = FusedFrame | Status


class Subscription:
    """A subscriber's queue; iterate it (``async for item in sub``) until the publisher closes.

    Parameters
    ----------
    maxsize : int or None
        Lossy: keep only the newest ``maxsize`` items (older ones are dropped and counted in
        :attr:`dropped`). None: lossless, keep everything.
    """

    def __init__(self, publisher: Publisher, maxsize: int | None) -> None:
        if maxsize is not None and maxsize < 1:
            raise ValueError(f"maxsize must be >= 1 or None, got {maxsize}")
        self._publisher = publisher
        self._items: deque[Item] = deque(maxlen=maxsize)
        self._wake = asyncio.Event()
        self._closed = False
        #: items dropped because the subscriber fell behind (lossy subscriptions only)
        self.dropped = 0

    def _put(self, item: Item) -> None:
        if self._items.maxlen is not None and len(self._items) == self._items.maxlen:
            self.dropped += 1
        self._items.append(item)
        self._wake.set()

    def _close(self) -> None:
        self._closed = True
        self._wake.set()

    def close(self) -> None:
        """Stop receiving (the iteration ends after the items already queued)."""
        self._publisher._remove(self)
        self._close()

    def __aiter__(self) -> AsyncIterator[Item]:
        return self._iter()

    async def _iter(self) -> AsyncIterator[Item]:
        while True:
            while self._items:
                yield self._items.popleft()
            if self._closed:
                return
            self._wake.clear()
            await self._wake.wait()

    def __len__(self) -> int:
        return len(self._items)


class Publisher:
    """Fan-out of published items to subscriptions (see the module docstring)."""

    def __init__(self) -> None:
        self._subs: list[Subscription] = []
        self._closed = False
        #: the last status published (a new subscriber gets it first)
        self.last_status: Status | None = None

    def subscribe(self, maxsize: int | None = 2) -> Subscription:
        """A new subscription (lossy with the newest ``maxsize`` items; None = lossless)."""
        sub = Subscription(self, maxsize)
        if self._closed:
            sub._close()
        else:
            self._subs.append(sub)
            if self.last_status is not None:
                sub._put(self.last_status)
        return sub

    def publish(self, item: Item) -> None:
        """Hand ``item`` to every subscription; never blocks."""
        if self._closed:
            raise RuntimeError("publish after close")
        if isinstance(item, Status):
            self.last_status = item
        for sub in self._subs:
            sub._put(item)

    def close(self) -> None:
        """End every subscription (after the items already queued)."""
        self._closed = True
        for sub in self._subs:
            sub._close()
        self._subs.clear()

    @property
    def n_subscribers(self) -> int:
        return len(self._subs)

    def _remove(self, sub: Subscription) -> None:
        if sub in self._subs:
            self._subs.remove(sub)
