"""``kinefuse serve`` as a process: its first line, a clean stop on SIGINT, the recording, and
``kinefuse calibrate --live`` against it (issue 11)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from kinefuse.app.cli import main
from kinefuse.formats.store.session_store import SessionStore

ROOT = Path(__file__).resolve().parents[1]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT / "src") + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture
def serve(tmp_path):
    procs = []

    def start(*args: str) -> tuple[subprocess.Popen, str]:
        p = subprocess.Popen(
            [sys.executable, "-m", "kinefuse", "serve", "--port", "0", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_env(),
            cwd=tmp_path,
        )
        procs.append(p)
        assert p.stdout is not None
        return p, p.stdout.readline().strip()

    yield start
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait(10)


def test_serve_prints_its_port_records_and_stops_cleanly_on_sigint(serve, tmp_path, capsys) -> None:
    rec = tmp_path / "rec.sqlite"
    p, first = serve("--record", str(rec))
    assert first.startswith("kinefuse serve: listening on 127.0.0.1:"), first
    port = int(first.rsplit(":", 1)[1])
    assert port > 0
    # a live calibration with no sensor connected fails cleanly: exit 3, the reason said
    code = main(["calibrate", "--live", f"127.0.0.1:{port}", "--seconds", "0.3"])
    out = capsys.readouterr().out
    assert code == 3 and "no sensor sent wand sightings" in out
    p.send_signal(signal.SIGINT)
    rest, err = p.communicate(timeout=20)
    assert p.returncode == 0, err
    assert "stopped (signal SIGINT)" in rest
    with SessionStore.open(rec) as st:
        assert st.complete and st.meta()["recorded_by"] == "kinefuse serve"
    # the recording is never replaced
    p2 = subprocess.run(
        [sys.executable, "-m", "kinefuse", "serve", "--port", "0", "--record", str(rec)],
        capture_output=True,
        text=True,
        env=_env(),
        timeout=30,
    )
    assert p2.returncode == 2 and "already exists" in p2.stderr and "Traceback" not in p2.stderr


def test_serve_warns_when_bound_beyond_loopback_without_a_token(serve) -> None:
    p, first = serve("--host", "0.0.0.0")
    assert first.startswith("kinefuse serve: listening on 0.0.0.0:")
    p.send_signal(signal.SIGTERM)
    _out, err = p.communicate(timeout=20)
    assert p.returncode == 0
    assert "without a token" in err


def test_calibrate_live_without_a_server_says_so(capsys) -> None:
    assert main(["calibrate", "--live", "127.0.0.1:1"]) == 2
    assert "cannot reach the server" in capsys.readouterr().err
    assert main(["calibrate"]) == 2
    assert "give a session" in capsys.readouterr().err


def test_serve_runs_the_live_viewer_on_its_publisher(serve) -> None:
    import urllib.request

    p, first = serve("--viewer-port", "0")
    assert first.startswith("kinefuse serve: listening on 127.0.0.1:")
    assert p.stdout is not None
    second = p.stdout.readline().strip()
    assert second.startswith("kinefuse serve: viewer at http://127.0.0.1:"), second
    url = second.split(" at ", 1)[1]
    with urllib.request.urlopen(url, timeout=10) as r:
        assert r.status == 200 and b"<html" in r.read().lower()
    p.send_signal(signal.SIGINT)
    _out, err = p.communicate(timeout=20)
    assert p.returncode == 0, err
