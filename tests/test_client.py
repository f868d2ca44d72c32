"""The sensor client against a small test server written with the protocol's codec (loopback,
port 0, every test bounded in time)."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from kinefuse.capture.occlusion.segments import detect_occlusion
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrame as SourceBody
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.live.client.client import ClientOptions, ClientRefused, SensorClient, backoff_delay
from kinefuse.live.client.clocks import HostClock, real_host_clock
from kinefuse.live.client.playback import SourceTimeline
from kinefuse.live.protocol import (
    PROTOCOL_VERSION,
    AuthReply,
    BodyFrameMessage,
    Challenge,
    ClockProbe,
    ClockReply,
    Decoder,
    Error,
    Goodbye,
    Heartbeat,
    Hello,
    Message,
    Welcome,
    auth,
    encode,
)

LIMIT_S = 30.0  # no test of this module may take longer (a hang fails instead of blocking)


# ---- a small test server -------------------------------------------------------------------


@dataclass
class Peer:
    """One connection the test server accepted."""

    hello: Hello | None = None
    messages: list[Message] = field(default_factory=list)
    replies: list[tuple[ClockReply, float]] = field(default_factory=list)  # with t4
    writer: asyncio.StreamWriter | None = None


class TestServer:
    """Speaks the server's side of the handshake, records everything, sends what it is told."""

    __test__ = False

    def __init__(
        self,
        *,
        token: str | None = None,
        refuse: str | None = None,
        welcome: Welcome | None = None,
        on_welcome: Any = None,
    ) -> None:
        self.token = token
        self.refuse = refuse
        self.welcome = welcome or Welcome(session="test", heartbeat_s=0.2, timeout_s=3.0)
        self.on_welcome = on_welcome
        self.peers: list[Peer] = []
        self.t0 = time.monotonic()
        self.port = 0
        self._server: asyncio.Server | None = None
        self.changed = asyncio.Event()
        self._beats: list[asyncio.Future[None]] = []

    def clock(self) -> float:
        return time.monotonic() - self.t0

    async def start(self, port: int = 0) -> None:
        self._server = await asyncio.start_server(self._handle, "127.0.0.1", port)
        self.port = self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        """Close the listener and every connection abruptly (no Goodbye): a crashed server."""
        assert self._server is not None
        self._server.close()
        for p in self.peers:
            if p.writer is not None:
                p.writer.transport.abort()
        for b in self._beats:
            b.cancel()
        await self._server.wait_closed()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = Peer(writer=writer)
        self.peers.append(peer)
        dec = Decoder()
        stage = "hello"
        nonce = b""
        try:
            while data := await reader.read(65536):
                t4 = self.clock()
                for m in dec.feed(data):
                    peer.messages.append(m)
                    if stage == "hello" and isinstance(m, Hello):
                        peer.hello = m
                        if self.token is not None:
                            nonce = auth.new_nonce()
                            proof = None
                            if m.client_nonce is not None:  # the server's proof (1.1)
                                proof = auth.compute_server_mac(
                                    self.token, m.client_nonce, nonce, role="sensor",
                                    sensor_id=m.sensor_id,
                                )  # fmt: skip
                            writer.write(encode(Challenge(nonce, server_mac=proof)))
                            stage = "auth"
                        else:
                            stage = self._admit(writer)
                    elif stage == "auth" and isinstance(m, AuthReply):
                        assert peer.hello is not None and self.token is not None
                        try:
                            auth.verify_mac(
                                self.token, nonce, m.mac, role="sensor",
                                sensor_id=peer.hello.sensor_id,
                            )  # fmt: skip
                        except auth.AuthError as e:
                            writer.write(encode(Error("auth", str(e))))
                            writer.close()
                            return
                        stage = self._admit(writer)
                    elif isinstance(m, ClockReply):
                        peer.replies.append((m, t4))
                self.changed.set()
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            writer.close()

    def _admit(self, writer: asyncio.StreamWriter) -> str:
        if self.refuse is not None:
            writer.write(encode(Error(self.refuse, "refused by the test server")))
            writer.close()
            return "closed"
        writer.write(encode(self.welcome))
        self._beats.append(asyncio.ensure_future(self._heartbeats(writer)))
        if self.on_welcome is not None:
            self.on_welcome(self, writer)
        return "ready"

    async def _heartbeats(self, writer: asyncio.StreamWriter) -> None:
        # the protocol's rule: a side that sent nothing for heartbeat_s sends a Heartbeat
        while not writer.is_closing():
            writer.write(encode(Heartbeat(self.clock())))
            await asyncio.sleep(self.welcome.heartbeat_s)

    def bodies(self) -> list[BodyFrameMessage]:
        return [m for p in self.peers for m in p.messages if isinstance(m, BodyFrameMessage)]

    async def wait_for(self, cond: Any, timeout: float = 10.0) -> None:
        async with asyncio.timeout(timeout):
            while not cond():
                self.changed.clear()
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(0.05):
                        await self.changed.wait()


