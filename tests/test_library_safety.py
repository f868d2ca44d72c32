"""The library keeps the CLI's rule: a writer never replaces a file kinefuse did not make, writes
through a temporary file renamed into place, and fails loudly (kinefuse.core.outputs).

The CLI checks before it calls the library (tests/test_data_safety.py); these tests call the
library writers directly, with their ``overwrite`` options, on files that are not theirs."""

from __future__ import annotations

import hashlib
import os
import sqlite3
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import InputError, OutputError
from kinefuse.formats.store.session_store import SessionStore

SMALL = Intrinsics(width=8, height=6, fx=5.0, fy=5.0, cx=3.5, cy=2.5)


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def only(folder: Path) -> list[str]:
    """The folder's files: no temporary file may be left beside the target."""
    return sorted(p.name for p in folder.iterdir())


def foreign(path: Path, data: bytes = b"") -> str:
    path.write_bytes(data or os.urandom(4096))
    return digest(path)


def foreign_sqlite(path: Path) -> str:
    c = sqlite3.connect(path)
    c.execute("CREATE TABLE meta (key TEXT, value TEXT)")  # a session's table name, not ours
    c.commit()
    c.close()
    return digest(path)


def live_recording(path: Path) -> str:
    with SessionStore.create(path) as st:  # no truth: a live recording, never replaced
        st.add_sensor("k0", "A", SMALL)
        st.mark_complete()
    return digest(path)


# -- sessions ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny(shared_data):
    """A placed 0.3 s walk and a 2-sensor rig: a session simulates in about a second."""
    from kinefuse.formats.motion import load_motion
    from kinefuse.sim.lab import LabConfig
    from kinefuse.sim.rig import default_rig, place_actor

    rig = default_rig(2)
    motion = place_actor(load_motion(shared_data / "motion" / "cmu" / "02_walk_a.amc"), rig, 0.3)
    return motion, rig, LabConfig(seed=3, calibration_s=0.0, motion_s=0.3)


@pytest.mark.parametrize("kind", ["random bytes", "foreign sqlite", "live recording"])
def test_simulate_session_overwrite_refuses_what_it_did_not_make(tmp_path, tiny, kind) -> None:
    from kinefuse.sim.lab import simulate_session

    victim = tmp_path / "notes.sqlite"
    make = {"random bytes": foreign, "foreign sqlite": foreign_sqlite,
            "live recording": live_recording}[kind]  # fmt: skip
    before = make(victim)
    with pytest.raises((OutputError, InputError), match=r"notes\.sqlite") as e:
        simulate_session(*tiny[:2], victim, tiny[2], overwrite=True)
    assert "refusing" in str(e.value) or "recording without ground truth" in str(e.value)
    assert digest(victim) == before
    assert only(tmp_path) == ["notes.sqlite"]


def test_simulate_session_overwrite_replaces_its_own_simulation(tmp_path, tiny) -> None:
    from kinefuse.sim.lab import LabConfig, simulate_session

    out = tmp_path / "s.sqlite"
    simulate_session(*tiny[:2], out, tiny[2])
    with pytest.raises(Exception, match="already exists"):
        simulate_session(*tiny[:2], out, tiny[2])
    other = LabConfig(seed=4, calibration_s=0.0, motion_s=0.3)
    simulate_session(*tiny[:2], out, other, overwrite=True)
    with SessionStore.open(out) as st:
        assert st.truth().info("seed") == 4
    assert only(tmp_path) == ["s.sqlite"]


def test_simulate_session_failure_leaves_the_old_session_whole(tmp_path, tiny) -> None:
    from kinefuse.sim.lab import simulate_session

    out = tmp_path / "s.sqlite"
    simulate_session(*tiny[:2], out, tiny[2])
    before = digest(out)

    def boom(msg: str) -> None:
        if "tracker" in msg:
            raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError, match="interrupted"):
        simulate_session(*tiny[:2], out, tiny[2], overwrite=True, progress=boom)
    assert digest(out) == before
    assert only(tmp_path) == ["s.sqlite"]


@pytest.mark.parametrize("kind", ["random bytes", "foreign sqlite", "live recording"])
def test_store_create_overwrite_refuses_what_it_did_not_make(tmp_path, kind) -> None:
    victim = tmp_path / "notes.sqlite"
    make = {"random bytes": foreign, "foreign sqlite": foreign_sqlite,
            "live recording": live_recording}[kind]  # fmt: skip
    before = make(victim)
    with pytest.raises(OutputError, match=r"refusing to replace .*notes\.sqlite"):
        SessionStore.create(victim, overwrite=True)
    assert digest(victim) == before


# -- angle files and skeleton exports --------------------------------------------------------------


