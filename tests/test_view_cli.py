"""``kinefuse view`` as the user runs it: ``--allow-host`` on a real socket, and a port that is
taken is one line (``kinefuse: error: ...``, one colon after ``error``) and exit 2."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from kinefuse.app.cli.main import main

TIMEOUT_S = 30.0


@pytest.fixture(scope="module")
def session(tmp_path_factory, shared_data) -> Path:
    """A short simulated walk (no wand phase) with ``best`` fused on the true poses."""
    out = tmp_path_factory.mktemp("view_cli") / "walk.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    sim = ["simulate", "--clip", str(clip), "--calibration-seconds", "0", "--seed", "3"]
    assert main([*sim, "--out", str(out)]) == 0
    assert main(["fuse", str(out), "--method", "best", "--true-calibration", "--store"]) == 0
    return out


def _status(port: int, host: str) -> int:
    """The HTTP status of ``GET /`` on 127.0.0.1:port sent with ``Host: host``."""
    with socket.create_connection(("127.0.0.1", port), timeout=TIMEOUT_S) as s:
        s.sendall(f"GET / HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n".encode())
        head = s.recv(64).decode("latin-1")
    return int(head.split()[1])


def test_view_answers_to_an_allowed_host_and_refuses_others(session) -> None:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    cmd = [sys.executable, "-m", "kinefuse", "view", str(session), "--port", "0"]
    proc = subprocess.Popen(
        [*cmd, "--allow-host", "mylab.example"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        port = int(lines[1].split()[1].rstrip("/").rsplit(":", 1)[1])
        allowed = _status(port, f"mylab.example:{port}")
        loopback = _status(port, f"localhost:{port}")
        other = _status(port, f"rebind.evil.example:{port}")
        proc.send_signal(signal.SIGINT)
        _out, err = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert (allowed, loopback, other) == (200, 200, 403), lines
    assert proc.returncode == 0 and "Traceback" not in err


def test_view_refuses_an_allow_host_that_is_not_a_host_name(session, capsys) -> None:
    assert main(["view", str(session), "--allow-host", "http://mylab.example/"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("kinefuse: error: --allow-host: 'http://mylab.example/' is not a host")
    assert len(err.splitlines()) == 1


def test_a_taken_port_is_one_line_with_one_colon_and_exit_2(session, capsys) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        code = main(["view", str(session), "--port", str(port)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith(f"kinefuse: error: the viewer cannot listen on 127.0.0.1:{port}: "), err
    assert "error::" not in err and len(err.splitlines()) == 1


def test_an_os_error_naming_a_file_says_the_file_once(tmp_path, capsys) -> None:
    """The other shape of the same handler: an error with a file name puts it after ``error:``."""
    folder = tmp_path / "a_folder.sqlite"
    folder.mkdir()
    code = main(["inspect", str(folder)])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("kinefuse: error: ") and "error::" not in err, err
    assert str(folder) in err and len(err.splitlines()) == 1
