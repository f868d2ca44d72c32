"""The live server (``kinefuse serve``): sensor clients in, fused frames out, everything recorded.

Structure (all tasks in one :class:`asyncio.TaskGroup`, so an unexpected error anywhere stops
the whole server loudly instead of leaving half of it running):

- one task per accepted connection (:meth:`Server._connection`): the handshake (Hello, the HMAC
  challenge when a token is set, with the server's own proof over the peer's nonce, Welcome
  or a refusal), then for a sensor its reader and its clock prober (bursts of
  ``probe_burst`` probes ``probe_spacing_s`` apart every ``probe_interval_s``), for a control
  peer its requests. A protocol error or a silent peer
  closes only that connection, with the reason logged; a bug while serving one peer is logged
  and closes that peer only;
- the fusion loop (:class:`~kinefuse.live.server.fusion_loop.FusionLoop`, 30 Hz on the server
  clock);
- housekeeping: ``Status`` about once a second and on every change, the end of a
  calibration (:mod:`kinefuse.live.server.live_calibration`);
- the recorder (:class:`~kinefuse.live.server.recorder.Recorder`), when recording;
- the live web viewer (:func:`kinefuse.live.viewer.live_viewer`) on the same publisher, when asked.

The parts live beside it: ``server_conn`` (one connection's bytes and messages),
``server_client`` (a sensor's state across connections), ``server_control`` (a control peer),
``server_report`` (status snapshots, calibration outcomes, run figures), ``fusion_loop``,
``live_calibration`` and ``recorder``.

Per sensor the server keeps a :class:`~kinefuse.live.server.sensor_state.SensorState` across
connections (pose, clocks, statistics): a client that dies is marked offline and fusion goes on
with the others; when it comes back (same ``sensor_id``) it is re-synchronized and fused with its
pose at once. Each connection is a new stream: its ``seq`` starts afresh (a restarted sensor's
counter from 0 is fused from its first frame), a ``seq`` that does not increase on it is a stale
frame (counted in the status, and the connection closed). A second connection claiming a
connected sensor id is refused (``duplicate_id``). Who may start a handshake is decided at the
accept (:class:`~kinefuse.live.server.peer_limits.HandshakeSlots`); a sensor's own events are logged
rate-limited, and every string a peer sent is escaped before it is logged.

The server clock is ``clock()``: ``time.monotonic() - t0`` by default (recorded as the meta
``server_t0_monotonic``), injectable for tests.

Why about 820 lines: :class:`Server` is the one owner of the run's tasks and their shutdown order;
the per-connection protocol, the control commands and the report live in the ``server_*``
modules beside it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import socket
import time
from collections.abc import Callable, Mapping
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.capture.fusion.live import LiveOptions
from kinefuse.core.frames.observations import BodyFrame
from kinefuse.errors import CalibrationError, SyncError
from kinefuse.formats.store.live_tables import SightingRow
from kinefuse.live.address import is_loopback
from kinefuse.live.bus import Publisher, Status
from kinefuse.live.protocol import (
    MAX_FRAME_BYTES,
    AuthError,
    BodyFrameMessage,
    CalibrationStart,
    CalibrationStop,
    ClockProbe,
    ClockReply,
    Error,
    FloorPlaneMessage,
    Goodbye,
    Heartbeat,
    Hello,
    WandSighting,
    Welcome,
    WireError,
    encode,
    printable,
)
from kinefuse.live.protocol.wire_errors import OutOfOrder
from kinefuse.live.server.conn import Connection, ConnectionClosed, DuplicateSensor, TooSlow
from kinefuse.live.server.control import serve_control
from kinefuse.live.server.fusion_loop import FrameFusion, FusionLoop
from kinefuse.live.server.live_calibration import (
    CalibrationOutcome,
    LiveCalibration,
    LiveCalibrationOptions,
    SolveInput,
    solve_calibration,
)
from kinefuse.live.server.peer_limits import HandshakeSlots, RefusalLog, StampGate
from kinefuse.live.server.person import PersonCalibration, person_step
from kinefuse.live.server.recorder import Recorder
from kinefuse.live.server.sensor_state import Observation, SensorState, sanitize_joints
from kinefuse.live.server.status_report import (
    outcome_meta,
    result_message,
    run_stats,
    server_status,
)

log = logging.getLogger("kinefuse.serve")


@dataclass(frozen=True)
class ServerOptions:
    """Everything ``kinefuse serve`` can be told (seconds unless named otherwise)."""

    host: str = "127.0.0.1"
    port: int = 7400
    token: str | None = None
    record: Path | None = None
    method: str = "best-live"
    latency_budget_s: float = 0.010
    auto_calibrate: bool = False
    calibration: LiveCalibrationOptions = field(default_factory=LiveCalibrationOptions)
    probe_burst: int = 5
    probe_spacing_s: float = 0.020
    probe_interval_s: float = 1.0
    heartbeat_s: float = 1.0
    timeout_s: float = 5.0
    handshake_timeout_s: float = 5.0
    status_interval_s: float = 1.0
    max_frame_bytes: int = MAX_FRAME_BYTES
    max_sensors: int = 64
    session: str = "kinefuse-live"
    # what a hostile peer may cost (issue 23; docs/protocol.md "Limits"):
    #: frames before the Welcome (a Hello is a few kB): an unauthenticated peer buffers no MiB
    handshake_frame_bytes: int = 64 << 10
    #: connections accepted but not welcomed yet (guard.HandshakeSlots): from strangers, from
    #: addresses a peer was welcomed from before, and from any one address; more are refused at
    #: once (busy)
    max_pending: int = 32
    max_pending_known: int = 16
    max_pending_per_address: int = 8
    #: failed authentications an address may have per second, and at once (then: limit)
    auth_fail_rate: float = 1.0
    auth_fail_burst: float = 10.0
    #: a connection refused at the door is closed this much later (s), at most this many at once
    refuse_linger_s: float = 0.5
    max_lingering: int = 128
    max_controls: int = 8
    #: frames a peer may send per second on average, and at once
    msg_rate: float = 600.0
    msg_burst: float = 1200.0
    #: control requests (status, calibration, shutdown) a peer may send per second, and at once
    control_rate: float = 10.0
    control_burst: float = 20.0
    #: a sensor's stamps: how far they may jump on one connection, and the largest clock offset
    stamp_window_s: float = 30.0
    max_clock_offset_s: float = 1e9
    #: a body frame this much later than its clock says (a stalled sensor's backlog) is dropped
    max_backlog_s: float = 0.5


class Server:
    """The live server (see the module docstring).

    Parameters
    ----------
    options : ServerOptions
    clock : callable, optional
        The server clock, seconds (default: monotonic seconds since construction).
    services : mapping of name to callable, optional
        What else runs on the publisher while the server runs (the live web viewer, say): each
        is called with :attr:`publisher` and gives an async context manager, entered once the
        server listens and left when it stops; what it yields lands in :attr:`services`. The
        server knows them only by this contract (live/bus.py), not by what they are.
    """

    def __init__(
        self,
        options: ServerOptions,
        *,
        clock: Callable[[], float] | None = None,
        services: Mapping[str, Callable[[Publisher], AbstractAsyncContextManager[object]]]
        | None = None,
    ) -> None:
        self.options = options
        self._service_factories = dict(services or {})
        #: what each service yielded once running (the viewer: its port), by name
        self.services: dict[str, object] = {}
        self.t0_monotonic = time.monotonic()
        self.clock = clock or (lambda: time.monotonic() - self.t0_monotonic)
        self.clients: dict[str, SensorState] = {}
        self.calibration = LiveCalibration(options.calibration)
        self.person = PersonCalibration()  # calibration from the person when there is no wand
        self.publisher = Publisher()
        live = LiveOptions()
        self.fusion = FrameFusion(options.method, live)
        # the subject and each change of it go into the recording (an event `fuse` reads)
        self.fusion.on_subject = lambda _t, detail: self._event("subject", None, **detail)
        self.loop = FusionLoop(
            self.fusion, self.clients, self.publisher, self.clock, wait_s=options.latency_budget_s
        )
        self.recorder: Recorder | None = None
        self.port: int | None = None
        self._stop = asyncio.Event()
        self._stop_reason = ""
        self._conns: set[Connection] = set()
        self._controls: set[Connection] = set()
        self._sensor_conns: dict[str, Connection] = {}
        self._tg: asyncio.TaskGroup | None = None
        self._status_dirty = True
        self._last_status = -math.inf
        self._probe_id = 0
        #: refused connections: counted, the last 100 kept, logged and recorded rate-limited
        self.refusals = RefusalLog()
        #: connections in their handshake, and the slot each holds: (address, known)
        self._pending: dict[Connection, tuple[str, bool]] = {}
        self.slots = HandshakeSlots(
            max_pending=options.max_pending,
            max_pending_known=options.max_pending_known,
            per_address=options.max_pending_per_address,
            fail_rate=options.auth_fail_rate,
            fail_burst=options.auth_fail_burst,
        )
        self.last_outcome: CalibrationOutcome | None = None
        #: connections refused at the door, closed a moment later (:meth:`_refuse_at_door`)
        self._lingering: set[asyncio.StreamWriter] = set()

    @property
    def refused(self) -> list[tuple[str, str]]:
        """(code, reason) of the last refused connections (at most 100; reasons name the peer)."""
        return list(self.refusals.recent)

    # -- lifecycle ---------------------------------------------------------------------------------

    def load_calibration(self, cal: object) -> None:
        """Start with a calibration file's poses (``kinefuse serve --calibration``)."""
        from kinefuse.capture.calibration.calib_file import CalibrationFile

        assert isinstance(cal, CalibrationFile)
        self.calibration.load(cal)
        if self._tg is None:
            self.fusion.set_poses(cal.sensor2world)
        else:  # running: the fusion may be fusing in a worker thread; the loop applies them
            self.loop.set_poses(cal.sensor2world)

    def request_stop(self, reason: str = "stop requested") -> None:
        """Stop cleanly: goodbye to every peer, finish the recording."""
        if not self._stop.is_set():
            self._stop_reason = reason
            log.info("stopping: %s", reason)
            self._stop.set()

    async def run(self, ready: Callable[[str, int], None] | None = None) -> None:
        """Serve until :meth:`request_stop`; ``ready(host, port)`` is called once listening."""
        o = self.options
        if not is_loopback(o.host) and not o.token:
            log.warning(
                "listening on %s without a token: anyone who can reach this port can send data; "
                "pass --token-file (or KINEFUSE_TOKEN) and open the port only to the sensor PCs",
                o.host,
            )
        if o.record is not None:
            self.recorder = Recorder(o.record, self._meta(), clock=self.clock)
            await self.recorder.open()
            if self.calibration.calibration is not None:
                from kinefuse.capture.calibration.calib_file import dumps_calibration

                cal = self.calibration.calibration
                self.recorder.add_calibration(cal.method, dumps_calibration(cal))
        clean = False
        try:
            async with contextlib.AsyncExitStack() as stack, asyncio.TaskGroup() as tg:
                self._tg = tg
                srv = await asyncio.start_server(
                    self._accept, o.host, o.port, limit=o.max_frame_bytes + 8
                )
                self.port = int(srv.sockets[0].getsockname()[1])
                for name, factory in self._service_factories.items():
                    self.services[name] = await stack.enter_async_context(factory(self.publisher))
                if ready is not None:
                    ready(o.host, self.port)
                if self.recorder is not None:
                    tg.create_task(self.recorder.run(self.publisher.subscribe(None)))
                fusing = tg.create_task(self.loop.run(self._stop))
                tg.create_task(self._housekeeping())
                await self._stop.wait()
                srv.close()
                for w in list(self._lingering):
                    w.close()
                # the loop sees the stop before its next frame; a frame being fused (in a worker
                # thread) is published first, so the publisher is closed after the last one
                await fusing
                for c in list(self._conns):
                    with contextlib.suppress(Exception):
                        c.send(Goodbye(reason=f"server stopping: {self._stop_reason}"[:1024]))
                    c.close()
                self.publisher.close()
                if self.recorder is not None:
                    self.recorder.add_meta("live_run", self.run_stats())
                    self.recorder.stop()
            clean = True
        finally:
            self._tg = None
            if self.recorder is not None:
                await self.recorder.close(clean=clean)

    def run_stats(self) -> dict[str, object]:
        """Figures of the run so far (also stored as the meta ``live_run`` at a clean stop)."""
        return run_stats(self)

    def _meta(self) -> dict[str, object]:
        o = self.options
        return {
            "recorded_by": "kinefuse serve",
            "server_t0_monotonic": self.t0_monotonic,
            "live_method": o.method,
            "latency_budget_s": o.latency_budget_s,
            "fusion_delay_s": self.loop.delay_s,
            "calibration_method": o.calibration.method,
            "wand_protocol": (
                {"axis_length_m": o.calibration.axis_length_m}
                if o.calibration.axis_length_m is not None
                else {}
            ),
            "clock_probes": {
                "burst": o.probe_burst,
                "spacing_s": o.probe_spacing_s,
                "interval_s": o.probe_interval_s,
            },
        }

    def _event(self, kind: str, sensor_id: str | None, **detail: object) -> None:
        if self.recorder is not None:
            self.recorder.add_event(self.clock(), kind, sensor_id, dict(detail))

    # -- connections -------------------------------------------------------------------------------

    def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._tg is None or self._stop.is_set():
            writer.close()
            return
        o = self.options
        peer = writer.get_extra_info("peername")
        addr = str(peer[0]) if isinstance(peer, tuple) else str(peer)
        known, refusal = self.slots.admit(addr, self.clock())
        if refusal is not None:
            code, reason = refusal
            name = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
            self._refused(name, code, reason)
            self._refuse_at_door(writer, code, reason)
            return
        sock = writer.get_extra_info("socket")
        if sock is not None:  # a bounded kernel send buffer: a peer that never reads shows soon
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 256 << 10)
        conn = Connection(
            reader,
            writer,
            self.clock,
            max_frame_bytes=o.handshake_frame_bytes,
            token=o.token,
            stall_s=o.timeout_s,
            msg_rate=o.msg_rate,
            msg_burst=o.msg_burst,
        )
        self._pending[conn] = (addr, known)
        self._conns.add(conn)
        self._tg.create_task(self._connection(conn))

    def _refuse_at_door(self, writer: asyncio.StreamWriter, code: str, reason: str) -> None:
        """Refuse a connection before any task or buffer is spent on it: the Error at once,
        nothing more read, and the close ``refuse_linger_s`` later (at once when
        ``max_lingering`` refused connections are waiting already). A well-behaved client
        closes on the Error itself; an attacker that reopens as soon as the server closes
        gets to do it twice a second per connection, not hundreds of times."""
        with contextlib.suppress(Exception):
            writer.write(encode(Error(code=code, reason=reason[:1024])))
            tr = writer.transport
            if isinstance(tr, asyncio.Transport):
                tr.pause_reading()
            if len(self._lingering) >= self.options.max_lingering:
                writer.close()
                return
            self._lingering.add(writer)

            def close() -> None:
                self._lingering.discard(writer)
                writer.close()

            asyncio.get_running_loop().call_later(self.options.refuse_linger_s, close)

    def _refused(self, name: str, code: str, reason: str, sensor_id: str | None = None) -> None:
        """Count a refusal of the peer ``name``; log and record it unless too many came lately
        (then summarized)."""
        text = printable(f"closing {name}: {reason} ({code})", 600)
        if self.refusals.add(self.clock(), code, text):
            log.warning("%s", text)
            self._event("refused", sensor_id, code=code, reason=reason[:300], peer=name)

    def _release(self, conn: Connection) -> None:
        """``conn`` leaves its handshake (welcomed or closed): its slot is free again."""
        slot = self._pending.pop(conn, None)
        if slot is not None:
            self.slots.release(*slot)

    def _welcomed(self, conn: Connection) -> None:
        """The handshake is done: full-size frames from now on, the address known."""
        slot = self._pending.get(conn)
        if slot is not None:
            self.slots.welcomed(slot[0])
        self._release(conn)
        conn.decoder.max_frame_bytes = self.options.max_frame_bytes

    async def _connection(self, conn: Connection) -> None:
        sensor: SensorState | None = None
        try:
            hello = await self._handshake(conn)
            if hello.role == "control":
                n = self.options.max_controls
                if len(self._controls) >= n:
                    raise TooSlow(f"the server takes at most {n} control peers")
                self._welcomed(conn)
                await self._serve_control(conn)
            else:
                sensor = self._register(conn, hello)
                await self._serve_sensor(conn, sensor)
            conn.close()
        except ConnectionClosed as e:
            log.info("%s: %s", conn.name, e)
        except WireError as e:
            if isinstance(e, AuthError) and conn in self._pending:
                self.slots.auth_failed(self._pending[conn][0], self.clock())
            self._refused(conn.name, e.code, str(e), sensor.sensor_id if sensor else None)
            conn.refuse(e.code, str(e))
        except Exception as e:  # a bug serving this peer: close it, keep serving the others
            log.exception("internal error serving %s; closing it", conn.name)
            self.refusals.add(self.clock(), "internal", f"{conn.name}: {e!r}")
            conn.refuse("internal", f"server error: {type(e).__name__}")
        finally:
            conn.close()
            self._release(conn)
            self._conns.discard(conn)
            self._controls.discard(conn)
            if sensor is not None and self._sensor_conns.get(sensor.sensor_id) is conn:
                del self._sensor_conns[sensor.sensor_id]
                sensor.disconnect()
                self._sensor_event(sensor, logging.INFO, "disconnected", " is offline")
                self._status_dirty = True
            await conn.wait_closed()

    async def _handshake(self, conn: Connection) -> Hello:
        """Hello (and the challenge when there is a token), all within ``handshake_timeout_s``
        of the accept: a peer cannot stretch it by answering slowly. The sequence is
        ``conn.handshake``'s (:mod:`kinefuse.live.protocol.handshake`); this only moves messages."""
        o = self.options
        hs = conn.handshake
        deadline = self.clock() + o.handshake_timeout_s
        msg, _ = await conn.recv(o.handshake_timeout_s, deadline=deadline)
        challenge = hs.receive(msg)
        assert hs.hello is not None
        hello = hs.hello
        conn.role = hello.role
        who = f"{hello.role} {hello.sensor_id}".strip()
        conn.name = f"{who} from {conn.peer}" + (", not authenticated" if o.token else "")
        if challenge is not None:
            conn.send(challenge)
            reply, _ = await conn.recv(o.handshake_timeout_s, deadline=deadline)
            hs.receive(reply)
            conn.name = f"{who} from {conn.peer}"
        return hello

    def _register(self, conn: Connection, hello: Hello) -> SensorState:
        sid = hello.sensor_id
        if sid in self._sensor_conns:
            raise DuplicateSensor(
                f"sensor {sid} is already connected (from {self._sensor_conns[sid].peer}); give "
                "each client its own sensor id"
            )
        if sid not in self.clients and len(self.clients) >= self.options.max_sensors:
            raise TooSlow(f"the server takes at most {self.options.max_sensors} sensors")
        assert hello.intrinsics is not None  # Hello.check() requires it of a sensor
        client = self.clients.get(sid)
        if client is None:
            client = SensorState(sid, hello.serial, hello.intrinsics)
            self.clients[sid] = client
            if self.recorder is not None:
                self.recorder.add_sensor(sid, hello.serial, hello.intrinsics)
        client.connect()
        self._sensor_conns[sid] = conn
        if self.recorder is not None:  # a new stream: its seq may start again below the last
            self.recorder.new_stream(sid)
        self._welcomed(conn)
        cal = self.calibration
        if cal.collecting:
            cal.add_target(sid)
        conn.send(
            conn.handshake.send(
                Welcome(
                    session=self.options.session,
                    t_server_s=self.clock(),
                    heartbeat_s=self.options.heartbeat_s,
                    timeout_s=self.options.timeout_s,
                    calibrating=cal.collecting,
                    calibration_id=cal.calibration_id,
                )
            )
        )
        self._sensor_event(
            client,
            logging.INFO,
            "connected",
            f" connected from {conn.peer} (connection #{client.connections})"
            + (", calibrated" if sid in cal.poses else ""),
            peer=conn.peer,
            connection=client.connections,
            has_pose=sid in cal.poses,
        )
        self._status_dirty = True
        if (
            self.options.auto_calibrate
            and not cal.collecting
            and not cal.solving
            and sid not in cal.poses
        ):
            self._start_calibration(method="", sensor_ids=())
        return client

    # -- a sensor ----------------------------------------------------------------------------------

    async def _serve_sensor(self, conn: Connection, client: SensorState) -> None:
        outstanding: dict[int, float] = {}
        prober = asyncio.ensure_future(self._probe_loop(conn, outstanding))
        try:
            await self._sensor_reader(conn, client, outstanding)
        finally:
            prober.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await prober

    async def _probe_loop(self, conn: Connection, outstanding: dict[int, float]) -> None:
        o = self.options
        while not conn.closed:
            for i in range(o.probe_burst):
                self._probe_id += 1
                t1 = self.clock()
                outstanding[self._probe_id] = t1
                conn.send(ClockProbe(probe_id=self._probe_id, t1=t1))
                if i < o.probe_burst - 1:
                    await asyncio.sleep(o.probe_spacing_s)
            while len(outstanding) > 4 * o.probe_burst:  # lost replies
                outstanding.pop(next(iter(outstanding)))
            await asyncio.sleep(
                max(o.probe_interval_s - (o.probe_burst - 1) * o.probe_spacing_s, 0.01)
            )

    async def _sensor_reader(
        self, conn: Connection, client: SensorState, outstanding: dict[int, float]
    ) -> None:
        sid = client.sensor_id
        o = self.options
        # time stamps outside a plausible window are refused at the door (guard.StampGate)
        gate = StampGate(window_s=o.stamp_window_s, max_offset_s=o.max_clock_offset_s)
        while True:
            msg, t_arr = await conn.recv(self.options.timeout_s)
            conn.check_sender(msg)
            if isinstance(msg, ClockReply):
                t1 = outstanding.pop(msg.probe_id, None)
                if t1 is None or t1 != msg.t1:
                    raise OutOfOrder(
                        f"clock_reply to probe {msg.probe_id}, which was not sent "
                        "(or with another t1)"
                    )
                gate.reply(msg.t1, msg.t2, msg.t3, t_arr)
                self._clock_reply(client, msg, t_arr)
            elif isinstance(msg, BodyFrameMessage):
                if client.last_seq is not None and msg.seq <= client.last_seq:
                    # a stale frame (the sensor's counter went back under a running client):
                    # counted in its status, and the connection closed; a client that
                    # reconnects starts a new stream, fused from its first frame
                    client.stale += 1
                    self._status_dirty = True
                    raise OutOfOrder(
                        f"body_frame seq {msg.seq} after {client.last_seq}: seq must increase "
                        "on a connection (a restarted sensor must connect again)"
                    )
                gate.host(msg.TYPE, "t_host_s", msg.t_host_s, t_arr)
                gate.device(msg.TYPE, msg.t_device_s, msg.t_host_s)
                self._body(client, msg, t_arr)
            elif isinstance(msg, WandSighting):
                gate.host(msg.TYPE, "t_host_s", msg.t_host_s, t_arr)
                gate.device(msg.TYPE, msg.t_device_s, msg.t_host_s)
                self._sighting(client, msg, t_arr)
            elif isinstance(msg, FloorPlaneMessage):
                fl = FloorPlane(msg.normal, msg.offset_m, msg.n_inliers, msg.residual_m)
                self.calibration.add_floor(sid, fl)
                client.floor_error = None
                if self.recorder is not None:
                    self.recorder.add_floor(sid, t_arr, fl)
            elif isinstance(msg, Goodbye):
                self._sensor_event(
                    client, logging.INFO, "goodbye", f" said goodbye: {printable(msg.reason)}"
                )
                return
            elif isinstance(msg, Heartbeat):
                self._floor_error(client, msg.floor_error)
                if msg.tracker != client.tracker:
                    client.tracker = msg.tracker
                    self._status_dirty = True
            else:
                raise OutOfOrder(f"a sensor may not send {msg.TYPE} after the handshake")

    def _floor_error(self, client: SensorState, error: str | None) -> None:
        """What a sensor's heartbeat says of its floor fit (None: it did not fail)."""
        if error == client.floor_error:
            return
        client.floor_error = error
        if error is not None:
            self._sensor_event(
                client, logging.WARNING, "floor_error", f": {printable(error)}", error=error
            )
        self._status_dirty = True

    def _sensor_event(
        self, client: SensorState, level: int, kind: str, text: str, **detail: object
    ) -> None:
        """Log ``sensor ID`` + ``text`` and record the event ``kind``, unless this sensor had too
        many events lately (then counted and summarized by :meth:`_housekeeping`): a peer that
        changes its floor error 600 times a second, or reconnects as fast as it can, costs the
        log and the recording a bounded amount. ``text`` is escaped already (:func:`printable`)."""
        if client.events.allow(self.clock(), kind):
            log.log(level, "sensor %s%s", client.sensor_id, text)
            self._event(kind, client.sensor_id, **detail)

    def _clock_reply(self, client: SensorState, msg: ClockReply, t4: float) -> None:
        try:
            client.clock.add_probe(msg.t1, msg.t2, msg.t3, t4)
        except SyncError as e:
            raise OutOfOrder(f"impossible clock reply: {e}") from None
        client.rtt_s = (t4 - msg.t1) - (msg.t3 - msg.t2)
        rec = self.recorder
        if rec is not None:
            rec.add_probe(client.sensor_id, msg.t1, msg.t2, msg.t3, t4)
            with contextlib.suppress(SyncError):
                est = client.clock.estimate(t4)
                rec.add_clock(
                    client.sensor_id, t4, est.offset_s, est.drift_ppm, est.offset_se_s, est.epoch
                )

    def _body(self, client: SensorState, msg: BodyFrameMessage, t_arr: float) -> None:
        client.last_seq = msg.seq  # increasing on this connection (the reader checked)
        late = client.lateness(msg.t_device_s, msg.t_host_s, t_arr)
        backlog = late > self.options.max_backlog_s
        if backlog:
            # a stalled sensor's backlog (or a frame held in a queue): fused it would be late,
            # and its stamps would bend the device clock fit; kept out of both and counted, but
            # recorded like any frame (it is data: the offline fusion's robust clock fit and
            # interpolation can use it)
            client.drop_late(t_arr)
        else:
            client.device.add(msg.t_device_s, msg.t_host_s)
        joints, states = sanitize_joints(msg.joints_m, msg.states)
        t_cap = client.capture_to_server(msg.t_device_s)
        t_host = client.host_to_server(msg.t_host_s)
        bodies = _bodies(client.sensor_id, msg, joints, states)
        for b in bodies:  # (the calibration from the person keeps the subject's only)
            self.person.add_body(client.sensor_id, msg.t_device_s, t_host, b.joints_m, b.body_id)
        if self.recorder is not None:
            self.recorder.add_observation(
                client.sensor_id,
                msg.seq,
                msg.t_device_s,
                msg.t_host_s,
                t_arr,
                t_cap,
                joints,
                states,
                msg.occluded,
                msg.n_crossings,
                bodies=bodies,
            )
        if backlog:
            return
        client.keep_bodies(bodies, t_cap)
        obs = Observation(
            msg.seq, t_cap, t_host, joints, states, msg.occluded, msg.n_crossings, bodies
        )
        client.enqueue(obs, t_arr)
        self.loop.notify()
        if math.isfinite(t_host):
            client.latency_s = t_arr - t_host

    def _sighting(self, client: SensorState, msg: WandSighting, t_arr: float) -> None:
        # sightings carry host arrival times too: they feed the device -> host fit
        client.device.add(msg.t_device_s, msg.t_host_s)
        t_srv = client.capture_to_server(msg.t_device_s)
        kept = self.calibration.add_sighting(client.sensor_id, t_srv, msg.centre_m, msg.score)
        if self.recorder is not None:
            c = msg.centre_m
            self.recorder.add_sighting(
                SightingRow(
                    client.sensor_id,
                    msg.seq,
                    msg.t_device_s,
                    msg.t_host_s,
                    t_srv,
                    (c[0], c[1], c[2]),
                    msg.score,
                    msg.n_points,
                    msg.residual_m,
                )
            )
        if kept and self.calibration.n_sightings().get(client.sensor_id) == 1:
            self._status_dirty = True

    # -- a control peer ----------------------------------------------------------------------------

    async def _serve_control(self, conn: Connection) -> None:
        await serve_control(self, conn)

    # -- calibration -------------------------------------------------------------------------------

    def _start_calibration(
        self,
        *,
        method: str,
        sensor_ids: tuple[str, ...] | list[str],
        seconds: float | None = None,
    ) -> None:
        cal = self.calibration
        if cal.solving:
            raise CalibrationError("a calibration is being solved; start again when it is done")
        connected = [s for s, c in self.clients.items() if c.connected]
        cid = cal.start(
            self.clock(), connected, sensor_ids=tuple(sensor_ids), method=method, seconds=seconds
        )
        log.info(
            "calibration %d started (%s) for %s",
            cid,
            cal.method,
            ", ".join(cal.targets) or "the sensors that join",
        )
        self._event(
            "calibration_start",
            None,
            calibration_id=cid,
            method=cal.method,
            targets=list(cal.targets),
        )
        for c in self._sensor_conns.values():
            c.send(CalibrationStart(calibration_id=cid, method=cal.method))
        for s in self.clients.values():
            s.floor_error = None  # each sensor fits its floor anew
        self._status_dirty = True

    def _finish_calibration(self, *, abort: bool, why: str) -> None:
        cal = self.calibration
        cid = cal.calibration_id
        for c in self._sensor_conns.values():
            c.send(CalibrationStop(calibration_id=cid, abort=abort))
        log.info("calibration %d ends: %s; sightings %s", cid, why, cal.n_sightings())
        self._event(
            "calibration_stop",
            None,
            calibration_id=cid,
            why=why,
            abort=abort,
            sightings=cal.n_sightings(),
        )
        if abort:
            cal.abort()
            self._status_dirty = True
            return
        # the solve runs in a worker thread on a snapshot taken here, on the loop; its outcome
        # is applied on the loop (floors that arrive meanwhile are kept for the next one)
        job = cal.begin_solve(
            {s: c.intrinsics for s, c in self.clients.items()},
            {s: c.serial for s, c in self.clients.items()},
        )
        assert self._tg is not None
        self._tg.create_task(self._solve(job))

    async def _solve(self, job: SolveInput) -> None:
        out = await asyncio.to_thread(solve_calibration, job)
        self.calibration.apply(out)
        self.announce_calibration(out)

    def announce_calibration(self, out: CalibrationOutcome) -> None:
        """Log, record and send a calibration's outcome; its poses to the fusion if it is used."""
        self.last_outcome = out
        log.info("calibration %d: %s", out.calibration_id, out.message)
        for r in out.grade.reasons:
            log.info("  %s", r)
        if out.ok and out.calibration is not None:
            self.loop.set_poses(out.calibration.sensor2world)
            if self.recorder is not None and out.text is not None:
                self.recorder.add_calibration(out.method, out.text)
                self.recorder.add_meta("live_calibration", outcome_meta(out))
        self._event("calibration_result", None, **outcome_meta(out))
        res = result_message(out)
        for c in list(self._controls):
            c.send(res)
        self._status_dirty = True

    # -- status ------------------------------------------------------------------------------------

    async def _housekeeping(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._stop.wait(), 0.1)
            now = self.clock()
            self.slots.prune(now)
            suppressed = self.refusals.summary(now)
            if suppressed:
                log.warning(
                    "%d more connections refused in the last %g s (%s)",
                    sum(suppressed.values()),
                    self.refusals.window_s,
                    ", ".join(f"{c}: {n}" for c, n in sorted(suppressed.items())),
                )
                self._event("refused_summary", None, **suppressed)
            for client in self.clients.values():
                more = client.events.summary(now)
                if more:
                    log.warning(
                        "sensor %s: %d more events in the last %g s, not logged one by one (%s)",
                        client.sensor_id,
                        sum(more.values()),
                        client.events.window_s,
                        ", ".join(f"{k}: {n}" for k, n in sorted(more.items())),
                    )
                    self._event("events_summary", client.sensor_id, **more)
            why = self.calibration.should_stop(now)
            if why is not None:
                self._finish_calibration(abort=False, why=why)
            person_step(self, now)
            if self._status_dirty or now - self._last_status >= self.options.status_interval_s:
                self._status_dirty = False
                self._last_status = now
                if not self.publisher._closed:
                    self.publisher.publish(self.status())

    def status(self) -> Status:
        """The status snapshot (:func:`kinefuse.live.server.status_report.server_status`)."""
        return server_status(self)


def _bodies(
    sensor_id: str, msg: BodyFrameMessage, joints: NDArray[np.float64], states: NDArray[np.int8]
) -> tuple[BodyFrame, ...]:
    """Every body of a body frame (the first with its sanitized ``joints``/``states``), each
    a :class:`BodyFrame` with the sensor's tracking id; the others sanitized the same way."""
    first = BodyFrame(
        sensor_id, msg.seq, msg.t_device_s, msg.t_host_s, joints, states,
        msg.occluded, msg.n_crossings, msg.body_id,
    )  # fmt: skip
    out = [first]
    for b in msg.others:
        j, st = sanitize_joints(b.joints_m, b.states)
        out.append(
            BodyFrame(
                sensor_id,
                msg.seq,
                msg.t_device_s,
                msg.t_host_s,
                j,
                st,
                b.occluded,
                b.n_crossings,
                b.body_id,
            )
        )
    return tuple(out)
