"""Mutual authentication (issue 23): a client with a token streams to no impostor.

An impostor is a small asyncio server written here with the protocol's codec: it speaks the
protocol but does not know the token. It challenges the client and then sends no proof, a fake
one, a proof reflected from the other direction, or a real server's proof replayed from an
earlier handshake; or it welcomes the client without any challenge. It welcomes whatever the
client answers and records everything, so a client that does not check the server would
stream its body frames to it. The real path (a real ``Server`` with a token, a real client) must
still work. Loopback, port 0, every test bounded in time.
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import struct
from collections.abc import Iterator
from typing import Any

import msgpack
import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import BodyFrame as SourceBody
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import KinefuseError
from kinefuse.live.client.client import ClientOptions, ClientRefused, SensorClient
from kinefuse.live.client.clocks import HostClock
from kinefuse.live.client.playback import SourceTimeline
from kinefuse.live.protocol import (
    AuthReply,
    BodyFrameMessage,
    CalibrationStart,
    Challenge,
    Decoder,
    Error,
    Hello,
    Message,
    Welcome,
    encode,
)
from kinefuse.live.protocol.auth import compute_mac, new_nonce
from kinefuse.live.server.server import Server, ServerOptions

TOKEN = "s3cret-token"
SID = "m0"
LIMIT_S = 20.0  # no test here may take longer


def run(coro: Any) -> Any:
    async def bounded() -> Any:
        async with asyncio.timeout(LIMIT_S):
            return await coro

    return asyncio.run(bounded())


class Walk:
    """A synthetic sensor source: ``n`` body frames at 30 Hz."""

    def __init__(self, n: int = 30) -> None:
        self.n = n

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        return (SID,)

    def intrinsics(self, sensor_id: str) -> Intrinsics:
        return Intrinsics()

    def __iter__(self) -> Iterator[SourceBody]:
        j = np.column_stack(
            [np.linspace(-0.3, 0.3, N_JOINTS), np.zeros(N_JOINTS), np.full(25, 2.5)]
        )
        states = np.full(N_JOINTS, 2, dtype=np.int8)
        for k in range(self.n):
            yield SourceBody(SID, k, 1000.0 + k / 30, 500.0 + k / 30, j + 0.01 * k, states)


def client(port: int, n: int = 30, **opts: Any) -> SensorClient:
    o = dict(backoff_initial_s=0.05, backoff_max_s=0.2, connect_timeout_s=2.0, speed=10.0)
    o.update(opts)
    return SensorClient(
        SourceTimeline(Walk(n)),
        ClientOptions(server=("127.0.0.1", port), **o),
        host_clock=lambda m0: HostClock(77.0, 20e-6, m0),
    )


async def real_server(token: str | None = TOKEN) -> tuple[Server, asyncio.Future[None]]:
    srv = Server(ServerOptions(port=0, token=token, timeout_s=2.0, handshake_timeout_s=2.0))
    task = asyncio.ensure_future(srv.run())
    while srv.port is None:
        await asyncio.sleep(0.01)
    return srv, task


async def stop_server(srv: Server, task: asyncio.Future[None]) -> None:
    srv.request_stop("test")
    await asyncio.wait_for(task, 10)


async def recorded_challenge(port: int, role: str = "sensor", sensor_id: str = SID) -> Challenge:
    """The challenge (with its proof) a real server sends for a Hello with a nonce of ours: what
    an eavesdropper records from an earlier handshake."""
    r, w = await asyncio.open_connection("127.0.0.1", port)
    try:
        nonce = (
            {"client_nonce": new_nonce()} if "client_nonce" in Hello.__dataclass_fields__ else {}
        )
        w.write(encode(Hello(role=role, sensor_id=sensor_id, intrinsics=Intrinsics(), **nonce)))
        dec, got = Decoder(), []
        while not got:
            data = await asyncio.wait_for(r.read(65536), 5.0)
            assert data, "the real server closed before its challenge"
            got = dec.feed(data)
        assert isinstance(got[0], Challenge)
        return got[0]
    finally:
        w.close()


class Impostor:
    """A server that does not know the token. ``mode`` is what it answers a Hello with:

    - ``no_proof``: a challenge without the server's proof;
    - ``fake_proof``: a challenge with 32 random bytes as the proof;
    - ``reflected``: a challenge whose proof is a *peer's* MAC over the client's own nonce (what
      a reflection of the other direction, the client's or another sensor's reply, gives);
    - ``replayed``: ``self.replay``, a real server's challenge recorded from an earlier handshake;
    - ``welcome``: no challenge at all, straight to the Welcome.

    Whatever the client answers then, it is welcomed; everything it sends is recorded.
    """

    def __init__(self, mode: str, replay: Challenge | None = None) -> None:
        self.mode, self.replay = mode, replay
        self.received: list[Message] = []
        self.connections = 0
        self.port = 0
        self._server: asyncio.Server | None = None

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._handle, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        assert self._server is not None
        self._server.close()
        await self._server.wait_closed()

    def _challenge(self, hello: Hello) -> bytes:
        """The challenge frame, built from its wire map (the same bytes as the codec's)."""
        nonce = new_nonce()
        client_nonce = getattr(hello, "client_nonce", None) or secrets.token_bytes(32)
        wire: dict[str, Any] = {"type": "challenge", "nonce": nonce, "algorithm": "hmac-sha256"}
        if self.mode == "fake_proof":
            wire["server_mac"] = secrets.token_bytes(32)
        elif self.mode == "reflected":
            # the MAC the peer direction gives over the client's own nonce (computed here with
            # the token, as an oracle of that direction would): never a valid server proof
            mac = compute_mac(TOKEN, client_nonce, role=hello.role, sensor_id=hello.sensor_id)
            wire |= {"nonce": client_nonce, "server_mac": mac}
        elif self.mode == "replayed":
            assert self.replay is not None
            wire = {**self.replay.__dict__, "type": "challenge"}
        body = msgpack.packb(wire, use_bin_type=True)
        return struct.pack(">I", len(body)) + body

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        dec = Decoder()
        try:
            while data := await reader.read(65536):
                for m in dec.feed(data):
                    self.received.append(m)
                    if isinstance(m, Hello):
                        if self.mode == "welcome":
                            writer.write(encode(Welcome(session="impostor", heartbeat_s=0.2)))
                        else:
                            writer.write(self._challenge(m))
                    elif isinstance(m, AuthReply):
                        writer.write(encode(Welcome(session="impostor", heartbeat_s=0.2)))
                    elif isinstance(m, CalibrationStart):
                        writer.close()  # (a control peer got this far: the test has failed)
                        return
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            writer.close()

    def got(self, cls: type[Message]) -> list[Message]:
        return [m for m in self.received if isinstance(m, cls)]


MODES = ["no_proof", "fake_proof", "reflected", "replayed", "welcome"]
WHY = {
    "no_proof": "did not prove that it knows the token",
    "fake_proof": "could not prove that it knows the token",
    "reflected": "could not prove that it knows the token",
    "replayed": "could not prove that it knows the token",
    "welcome": "offers no authentication",
}


async def make_impostor(mode: str) -> Impostor:
    replay = None
    if mode == "replayed":  # a real server's proof, recorded for an earlier nonce
        srv, task = await real_server()
        try:
            replay = await recorded_challenge(srv.port)
        finally:
            await stop_server(srv, task)
    imp = Impostor(mode, replay)
    await imp.start()
    return imp


@pytest.mark.parametrize("mode", MODES)
def test_a_sensor_with_a_token_sends_no_body_frame_to_an_impostor(mode):
    async def go() -> tuple[Impostor, BaseException | int]:
        imp = await make_impostor(mode)
        try:
            c = client(imp.port, n=30, token=TOKEN)
            try:
                outcome: BaseException | int = await c.run()
            except ClientRefused as e:
                outcome = e
        finally:
            await imp.stop()
        return imp, outcome

    imp, outcome = run(go())
    assert not imp.got(BodyFrameMessage), f"{len(imp.got(BodyFrameMessage))} body frames leaked"
    assert isinstance(outcome, ClientRefused), f"the client ran to the end ({outcome!r})"
    assert outcome.code == "auth"  # kinefuse sensor: exit 3, as for any refusal
    assert "refusing the server" in str(outcome) and WHY[mode] in str(outcome)
    assert imp.connections == 1  # refused for good: no reconnecting to the impostor
    assert not imp.got(AuthReply)  # not even a MAC (no oracle for anyone)
    errors = imp.got(Error)
    assert errors and errors[0].code == "auth"  # and it says why before closing


@pytest.mark.parametrize("mode", ["no_proof", "reflected", "welcome"])
def test_a_control_peer_with_a_token_refuses_an_impostor_too(mode):
    from kinefuse.app.workflows.serve import _control_calibrate

    async def go() -> tuple[Impostor, BaseException | None]:
        imp = await make_impostor(mode)
        try:
            try:
                await _control_calibrate("127.0.0.1", imp.port, TOKEN, "", 1.0, 5.0)
            except KinefuseError as e:
                return imp, e
            return imp, None
        finally:
            await imp.stop()

    imp, err = run(go())
    assert not imp.got(CalibrationStart), "the control peer sent its request to an impostor"
    assert not imp.got(AuthReply)
    assert err is not None and "refusing the server" in str(err) and WHY[mode] in str(err)


def test_the_proofs_of_the_two_directions_never_stand_in_for_each_other():
    from kinefuse.live.protocol.auth import (
        AuthError,
        compute_server_mac,
        verify_mac,
        verify_server_mac,
    )

    cn, sn = new_nonce(), new_nonce()
    proof = compute_server_mac(TOKEN, cn, sn, role="sensor", sensor_id=SID)
    verify_server_mac(TOKEN, cn, sn, proof, role="sensor", sensor_id=SID)  # the right one
    for mac in (  # a peer's reply over either nonce is no server proof
        compute_mac(TOKEN, cn, role="sensor", sensor_id=SID),
        compute_mac(TOKEN, sn, role="sensor", sensor_id=SID),
    ):
        with pytest.raises(AuthError, match="could not prove"):
            verify_server_mac(TOKEN, cn, sn, mac, role="sensor", sensor_id=SID)
    with pytest.raises(AuthError):  # nor is the server's proof a peer's reply
        verify_mac(TOKEN, sn, proof, role="sensor", sensor_id=SID)
    with pytest.raises(AuthError, match="could not prove"):  # another client nonce: a replay
        verify_server_mac(TOKEN, new_nonce(), sn, proof, role="sensor", sensor_id=SID)
    with pytest.raises(AuthError, match="could not prove"):  # another peer
        verify_server_mac(TOKEN, cn, sn, proof, role="sensor", sensor_id="m1")
    with pytest.raises(AuthError, match="could not prove"):  # another token
        verify_server_mac("other", cn, sn, proof, role="sensor", sensor_id=SID)
    with pytest.raises(AuthError, match="did not prove"):  # no proof
        verify_server_mac(TOKEN, cn, sn, None, role="sensor", sensor_id=SID)


def test_the_right_token_still_works_end_to_end_with_a_real_server():
    async def go() -> tuple[int, int, int, Challenge]:
        srv, task = await real_server()
        try:
            c = client(srv.port, n=20, token=TOKEN)
            code = await c.run()
            # the server's challenge carries its proof over the nonce of the Hello
            challenge = await recorded_challenge(srv.port, sensor_id="probe")
            return code, c.stats.body_sent, srv.clients[SID].connections, challenge
        finally:
            with contextlib.suppress(Exception):
                await stop_server(srv, task)

    code, sent, connections, challenge = run(go())
    assert code == 0 and sent == 20 and connections == 1
    assert getattr(challenge, "server_mac", None) is not None


def test_a_client_without_a_token_and_a_server_without_one_still_talk():
    async def go() -> tuple[int, int]:
        srv, task = await real_server(token=None)
        try:
            c = client(srv.port, n=10)
            return await c.run(), c.stats.body_sent
        finally:
            await stop_server(srv, task)

    assert run(go()) == (0, 10)
