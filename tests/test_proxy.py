"""The fault-injecting TCP proxy over real loopback sockets (port 0), each test bounded in time."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest

from kinefuse.errors import InputError
from kinefuse.live.proxy import FaultProxy, LinkProfile, LinkSchedule, ProxyThread, jitter_profiles

TIMEOUT_S = 20.0  # no test may hang: every one runs under this bound


def run(coro: object) -> object:
    return asyncio.run(asyncio.wait_for(coro, TIMEOUT_S))  # type: ignore[arg-type]


class Target:
    """A loopback server that records what it receives (with arrival times) and can echo."""

    def __init__(self, echo: bool = False) -> None:
        self.echo = echo
        self.received = bytearray()
        self.arrivals: list[tuple[float, bytes]] = []
        self.closed = asyncio.Event()
        self.writers: list[asyncio.StreamWriter] = []
        self.server: asyncio.Server | None = None

    async def _handle(self, r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        self.writers.append(w)
        loop = asyncio.get_running_loop()
        try:
            while chunk := await r.read(65536):
                self.arrivals.append((loop.time(), chunk))
                self.received += chunk
                if self.echo:
                    w.write(chunk)
                    await w.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            self.closed.set()
            w.close()

    async def __aenter__(self) -> Target:
        self.server = await asyncio.start_server(self._handle, "127.0.0.1", 0)
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self.server is not None
        self.server.close()
        for w in self.writers:
            w.close()
        await self.server.wait_closed()

    @property
    def port(self) -> int:
        assert self.server is not None
        return int(self.server.sockets[0].getsockname()[1])


# ------------------------------------------------------------------------------------------
# the timing rule, without sockets


def test_schedule_never_reorders_and_matches_its_distribution() -> None:
    p = LinkProfile(delay_s=0.002, jitter_s=0.003, jitter="exponential")
    s = LinkSchedule(p, np.random.default_rng(1))
    arrivals = np.arange(20000) * 0.001  # a chunk every ms: big draws queue the ones behind
    rel = np.array([s.release(float(a), 100) for a in arrivals])
    assert (np.diff(rel) >= 0).all()  # a TCP stream keeps its order
    # spaced-out chunks get the distribution itself: delay + exponential(mean 3 ms)
    s2 = LinkSchedule(p, np.random.default_rng(2))
    d = np.array([s2.release(10.0 * k, 100) - 10.0 * k for k in range(20000)])
    assert abs(d.mean() - 0.005) < 1e-4  # 0.1 ms: 20000 draws of sd 3 ms give se 0.02 ms
    assert abs(np.median(d) - (0.002 + 0.003 * math.log(2))) < 1e-4
    assert d.min() >= 0.002


def test_schedule_bandwidth_and_other_distributions() -> None:
    s = LinkSchedule(LinkProfile(bandwidth_Bps=1000.0), np.random.default_rng(0))
    assert s.release(0.0, 500) == pytest.approx(0.5)
    assert s.release(0.1, 500) == pytest.approx(1.0)  # waits for the link to be free
    assert s.release(5.0, 100) == pytest.approx(5.1)
    for kind in ("uniform", "halfnormal"):
        sc = LinkSchedule(LinkProfile(jitter_s=0.004, jitter=kind), np.random.default_rng(3))
        d = np.array([sc.release(k, 1) - k for k in range(20000)], dtype=float)
        assert abs(d.mean() - 0.004) < 1e-4, kind  # every kind has mean jitter_s
    same = [LinkSchedule(LinkProfile(jitter_s=0.01), np.random.default_rng(7)) for _ in "ab"]
    assert [same[0].release(k, 1) for k in range(5)] == [same[1].release(k, 1) for k in range(5)]


def test_bad_profiles_are_refused_with_the_reason() -> None:
    with pytest.raises(InputError, match="delay_s must be a finite number >= 0"):
        LinkProfile(delay_s=-1.0)
    with pytest.raises(InputError, match="jitter must be one of"):
        LinkProfile(jitter="pareto")
    with pytest.raises(InputError, match="bandwidth_Bps"):
        LinkProfile(bandwidth_Bps=0.0)
    with pytest.raises(InputError, match="cut_after_bytes"):
        LinkProfile(cut_after_bytes=-3)
    with pytest.raises(InputError, match="--net-jitter-ms"):
        jitter_profiles(float("nan"))
    with pytest.raises(InputError, match="target port"):
        FaultProxy("127.0.0.1", 0)


# ------------------------------------------------------------------------------------------
# real sockets


def test_bytes_arrive_intact_and_in_order_both_ways_under_jitter() -> None:
    rng = np.random.default_rng(0)
    data = rng.integers(0, 256, 300_000, dtype=np.uint8).tobytes()

    async def main() -> bytes:
        async with Target(echo=True) as target:
            jitter = LinkProfile(delay_s=0.001, jitter_s=0.01, jitter="uniform")
            async with FaultProxy("127.0.0.1", target.port, up=jitter, down=jitter) as proxy:
                r, w = await asyncio.open_connection("127.0.0.1", proxy.port)
                back = bytearray()

                async def receive() -> None:
                    while len(back) < len(data):
                        chunk = await r.read(65536)
                        assert chunk, "the connection closed early"
                        back.extend(chunk)

                recv = asyncio.create_task(receive())
                i = 0
                while i < len(data):  # many small writes of random sizes
                    n = int(rng.integers(1, 5000))
                    w.write(data[i : i + n])
                    await w.drain()
                    i += n
                    if rng.random() < 0.05:
                        await asyncio.sleep(0.001)
                await recv
                w.close()
                stats = proxy.connections[0]
                assert stats.bytes_up == stats.bytes_down == len(data)
                return bytes(back)

    assert run(main()) == data


def test_measured_delays_follow_the_configured_asymmetric_distribution() -> None:
    up = LinkProfile(delay_s=0.004, jitter_s=0.003, jitter="exponential")
    down = LinkProfile(delay_s=0.001, jitter_s=0.001, jitter="exponential")
    n, gap = 120, 0.02  # messages far enough apart that none waits behind another

    async def main() -> tuple[np.ndarray, np.ndarray, FaultProxy]:
        loop = asyncio.get_running_loop()
        async with (
            Target(echo=True) as target,
            FaultProxy("127.0.0.1", target.port, up=up, down=down, seed=5) as proxy,
        ):
            r, w = await asyncio.open_connection("127.0.0.1", proxy.port)
            sent, back = [], []
            for k in range(n):
                sent.append(loop.time())
                w.write(k.to_bytes(4, "big"))
                await w.drain()
                assert await r.readexactly(4) == k.to_bytes(4, "big")
                back.append(loop.time())
                await asyncio.sleep(gap)
            w.close()
            one_way = np.array([t for t, _ in target.arrivals]) - np.array(sent)
            return one_way, np.array(back) - np.array(sent), proxy

    one_way, rtt, proxy = run(main())  # type: ignore[misc]
    assert one_way.size == n  # every message was its own chunk
    # The proxy's own delays follow the draws of its seeded streams exactly, plus the event
    # loop's wake-up latency (epoll rounds timeouts up to 1 ms; a loaded machine adds more).
    rng = np.random.default_rng(np.random.SeedSequence([5, 0]).spawn(2)[0])
    drawn = np.array([up.delay_s + up.draw_jitter(rng) for _ in range(n)])
    late = np.array(proxy.connections[0].delays_up_s) - drawn
    assert (late > -1e-4).all()  # never early (0.1 ms: clock reads)
    assert np.median(late) < 0.003  # 3 ms: timer rounding plus scheduling on a busy machine
    # end to end: mean one-way 7 ms up, round trip 7 + 2 ms, within 3 ms of wake-up latency
    assert 0.007 <= one_way.mean() < 0.010
    assert 0.009 <= rtt.mean() < 0.014
    assert one_way.min() >= 0.004  # the fixed delay always holds


def test_cut_after_bytes_delivers_them_then_closes_both_sides() -> None:
    async def main() -> None:
        async with Target() as target:
            cut = LinkProfile(cut_after_bytes=1234)
            async with FaultProxy("127.0.0.1", target.port, up=cut) as proxy:
                r, w = await asyncio.open_connection("127.0.0.1", proxy.port)
                w.write(bytes(range(256)) * 40)  # 10240 bytes
                await w.drain()
                await asyncio.wait_for(target.closed.wait(), 5)  # the target's side is closed
                with pytest.raises((ConnectionError, asyncio.IncompleteReadError)):
                    await asyncio.wait_for(r.readexactly(1), 5)  # and the client's
                assert bytes(target.received) == (bytes(range(256)) * 40)[:1234]
                assert proxy.connections[0].cut == "cut after 1234 bytes up"
                w.close()

    run(main())


def test_cut_at_a_time_limited_to_the_first_connection_and_on_request() -> None:
    async def main() -> None:
        async with (
            Target(echo=True) as target,
            FaultProxy("127.0.0.1", target.port, cut_after_s=0.2, max_cuts=1) as p,
        ):
            loop = asyncio.get_running_loop()
            t0 = loop.time()
            r, w = await asyncio.open_connection("127.0.0.1", p.port)
            with pytest.raises((ConnectionError, asyncio.IncompleteReadError)):
                await asyncio.wait_for(r.readexactly(1), 5)
            assert 0.19 <= loop.time() - t0 < 2.0
            assert p.connections[0].cut == "cut 0.2 s after it was accepted"
            # the reconnect goes through and stays up past the cut time
            r2, w2 = await asyncio.open_connection("127.0.0.1", p.port)
            await asyncio.sleep(0.4)
            w2.write(b"still here")
            assert await asyncio.wait_for(r2.readexactly(10), 5) == b"still here"
            p.cut()  # and a cut on request closes it
            with pytest.raises((ConnectionError, asyncio.IncompleteReadError)):
                await asyncio.wait_for(r2.readexactly(1), 5)
            assert p.connections[1].cut == "cut on request"
            for x in (w, w2):
                x.close()

    run(main())


def test_a_clean_close_passes_through_and_the_thread_runner_works() -> None:
    async def target_main(port_box: list[int], done: asyncio.Event) -> None:
        async with Target(echo=True) as target:
            port_box.append(target.port)
            await done.wait()

    import socket
    import threading

    loop = asyncio.new_event_loop()
    box: list[int] = []
    done = asyncio.Event()
    th = threading.Thread(target=lambda: loop.run_until_complete(target_main(box, done)))
    th.start()
    try:
        for _ in range(200):
            if box:
                break
            threading.Event().wait(0.01)
        with ProxyThread() as pt:
            proxy = pt.add("127.0.0.1", box[0], up=LinkProfile(delay_s=0.002))
            with socket.create_connection(("127.0.0.1", proxy.port), timeout=5) as s:
                s.sendall(b"hello")
                got = b""
                while len(got) < 5:
                    got += s.recv(5)
                assert got == b"hello"
                s.shutdown(socket.SHUT_WR)  # a FIN from the client reaches the target ...
                assert s.recv(10) == b""  # ... which closes, and its FIN comes back
            for _ in range(200):
                if proxy.connections[0].closed:
                    break
                threading.Event().wait(0.01)
            assert proxy.connections[0].closed and proxy.connections[0].cut is None
    finally:
        loop.call_soon_threadsafe(done.set)
        th.join(10)
        loop.close()


def test_the_proxy_command_forwards_and_stops_cleanly_on_sigint() -> None:
    import re
    import signal
    import socket
    import subprocess
    import sys
    import threading

    srv = socket.create_server(("127.0.0.1", 0))

    def echo_once() -> None:
        c, _ = srv.accept()
        with c:
            while data := c.recv(65536):
                c.sendall(data)

    threading.Thread(target=echo_once, daemon=True).start()
    port = srv.getsockname()[1]
    cmd = [sys.executable, "-m", "kinefuse", "proxy", "--target", f"127.0.0.1:{port}"]
    cmd += ["--up-delay-ms", "5", "--down-jitter-ms", "2", "--seed", "3"]
    p = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert p.stdout is not None
        first = p.stdout.readline()
        m = re.match(r"kinefuse proxy: listening on 127\.0\.0\.1:(\d+) -> 127\.0\.0\.1:\d+", first)
        assert m, first
        with socket.create_connection(("127.0.0.1", int(m[1])), timeout=10) as s:
            s.sendall(b"through the proxy")
            got = b""
            while len(got) < 17:
                got += s.recv(100)
        assert got == b"through the proxy"
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=10)
        assert p.returncode == 0, err
        assert "connection 0: 17 bytes up, 17 bytes down" in out
    finally:
        if p.poll() is None:
            p.kill()
        srv.close()