# ---- a source defined in the test (the driver interface) -------------------------------------


class WalkSource:
    """A synthetic sensor: ``n`` body frames at ``rate_hz`` of a skeleton moving in x.

    ``live=True`` makes it behave as a driver: its iterator waits for each frame's time and
    stamps the host receive time with ``time.monotonic()``.
    """

    def __init__(self, n: int = 60, rate_hz: float = 30.0, *, live: bool = False, sid: str = "w0"):
        self.n, self.rate, self.live, self.sid = int(n), float(rate_hz), live, sid
        rng = np.random.default_rng(3)
        self.base = np.column_stack(
            [rng.uniform(-0.3, 0.3, N_JOINTS), rng.uniform(-0.8, 0.8, N_JOINTS), np.full(25, 2.5)]
        )

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return (self.sid,)

    def intrinsics(self, sensor_id: str) -> Intrinsics:
        return Intrinsics(fx=360.0, fy=361.0)

    def joints(self, k: int) -> np.ndarray:
        j = self.base.copy()
        j[:, 0] += 0.01 * k
        if k % 7 == 3:
            j[5] = np.nan  # a joint not tracked now and then
        return j

    def __iter__(self) -> Iterator[SourceBody]:
        start = time.monotonic()
        for k in range(self.n):
            t_host = math.nan
            if self.live:
                delay = start + k / self.rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                t_host = time.monotonic()
            else:
                t_host = 500.0 + k / self.rate
            j = self.joints(k)
            states = np.where(np.isfinite(j).all(-1), 2, 0).astype(np.int8)
            yield SourceBody(self.sid, k, 1000.0 + k / self.rate, t_host, j, states)


def _client(server: TestServer, source: Any = None, **opts: Any) -> SensorClient:
    src = source or WalkSource()
    live = getattr(src, "live", False)
    defaults = dict(backoff_initial_s=0.05, backoff_max_s=0.2, connect_timeout_s=2.0)
    defaults.update(opts)
    return SensorClient(
        SourceTimeline(src, live=live),
        ClientOptions(server=("127.0.0.1", server.port), **defaults),
        host_clock=real_host_clock() if live else (lambda m0: HostClock(77.0, 20e-6, m0)),
    )


def run(coro: Any) -> Any:
    async def bounded() -> Any:
        async with asyncio.timeout(LIMIT_S):
            return await coro

    return asyncio.run(bounded())


# ---- tests -------------------------------------------------------------------------------------


