"""A failed floor fit on a sensor client is logged and shows in that sensor's status.

The client fits the floor on a worker thread from its first depth frames after a calibration
starts; a failure there used to vanish (the thread's exception was dropped). Real sockets on
127.0.0.1: the server, the real sensor client and a control peer asking for the status.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Iterator

import numpy as np

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import DepthFrame
from kinefuse.live.client.client import ClientOptions, SensorClient
from kinefuse.live.client.clocks import HostClock
from kinefuse.live.client.playback import SourceTimeline
from kinefuse.live.protocol import (
    Decoder,
    Heartbeat,
    Hello,
    SensorInfo,
    Status,
    StatusRequest,
    Welcome,
    encode,
)
from kinefuse.live.protocol.codec import from_wire, to_wire
from kinefuse.live.server.server import Server, ServerOptions

LIMIT_S = 30.0


class SwitchingDepthMode:
    """A driver whose depth frames alternate between two resolutions (a device that switched
    its depth mode): the floor fit's per-pixel median of the first frames cannot be taken."""

    sensor_ids = ("k9",)

    def __init__(self, n: int = 150) -> None:
        self.n = n

    def intrinsics(self, sensor_id: str) -> Intrinsics:
        return Intrinsics()

    def __iter__(self) -> Iterator[DepthFrame]:
        for k in range(self.n):
            shape = (424, 512) if k % 2 == 0 else (212, 256)
            t = k / 30.0
            yield DepthFrame("k9", k, 100.0 + t, 200.0 + t, np.full(shape, 2500, np.uint16))


async def until(cond, timeout: float, what: str) -> None:
    t_end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > t_end:
            raise TimeoutError(f"timed out waiting for {what}")
        await asyncio.sleep(0.05)


async def control_status(port: int) -> Status:
    r, w = await asyncio.open_connection("127.0.0.1", port)
    dec, inbox = Decoder(), []

    async def recv():
        while not inbox:
            data = await asyncio.wait_for(r.read(65536), 5.0)
            assert data, "the server closed"
            inbox.extend(dec.feed(data))
        return inbox.pop(0)

    w.write(encode(Hello(role="control")))
    assert isinstance(await recv(), Welcome)
    w.write(encode(StatusRequest(request_id=7)))
    while not isinstance(m := await recv(), Status):
        pass
    w.close()
    return m


def test_a_failed_floor_fit_is_logged_and_in_the_sensors_status(caplog) -> None:
    caplog.set_level(logging.INFO)

    def floor_error(srv: Server) -> str | None:
        for s in srv.status().sensors:
            if s.sensor_id == "k9":
                return getattr(s, "floor_error", None)
        return None

    async def main() -> tuple[str | None, Status]:
        srv = Server(ServerOptions(port=0, auto_calibrate=True, timeout_s=5.0))
        task = asyncio.ensure_future(srv.run())
        await until(lambda: srv.port is not None, 5, "the server")
        assert srv.port is not None
        client = SensorClient(
            SourceTimeline(SwitchingDepthMode()),
            ClientOptions(server=("127.0.0.1", srv.port)),
            host_clock=lambda m0: HostClock(77.0, 20e-6, m0),
        )
        running = asyncio.ensure_future(client.run())
        try:
            await until(
                lambda: floor_error(srv) is not None or running.done(),
                15,
                "the floor fit's failure in the sensor's status",
            )
            status = await control_status(srv.port)
        finally:
            client.stop("done")
            await asyncio.wait_for(running, 10)
            srv.request_stop("done")
            await asyncio.wait_for(task, 10)
        return floor_error(srv), status

    err, status = asyncio.run(asyncio.wait_for(main(), LIMIT_S))
    assert err is not None, "the floor fit failed on the client, the sensor's status says nothing"
    assert "shape" in err, err
    (info,) = [s for s in status.sensors if s.sensor_id == "k9"]
    assert info.floor_error == err
    logged = [
        r
        for r in caplog.records
        if r.name == "kinefuse.sensor" and r.levelno >= logging.WARNING and "floor" in r.message
    ]
    assert logged and "shape" in logged[0].message, [r.message for r in caplog.records]


def test_the_floor_error_fields_are_optional_on_the_wire() -> None:
    """A peer of the same version without the fields still talks: a heartbeat without
    ``floor_error`` and a status whose sensor maps lack it (an older server) decode with nil."""
    beat = from_wire(to_wire(Heartbeat(t_s=1.0, floor_error="ValueError: x")))
    assert isinstance(beat, Heartbeat) and beat.floor_error == "ValueError: x"
    raw = to_wire(Heartbeat(t_s=1.0))
    raw.pop("floor_error", None)
    beat = from_wire(raw)
    assert isinstance(beat, Heartbeat) and beat.floor_error is None
    info = SensorInfo("k0", True, 1.0, 0.0, 0.1, 30.0, 60.0, 1.0)
    raw = to_wire(Status(sensors=(info,)))
    for x in raw["sensors"]:
        x.pop("floor_error", None)
    back = from_wire(raw)
    assert isinstance(back, Status) and back.sensors[0].floor_error is None
