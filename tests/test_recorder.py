"""The live recorder: commits within 0.5 s, readable while it writes, complete on a clean stop,
never replaces a file (issue 11)."""

from __future__ import annotations

import asyncio
import sqlite3
import time

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import OutputError
from kinefuse.formats.store import live_tables as store_live
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.bus import FusedFrame, Publisher
from kinefuse.live.server.recorder import Recorder


def rows_now(path) -> tuple[int, int]:
    """(observations, live fused frames) as another process would read them now."""
    conn = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        o = conn.execute("SELECT count(*) FROM observations").fetchone()[0]
        f = conn.execute("SELECT count(*) FROM live_fused").fetchone()[0]
        return int(o), int(f)
    finally:
        conn.close()


def test_rows_are_committed_within_half_a_second_and_the_stop_completes(tmp_path) -> None:
    path = tmp_path / "rec.sqlite"
    joints = np.ones((N_JOINTS, 3))
    states = np.full(N_JOINTS, 2, np.int8)

    async def main() -> tuple:
        t0 = time.monotonic()
        rec = Recorder(path, {"recorded_by": "test"}, clock=lambda: time.monotonic() - t0)
        await rec.open()
        pub = Publisher()
        task = asyncio.ensure_future(rec.run(pub.subscribe(None)))
        rec.add_sensor("k0", "S0", Intrinsics())
        for seq in range(10):
            rec.add_observation(
                "k0", seq, 1.0 + seq / 30, 2.0 + seq / 30, 3.0, 2.9, joints, states, None, None
            )
        rec.new_stream("k0")  # a restarted sensor counts from 0 again: kept, after the others
        rec.add_observation("k0", 4, 9.0, 9.0, 9.0, 9.0, joints, states, None, None)
        rec.add_probe("k0", 1.0, 11.0, 11.001, 1.002)
        for k in range(5):
            pub.publish(
                FusedFrame(
                    seq=k,
                    t_server_s=k / 30,
                    positions_m=joints,
                    variance_m2=np.zeros(N_JOINTS),
                    status=states,
                    latency_s=0.02,
                )
            )
        await asyncio.sleep(0.5)
        seen = rows_now(path)  # committed, while the recorder still has the file open
        pub.close()
        rec.stop()
        await task
        await rec.close(clean=True)
        return seen

    seen = asyncio.run(asyncio.wait_for(main(), 20))
    assert seen == (11, 5)
    with SessionStore.open(path) as st:
        assert st.complete and st.meta()["recorded_by"] == "test"
        o = st.observations("k0")
        assert o.seq.tolist() == list(range(11))  # the new stream's seq 4 is recorded as 10
        np.testing.assert_allclose(o.t_host_s[:10], 2.0 + np.arange(10) / 30)
        assert o.t_host_s[10] == 9.0
        assert len(st.clock_probes("k0")) == 1
        seq, t = store_live.obs_times(st, "k0")
        assert seq.tolist() == list(range(11)) and np.allclose(t[:10], 2.9)
        shifts = [d for _, kind, _, d in store_live.events(st) if kind == "seq_offset"]
        assert shifts == [{"seq": 4, "offset": 6}]
        lf = store_live.live_fused(st)
        assert lf.frame.tolist() == [0, 1, 2, 3, 4] and np.allclose(lf.latency_s, 0.02)
        t_live, j_live, _ = st.fused("live")
        assert len(t_live) == 5 and np.allclose(j_live, 1.0)


def test_an_interrupted_recording_opens_and_says_it_is_incomplete(tmp_path) -> None:
    path = tmp_path / "rec.sqlite"

    async def main() -> None:
        rec = Recorder(path, {}, clock=time.monotonic)
        await rec.open()
        rec.add_sensor("k0", "S0", Intrinsics())
        await rec.flush()
        await rec.close(clean=False)  # as after a crash of the server: nothing marked

    asyncio.run(main())
    with SessionStore.open(path) as st:
        assert not st.complete and [s.id for s in st.sensors()] == ["k0"]


@pytest.mark.parametrize("name", ["exists.sqlite", "calib.toml"])
def test_a_recording_never_replaces_a_file(tmp_path, name) -> None:
    path = tmp_path / name
    if name == "exists.sqlite":
        path.write_bytes(b"precious")

    async def main() -> None:
        await Recorder(path, {}, clock=time.monotonic).open()

    with pytest.raises(OutputError, match=r"never replaced|extension of another format"):
        asyncio.run(main())
    if name == "exists.sqlite":
        assert path.read_bytes() == b"precious"
    with pytest.raises(OutputError, match="does not exist"):
        asyncio.run(Recorder(tmp_path / "no" / "r.sqlite", {}, clock=time.monotonic).open())
