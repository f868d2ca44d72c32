"""The live subscription API: a versioned WebSocket for third-party programs (``docs/api.md``).

``GET /api/v1/stream[?format=json|binary][&people=subject|all]`` on the viewer's HTTP server
(``kinefuse serve --viewer-port``) upgrades to a WebSocket that carries, after an optional token
handshake, a ``welcome``, then every published status (per-sensor state and calibration poses) as
JSON and every fused frame as JSON or as the viewer's compact binary frame
(:mod:`kinefuse.live.viewer.wire`): the subject's, and with ``people=all`` every person's besides.

Each subscriber has a lossy subscription on the server's publisher (the newest 2 items): a slow
one skips frames and fusion never waits. One whose socket accepts nothing for
:data:`STALL_LIMIT_S` (its send buffer is capped at :data:`SEND_BUFFER_BYTES`) is disconnected
with a TCP reset, so that neither its buffers nor an orphaned socket outlive it.
Cross-origin WebSockets are refused (the ``Origin`` header, when a browser sends one, must be
this server: :meth:`~kinefuse.live.viewer.port_limits.HostNames.origin_error`), here and on the
viewer's ``/ws``.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import hashlib
import hmac
import json
import math
import secrets
import socket
import struct
import termios
import time
from typing import Any

from aiohttp import WSMsgType, web

from kinefuse.core.skeleton import JOINTS
from kinefuse.live.bus import FusedFrame, Publisher, Status
from kinefuse.live.viewer.port_limits import HostNames, reset
from kinefuse.live.viewer.wire import fused_frame_bytes, status_message

API_NAME = "kinefuse-live"
API_VERSION = 1
API_PATH = f"/api/v{API_VERSION}/stream"
FORMATS = ("json", "binary")
#: ``?people=``: the subject only (default), or every person besides
PEOPLE = ("subject", "all")
#: a subscriber whose socket takes nothing for this long is disconnected (close code 4408)
STALL_LIMIT_S = 5.0
#: how often the stall watchdog looks at a subscriber's send buffer
STALL_POLL_S = 0.25
#: the kernel send buffer of each subscriber's socket: a stalled reader blocks sends soon
SEND_BUFFER_BYTES = 64 * 1024
#: the client must answer the token challenge within this time
AUTH_TIMEOUT_S = 10.0
#: close codes (the reason is also sent first as an ``error`` message when possible)
CLOSE_UNAUTHORIZED = 4401
CLOSE_MALFORMED = 4400
CLOSE_TOO_SLOW = 4408


def api_mac(token: str, nonce: str) -> str:
    """The answer to a challenge: hex HMAC-SHA256 keyed by the token over
    ``"kinefuse-live/1|" + nonce`` (the token itself never crosses the wire)."""
    msg = f"{API_NAME}/{API_VERSION}|{nonce}".encode()
    return hmac.new(token.encode(), msg, hashlib.sha256).hexdigest()


async def check_token(ws: web.WebSocketResponse, token: str | None, nonce: str) -> str | None:
    """Read the client's ``auth`` message; None when it proves the token, else the error."""
    if token is None:
        return None
    try:
        msg = await ws.receive(timeout=AUTH_TIMEOUT_S)
    except TimeoutError:
        return "malformed: no auth message within the time limit"
    if msg.type != WSMsgType.TEXT:
        return "malformed: the first message must be a JSON auth message"
    try:
        auth = json.loads(msg.data)
    except ValueError:
        return "malformed: the auth message is not JSON"
    if not isinstance(auth, dict) or auth.get("type") != "auth":
        return 'malformed: expected {"type": "auth", "mac": ...} or {"type": "auth", "token": ...}'
    mac, bearer = auth.get("mac"), auth.get("token")
    if isinstance(mac, str) and hmac.compare_digest(mac, api_mac(token, nonce)):
        return None
    if isinstance(bearer, str) and hmac.compare_digest(bearer.encode(), token.encode()):
        return None
    return "unauthorized: wrong token"


async def refuse(ws: web.WebSocketResponse, error: str) -> None:
    """Send an ``error`` message and close with the matching code."""
    code = CLOSE_UNAUTHORIZED if error.startswith("unauthorized") else CLOSE_MALFORMED
    with contextlib.suppress(ConnectionError, RuntimeError):
        await ws.send_str(json.dumps({"type": "error", "error": error}))
        await ws.close(code=code, message=error[:100].encode())


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else round(float(x), 6)


def _points(positions_m: Any) -> list[list[float] | None]:
    return [
        [round(float(v), 6) for v in p] if bool(all(math.isfinite(v) for v in p)) else None
        for p in positions_m
    ]


