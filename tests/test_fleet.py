"""Many light sensor clients on one event loop (live/client/fleet.py, the capacity benchmark's
sensors) against a real server on 127.0.0.1: each its own authenticated connection and clock."""

from __future__ import annotations

import asyncio
import datetime as _dt
import time
from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.calibration.calib_file import CalibrationFile, SensorCalibration
from kinefuse.core.frames.observations import BodyFrame, DepthFrame
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.bus import FusedFrame
from kinefuse.live.client.client import ClientOptions, ClientRefused
from kinefuse.live.client.fleet import replay_clients, run_clients
from kinefuse.live.client.playback import SimTimeline
from kinefuse.live.server.server import Server, ServerOptions

TOKEN = "fleet-test-token"
IDS = ["k0", "k1", "k2"]


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """3 sensors, a 1 s wand phase (depth frames the fleet must not play), 3 s of motion."""
    from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate

    out = tmp_path_factory.mktemp("fleet") / "s.sqlite"
    run_simulate(
        clip=demo_clip_path(), out=out, sensors=3, seconds=3.0, calibration_s=1.0,
        depth_rate_hz=5.0,
    )  # fmt: skip
    return out


def test_a_body_only_timeline_plays_the_body_frames_as_the_full_one(session: Path) -> None:
    full = list(SimTimeline(str(session), "k1").frames())
    light = list(SimTimeline(str(session), "k1", depth=False).frames())
    assert any(isinstance(x.frame, DepthFrame) for x in full)
    assert all(isinstance(x.frame, BodyFrame) for x in light)
    body = [x for x in full if isinstance(x.frame, BodyFrame)]
    with SessionStore.open(session) as st:
        assert len(light) == len(body) == st.observation_count("k1")
    assert [x.t_play_s for x in light] == [x.t_play_s for x in body]
    assert [x.frame.seq for x in light] == [x.frame.seq for x in body]


def _server(session: Path) -> Server:
    srv = Server(ServerOptions(port=0, token=TOKEN, timeout_s=5.0))
    with SessionStore.open(session) as st:
        truth = st.truth()
        cals = tuple(
            SensorCalibration(s.id, s.serial, truth.sensor(s.id)[0], s.intrinsics, 0.001, 100)
            for s in st.sensors()
        )
    srv.load_calibration(CalibrationFile("full", _dt.datetime.now(_dt.UTC), cals))
    return srv


def test_each_client_is_its_own_authenticated_connection_with_its_own_clock(session: Path) -> None:
    async def main() -> tuple[Server, list, list[FusedFrame], set[str]]:
        srv = _server(session)
        task = asyncio.ensure_future(srv.run())
        while srv.port is None:
            await asyncio.sleep(0.01)
        sub = srv.publisher.subscribe(None)
        frames: list[FusedFrame] = []
        peers: set[str] = set()

        async def collect() -> None:
            async for it in sub:
                if isinstance(it, FusedFrame):
                    frames.append(it)
                    peers.update(c.peer for c in srv._sensor_conns.values())

        col = asyncio.ensure_future(collect())
        opts = ClientOptions(server=("127.0.0.1", srv.port), token=TOKEN)
        clients = replay_clients(session, IDS, opts, epoch_monotonic=time.monotonic() + 0.5)
        try:
            codes = await run_clients(clients)
            assert codes == [0, 0, 0]
        finally:
            srv.request_stop("test")
            await asyncio.wait_for(task, 10)
            col.cancel()
        return srv, clients, frames, peers

    srv, clients, frames, peers = asyncio.run(asyncio.wait_for(main(), 60))
    assert len(peers) == 3  # three TCP connections, one per sensor
    with SessionStore.open(session) as st:
        for sid, c in zip(IDS, clients, strict=True):
            state = srv.clients[sid]
            assert state.connections == 1
            # every body frame of the session reached the server, none dropped anywhere
            assert c.stats.body_sent == st.observation_count(sid) - c.stats.skipped_at_start
            assert c.stats.body_dropped == 0 and state.dropped == 0 and state.late_dropped == 0
            assert c.stats.probes_answered >= 5  # synchronized by its own probes
    offsets = {sid: srv.clients[sid].clock.estimate(srv.clock()).offset_s for sid in IDS}
    # each its own emulated host clock (the session's simulated offsets, seconds apart)
    assert len({round(v, 3) for v in offsets.values()}) == 3
    fused = [f for f in frames if np.isfinite(f.positions_m).all()]
    assert len(fused) > 45  # over 1.5 s of the 3 s fused from all three
    assert all(len(f.raw_m) == 3 for f in fused[-10:])


def test_one_refused_client_stops_the_fleet(session: Path) -> None:
    async def main() -> None:
        srv = _server(session)
        task = asyncio.ensure_future(srv.run())
        while srv.port is None:
            await asyncio.sleep(0.01)
        good = replay_clients(session, IDS[:2], ClientOptions(("127.0.0.1", srv.port), TOKEN))
        bad = replay_clients(session, IDS[2:], ClientOptions(("127.0.0.1", srv.port), "wrong-tok"))
        try:
            with pytest.raises(ClientRefused) as e:
                await run_clients([*good, *bad])
            assert e.value.code == "auth"
            assert all(c._stop.is_set() for c in good)  # the others were stopped
        finally:
            srv.request_stop("test")
            await asyncio.wait_for(task, 10)

    asyncio.run(asyncio.wait_for(main(), 30))
