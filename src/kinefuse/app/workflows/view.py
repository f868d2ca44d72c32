"""``kinefuse view SESSION``: the replay viewer of a recorded (or simulated) session."""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Callable
from pathlib import Path

from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.address import is_loopback


def run_view(
    session: Path,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    allow_hosts: tuple[str, ...] = (),
    say: Callable[[str], None] = print,
    stop: asyncio.Event | None = None,
) -> int:
    """Serve the replay viewer of ``session`` until Ctrl-C (or ``stop`` is set).

    The session is opened read-only, read into memory and closed before serving starts.
    Requests must name the viewer by ``host``, a loopback name or one of ``allow_hosts``
    (:class:`kinefuse.live.viewer.port_limits.HostNames`).
    """
    from kinefuse.live.viewer.http_server import serve
    from kinefuse.live.viewer.port_limits import host_name
    from kinefuse.live.viewer.replay import ReplaySource
    from kinefuse.live.viewer.session_data import load_session_view

    if not 0 <= port <= 65535:
        raise InputError(f"--port must be 0..65535 (0 picks a free port), got {port}")
    for name in allow_hosts:
        try:
            host_name(name)
        except ValueError as e:
            raise InputError(f"--allow-host: {e}; give a DNS name or an IP address") from None
    with SessionStore.open(session) as store:
        view = load_session_view(store)
    source = ReplaySource(view, name=session.name)

    async def main() -> None:
        async with serve(source, host=host, port=port, allowed_hosts=allow_hosts) as bound:
            shown = f"[{host}]" if ":" in host else host
            say(
                f"kinefuse view: {session.name}, {view.n_frames} frames, results: "
                f"{', '.join(view.methods)}" + (", with truth" if view.truth is not None else "")
            )
            say(f"open http://{shown}:{bound}/  (Ctrl-C stops)")
            if not is_loopback(host):
                print(
                    f"kinefuse view: warning: serving on {host}, beyond this machine; anyone "
                    "who can reach it sees the session",
                    file=sys.stderr,
                )
            await (stop.wait() if stop is not None else asyncio.Event().wait())

    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        say("viewer stopped")
    return 0
