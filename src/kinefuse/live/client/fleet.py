"""Many light sensor clients in one process: a simulated session's body frames, replayed.

The capacity benchmark (``benchmarks/bench_capacity.py``) needs 16 or 24 sensors on a 2-core
machine. A ``kinefuse sensor`` process per sensor would spend a core on interpreters alone, so
these clients share one event loop. Each is the real :class:`SensorClient` (its own TCP
connection, Hello and token proof, probe replies stamped in the socket callback, the occlusion
test, bounded queues, its own emulated host clock that the server synchronizes with probes);
only their timelines are light: a :class:`~kinefuse.live.client.playback.SimTimeline` without
depth frames (no wand detection, no floor fit). The server cannot tell them from separate
processes.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from pathlib import Path

from kinefuse.live.client.client import ClientOptions, SensorClient
from kinefuse.live.client.clocks import HostClock
from kinefuse.live.client.playback import SimTimeline


def replay_clients(
    session: Path,
    sensor_ids: Sequence[str],
    options: ClientOptions,
    *,
    epoch_monotonic: float | None = None,
) -> list[SensorClient]:
    """One body-only client per sensor of a simulated ``session``, all playing from
    ``epoch_monotonic`` (timeline time ``T`` at monotonic ``epoch + T / speed``), each with the
    simulated host clock of its sensor (offset and drift from the session's truth, as
    ``kinefuse sensor`` emulates them)."""
    clients = []
    for sid in sensor_ids:
        tl = SimTimeline(str(session), sid, depth=False)
        truth = tl.truth
        assert truth is not None  # a SimTimeline always has its truth
        h0, drift = truth.host.offset_s, truth.host.drift_ppm * 1e-6

        def emulated(m0: float, h0: float = h0, drift: float = drift) -> HostClock:
            return HostClock(h0, drift, m0)

        clients.append(
            SensorClient(
                tl,
                options if options.serial else _with_serial(options, tl.serial),
                host_clock=emulated,
                epoch_monotonic=epoch_monotonic,
            )
        )
    return clients


def _with_serial(options: ClientOptions, serial: str) -> ClientOptions:
    from dataclasses import replace

    return replace(options, serial=serial)


async def run_clients(clients: Sequence[SensorClient]) -> list[int]:
    """Run every client until each stops (the end of its source, or :meth:`stop_all`); the
    exit codes in order. One that fails (refused, a bad source) stops the others and raises."""
    try:
        async with asyncio.TaskGroup() as tg:
            tasks = [tg.create_task(c.run()) for c in clients]
    except BaseExceptionGroup as eg:
        stop_all(clients, "a sibling client failed")
        raise eg.exceptions[0] from None
    except BaseException:
        stop_all(clients, "stopped")
        raise
    return [t.result() for t in tasks]


def stop_all(clients: Sequence[SensorClient], reason: str = "stopped") -> None:
    """Ask every client to stop (each says Goodbye)."""
    for c in clients:
        c.stop(reason)
