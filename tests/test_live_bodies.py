"""Every body on real sockets: a sensor client sends two bodies a frame, the live server keeps
both per sensor and its recording stores both; a 1.2 server is sent the first body only."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Iterator
from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from kinefuse.core.frames.observations import BodyFrame
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.protocol import BodyFrameMessage, Goodbye, Welcome
from kinefuse.live.server.sensor_state import latest_bodies
from kinefuse.live.server.server import Server, ServerOptions
from test_client import TestServer, WalkSource, _client, run

N = 30


class TwoPeople(WalkSource):
    """The walk of :class:`WalkSource` (tracking id 3) with a second person 0.9 m to its side
    (tracking id 8) in every frame but each fifth, where the tracker lists only the first."""

    def __iter__(self) -> Iterator[BodyFrame]:
        for f in super().__iter__():
            other = replace(f, joints_m=f.joints_m + np.array([0.9, 0.0, 0.4]), body_id=8)
            yield replace(f, body_id=3, others=() if f.seq % 5 == 4 else (other,))


def test_two_bodies_reach_the_server_state_and_the_recording(tmp_path) -> None:
    path = tmp_path / "live.sqlite"
    src = TwoPeople(n=N)
    seen: list[tuple[int, ...]] = []

    async def go() -> Server:
        srv = Server(ServerOptions(port=0, record=path))
        task = asyncio.ensure_future(srv.run())
        while srv.port is None:
            await asyncio.sleep(0.01)
        client = _client(SimpleNamespace(port=srv.port), src, speed=3.0)  # type: ignore[arg-type]
        play = asyncio.ensure_future(client.run())
        while not play.done():
            now = latest_bodies(srv.clients)
            if now:
                seen.append(tuple(b.body_id for b in now["w0"]))
                assert srv.clients["w0"].bodies()[1][0].sensor_id == "w0"
            await asyncio.sleep(0.01)
        assert await play == 0
        srv.request_stop("test done")
        await asyncio.wait_for(task, 20)
        return srv

    run(go())
    # the server's per-sensor state kept both bodies, the first listed first
    assert (3, 8) in seen and set(seen) <= {(3, 8), (3,)}
    with SessionStore.open(path) as st:
        first = st.observations("w0")
        every = st.observations("w0", bodies="all")
    assert first.seq.tolist() == list(range(N)) and first.body_id.tolist() == [3] * N
    two = [k for k in range(N) if k % 5 != 4]
    assert every.n_frames == N + len(two)
    assert (every.body_id == 8).sum() == len(two)
    assert every.seq[every.body_id == 8].tolist() == two
    # the second body is the second person: the first's joints 0.9 m to the side
    np.testing.assert_array_equal(every.first_bodies().joints_m, first.joints_m)
    rows = every.take(np.flatnonzero(every.body_id == 8))
    base = first.take(np.array(two))
    np.testing.assert_allclose(rows.joints_m, base.joints_m + np.array([0.9, 0.0, 0.4]), atol=1e-5)
    np.testing.assert_array_equal(rows.t_device_s, base.t_device_s)
    assert every.occluded is not None and every.n_crossings is not None  # each body's own test


def test_a_1_2_server_is_sent_the_first_body_only_and_the_log_says_so_once(caplog) -> None:
    src = TwoPeople(n=12)

    async def go() -> TestServer:
        server = TestServer(welcome=Welcome(protocol_version=(1, 2)))
        await server.start()
        client = _client(server, src, speed=3.0)
        await client.run()
        await server.wait_for(lambda: any(isinstance(m, Goodbye) for m in server.peers[0].messages))
        return server

    with caplog.at_level(logging.WARNING, logger="kinefuse.sensor"):
        server = run(go())
    frames = [m for m in server.peers[0].messages if isinstance(m, BodyFrameMessage)]
    assert len(frames) == 12 and all(m.others == () for m in frames)
    assert all(m.body_id == 3 for m in frames)
    said = [r for r in caplog.records if "first body of each frame only" in r.getMessage()]
    assert len(said) == 1 and "protocol 1.2" in said[0].getMessage()