@pytest.mark.parametrize("name", ["angles.csv", "angles.mot"])
def test_angle_writers_overwrite_only_their_own_files(tmp_path, name) -> None:
    from kinefuse.formats.angles import write_angles_csv, write_angles_mot

    t = np.arange(3) / 10.0

    def write(path: Path, scale: float) -> Path:
        if name.endswith(".csv"):
            return write_angles_csv(path, t, {"x": scale * t}, {"x": "KneeLeft"}, overwrite=True)
        return write_angles_mot(path, t, {"x": scale * t}, overwrite=True)

    victim = tmp_path / name
    before = foreign(victim, b"time,x\n0,1\n")  # a CSV / text file someone else made
    with pytest.raises(OutputError, match=rf"refusing to replace .*{name}"):
        write(victim, 1.0)
    assert digest(victim) == before
    # a foreign OpenSim .mot (its header as OpenSim's own tools write it) is not ours either
    if name.endswith(".mot"):
        victim.write_text("Coordinates\nversion=1\nnRows=1\nnColumns=2\ninDegrees=yes\n"
                          "endheader\ntime\tx\n0.0\t1.0\n")  # fmt: skip
        before = digest(victim)
        with pytest.raises(OutputError, match="refusing to replace"):
            write(victim, 1.0)
        assert digest(victim) == before
    mine = tmp_path / f"mine_{name}"
    write(mine, 1.0)
    first = digest(mine)
    write(mine, 2.0)  # its own file: replaced
    assert digest(mine) != first
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize("fmt", ["csv", "trc", "c3d"])
def test_exporters_called_directly_refuse_foreign_files(tmp_path, fmt) -> None:
    from kinefuse.formats import export

    writer = getattr(export, f"export_{fmt}")
    t = np.arange(4) / 30.0
    p = np.zeros((4, N_JOINTS, 3)) + 0.5
    victim = tmp_path / f"take.{fmt}"
    before = foreign(victim)
    with pytest.raises(OutputError, match=rf"refusing to replace .*take\.{fmt}"):
        writer(victim, t, p)
    assert digest(victim) == before
    mine = tmp_path / f"mine.{fmt}"
    writer(mine, t, p)
    writer(mine, t, p + 0.1)  # a kinefuse export of that format is replaced
    assert only(tmp_path) == sorted([f"take.{fmt}", f"mine.{fmt}"])


# -- tables and plots written into a folder the caller names ---------------------------------------


def test_tables_and_plots_never_replace_an_existing_file(tmp_path) -> None:
    from kinefuse.lab.calibration_truth import WandErrors, plot_calibration_errors
    from kinefuse.lab.fusion_truth import _write_table, plot_trajectories

    victim = tmp_path / "table1.md"
    before = foreign(victim, b"my notes\n")
    with pytest.raises(OutputError, match=r"refusing to replace .*table1\.md"):
        _write_table(tmp_path, "table1", ["a"], [["1"]])
    assert digest(victim) == before

    png = tmp_path / "trajectories.png"
    before = foreign(png)
    t = np.arange(5) / 10.0
    res = SimpleNamespace(t_server_s=t, positions=np.zeros((5, N_JOINTS, 3)))
    with pytest.raises(OutputError, match=r"refusing to replace .*trajectories\.png"):
        plot_trajectories({"paper": res}, np.zeros((5, N_JOINTS, 3)), png)  # type: ignore[dict-item]
    assert digest(png) == before

    png2 = tmp_path / "calib.png"
    before = foreign(png2)
    errs = WandErrors(np.full(20, 0.01), np.linspace(1, 4, 20), np.linspace(0, 60, 20))
    with pytest.raises(OutputError, match=r"refusing to replace .*calib\.png"):
        plot_calibration_errors(png2, errs)
    assert digest(png2) == before
    assert only(tmp_path) == ["calib.png", "table1.md", "trajectories.png"]


def test_child_process_logs_never_replace_a_file(tmp_path) -> None:
    from kinefuse.app.workflows.demo import ChildProcesses, ProcessError

    logs = tmp_path / "logs"
    logs.mkdir()
    before = foreign(logs / "server.log", b"yesterday's log\n")
    with (
        ChildProcesses(logs) as procs,
        pytest.raises(ProcessError, match=r"server\.log exists already"),
    ):
        procs.start("server", ["--version"])
    assert digest(logs / "server.log") == before


def test_a_figure_replaces_only_a_png(tmp_path: Path) -> None:
    from kinefuse.core.outputs import atomic_file, is_png

    png, notes = tmp_path / "fig.png", tmp_path / "notes.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 8)
    notes.write_text("my notes, misnamed")
    assert is_png(png) and not is_png(notes) and not is_png(tmp_path / "absent.png")
    with atomic_file(png, what="figure", recognizer=is_png, suffix=".png") as tmp:
        tmp.write_bytes(b"\x89PNG\r\n\x1a\nnew")
    assert png.read_bytes().endswith(b"new")
    with pytest.raises(OutputError), atomic_file(notes, what="figure", recognizer=is_png) as tmp:
        tmp.write_bytes(b"x")
    assert notes.read_text() == "my notes, misnamed"
