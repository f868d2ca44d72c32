"""Fuzzing the wire, bounded, in every CI run (issue 23): at least 100,000 inputs, 0 crashes.

A seeded pure-Python mutation loop (no hypothesis: it is deterministic, and its speed is ours
to measure). Its inputs, from a stream of real messages (a recorded-like session: hello, auth,
clock replies, body frames, sightings, a floor, heartbeats, control requests):

- random bytes; valid length prefixes with random payloads; truncated frames;
- valid msgpack maps of every message type with a field of the wrong type, a missing field,
  NaN/inf, a huge array (announced shape or data), deep nesting, unknown types and fields;
- mutations of the real stream: bit flips, byte insertions and deletions, spliced frames,
  frames swapped (out of order), repeated, or cut short.

The split: most inputs (``N_DECODER``) go through the sans-I/O decoder directly, in random
chunkings (it is where every byte is parsed, and it is fast); a real-socket share
(``N_SOCKET``) drives a real ``kinefuse serve`` process over 127.0.0.1: each connection sends
one input, before or after an authenticated handshake as a sensor or a control peer. Meanwhile
two well-behaved sensors stream at 30 Hz; afterwards the server is alive, both are connected
and still fused, its RSS is within 20 % of before, and the recording opens. A crash (anything
but a :class:`WireError` from the decoder; an ``internal`` error or a dead server) fails with
the input, to become a regression test.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as _dt
import math
import os
import random
import struct
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np

import test_server_safety as safety
from kinefuse.capture.calibration.calib_file import (
    CalibrationFile,
    SensorCalibration,
    write_calibration,
)
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS, standing_pose
from kinefuse.live.protocol import (
    MESSAGE_TYPES,
    AuthReply,
    BodyFrameMessage,
    CalibrationStart,
    CalibrationStop,
    Challenge,
    ClockProbe,
    ClockReply,
    Decoder,
    Error,
    FloorPlaneMessage,
    Goodbye,
    Heartbeat,
    Hello,
    OtherBody,
    Status,
    StatusRequest,
    WandSighting,
    Welcome,
    WireError,
    encode,
)
from kinefuse.live.protocol.auth import compute_mac
from kinefuse.live.protocol.codec import HEADER, to_wire

SEED = 20261123
N_DECODER = 96_000
N_SOCKET = 4_000
TOKEN = "c4e6a8b0d2f41357e9f1a3b5c7d9e0f2a4b6c8d0e2f4a6b8c0d2e4f6a8b0c2d4"  # 256 bits


# -- inputs ------------------------------------------------------------------------------------


def real_stream(rng: random.Random) -> list[bytes]:
    """Frames of a plausible sensor session (as recorded: what a client sends)."""
    intr = Intrinsics()
    out = [encode(Hello(role="sensor", sensor_id="k0", intrinsics=intr, serial="SN1"))]
    out.append(encode(AuthReply(mac=bytes(rng.getrandbits(8) for _ in range(32)))))
    joints = standing_pose() + np.array([0.0, 2.5, 0.0])
    t = 100.0
    for k in range(12):
        t += 1 / 30
        out.append(
            encode(
                BodyFrameMessage(
                    seq=k,
                    t_device_s=t - 0.06,
                    t_host_s=t,
                    joints_m=joints,
                    states=np.full(N_JOINTS, 2, np.int8),
                    occluded=np.zeros(N_JOINTS, bool),
                    n_crossings=0,
                    body_id=7,
                    others=_others(joints, k % 3),
                )
            )
        )
        if k % 4 == 0:
            out.append(encode(ClockReply(probe_id=k, t1=t - 50, t2=t, t3=t + 1e-4)))
        if k % 3 == 0:
            out.append(
                encode(
                    WandSighting(
                        seq=k, t_device_s=t, t_host_s=t, centre_m=np.array([0.1, 0.2, 2.0])
                    )
                )
            )
    out.append(encode(FloorPlaneMessage(normal=np.array([0.0, -1.0, 0.0]), offset_m=1.2)))
    out.append(encode(Heartbeat(t_s=t, sent=40, floor_error="no floor")))
    out += [encode(StatusRequest(request_id=1)), encode(CalibrationStart(method="full"))]
    out += [encode(CalibrationStop(abort=True)), encode(Goodbye(reason="done"))]
    return out


def _others(joints: np.ndarray, n: int) -> tuple[OtherBody, ...]:
    """``n`` more bodies beside ``joints`` (ids 11, 12, ...), one without occlusion flags."""
    return tuple(
        OtherBody(
            11 + i,
            joints + np.array([0.7 * (i + 1), 0.0, 0.0]),
            np.full(N_JOINTS, 2, np.int8),
            None if i else np.zeros(N_JOINTS, bool),
            None if i else 1,
        )
        for i in range(n)
    )


def _sample_messages() -> list[dict]:
    """One wire map of every message type (to mutate field by field)."""
    arr = np.zeros((2, 4, 4))
    msgs = [
        Hello(role="sensor", sensor_id="k0", intrinsics=Intrinsics()),
        Challenge(nonce=bytes(32)),
        AuthReply(mac=bytes(32)),
        Welcome(),
        Error(code="order", reason="x"),
        Goodbye(),
        Heartbeat(),
        ClockProbe(probe_id=1, t1=1.0),
        ClockReply(probe_id=1, t1=1.0, t2=2.0, t3=2.0),
        CalibrationStart(sensor_ids=("k0",), seconds=3.0),
        CalibrationStop(),
        WandSighting(seq=1, t_device_s=1.0, t_host_s=1.0, centre_m=np.zeros(3)),
        FloorPlaneMessage(normal=np.array([0.0, -1.0, 0.0]), offset_m=1.0),
        BodyFrameMessage(
            seq=1,
            t_device_s=1.0,
            t_host_s=1.0,
            joints_m=np.zeros((N_JOINTS, 3)),
            states=np.zeros(N_JOINTS, np.int8),
            body_id=3,
            others=_others(np.zeros((N_JOINTS, 3)), 2),
        ),
        StatusRequest(),
        Status(),
    ]
    out = [to_wire(m) for m in msgs]
    cr = MESSAGE_TYPES["calibration_result"]
    out.append(
        to_wire(
            cr(
                sensor_ids=("a", "b"),
                sensor2world=arr,
                residual_m=np.zeros(2),
                n_sightings=np.zeros(2, np.int64),
            )
        )
    )
    return out


_WEIRD: list[object] = [
    None,
    True,
    -1,
    2**64 - 1,
    -(2**63),
    math.nan,
    math.inf,
    -math.inf,
    1e308,
    "",
    "x" * 5000,
    "\u0000\ud7ff",
    b"",
    b"\xff" * 40,
    [],
    [1, 2],
    {},
    {"dtype": "<f8", "shape": [1 << 30, 3], "data": b""},
    {"dtype": "<f8", "shape": [25, 3], "data": b"\x00" * 8},
    {"dtype": "<f8", "shape": [25, 3], "data": struct.pack("<d", math.nan) * 75},
    {"dtype": "<f8", "shape": [25, 3], "data": struct.pack("<d", math.inf) * 75},
    {"dtype": "|O", "shape": [1], "data": b"\x00" * 8},
    {"dtype": "<f8", "shape": [-1], "data": b""},
    {"dtype": "<f8", "shape": "25", "data": b""},
    {"dtype": 5, "shape": [], "data": 5},
    [[[[[]]]]],
]


def _nest(depth: int) -> object:
    v: object = 0
    for i in range(depth):
        v = [v] if i % 2 else {"a": v}
    return v


def _frame(body: bytes) -> bytes:
    return HEADER.pack(len(body)) + body


def _big_frames() -> list[bytes]:
    """Deeply nested and oversized containers (built once: they are slow to pack)."""
    out = []
    for n in (10, 100, 500, 1000, 3000):
        out.append(_frame(_pack({"type": "hello", "role": _nest(n)})))
        out.append(_frame(_pack({"type": "status", "sensors": [{}] * (2 * n)})))
        out.append(_frame(_pack({"type": "hello", "capabilities": ["a"] * (n + 60)})))
    # a body frame with more bodies than the limit (8 a frame): refused, nothing decoded
    body = to_wire(BodyFrameMessage(seq=1, t_device_s=1.0, t_host_s=1.0,
                                    joints_m=np.zeros((N_JOINTS, 3)),
                                    states=np.zeros(N_JOINTS, np.int8)))  # fmt: skip
    for n in (8, 64, 4000):
        one = {"body_id": 1, "joints_m": body["joints_m"], "states": body["states"]}
        out.append(_frame(_pack({**body, "others": [dict(one, body_id=i) for i in range(n)]})))
    return out


def _pack(obj: object) -> bytes:
    try:
        return msgpack.packb(obj, use_bin_type=True)
    except (ValueError, OverflowError, TypeError):
        return msgpack.packb({"type": "hello"}, use_bin_type=True)


_BIG: list[bytes] = []


def make_input(rng: random.Random, stream: list[bytes], samples: list[dict]) -> bytes:
    """One fuzz input (bytes a peer might send), of a randomly chosen kind."""
    if not _BIG:
        _BIG.extend(_big_frames())
    kind = rng.randrange(10)
    if kind == 0:  # random bytes
        return rng.randbytes(rng.randrange(0, 300))
    if kind == 1:  # a valid prefix with a random payload (maybe shorter than announced)
        body = rng.randbytes(rng.randrange(1, 200))
        n = len(body) if rng.random() < 0.7 else rng.randrange(0, 1 << 21)
        return HEADER.pack(n) + body
    if kind in (2, 3):  # a real message map with one field mutated or removed
        m = dict(rng.choice(samples))
        keys = [k for k in m if k != "type"]
        if keys and rng.random() < 0.8:
            k = rng.choice(keys)
            if rng.random() < 0.3:
                del m[k]
            else:
                m[k] = rng.choice(_WEIRD)
        if rng.random() < 0.1:
            m["type"] = rng.choice(["", "x" * 70, 5, None, "future_type"])
        if rng.random() < 0.1:
            m[f"extra_{rng.randrange(9)}"] = rng.choice(_WEIRD)
        return _frame(_pack(m))
    if kind == 4:  # deep nesting / big containers / not-a-map bodies
        choice = rng.randrange(4)
        if choice == 2:
            return _frame(_pack(rng.choice(_WEIRD)))
        return rng.choice(_BIG)
    if kind == 5:  # truncated real frames
        f = rng.choice(stream)
        return f[: rng.randrange(0, len(f))]
    # mutations of the real stream (kinds 6-9)
    frames = [rng.choice(stream) for _ in range(rng.randrange(1, 6))]
    op = rng.randrange(5)
    if op == 0:  # swapped: out of order
        rng.shuffle(frames)
        data = bytearray(b"".join(frames))
    elif op == 1:  # repeated
        data = bytearray(b"".join(frames) * rng.randrange(2, 4))
    else:
        data = bytearray(b"".join(frames))
        for _ in range(rng.randrange(1, 8)):
            if not data:
                break
            i = rng.randrange(len(data))
            r = rng.random()
            if r < 0.5:
                data[i] ^= 1 << rng.randrange(8)
            elif r < 0.7:
                data.insert(i, rng.randrange(256))
            elif r < 0.85:
                del data[i]
            else:  # splice the tail of another frame in
                other = rng.choice(stream)
                data[i:i] = other[rng.randrange(len(other)) :]
    return bytes(data)


_CHUNKS = (1, 7, 7, 64, 64, 4096, 4096, 1 << 20, 1 << 20, 1 << 20)


def decode_all(data: bytes, rng: random.Random, peer_version=None) -> None:
    """Feed ``data`` in random chunks, going on after non-framing errors as a lenient peer
    would; anything but a WireError escapes (a crash)."""
    dec = Decoder()
    dec.peer_version = peer_version
    i = 0
    while i < len(data):
        j = min(len(data), i + rng.choice(_CHUNKS))
        try:
            dec.feed(data[i:j])
            i = j
        except WireError as e:
            if dec._broken is not None:
                return
            i = j
            _ = e.code  # every error carries its wire code
            try:
                dec.feed(b"")
            except WireError:
                if dec._broken is not None:
                    return
    with contextlib.suppress(WireError):
        dec.close()


# -- the decoder share -------------------------------------------------------------------------


def test_the_decoder_survives_fuzzing() -> None:
    rng = random.Random(SEED)
    stream, samples = real_stream(rng), _sample_messages()
    t0 = time.perf_counter()
    for n in range(N_DECODER):
        data = make_input(rng, stream, samples)
        version = (1, 9) if n % 5 == 0 else None  # a newer minor peer: unknown types skipped
        try:
            decode_all(data, rng, version)
        except Exception as e:  # a crash: fail with the input, to make it a regression test
            raise AssertionError(f"input {n} crashed the decoder: {e!r}; input {data!r}") from e
    took = time.perf_counter() - t0
    print(f"fuzz: {N_DECODER} decoder inputs in {took:.1f} s")


# -- the real-socket share ---------------------------------------------------------------------


def _rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


async def _sensor(port: int, sid: str, pose: np.ndarray, stop: asyncio.Event, stats: dict):
    """A well-behaved sensor: 30 Hz body frames of a standing skeleton, probes answered."""
    r, w = await asyncio.open_connection("127.0.0.1", port)
    p = safety.Peer(r, w)
    p.send(Hello(role="sensor", sensor_id=sid, intrinsics=Intrinsics()))
    m = await p.recv()
    p.send(AuthReply(mac=compute_mac(TOKEN, m.nonce, role="sensor", sensor_id=sid)))
    assert isinstance(await p.recv(), Welcome)
    joints = (standing_pose() - pose[:3, 3]) @ pose[:3, :3]
    await safety.stream_standing(
        p, joints, stop, h0=30.0 + len(sid), on_frame=lambda seq: stats.__setitem__(sid, seq)
    )


async def _status(port: int) -> Status:
    r, w = await asyncio.open_connection("127.0.0.1", port)
    p = safety.Peer(r, w)
    try:
        p.send(Hello(role="control"))
        m = await p.recv()
        p.send(AuthReply(mac=compute_mac(TOKEN, m.nonce, role="control", sensor_id="")))
        assert isinstance(await p.recv(), Welcome)
        p.send(StatusRequest(request_id=7))
        while True:
            m = await p.recv(5.0)
            if isinstance(m, Status):
                return m
    finally:
        w.close()


async def _one(port: int, data: bytes, mode: int, sid: str) -> str:
    """Send one fuzz input (raw, or after an authenticated handshake); read until closed."""
    r, w = await asyncio.wait_for(asyncio.open_connection("127.0.0.1", port), 5.0)
    dec = Decoder()
    try:
        if mode:
            role = "sensor" if mode == 1 else "control"
            hello = Hello(role=role, sensor_id=sid if mode == 1 else "", intrinsics=Intrinsics())
            if mode == 2:
                hello = Hello(role="control")
            w.write(encode(hello))
            msgs: list = []
            while not msgs:
                chunk = await asyncio.wait_for(r.read(65536), 5.0)
                if not chunk:
                    return "closed"
                msgs = dec.feed(chunk)
            if not isinstance(msgs[0], Challenge):
                return type(msgs[0]).__name__
            mac = compute_mac(TOKEN, msgs[0].nonce, role=role, sensor_id=hello.sensor_id)
            w.write(encode(AuthReply(mac=mac)))
        w.write(data)
        if mode == 0 or random.random() < 0.5:
            w.write_eof()
        codes = []
        t_end = time.monotonic() + 8.0
        while time.monotonic() < t_end:
            chunk = await asyncio.wait_for(r.read(65536), t_end - time.monotonic())
            if not chunk:
                break
            try:
                codes += [m.code for m in dec.feed(chunk) if isinstance(m, Error)]
            except WireError:
                break
        return ",".join(codes) or "none"
    except (ConnectionError, TimeoutError, OSError):
        return "reset"
    finally:
        w.close()


def test_the_real_server_survives_fuzzing_and_keeps_fusing(tmp_path) -> None:
    rng = random.Random(SEED + 1)
    stream, samples = real_stream(rng), _sample_messages()
    poses = {"s0": safety.pose_front(), "s1": safety.pose_front(3.0)}
    cal = CalibrationFile(
        "full",
        _dt.datetime.now(_dt.UTC),
        tuple(SensorCalibration(s, "", p, Intrinsics(), 0.001, 100) for s, p in poses.items()),
    )
    cal_path = write_calibration(tmp_path / "cal.toml", cal)
    rec = tmp_path / "rec.sqlite"
    env = {**os.environ, "KINEFUSE_TOKEN": TOKEN}
    args = [sys.executable, "-m", "kinefuse", "serve", "--port", "0", "--record", str(rec)]
    err_path = tmp_path / "server.err"  # what the server said, shown if it fails
    with err_path.open("w") as err_log:
        server = subprocess.Popen(
            [*args, "--calibration", str(cal_path)],
            stdout=subprocess.PIPE,
            stderr=err_log,
            text=True,
            env=env,
        )
    try:
        assert server.stdout is not None
        line = server.stdout.readline()
        assert "listening on" in line, line
        port = int(line.rsplit(":", 1)[1])

        async def main() -> dict:
            stop, stats = asyncio.Event(), {}
            sensors = [
                asyncio.ensure_future(_sensor(port, s, p, stop, stats)) for s, p in poses.items()
            ]
            await asyncio.sleep(3.0)  # synchronized and fusing
            before = await _status(port)
            rss0 = _rss_kib(server.pid)
            t0 = time.perf_counter()
            outcomes: dict[str, int] = {}
            sem = asyncio.Semaphore(16)

            async def one(n: int) -> None:
                data = make_input(rng, stream, samples)
                async with sem:
                    got = await _one(port, data, n % 3, f"fz{n % 4}")
                outcomes[got] = outcomes.get(got, 0) + 1

            await asyncio.gather(*(one(n) for n in range(N_SOCKET)))
            took = time.perf_counter() - t0
            await asyncio.sleep(1.5)
            rss1 = _rss_kib(server.pid)
            after = await _status(port)
            n1 = after.frames_fused
            await asyncio.sleep(1.0)
            n2 = (await _status(port)).frames_fused
            stop.set()
            await asyncio.gather(*sensors, return_exceptions=True)
            return {
                "before": before,
                "after": after,
                "rate": n2 - n1,
                "rss": (rss0, rss1),
                "took": took,
                "outcomes": outcomes,
            }

        try:
            out = asyncio.run(asyncio.wait_for(main(), 240))
        except OSError as e:  # the server stopped answering: say what it printed
            tail = err_path.read_text(errors="replace")[-3000:]
            alive = server.poll() is None
            raise AssertionError(f"{e}; server alive: {alive}; stderr:\n{tail}") from e
        print(
            f"fuzz: {N_SOCKET} socket inputs in {out['took']:.1f} s; RSS {out['rss'][0]} -> "
            f"{out['rss'][1]} KiB; outcomes {sorted(out['outcomes'].items())}"
        )
        assert server.poll() is None, "the server died"
        assert "internal" not in ",".join(out["outcomes"]), out["outcomes"]
        conn = {s.sensor_id: s.connected for s in out["after"].sensors}
        assert conn.get("s0") and conn.get("s1"), conn  # the real sensors stayed connected
        assert out["rate"] >= 20, out["rate"]  # and fused (30 Hz; 1 s measured on a busy CI)
        rss0, rss1 = out["rss"]
        assert rss1 < 1.2 * rss0, out["rss"]
        server.send_signal(2)
        assert server.wait(20) == 0
    finally:
        if server.poll() is None:
            server.kill()
            server.wait(10)
    from kinefuse.formats.store.session_store import SessionStore

    with SessionStore.open(rec) as st:
        assert st.complete
        assert {s.id for s in st.sensors()} >= {"s0", "s1"}
