"""The viewer's web server: the page, its static files and one WebSocket, over aiohttp.

Two data sources sit behind one small interface (:class:`Source`): :class:`LiveSource` follows a
:class:`~kinefuse.live.bus.Publisher` (the live server), :class:`~kinefuse.live.viewer.replay.
ReplaySource` plays a recorded session. Each WebSocket connection gets its own
``Source.serve`` call; the server only moves bytes.

The live path never slows the publisher: each page has a lossy subscription of ``maxsize``
items, so a page (or a network) that falls behind skips frames instead of queueing them, and
``Publisher.publish`` stays a few appends.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import secrets
import socket
import weakref
from collections.abc import AsyncIterator, Callable, Iterable
from importlib import resources
from typing import Any, Protocol

from aiohttp import WSMsgType, web

from kinefuse.live.bus import FusedFrame, Publisher, Status
from kinefuse.live.viewer.port_limits import (
    Admission,
    Guarded,
    HostNames,
    PortLimits,
    capacity,
    raise_descriptor_limit,
    reset,
)
from kinefuse.live.viewer.wire import fused_frame_bytes, hello_message, status_message

#: Default host: loopback only (a viewer shows a lab's capture; exposing it is a choice).
DEFAULT_HOST = "127.0.0.1"
#: the port's default caps and header deadline (``docs/security.md``)
DEFAULT_LIMITS = PortLimits()

_STATIC = ("index.html", "viewer.css", "viewer.js")
_TYPES = {".html": "text/html", ".css": "text/css", ".js": "text/javascript"}


class Source(Protocol):
    """What the server needs of a data source."""

    def hello(self) -> dict[str, Any]:
        """The ``hello`` message sent first on every connection."""
        ...

    async def serve(self, ws: web.WebSocketResponse) -> None:
        """Send to ``ws`` (and read its commands) until it closes or the source ends."""
        ...


class LiveSource:
    """Frames and status from a live :class:`Publisher`, one lossy subscription per page.

    Parameters
    ----------
    publisher : Publisher
    maxsize : int
        Items a page's subscription keeps while the page is busy (older ones are dropped).
    method : str
        Name shown for the fused layer.
    on_subject : callable, optional
        Called with a person id when the operator makes that person the subject (the page's
        ``{"cmd": "subject", "person": ID}``); without it the command is ignored.
    """

    def __init__(
        self,
        publisher: Publisher,
        *,
        maxsize: int = 2,
        method: str = "fused",
        on_subject: Callable[[int], object] | None = None,
    ) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize}")
        self.publisher = publisher
        self.maxsize = maxsize
        self.method = method
        self.on_subject = on_subject
        #: frames the pages skipped because they fell behind (sum over closed connections)
        self.dropped = 0

    def hello(self) -> dict[str, Any]:
        return hello_message("live")

    async def serve(self, ws: web.WebSocketResponse) -> None:
        sub = self.publisher.subscribe(maxsize=self.maxsize)

        async def read() -> None:
            # the one live command: the operator picks the subject; reading notices the close
            async for cmd in read_commands(ws):
                person = cmd.get("person")
                pick = cmd.get("cmd") == "subject" and isinstance(person, int)
                ok = isinstance(person, int) and not isinstance(person, bool) and person >= 0
                if pick and ok and isinstance(person, int) and self.on_subject:
                    self.on_subject(person)
            sub.close()

        async def send() -> None:
            sent: Status | None = None
            async for item in sub:
                if isinstance(item, Status):
                    if item is not sent:  # not already sent ahead of a frame
                        await ws.send_str(json.dumps(status_message(item)))
                        sent = item
                    continue
                assert isinstance(item, FusedFrame)
                last = self.publisher.last_status  # a lagging page may have lost it in the queue
                if last is not None and last is not sent:
                    await ws.send_str(json.dumps(status_message(last)))
                    sent = last
                await ws.send_bytes(fused_frame_bytes(item, method=self.method, people=True))
            await ws.close()  # the publisher closed

        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(read())
                tg.create_task(send())
        except* (ConnectionResetError, ConnectionError):
            pass  # the page went away mid-send
        finally:
            sub.close()
            self.dropped += sub.dropped


def make_app(
    source: Source,
    *,
    token: str | None = None,
    publisher: Publisher | None = None,
    names: HostNames | None = None,
) -> web.Application:
    """The aiohttp application: ``/`` (the page), ``/static/*``, ``/ws``, and with a live
    ``publisher`` the subscription API (:mod:`kinefuse.live.viewer.subscription_api`). A request
    whose ``Host`` is not one of ``names`` (default: those of a loopback server) is refused with
    403, and so is a WebSocket from another origin; with a ``token`` the page's ``/ws`` asks for it
    first (``auth_required`` with a nonce; the page answers with the HMAC or the token itself,
    ``docs/api.md``)."""
    from kinefuse.live.viewer.subscription_api import (
        API_PATH,
        SEND_BUFFER_BYTES,
        Stalled,
        api_handler,
        check_token,
        refuse,
        unsent_bytes,
        watch_stall,
    )

    app = web.Application(middlewares=[_guard(names or HostNames.of(DEFAULT_HOST))])
    sockets: weakref.WeakSet[web.WebSocketResponse] = weakref.WeakSet()
    files = {name: (resources.files("kinefuse.live.viewer") / "static" / name) for name in _STATIC}

    async def page(_request: web.Request) -> web.Response:
        return _file_response(files["index.html"].read_bytes(), "index.html")

    async def static(request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in files:
            raise web.HTTPNotFound()
        return _file_response(files[name].read_bytes(), name)

    async def websocket(request: web.Request) -> web.WebSocketResponse:
        refusal = HostNames.origin_error(request.headers.get("Origin"), request.headers.get("Host"))
        if refusal is not None:
            raise web.HTTPForbidden(text=refusal)
        # the heartbeat finds a page whose peer vanished while nothing is sent (a paused
        # replay); a page that stops reading while frames flow is cut by the API's stall rule
        # first (docs/api.md): a reset, so no orphaned socket keeps its queued frames
        ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=1 << 16)
        await ws.prepare(request)
        transport = request.transport
        sock = transport.get_extra_info("socket") if transport is not None else None
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        sockets.add(ws)

        async def page_session() -> None:
            if token is not None:
                nonce = secrets.token_hex(16)
                await ws.send_str(json.dumps({"type": "auth_required", "nonce": nonce}))
                error = await check_token(ws, token, nonce)
                if error is not None:
                    await refuse(ws, error)
                    return
            await ws.send_str(json.dumps(source.hello()))
            await source.serve(ws)

        stalled = False
        try:
            async with asyncio.TaskGroup() as tg:
                serving = tg.create_task(page_session())
                watchdog = tg.create_task(watch_stall(transport)) if transport else None
                await serving
                if watchdog is not None:
                    watchdog.cancel()
        except* (TimeoutError, Stalled):
            stalled = True
        except* (ConnectionResetError, ConnectionError):
            pass
        finally:
            sockets.discard(ws)
            if transport is not None and (
                stalled or transport.get_write_buffer_size() > 0 or unsent_bytes(sock) > 0
            ):
                reset(transport, sock)
        return ws

    async def close_sockets(_app: web.Application) -> None:
        for ws in list(sockets):
            await ws.close(code=1001, message=b"server stopping")

    app.router.add_get("/", page)
    app.router.add_get("/static/{name}", static)
    app.router.add_get("/ws", websocket)
    if publisher is not None:
        app.router.add_get(API_PATH, api_handler(publisher, token))
    app.on_shutdown.append(close_sockets)
    return app


def _guard(names: HostNames) -> Any:
    """The middleware every request passes: its connection's header deadline is stopped while
    it is answered (and started again for the next request on the connection), and a ``Host``
    the server does not answer to is refused (DNS rebinding)."""

    @web.middleware
    async def guard(request: web.Request, handler: Any) -> web.StreamResponse:
        transport = request.transport
        conn = transport.get_protocol() if transport is not None else None
        if isinstance(conn, Guarded):
            conn.disarm()
        try:
            refusal = names.host_error(request.headers.get("Host"))
            if refusal is not None:
                raise web.HTTPForbidden(text=refusal)
            return await handler(request)
        finally:
            if isinstance(conn, Guarded):
                conn.arm()

    return guard


def _file_response(body: bytes, name: str) -> web.Response:
    ext = name[name.rfind(".") :]
    return web.Response(body=body, content_type=_TYPES[ext], headers={"Cache-Control": "no-store"})


@contextlib.asynccontextmanager
async def serve(
    source: Source,
    *,
    host: str = DEFAULT_HOST,
    port: int = 0,
    token: str | None = None,
    publisher: Publisher | None = None,
    allowed_hosts: Iterable[str] = (),
    limits: PortLimits = DEFAULT_LIMITS,
) -> AsyncIterator[int]:
    """Serve ``source`` on the running loop; yields the bound port; stops on exit (no access
    log: nothing a client sends is logged).

    The port is guarded (:mod:`kinefuse.live.viewer.port_limits`, ``docs/security.md``): the
    process's descriptor limit is raised to its hard limit, connections are capped (``limits``, and
    what the limit leaves after a reserve for the rest of the server), headers have a deadline, and
    requests must name the server by its bind address, a loopback name or one of
    ``allowed_hosts`` (ValueError if one is not a host name)."""
    names = HostNames.of(host, allowed_hosts)
    app = make_app(source, token=token, publisher=publisher, names=names)
    runner = web.AppRunner(app, handle_signals=False, access_log=None)
    await runner.setup()
    assert runner.server is not None
    admission = Admission(limits, capacity(limits, raise_descriptor_limit()), runner.server)
    try:
        try:
            bound = await admission.listen(host, port)
        except OSError as e:
            raise OSError(f"the viewer cannot listen on {host}:{port}: {e.strerror or e}") from None
        yield bound
    finally:
        admission.close()
        await runner.cleanup()


@contextlib.asynccontextmanager
async def live_viewer(
    publisher: Publisher,
    host: str = DEFAULT_HOST,
    port: int = 0,
    *,
    maxsize: int = 2,
    token: str | None = None,
    allowed_hosts: Iterable[str] = (),
    limits: PortLimits = DEFAULT_LIMITS,
    on_subject: Callable[[int], object] | None = None,
) -> AsyncIterator[int]:
    """Serve the live viewer of ``publisher`` on the running loop.

    ::

        async with live_viewer(publisher, host="127.0.0.1", port=0) as bound_port:
            ...  # the page is at http://127.0.0.1:{bound_port}/

    Parameters
    ----------
    publisher : Publisher
        The live server's publisher; every open page subscribes to it (lossy, ``maxsize``).
    host : str
        Interface to bind (loopback by default).
    port : int
        TCP port; 0 picks a free one.
    maxsize : int
        Items a page keeps queued while it is busy; older ones are skipped.
    token : str, optional
        The server's token: the page and the subscription API ask for it.
    allowed_hosts : iterable of str
        Names the server answers to beside its bind address and the loopback names (the
        ``Host`` of every request must be one of them).
    limits : PortLimits
        The port's connection caps and header deadline (:mod:`kinefuse.live.viewer.port_limits`).
    on_subject : callable, optional
        Where the operator's choice of subject goes (:class:`LiveSource`).

    Yields
    ------
    bound_port : int
    """
    source = LiveSource(publisher, maxsize=maxsize, on_subject=on_subject)
    async with serve(
        source,
        host=host,
        port=port,
        token=token,
        publisher=publisher,
        allowed_hosts=allowed_hosts,
        limits=limits,
    ) as p:
        yield p


async def read_commands(ws: web.WebSocketResponse) -> AsyncIterator[dict[str, Any]]:
    """The JSON objects a page sends (anything else is ignored)."""
    async for msg in ws:
        if msg.type != WSMsgType.TEXT:
            continue
        try:
            cmd = json.loads(msg.data)
        except ValueError:
            continue
        if isinstance(cmd, dict):
            yield cmd
