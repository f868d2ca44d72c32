"""Bad peers are refused without harm to the running session (issue 11, safety basics).

A server with a token and a calibration runs with one well-behaved sensor client streaming
body frames; each bad peer (garbage bytes, an oversized frame, a wrong token, a duplicate
sensor id, a message out of order, silence) is closed with its error code while the good
client stays connected and fused frames keep coming. Real sockets on 127.0.0.1, port 0.
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import struct
import time
from collections.abc import Callable

import numpy as np
import pytest

from kinefuse.capture.calibration.calib_file import CalibrationFile, SensorCalibration
from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS, standing_pose
from kinefuse.live.bus import FusedFrame
from kinefuse.live.protocol import (
    AuthReply,
    BodyFrameMessage,
    Challenge,
    ClockProbe,
    ClockReply,
    Decoder,
    Error,
    Hello,
    Welcome,
    encode,
)
from kinefuse.live.protocol.auth import compute_mac
from kinefuse.live.server.server import Server, ServerOptions, is_loopback

TOKEN = "s3cret-token"


class Peer:
    def __init__(self, r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        self.r, self.w, self.dec, self.inbox = r, w, Decoder(), []

    @classmethod
    async def open(cls, port: int) -> Peer:
        return cls(*await asyncio.open_connection("127.0.0.1", port))

    def send(self, msg) -> None:
        self.w.write(encode(msg))

    async def recv(self, timeout: float = 3.0):
        while not self.inbox:
            data = await asyncio.wait_for(self.r.read(65536), timeout)
            if not data:
                raise ConnectionError("closed")
            self.inbox.extend(self.dec.feed(data))
        return self.inbox.pop(0)

    async def error_then_close(self, timeout: float = 8.0) -> Error | None:
        """Everything until the server closes; the Error it sent, if any."""
        err = None
        t_end = time.monotonic() + timeout
        try:
            while time.monotonic() < t_end:
                m = await self.recv(t_end - time.monotonic())
                if isinstance(m, Error):
                    err = m
        except (ConnectionError, TimeoutError):
            pass
        return err

    async def hello(self, sensor_id: str, token: str | None = TOKEN):
        self.send(Hello(role="sensor", sensor_id=sensor_id, intrinsics=Intrinsics()))
        m = await self.recv()
        if isinstance(m, Challenge) and token is not None:
            mac = compute_mac(token, m.nonce, role="sensor", sensor_id=sensor_id)
            self.send(AuthReply(mac=mac))
            m = await self.recv()
        return m


def pose_front(distance_m: float = 2.5) -> np.ndarray:
    """A sensor at (0, -d, 1) looking along +y (sensor z), image-down = world -z."""
    p = np.eye(4)
    p[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
    p[:3, 3] = [0.0, -distance_m, 1.0]
    return p


async def good_client(port: int, stop: asyncio.Event, stats: dict) -> None:
    """Streams a standing skeleton at 30 Hz as sensor "good" and answers every probe."""
    p = await Peer.open(port)
    w = await p.hello("good")
    assert isinstance(w, Welcome), w
    pose = pose_front()
    world = standing_pose()  # (25, 3) z up, metres, at the origin
    joints = (world - pose[:3, 3]) @ pose[:3, :3]  # world -> sensor frame

    def count_probe() -> None:
        stats["probes"] = stats.get("probes", 0) + 1

    await stream_standing(p, joints, stop, h0=50.0, on_probe=count_probe)


async def stream_standing(
    p: Peer,
    joints: np.ndarray,
    stop: asyncio.Event,
    *,
    h0: float,
    on_probe: Callable[[], None] | None = None,
    on_frame: Callable[[int], None] | None = None,
) -> None:
    """Body frames of ``joints`` (sensor frame) at 30 Hz on a host clock ``monotonic + h0``,
    answering every clock probe, until ``stop``; then the connection is closed."""

    async def answer() -> None:
        while True:
            m = await p.recv(30.0)
            if isinstance(m, ClockProbe):
                t = time.monotonic() + h0
                p.send(ClockReply(probe_id=m.probe_id, t1=m.t1, t2=t, t3=t))
                if on_probe is not None:
                    on_probe()

    task = asyncio.ensure_future(answer())
    seq = 0
    try:
        while not stop.is_set():
            t = time.monotonic() + h0
            p.send(
                BodyFrameMessage(
                    seq=seq,
                    t_device_s=t - h0 - 0.06,
                    t_host_s=t,
                    joints_m=joints,
                    states=np.full(N_JOINTS, 2, np.int8),
                )
            )
            seq += 1
            if on_frame is not None:
                on_frame(seq)
            await asyncio.sleep(1 / 30)
            if task.done():
                task.result()
    finally:
        task.cancel()
        p.w.close()


@pytest.fixture
def running():
    """Run ``body(server, frames)`` against a server with a token, a calibration for "good" and
    the good client streaming; returns what body returns. Bounded to 40 s."""

    def run(body, **options):
        async def main():
            srv = Server(
                ServerOptions(
                    port=0, token=TOKEN, timeout_s=1.5, handshake_timeout_s=1.5, **options
                )
            )
            cal = CalibrationFile(
                "full",
                _dt.datetime.now(_dt.UTC),
                (SensorCalibration("good", "", pose_front(), Intrinsics(), 0.001, 100),),
            )
            srv.load_calibration(cal)
            task = asyncio.ensure_future(srv.run())
            while srv.port is None:
                await asyncio.sleep(0.01)
            frames: list[FusedFrame] = []
            sub = srv.publisher.subscribe(None)

            async def collect():
                async for it in sub:
                    if isinstance(it, FusedFrame) and np.isfinite(it.positions_m).all():
                        frames.append(it)

            col = asyncio.ensure_future(collect())
            stop, stats = asyncio.Event(), {}
            good = asyncio.ensure_future(good_client(srv.port, stop, stats))
            t_end = time.monotonic() + 5
            while len(frames) < 10:  # the session runs: fused frames of the good sensor
                assert time.monotonic() < t_end, "no fused frames from the good client"
                await asyncio.sleep(0.05)
            try:
                result = await body(srv, frames)
                # the session is unharmed: still connected, still fused, still probed
                n0, p0 = len(frames), stats.get("probes", 0)
                await asyncio.sleep(1.2)
                assert srv.clients["good"].connected
                assert len(frames) >= n0 + 20  # 1.2 s at 30 Hz
                assert stats["probes"] > p0
                assert not good.done()
            finally:
                stop.set()
                await asyncio.gather(good, return_exceptions=True)
                srv.request_stop("test")
                await asyncio.wait_for(task, 10)
                col.cancel()
            return result

        return asyncio.run(asyncio.wait_for(main(), 40))

    return run


def test_garbage_bytes_are_refused(running) -> None:
    async def body(srv, frames):
        p = await Peer.open(srv.port)
        p.w.write(struct.pack(">I", 12) + b"\xc1not msgpack!")  # 0xc1 is never valid msgpack
        return await p.error_then_close()

    err = running(body)
    assert err is not None and err.code == "malformed"


def test_an_oversized_frame_is_refused_from_its_prefix(running) -> None:
    async def body(srv, frames):
        p = await Peer.open(srv.port)
        p.w.write(struct.pack(">I", 64 << 20))  # announces 64 MiB and sends nothing more
        return await p.error_then_close(), srv.refused

    err, refused = running(body)
    assert err is not None and err.code == "oversize"
    assert any(code == "oversize" for code, _ in refused)


def test_a_wrong_token_is_refused(running) -> None:
    async def body(srv, frames):
        p = await Peer.open(srv.port)
        m = await p.hello("intruder", token="wrong")
        return m, await p.error_then_close(), "intruder" in srv.clients

    first, _rest, known = running(body)
    # the challenge was answered with a wrong MAC: the next thing is the refusal
    assert isinstance(first, Error) and first.code == "auth"
    assert not known  # never registered as a sensor


def test_a_duplicate_sensor_id_is_refused(running) -> None:
    async def body(srv, frames):
        p = await Peer.open(srv.port)
        return await p.hello("good"), srv.clients["good"].connections

    m, connections = running(body)
    assert isinstance(m, Error) and m.code == "duplicate_id" and "already connected" in m.reason
    assert connections == 1  # the connected one was not replaced


def test_out_of_order_and_silent_peers_are_closed(running) -> None:
    async def body(srv, frames):
        before = await Peer.open(srv.port)  # data before the hello
        before.send(
            BodyFrameMessage(
                seq=0,
                t_device_s=0.0,
                t_host_s=0.0,
                joints_m=np.zeros((N_JOINTS, 3)),
                states=np.full(N_JOINTS, 2, np.int8),
            )
        )
        e1 = await before.error_then_close()
        back = await Peer.open(srv.port)  # seq going backwards
        assert isinstance(await back.hello("other"), Welcome)
        for seq in (5, 3):
            back.send(
                BodyFrameMessage(
                    seq=seq,
                    t_device_s=1.0,
                    t_host_s=1.0,
                    joints_m=np.zeros((N_JOINTS, 3)),
                    states=np.full(N_JOINTS, 2, np.int8),
                )
            )
        e2 = await back.error_then_close()
        silent = await Peer.open(srv.port)  # says nothing at all
        e3 = await silent.error_then_close(timeout=8.0)
        return e1, e2, e3, srv.clients["other"].connected

    e1, e2, e3, other_connected = running(body)
    assert e1 is not None and e1.code == "order"
    assert e2 is not None and e2.code == "order" and "seq" in e2.reason
    assert e3 is not None and e3.code == "timeout"
    assert not other_connected  # marked offline


def test_the_paper_method_fuses_live(running) -> None:
    async def body(srv, frames):
        await asyncio.sleep(0.3)
        return list(frames), srv.fusion

    frames, fusion = running(body, method="paper")
    # the server fuses with the paper's method (not only carries the option): no filter lead
    assert fusion.method == "paper" and fusion.lead_s == 0.0
    # one sensor: the paper's trilateration has a single range per joint, too few to solve;
    # every joint of every frame says so (best-live would say SINGLE_SENSOR, with a variance),
    # and the skeleton is that one sensor's (the paper's chain falls back to it) to 1 mm
    assert len(frames) >= 10
    for fr in frames:
        assert (fr.status == FusionStatus.TOO_FEW_SENSORS).all(), fr.status
        assert np.isnan(fr.variance_m2).all()  # the paper's method gives no variance
        np.testing.assert_allclose(fr.positions_m, standing_pose(), atol=0.001)  # 1 mm


def test_loopback_detection() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.10")
