"""Run inside ``unshare -rn`` (only ``lo`` up) under strace, by tests/test_lsl.py; not a test.

``serve --lsl --people all`` in this process: a real server with the LSL outlet service
(``people="all"``), the true poses of a session simulated with a bystander, and one real sensor
client per sensor on 127.0.0.1 playing it. As each stream's description appears (``--lsl-xml``
and its per-person files) a discovery-free inlet is built from it (LSL confined to 127.0.0.1 as
tests/lsl_loopback_run.py does) and pulls its samples. Writes, per stream, what it received
against the fused frames the server published, as JSON to ``--out``; the test judges it.

    python tests/lsl_people_run.py --session S.sqlite --work DIR --out result.json
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as _dt
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from lsl_loopback_run import LSL_API_CFG, _inlet_from_xml

NAME = "kinefuse-people-test"
TOKEN = "lsl-people-token"


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--session", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    cfg = a.work / "lsl_api.cfg"
    cfg.write_text(LSL_API_CFG)
    os.environ["LSLAPICFG"] = str(cfg)
    probe = subprocess.run(
        [sys.executable, "-c", "import pylsl; pylsl.StreamInfo('probe', 'MoCap', 1)"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    result: dict[str, object] = {
        "config_loaded": f"Configuration loaded from {cfg}" in probe.stderr
    }
    if not result["config_loaded"]:
        a.out.write_text(json.dumps(result))
        return 1
    import pylsl

    from kinefuse.capture.calibration.calib_file import CalibrationFile, SensorCalibration
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.live.bus import FusedFrame
    from kinefuse.live.client.client import ClientOptions
    from kinefuse.live.client.fleet import replay_clients, run_clients
    from kinefuse.live.lsl import lsl_outlet, person_xml_path, sample_of
    from kinefuse.live.server.server import Server, ServerOptions

    xml = a.work / "stream.xml"
    paths = {None: xml, 0: person_xml_path(xml, 0), 1: person_xml_path(xml, 1)}
    received: dict[int | None, list[tuple[float, list[float]]]] = {k: [] for k in paths}
    names: dict[int | None, str] = {}
    stop = threading.Event()

    def pull(key: int | None) -> None:
        """Wait for the stream's description, then pull its samples until told to stop."""
        while not paths[key].exists():
            if stop.wait(0.05):
                return
        inlet = _inlet_from_xml(pylsl, paths[key].read_text())
        inlet.open_stream(timeout=10.0)  # type: ignore[attr-defined]
        names[key] = inlet.info(timeout=10.0).name()  # type: ignore[attr-defined]
        while not stop.is_set():
            try:
                sample, ts = inlet.pull_sample(timeout=0.2)  # type: ignore[attr-defined]
            except pylsl.LostError:
                return
            if ts is not None:
                received[key].append((ts, sample))

    pullers = [threading.Thread(target=pull, args=(k,), daemon=True) for k in paths]
    for t in pullers:
        t.start()
    frames: list[FusedFrame] = []

    async def run() -> Server:
        the: list[Server] = []
        services = {
            "lsl": lambda pub: lsl_outlet(
                pub, name=NAME, server_clock=lambda: the[0].clock(), xml_path=xml, people="all"
            )
        }
        srv = Server(ServerOptions(port=0, token=TOKEN), services=services)
        the.append(srv)
        with SessionStore.open(a.session) as st:
            truth = st.truth()
            ids = [s.id for s in st.sensors()]
            cals = tuple(
                SensorCalibration(s.id, s.serial, truth.sensor(s.id)[0], s.intrinsics, 0.001, 100)
                for s in st.sensors()
            )
        srv.load_calibration(CalibrationFile("full", _dt.datetime.now(_dt.UTC), cals))
        sub = srv.publisher.subscribe(None)
        task = asyncio.ensure_future(srv.run())
        while srv.port is None or "lsl" not in srv.services:
            await asyncio.sleep(0.01)

        async def collect() -> None:
            async for it in sub:
                if isinstance(it, FusedFrame):
                    frames.append(it)

        col = asyncio.ensure_future(collect())
        opts = ClientOptions(server=("127.0.0.1", srv.port), token=TOKEN)
        clients = replay_clients(a.session, ids, opts, epoch_monotonic=time.monotonic() + 1.0)
        try:
            result["sensor_rcs"] = await run_clients(clients)
            await asyncio.sleep(0.5)  # the last samples reach the inlets
        finally:
            srv.request_stop("done")
            await asyncio.wait_for(task, 20)
            col.cancel()
        return srv

    srv = asyncio.run(run())
    stop.set()
    for t in pullers:
        t.join(5.0)
    out = srv.services["lsl"]
    offset = out.clock.offset_s  # type: ignore[attr-defined]
    result["outlets"] = sorted([out.name, *(o.name for o in out.people.values())])  # type: ignore[attr-defined]
    by_t = {round(f.t_server_s, 6): f for f in frames}
    streams = {}
    for key, got in received.items():
        n_bad = n_pos = n_unmatched = 0
        for ts, sample in got:
            f = by_t.get(round(ts - offset, 6))
            if f is None:
                n_unmatched += 1
                continue
            want = np.array(sample_of(f, key), dtype=np.float32)
            have = np.array(sample, dtype=np.float32)
            n_bad += int(not np.all((have == want) | (np.isnan(have) & np.isnan(want))))
            n_pos += int(np.isfinite(have[:75]).any())
        streams["subject" if key is None else f"p{key}"] = {
            "name": names.get(key), "received": len(got), "not_matching": n_bad,
            "not_a_frame": n_unmatched, "with_positions": n_pos,
        }  # fmt: skip
    result["streams"] = streams
    result["frames"] = len(frames)
    result["frames_with_two_people"] = sum(len(f.people_m) == 2 for f in frames)
    a.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
