"""The publish interface: lossy subscribers keep the newest items, lossless ones keep all."""

from __future__ import annotations

import asyncio

import numpy as np

from kinefuse.live.bus import FusedFrame, Publisher, Status


def _frame(seq: int) -> FusedFrame:
    return FusedFrame(
        seq=seq,
        t_server_s=seq / 30,
        positions_m=np.zeros((25, 3)),
        variance_m2=np.zeros(25),
        status=np.zeros(25, np.int8),
        latency_s=0.01,
    )


def _status(t: float) -> Status:
    return Status(
        t_server_s=t,
        sensors=(),
        calibration_state="none",
        calibration_grade=None,
        fused_fps=0.0,
        method="best-live",
    )


async def _collect(sub) -> list:
    return [item async for item in sub]


def test_lossy_subscriber_keeps_newest_and_counts_drops() -> None:
    async def run() -> tuple[list, int, list]:
        pub = Publisher()
        slow = pub.subscribe(maxsize=2)
        full = pub.subscribe(maxsize=None)
        for k in range(10):
            pub.publish(_frame(k))
        pub.close()
        return await _collect(slow), slow.dropped, await _collect(full)

    slow_items, dropped, full_items = asyncio.run(run())
    assert [f.seq for f in slow_items] == [8, 9]
    assert dropped == 8
    assert [f.seq for f in full_items] == list(range(10))


def test_new_subscriber_gets_last_status_and_unsubscribe_stops_delivery() -> None:
    async def run() -> tuple[list, list, int]:
        pub = Publisher()
        pub.publish(_status(1.0))
        late = pub.subscribe(maxsize=4)
        gone = pub.subscribe(maxsize=4)
        gone.close()
        pub.publish(_frame(0))
        n = pub.n_subscribers
        pub.close()
        return await _collect(late), await _collect(gone), n

    late_items, gone_items, n = asyncio.run(run())
    assert isinstance(late_items[0], Status) and late_items[0].t_server_s == 1.0
    assert [type(i).__name__ for i in late_items] == ["Status", "FusedFrame"]
    assert [type(i).__name__ for i in gone_items] == ["Status"] and n == 1


def test_iteration_waits_for_items() -> None:
    async def run() -> list[int]:
        pub = Publisher()
        sub = pub.subscribe(maxsize=None)

        async def producer() -> None:
            for k in range(3):
                await asyncio.sleep(0.01)
                pub.publish(_frame(k))
            pub.close()

        async with asyncio.TaskGroup() as tg:
            tg.create_task(producer())
            got = tg.create_task(_collect(sub))
        return [f.seq for f in got.result()]

    assert asyncio.run(run()) == [0, 1, 2]