def test_handshake_and_body_frames_arrive_in_order_with_their_content():
    src = WalkSource(n=45)

    async def go() -> tuple[TestServer, SensorClient, int]:
        server = TestServer()
        await server.start()
        client = _client(server, src, serial="SN-7", speed=3.0)
        code = await client.run()  # the source ends: Goodbye and exit 0
        await server.wait_for(lambda: any(isinstance(m, Goodbye) for m in server.peers[0].messages))
        return server, client, code

    server, client, code = run(go())
    assert code == 0
    (peer,) = server.peers
    hello = peer.messages[0]
    assert isinstance(hello, Hello) and hello.role == "sensor" and hello.sensor_id == "w0"
    assert hello.serial == "SN-7" and hello.intrinsics == Intrinsics(fx=360.0, fy=361.0)
    assert hello.protocol_version == PROTOCOL_VERSION
    assert isinstance(peer.messages[-1], Goodbye) and peer.messages[-1].reason == "source ended"
    bodies = server.bodies()
    assert [b.seq for b in bodies] == list(range(45))
    occ = detect_occlusion(np.stack([src.joints(k) for k in range(45)]), src.intrinsics("w0"))
    host = client.host_clock
    assert host is not None
    for b in bodies:
        j = src.joints(b.seq)
        np.testing.assert_allclose(b.joints_m, j, atol=1e-6, equal_nan=True)  # float32: 1 um
        assert (b.states == np.where(np.isfinite(j).all(-1), 2, 0)).all()
        assert b.t_device_s == 1000.0 + b.seq / 30.0
        assert (b.occluded == occ.occluded[b.seq]).all()
        assert b.n_crossings == occ.n_intersections[b.seq]
        assert b.dropped == 0
    # played in real time at speed 3: host stamps 1/90 s apart on the emulated clock
    t_host = np.array([b.t_host_s for b in bodies])
    assert np.all(np.diff(t_host) > 0)
    assert abs((t_host[-1] - t_host[0]) - 44 / 90) < 0.05  # s, scheduling slack
    # and that clock is the one the client was given: h0 + (1 + drift)(t - m0)
    assert client.m0 is not None
    assert host.h0 == 77.0 and abs(t_host[0] - host.affine.forward(client.m0 + 500.0 / 3.0)) < 0.05


def test_probes_are_answered_at_once_with_consistent_times():
    def probe(server: TestServer, writer: asyncio.StreamWriter) -> None:
        async def burst() -> None:
            for i in range(20):
                writer.write(encode(ClockProbe(i, server.clock())))
                await asyncio.sleep(0.02)

        server.task = asyncio.ensure_future(burst())  # type: ignore[attr-defined]

    async def go() -> tuple[TestServer, SensorClient]:
        server = TestServer(on_welcome=probe)
        await server.start()
        client = _client(server, WalkSource(n=60), speed=1.0)
        task = asyncio.ensure_future(client.run())
        await server.wait_for(lambda: server.peers and len(server.peers[0].replies) == 20)
        client.stop()
        assert await task == 0
        return server, client

    server, client = run(go())
    host = client.host_clock
    assert host is not None
    offsets, delays = [], []
    for reply, t4 in server.peers[0].replies:
        assert reply.t3 >= reply.t2
        delays.append((t4 - reply.t1) - (reply.t3 - reply.t2))
        offsets.append(0.5 * ((reply.t2 - reply.t1) + (reply.t3 - t4)))
    assert [r.probe_id for r, _ in server.peers[0].replies] == list(range(20))
    # the true offset host - server at the mid-probe instant (the emulated clock is known here)
    expected = [
        host.affine.forward(server.t0 + 0.5 * (r.t1 + t4)) - 0.5 * (r.t1 + t4)
        for r, t4 in server.peers[0].replies
    ]
    err = np.abs(np.array(offsets) - np.array(expected))
    best = int(np.argmin(delays))
    assert err[best] < 0.5e-3  # s: the least-delay probe of loopback within 0.5 ms
    assert np.median(err) < 2e-3  # s
    assert np.min(delays) < 2e-3  # s: answered at once, not after queued data


def test_reconnects_after_the_server_restarts_and_keeps_id_and_stream():
    async def go() -> tuple[TestServer, SensorClient, list[int]]:
        server = TestServer()
        await server.start()
        client = _client(server, WalkSource(n=150), body_queue=5, speed=1.0)
        task = asyncio.ensure_future(client.run())
        await server.wait_for(lambda: len(server.bodies()) >= 20)
        port = server.port
        await server.stop()  # crash: no goodbye
        first = [b.seq for b in server.bodies()]
        await asyncio.sleep(1.0)  # 30 frames come due while the server is away
        await server.start(port)
        await server.wait_for(lambda: len(server.peers) == 2 and len(server.bodies()) > 60)
        client.stop()
        assert await task == 0
        return server, client, first

    server, client, first = run(go())
    assert [p.hello.sensor_id for p in server.peers if p.hello] == ["w0", "w0"]
    second = [m for m in server.peers[1].messages if isinstance(m, BodyFrameMessage)]
    seqs = first + [b.seq for b in second]
    assert seqs == sorted(set(seqs))  # in order, nothing twice
    assert second[0].seq > first[-1] + 5  # the stream went on while disconnected...
    assert second[-1].dropped >= 15  # ...and the frames beyond the bounded queue were counted
    assert client.stats.connections == 2 and client.stats.body_dropped == second[-1].dropped


