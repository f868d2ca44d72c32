"""The viewer page on the REAL live system: ``kinefuse serve --viewer-port 0`` and two real
``kinefuse sensor`` processes on 127.0.0.1; the page shows a status row per sensor and the fused
frame counter goes up while they play."""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Any

import pytest

from kinefuse.app.workflows.demo import ChildProcesses, parse_listening, sensor_args
from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate

_VIEWER = re.compile(r"viewer at (http://\S+)")


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("browser_live") / "sim.sqlite"
    # a 9 s wand phase: under load the sensor processes start late and skip busy depth frames;
    # with 6 s they once sent 31 wand sightings each (1.5 s skipped at the start, 12 of 43
    # depth frames skipped), along a line, and the live calibration failed
    run_simulate(clip=demo_clip_path(), out=out, sensors=2, seconds=8.0, calibration_s=9.0)
    return out


def _counter(page: Any) -> int:
    text = page.inner_text("#frame-counter")
    return int(text) if text.isdigit() else -1


def test_live_page_of_the_real_server(tmp_path, session, page) -> None:
    with ChildProcesses(tmp_path / "logs") as procs:
        server = procs.start(
            "server",
            [
                "serve",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--viewer-port",
                "0",
                "--record",
                str(tmp_path / "rec.sqlite"),
                "--auto-calibrate",
            ],
            announce=True,
        )
        port = parse_listening(procs.wait_first_line(server, 60.0))[1]
        m = server.wait_line(_VIEWER, 30.0)
        assert m is not None, server.tail()
        epoch = time.monotonic() + 3.0
        for sid in ("k0", "k1"):
            procs.start(
                f"sensor-{sid}", sensor_args(port, session, sid, tmp_path / f"{sid}.json", epoch)
            )
        page.goto(m[1])
        page.wait_for_selector("#sensors tr.sensor-row >> nth=1", timeout=30_000)
        rows = page.locator("#sensors tr.sensor-row")
        assert sorted(rows.nth(i).get_attribute("data-sensor") for i in range(rows.count())) == [
            "k0",
            "k1",
        ]
        page.wait_for_function(
            "Number(document.getElementById('frame-counter').textContent) > 0", timeout=30_000
        )
        first = _counter(page)
        page.wait_for_timeout(1000)
        assert _counter(page) >= first + 10  # 30 Hz fused frames keep coming
        assert page.errors == []
