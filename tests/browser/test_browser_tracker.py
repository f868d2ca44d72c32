"""The viewer's sensor row shows a sensor's body tracker: a real ``kinefuse serve
--viewer-port 0`` and a real ``kinefuse sensor`` playing the shared Azure Kinect recording
(``?repeat=N``) through the slow test tracker (``tests/plugins``); its status line, with the
tracker's refusal as text (not HTML), appears in the row."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from kinefuse.app.workflows.demo import ChildProcesses, parse_listening

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "plugins"))
from kinefuse_test_trackers import SLOW_REFUSAL  # noqa: E402

_VIEWER = re.compile(r"viewer at (http://\S+)")

pytest.importorskip("av")


def test_the_sensor_row_shows_the_tracker_rate_as_text(
    tmp_path, shared_data, page, monkeypatch
) -> None:
    paths = [str(ROOT / "src"), str(ROOT / "tests" / "plugins")]
    monkeypatch.setenv("PYTHONPATH", ":".join(paths))
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    with ChildProcesses(tmp_path / "logs") as procs:
        server = procs.start(
            "server", ["serve", "--port", "0", "--viewer-port", "0"], announce=True
        )
        port = parse_listening(procs.wait_first_line(server, 60.0))[1]
        m = server.wait_line(_VIEWER, 30.0)
        assert m is not None, server.tail()
        procs.start(
            "sensor",
            ["sensor", "--server", f"127.0.0.1:{port}", "--source",
             f"mkv:{mkv}?repeat=600#azure1", "--tracker", "slow", "--speed", "6"],
        )  # fmt: skip
        page.goto(m[1])
        row = page.locator('#sensors tr.sensor-row[data-sensor="azure1"]')
        row.locator(".tracker").wait_for(timeout=60_000)
        text = row.locator(".tracker").inner_text()
        assert re.search(r"tracker [0-9.]+ Hz, \d+ tracked, \d+ dropped \(behind\)", text), text
        assert SLOW_REFUSAL in text  # shown as the text it is
        assert row.locator("b").count() == 0  # its "<b>" made no element
        assert page.errors == []
