"""Hostile and careless peers on the viewer/API port (``docs/security.md``), on real sockets.

A flood of half-sent requests against ``kinefuse serve`` running under a descriptor limit of 256
(a sensor still connects, a new page is served once the flood is cut, stderr stays a few
lines); the header deadline; the per-address cap; a DNS-rebinding ``Host``; an ``https://``
Origin; a subscriber that sees the recording's file name only. Closures and refusals are
checked, never the fusion's timing (``benchmarks/bench_hostile.py`` measures that). Every wait
is bounded.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

import aiohttp

import test_server_safety as safety
from kinefuse.live.bus import Publisher
from kinefuse.live.protocol import Welcome
from kinefuse.live.viewer import live_viewer
from kinefuse.live.viewer.subscription_api import API_PATH

ROOT = Path(__file__).resolve().parents[1]
_VIEWER = re.compile(r"viewer at http://127\.0\.0\.1:(\d+)/")
HALF_SENT = "GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Unfinished: a"  # no end of line


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("KINEFUSE_TOKEN", None)
    return env


def _start_serve(tmp_path: Path, *args: str, nofile: int | tuple[int, int] | None = None):
    """``kinefuse serve --port 0 --viewer-port 0 ARGS`` (under a descriptor limit of ``nofile``,
    soft and hard, or ``(soft, hard)``); (process, sensor port, viewer port, stderr file)."""

    def lower() -> None:
        if nofile is not None:
            limit = nofile if isinstance(nofile, tuple) else (nofile, nofile)
            resource.setrlimit(resource.RLIMIT_NOFILE, limit)

    err = tmp_path / "serve.stderr"
    p = subprocess.Popen(
        [sys.executable, "-m", "kinefuse", "serve", "--port", "0", "--viewer-port", "0", *args],
        stdout=subprocess.PIPE,
        stderr=err.open("wb"),
        text=True,
        env=_env(),
        cwd=tmp_path,
        preexec_fn=lower,
    )
    assert p.stdout is not None
    first, second = p.stdout.readline(), p.stdout.readline()
    m = _VIEWER.search(second)
    assert first.startswith("kinefuse serve: listening on") and m, (first, second, err.read_text())
    return p, int(first.rsplit(":", 1)[1]), int(m.group(1)), err


def _stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.send_signal(2)
        try:
            p.wait(20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(10)


async def _open(port: int, source: str = "127.0.0.1"):
    return await asyncio.wait_for(
        asyncio.open_connection("127.0.0.1", port, local_addr=(source, 0)), 5.0
    )


async def _closed_within(reader: asyncio.StreamReader, seconds: float) -> float | None:
    """Seconds until the server closes the connection (reading all it sends); None if open."""
    t0 = time.monotonic()
    try:
        while True:
            left = seconds - (time.monotonic() - t0)
            if left <= 0 or not await asyncio.wait_for(reader.read(65536), left):
                break
    except (ConnectionError, OSError):
        pass
    except TimeoutError:
        return None
    took = time.monotonic() - t0
    return took if took < seconds else None


async def _half_sent(port: int, source: str = "127.0.0.1"):
    """A connection with a request that never ends; None if it was reset as it was made (or
    its SYN dropped all along: the listen queue is short on purpose)."""
    try:
        r, w = await _open(port, source)
    except (ConnectionError, TimeoutError):
        return None
    w.write(HALF_SENT.format(port=port).encode())
    return r, w


async def _all_closed_within(conns: list, seconds: float) -> list[float | None]:
    """:func:`_closed_within` of each of ``conns`` (0 for one reset as it was made), then
    each is closed."""

    async def one(c) -> float | None:
        return 0.0 if c is None else await _closed_within(c[0], seconds)

    out = await asyncio.gather(*(one(c) for c in conns))
    for c in conns:
        if c is not None:
            c[1].close()
    return list(out)


async def _request(
    port: int, path: str = "/", *, host: str | None = None, extra: str = "", source="127.0.0.1"
) -> tuple[int, str]:
    """One HTTP/1.1 request on a new connection: (status, body)."""
    r, w = await _open(port, source)
    host = host if host is not None else f"127.0.0.1:{port}"
    w.write(f"GET {path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n{extra}\r\n".encode())
    head = await asyncio.wait_for(r.readuntil(b"\r\n\r\n"), 5.0)
    status = int(head.split(b" ", 2)[1])
    body = b"" if status == 101 else await asyncio.wait_for(r.read(), 5.0)
    w.close()
    return status, body.decode(errors="replace")


def _upgrade(origin: str | None = None) -> str:
    key = base64.b64encode(os.urandom(16)).decode()
    return (
        f"Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
        "Sec-WebSocket-Version: 13\r\n" + (f"Origin: {origin}\r\n" if origin else "")
    )


def test_a_flood_under_a_low_descriptor_limit_leaves_sensors_and_new_pages_served(
    tmp_path,
) -> None:
    """600 half-sent requests from ten addresses against a server limited to 256 descriptors:
    those above the caps are reset at accept, the rest cut at the 5 s header deadline; a sensor
    connects during the flood, a new page is served after it, and stderr holds a few lines
    (it used to run out of descriptors, refuse the sensor and log a traceback per accept)."""
    p, port, viewer_port, err = _start_serve(tmp_path, nofile=256)

    async def body():
        flood = []
        for k in range(0, 600, 50):
            more = (_half_sent(viewer_port, f"127.0.0.{2 + j % 10}") for j in range(k, k + 50))
            flood += await asyncio.gather(*more)
        t_flood = time.monotonic()
        sensor = safety.Peer(*await _open(port))
        welcome = await asyncio.wait_for(sensor.hello("k0", token=None), 5.0)
        sensor.w.close()
        closed = await _all_closed_within(flood, 12.0)
        after = time.monotonic() - t_flood
        page = await _request(viewer_port)
        return welcome, closed, after, page

    try:
        welcome, closed, after, page = asyncio.run(body())
        time.sleep(0.5)
    finally:
        _stop(p)
    assert isinstance(welcome, Welcome), welcome
    assert all(c is not None for c in closed), f"{closed.count(None)} of 600 still open"
    early = sum(1 for c in closed if c is not None and c < 1.0)
    assert early >= 600 - 128 - 20  # above the cap (256 - a reserve of 128): reset at once
    assert after < 12.0  # and the others at the deadline
    assert page[0] == 200 and "/static/viewer.js" in page[1]
    log = err.read_text()
    assert len(log) < 4000, log[:2000]
    assert "Traceback" not in log and "refused at accept" in log, log


def test_the_server_raises_its_descriptor_limit_to_the_hard_limit(tmp_path) -> None:
    p, _port, _viewer_port, _err = _start_serve(tmp_path, nofile=(256, 2048))
    try:
        limits = Path(f"/proc/{p.pid}/limits").read_text()
    finally:
        _stop(p)
    line = next(x for x in limits.splitlines() if x.startswith("Max open files"))
    assert line.split()[3:5] == ["2048", "2048"], line


def test_accept_failures_are_counted_in_one_line_not_a_traceback_each(tmp_path) -> None:
    """A server whose caps exceed what its descriptors allow (here on purpose: no reserve, a
    limit of 64) fails accepts; they are logged once per interval with a count."""
    code = f"""