def frame_message(frame: FusedFrame, *, people: bool = False) -> dict[str, Any]:
    """A fused frame as JSON: the subject's positions in metres (world, z up; null = not
    solved); with ``people``, also the subject's id and every person's positions by id."""
    out = {
        "type": "frame",
        "seq": frame.seq,
        "t_server_s": frame.t_server_s,
        "positions_m": _points(frame.positions_m),
        "status": [int(s) for s in frame.status],
        "latency_ms": _num(frame.latency_s * 1e3),
    }
    if people:
        out["subject"] = frame.subject
        out["people_m"] = {str(p): _points(pos) for p, pos in sorted(frame.people_m.items())}
    return out


def unsent_bytes(sock: Any) -> int:
    """Bytes the kernel still holds to send on ``sock`` (Linux ``SIOCOUTQ``; 0 if unknown)."""
    try:
        buf = fcntl.ioctl(sock.fileno(), termios.TIOCOUTQ, b"\0\0\0\0")
    except (OSError, ValueError):
        return 0
    return int(struct.unpack("i", buf)[0])


class Stalled(Exception):
    """The subscriber's socket accepted nothing for :data:`STALL_LIMIT_S`."""


async def watch_stall(transport: Any, limit_s: float = STALL_LIMIT_S) -> None:
    """Return never; raise :class:`Stalled` once the transport's send buffer has been non-empty
    without shrinking for ``limit_s`` (its socket's kernel buffer full all that time)."""
    last, progress = 0, time.monotonic()
    while True:
        await asyncio.sleep(STALL_POLL_S)
        size = transport.get_write_buffer_size()
        now = time.monotonic()
        if size == 0 or size < last:
            progress = now
        elif now - progress >= limit_s:
            raise Stalled(f"accepted nothing for {now - progress:.1f} s")
        last = size


def api_handler(publisher: Publisher, token: str | None, *, maxsize: int = 2) -> Any:
    """The aiohttp handler of :data:`API_PATH` on ``publisher``."""

    async def handler(request: web.Request) -> web.StreamResponse:
        refusal = HostNames.origin_error(request.headers.get("Origin"), request.headers.get("Host"))
        if refusal is not None:
            raise web.HTTPForbidden(text=refusal)
        fmt = request.query.get("format", "json")
        if fmt not in FORMATS or set(request.query) - {"format", "people"}:
            raise web.HTTPBadRequest(text=f"format must be one of {', '.join(FORMATS)}")
        who = request.query.get("people", "subject")
        if who not in PEOPLE:
            raise web.HTTPBadRequest(text=f"people must be one of {', '.join(PEOPLE)}")
        every = who == "all"
        # no heartbeat: its close of a peer that does not answer is a graceful one, which leaves
        # the socket to the kernel with the queued frames; the stall watchdog cuts it instead
        ws = web.WebSocketResponse(max_msg_size=1 << 14)
        await ws.prepare(request)
        transport = request.transport
        sock = transport.get_extra_info("socket") if transport is not None else None
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        nonce = secrets.token_hex(16)
        await ws.send_str(json.dumps({
            "type": "hello", "api": API_NAME, "version": API_VERSION,
            "auth": "hmac-sha256" if token is not None else "none", "nonce": nonce,
        }))  # fmt: skip
        error = await check_token(ws, token, nonce)
        if error is not None:
            await refuse(ws, error)
            return ws
        await ws.send_str(json.dumps({
            "type": "welcome", "api": API_NAME, "version": API_VERSION, "format": fmt,
            "joints": list(JOINTS), "stall_limit_s": STALL_LIMIT_S,
        }))  # fmt: skip
        sub = publisher.subscribe(maxsize=maxsize)

        async def read() -> None:
            async for _msg in ws:  # nothing to say after auth; reading notices the close
                pass
            sub.close()

        async def send() -> None:
            async for item in sub:
                async with asyncio.timeout(STALL_LIMIT_S):  # a send blocked that long: cut
                    if isinstance(item, Status):
                        await ws.send_str(json.dumps(status_message(item)))
                    elif fmt == "json":
                        await ws.send_str(json.dumps(frame_message(item, people=every)))
                    else:
                        await ws.send_bytes(fused_frame_bytes(item, people=every))
            await ws.close()

        stalled = False
        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(read())
                sending = tg.create_task(send())
                watchdog = tg.create_task(watch_stall(transport)) if transport else None
                await sending
                if watchdog is not None:
                    watchdog.cancel()
        except* (TimeoutError, Stalled):  # the subscriber stopped reading: cut it off
            stalled = True
        except* (ConnectionResetError, ConnectionError):
            pass
        finally:
            sub.close()
            # never leave queued frames to a peer that does not read them
            if transport is not None and (
                stalled or transport.get_write_buffer_size() > 0 or unsent_bytes(sock) > 0
            ):
                reset(transport, sock)
        return ws

    return handler
