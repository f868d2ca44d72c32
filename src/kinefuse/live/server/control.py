"""The server's side of a control peer (``kinefuse calibrate --live``, the demo): calibration
start/stop, status requests, shutdown, heartbeats."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import TYPE_CHECKING

from kinefuse.errors import CalibrationError
from kinefuse.live.protocol import (
    CalibrationResult,
    CalibrationStart,
    CalibrationStop,
    Goodbye,
    Heartbeat,
    Shutdown,
    StatusRequest,
    Welcome,
    printable,
)
from kinefuse.live.protocol.wire_errors import LimitExceeded, OutOfOrder
from kinefuse.live.server.conn import Connection
from kinefuse.live.server.peer_limits import TokenBucket
from kinefuse.live.server.status_report import status_message

if TYPE_CHECKING:
    from kinefuse.live.server.server import Server

log = logging.getLogger("kinefuse.serve")


async def serve_control(srv: Server, conn: Connection) -> None:
    """A control peer: calibration start/stop, status, shutdown (see docs/protocol.md)."""
    conn.send(
        conn.handshake.send(
            Welcome(
                session=srv.options.session,
                t_server_s=srv.clock(),
                heartbeat_s=srv.options.heartbeat_s,
                timeout_s=srv.options.timeout_s,
                calibrating=srv.calibration.collecting,
                calibration_id=srv.calibration.calibration_id,
            )
        )
    )
    srv._controls.add(conn)
    log.info("control peer connected from %s", conn.peer)
    beat = asyncio.ensure_future(_heartbeat_loop(srv, conn))
    o = srv.options
    # requests cost the event loop (a status snapshot, a calibration): a peer gets so many
    requests = TokenBucket(o.control_rate, o.control_burst, srv.clock())
    try:
        while True:
            msg, t = await conn.recv(srv.options.timeout_s)
            conn.check_sender(msg)
            if not isinstance(msg, Heartbeat | Goodbye) and not requests.take(t):
                raise LimitExceeded(
                    f"{conn.name} sends more than {o.control_rate:g} requests a second "
                    f"(bursts of {o.control_burst:g})"
                )
            if isinstance(msg, CalibrationStart):
                try:
                    srv._start_calibration(
                        method=msg.method, sensor_ids=msg.sensor_ids, seconds=msg.seconds
                    )
                except CalibrationError as e:
                    conn.send(
                        CalibrationResult(
                            calibration_id=msg.calibration_id,
                            ok=False,
                            grade="failed",
                            message=str(e)[:1024],
                        )
                    )
            elif isinstance(msg, CalibrationStop):
                if srv.calibration.collecting:
                    srv._finish_calibration(abort=msg.abort, why="stopped by the control peer")
            elif isinstance(msg, StatusRequest):
                conn.send(status_message(srv, msg.request_id))
            elif isinstance(msg, Shutdown):
                conn.send(Goodbye(reason="shutting down"))
                srv.request_stop(f"shutdown asked by {conn.peer}: {printable(msg.reason)}")
                return
            elif isinstance(msg, Goodbye):
                return
            elif isinstance(msg, Heartbeat):
                pass
            else:
                raise OutOfOrder(f"a control peer may not send {msg.TYPE} after the handshake")
    finally:
        beat.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await beat


async def _heartbeat_loop(srv: Server, conn: Connection) -> None:
    while not conn.closed:
        await asyncio.sleep(srv.options.heartbeat_s / 2)
        if srv.clock() - conn.last_sent >= srv.options.heartbeat_s:
            conn.send(Heartbeat(t_s=srv.clock()))