import asyncio, logging, resource, sys
sys.path.insert(0, {str(ROOT / "src")!r})
from kinefuse.live.bus import Publisher
from kinefuse.live.viewer import live_viewer
from kinefuse.live.viewer.port_limits import PortLimits
logging.basicConfig(stream=sys.stderr, format="%(message)s")
resource.setrlimit(resource.RLIMIT_NOFILE, (64, 64))
async def main():
    limits = PortLimits(max_connections=1000, max_per_address=1000, fd_reserve=0)
    async with live_viewer(Publisher(), port=0, limits=limits) as port:
        print(port, flush=True)
        await asyncio.sleep(4.0)
asyncio.run(main())
"""
    err = tmp_path / "stderr"
    p = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=err.open("wb"), text=True
    )
    try:
        assert p.stdout is not None
        port = int(p.stdout.readline())

        async def flood():
            conns = [await _half_sent(port) for _ in range(150)]
            await asyncio.sleep(3.0)
            for c in conns:
                if c is not None:
                    c[1].close()

        asyncio.run(flood())
        assert p.wait(20) == 0
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(10)
    log = err.read_text()
    assert "Traceback" not in log and len(log.splitlines()) <= 4, log[:2000]
    assert re.search(r"accepts failed for want of descriptors.*: \d+ in the last", log), log


def test_headers_have_a_deadline_however_slowly_they_trickle_in() -> None:
    """A request sent a byte every 0.3 s (each well within any idle timeout) is closed at the
    5 s header deadline; so are a WebSocket upgrade left unfinished and an idle kept-alive
    connection; a whole request is served."""

    async def run():
        async with live_viewer(Publisher(), port=0) as port:
            r, w = await _open(port)
            request = f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n" + "X-Slow: " + "a" * 100

            async def dribble() -> None:
                for b in request.encode():
                    if w.is_closing():
                        return
                    w.write(bytes([b]))
                    await asyncio.sleep(0.3)

            task = asyncio.ensure_future(dribble())
            # and a WebSocket upgrade (the API's handshake) whose last header never ends
            r1, w1 = await _open(port)
            upgrade = f"GET {API_PATH} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n" + _upgrade()
            w1.write(upgrade.encode() + b"X-Never: ends")
            both = _closed_within(r, 9.0), _closed_within(r1, 9.0)
            slow, upgrade_cut = await asyncio.gather(*both)
            task.cancel()
            # a served request, then nothing more on the kept-alive connection
            r2, w2 = await _open(port)
            w2.write(f"GET /static/viewer.css HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
            head = await asyncio.wait_for(r2.readuntil(b"\r\n"), 5.0)
            idle = await _closed_within(r2, 9.0)
            return slow, upgrade_cut, head, idle

    slow, upgrade_cut, head, idle = asyncio.run(run())
    assert slow is not None and 4.5 < slow < 7.0, slow  # used to stay open for an hour
    assert upgrade_cut is not None and 4.5 < upgrade_cut < 7.0, upgrade_cut
    assert b" 200 " in head
    assert idle is not None and 4.5 < idle < 7.0, idle


def test_connections_above_the_per_address_cap_are_reset_at_once() -> None:
    """70 connections from one address: 64 are taken, 6 reset as they are accepted; another
    address is still served."""

    async def run():
        async with live_viewer(Publisher(), port=0) as port:
            conns = [await _half_sent(port) for _ in range(70)]
            await asyncio.sleep(0.5)
            other = await _request(port, source="127.0.0.2")
            return await _all_closed_within(conns, 1.5), other

    closed, other = asyncio.run(run())
    assert sum(c is not None for c in closed) == 6, closed
    assert other[0] == 200


def test_a_rebinding_host_is_refused_and_the_servers_own_names_are_served() -> None:
    """A page on another site whose name now points at 127.0.0.1 sends that name as ``Host``
    (and as ``Origin``): refused with 403 and a reason, on the page, the API and ``/ws``; the
    loopback names, the bind address and the names given are served."""

    async def run():
        pub = Publisher()
        async with live_viewer(pub, port=0, allowed_hosts=("mylab.example",)) as port:
            evil = f"rebind.evil.example:{port}"
            out = {"page": await _request(port, host=evil)}
            for path in (API_PATH, "/ws"):
                extra = _upgrade(origin=f"http://{evil}")
                out[path] = await _request(port, path, host=evil, extra=extra)
            for name in ("localhost", "127.0.0.1", "[::1]", "LOCALHOST.", "mylab.example"):
                out[name] = await _request(port, host=f"{name}:{port}")
            out["bad"] = await _request(port, host="a b")
            good = _upgrade(origin=f"http://localhost:{port}")
            out["api ok"] = await _request(port, API_PATH, host=f"localhost:{port}", extra=good)
            return out

    out = asyncio.run(run())
    for what in ("page", API_PATH, "/ws"):
        status, text = out[what]
        assert status == 403 and "does not answer to the name 'rebind.evil.example'" in text
        assert "--allow-host" in text
    for name in ("localhost", "127.0.0.1", "[::1]", "LOCALHOST.", "mylab.example"):
        assert out[name][0] == 200, (name, out[name])
    assert out["bad"][0] == 403 and "not a host name" in out["bad"][1]
    assert out["api ok"][0] == 101


def test_an_origin_is_compared_by_scheme_host_and_port() -> None:
    async def run():
        out = {}
        async with live_viewer(Publisher(), port=0) as port, aiohttp.ClientSession() as http:
            for origin in (
                f"https://127.0.0.1:{port}",  # an https page is another origin
                f"http://127.0.0.1:{port + 1}",
                "http://127.0.0.1",
                "null",
                f"http://127.0.0.1:{port}",
            ):
                for path in (API_PATH, "/ws"):
                    try:
                        url = f"ws://127.0.0.1:{port}{path}"
                        async with http.ws_connect(url, headers={"Origin": origin}):
                            out[origin, path] = 101
                    except aiohttp.WSServerHandshakeError as e:
                        out[origin, path] = e.status
            return port, out

    port, out = asyncio.run(run())
    for path in (API_PATH, "/ws"):
        assert out[f"https://127.0.0.1:{port}", path] == 403  # used to be accepted
        assert out[f"http://127.0.0.1:{port + 1}", path] == 403
        assert out["http://127.0.0.1", path] == 403
        assert out["null", path] == 403
        assert out[f"http://127.0.0.1:{port}", path] == 101


def test_subscribers_see_the_recordings_file_name_not_its_path(tmp_path) -> None:
    rec = tmp_path / "takes" / "rec.sqlite"
    rec.parent.mkdir()
    p, _port, viewer_port, err = _start_serve(tmp_path, "--record", str(rec))

    async def first_status() -> dict:
        url = f"ws://127.0.0.1:{viewer_port}{API_PATH}"
        async with aiohttp.ClientSession() as http, http.ws_connect(url) as ws:
            assert (await ws.receive_json(timeout=5.0))["type"] == "hello"
            assert (await ws.receive_json(timeout=5.0))["type"] == "welcome"
            while True:
                msg = json.loads((await ws.receive(timeout=5.0)).data)
                if msg["type"] == "status":
                    return msg

    try:
        status = asyncio.run(first_status())
    finally:
        _stop(p)
    assert status["recording"] == "rec.sqlite", status["recording"]  # not the absolute path
    assert "Traceback" not in err.read_text()


def test_allow_host_needs_the_viewer_and_a_host_name(tmp_path) -> None:
    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            [sys.executable, "-m", "kinefuse", "serve", "--port", "0", *args],
            capture_output=True,
            text=True,
            env=_env(),
            cwd=tmp_path,
            timeout=60,
        )

    alone = run("--allow-host", "mylab.example")
    bad = run("--viewer-port", "0", "--allow-host", "http://mylab.example/")
    assert alone.returncode == 2 and "give --viewer-port too" in alone.stderr
    assert bad.returncode == 2 and "is not a host name or an IP address" in bad.stderr
    assert "Traceback" not in alone.stderr + bad.stderr