def test_right_token_is_accepted_and_the_token_never_crosses_the_wire():
    async def go() -> TestServer:
        server = TestServer(token="s3cret-token")
        await server.start()
        assert await _client(server, WalkSource(n=10), token="s3cret-token", speed=5.0).run() == 0
        return server

    server = run(go())
    assert len(server.bodies()) == 10
    assert any(isinstance(m, AuthReply) for m in server.peers[0].messages)


@pytest.mark.parametrize(
    ("token", "match"),
    [
        # with another token the server's own proof fails first: the client refuses the server
        ("wrong", "could not prove that it knows the token"),
        (None, "requires a token: start the sensor with --token"),
    ],
)
def test_wrong_or_missing_token_is_a_clear_refusal(token, match):
    async def go() -> None:
        server = TestServer(token="right")
        await server.start()
        await _client(server, token=token).run()

    with pytest.raises(ClientRefused, match=match) as e:
        run(go())
    assert e.value.code == "auth"


def test_another_major_version_is_refused():
    async def go() -> None:
        server = TestServer(welcome=Welcome(protocol_version=(2, 0)))
        await server.start()
        await _client(server).run()

    with pytest.raises(ClientRefused, match="another version") as e:
        run(go())
    assert e.value.code == "version"


def test_a_duplicate_id_is_retried_then_refused():
    async def go() -> TestServer:
        server = TestServer(refuse="duplicate_id")
        await server.start()
        with pytest.raises(ClientRefused, match="already connected"):
            await _client(server, duplicate_wait_s=0.5).run()
        return server

    server = run(go())
    assert len(server.peers) >= 3  # it retried with backoff before giving up


def test_heartbeats_when_idle():
    async def go() -> TestServer:
        server = TestServer()
        await server.start()
        client = _client(server, WalkSource(n=2, rate_hz=1.0))  # 1 s without data
        assert await client.run() == 0
        return server

    server = run(go())
    beats = [m for m in server.peers[0].messages if isinstance(m, Heartbeat)]
    assert len(beats) >= 2  # heartbeat_s = 0.2 s in the test server's Welcome


def test_a_live_driver_source_is_sent_as_it_comes_with_its_own_host_stamps():
    src = WalkSource(n=20, rate_hz=40.0, live=True, sid="cam0")

    async def go() -> TestServer:
        server = TestServer()
        await server.start()
        assert await _client(server, src).run() == 0
        return server

    t_before = time.monotonic()
    server = run(go())
    bodies = server.bodies()
    assert [b.seq for b in bodies] == list(range(20))
    t_host = np.array([b.t_host_s for b in bodies])
    assert t_host[0] > t_before and np.all(np.diff(t_host) > 0.015)  # the driver's own stamps


def test_backoff_doubles_is_capped_and_jittered():
    import random

    rng = random.Random(5)
    d = np.array([[backoff_delay(a, 0.2, 5.0, rng) for a in range(12)] for _ in range(200)])
    hi = np.minimum(5.0, 0.2 * 2.0 ** np.arange(12))
    assert np.all(d <= hi) and np.all(d >= 0.5 * hi)  # within [0.5, 1] of the capped doubling
    assert d[:, -1].max() <= 5.0 and d[:, 0].max() <= 0.2
    assert d[:, 8].std() > 0.3  # s: jittered, not in step
    assert backoff_delay(10**6, 0.2, 5.0, rng) <= 5.0  # no overflow after a long outage
