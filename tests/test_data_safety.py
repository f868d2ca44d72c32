"""Nothing lost, nothing silent (issue 8): every command protects files it did not make, writes
atomically, fails loudly, reads sessions read-only, and says when a session is incomplete."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.core.outputs import DIR_MARKER, atomic_dir, atomic_file
from kinefuse.errors import OutputError
from kinefuse.formats.store.session_store import SessionStore

ROOT = Path(__file__).resolve().parents[1]


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def clip(shared_data) -> Path:
    return shared_data / "motion" / "cmu" / "02_walk_a.amc"


@pytest.fixture(scope="module")
def session(tmp_path_factory, clip) -> Path:
    """A short complete simulated session with a calibration phase (8 s of wand at 5 Hz)."""
    out = tmp_path_factory.mktemp("safety") / "s.sqlite"
    assert main(["simulate", "--clip", str(clip), "--seconds", "1", "--calibration-seconds", "8",
                 "--depth-rate", "5", "--seed", "1", "--out", str(out)]) == 0  # fmt: skip
    return out


def sim_args(clip: Path, out: Path, *extra: str) -> list[str]:
    return ["simulate", "--clip", str(clip), "--seconds", "0.5", "--calibration-seconds", "0",
            "--out", str(out), *extra]  # fmt: skip


# -- 1. --force replaces only kinefuse sessions; atomic replace ---------------------------------


@pytest.mark.parametrize("name", ["precious.csv", "myrig.toml", "take.c3d", "notes", "data.sqlite"])
def test_force_refuses_files_that_are_not_sessions(tmp_path, clip, capsys, name) -> None:
    victim = tmp_path / name
    victim.write_bytes(b"time,x\n0,1\n" if name.endswith(".csv") else os.urandom(4096))
    before = digest(victim)
    code, out, err = run(capsys, *sim_args(clip, victim, "--force"))
    assert code == 2 and "wrote" not in out
    assert str(victim) in err and ("not a kinefuse session" in err or "another format" in err)
    assert digest(victim) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # no temporary file left


def test_force_refuses_a_live_recording_and_a_foreign_sqlite(tmp_path, clip, capsys) -> None:
    live = tmp_path / "live.sqlite"
    with SessionStore.create(live) as st:  # a recording: no truth tables filled
        st.mark_complete()
    foreign = tmp_path / "other.sqlite"
    c = sqlite3.connect(foreign)
    c.execute("CREATE TABLE meta (key TEXT, value TEXT)")
    c.commit()
    c.close()
    for f in (live, foreign):
        before = digest(f)
        code, _, err = run(capsys, *sim_args(clip, f, "--force"))
        assert code == 2 and str(f) in err and digest(f) == before


def test_force_replaces_a_simulated_session(tmp_path, clip, capsys) -> None:
    s = tmp_path / "s.sqlite"
    assert run(capsys, *sim_args(clip, s, "--seed", "1"))[0] == 0
    code, _, err = run(capsys, *sim_args(clip, s, "--seed", "2"))
    assert code == 2 and "--force" in err  # not without --force
    first = digest(s)
    assert run(capsys, *sim_args(clip, s, "--seed", "2", "--force"))[0] == 0
    assert digest(s) != first
    with SessionStore.open(s) as st:
        assert st.complete and st.truth().info("seed") == 2


def _start_simulate(out: Path, clip: Path, *extra: str) -> subprocess.Popen[bytes]:
    argv = [sys.executable, "-m", "kinefuse", "simulate", "--clip", str(clip),
            "--calibration-seconds", "20", "--out", str(out), *extra]  # fmt: skip
    return subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _wait_for_partial(
    folder: Path,
    proc: subprocess.Popen[bytes],
    ready: str = "SELECT count(*) > 0 FROM sensors",
    timeout_s: float = 120,
) -> Path:
    """The partial session a running simulate writes, once the SQL ``ready`` is true in it."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, "simulate finished before it could be interrupted"
        for p in folder.glob(".*.partial.sqlite"):
            c = None
            try:
                c = sqlite3.connect(f"file:{p}?mode=ro", uri=True)
                if c.execute(ready).fetchone()[0]:
                    return p
            except sqlite3.Error:
                pass
            finally:
                if c is not None:
                    c.close()
        time.sleep(0.1)
    proc.kill()
    raise AssertionError("no partial session appeared")


def test_interrupted_force_leaves_the_old_session_byte_identical(tmp_path, clip) -> None:
    s = tmp_path / "s.sqlite"
    assert main(sim_args(clip, s)) == 0
    before = digest(s)
    proc = _start_simulate(s, clip, "--force")
    _wait_for_partial(tmp_path, proc)
    proc.send_signal(signal.SIGINT)  # what `timeout -s INT` sends
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and b"interrupted" in err
    assert digest(s) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.sqlite"]  # the partial is gone


def test_killed_simulate_leaves_an_incomplete_session(tmp_path, clip, capsys) -> None:
    s = tmp_path / "new.sqlite"
    proc = _start_simulate(s, clip)
    # killed after the first sensor's body frames, while the second one is being rendered
    ready = "SELECT (SELECT count(*) FROM sensors) >= 2 AND (SELECT count(*) FROM observations)"
    partial = _wait_for_partial(tmp_path, proc, ready)
    proc.kill()  # SIGKILL: no cleanup can run
    proc.wait(timeout=30)
    assert not s.exists()  # the session is only renamed into place when it is whole
    code, out, _ = run(capsys, "inspect", partial, "--json")
    assert code == 0 and json.loads(out)["complete"] is False
    code, out, _ = run(capsys, "inspect", partial)
    assert "INCOMPLETE" in out
    code, _, err = run(capsys, "fuse", partial, "--true-calibration")
    assert code == 2 and "incomplete" in err and "--partial" in err
    code, _, err = run(capsys, "calibrate", partial)
    assert code == 2 and "incomplete" in err
    # told to use what is there, fuse says which sensors it is missing
    with SessionStore.open(partial) as st:
        silent = [s.id for s in st.sensors() if st.observation_count(s.id) == 0]
    assert silent and silent[0] != "k0"
    code, _, err = run(capsys, "fuse", partial, "--true-calibration", "--partial")
    assert code == 0 and f"sensor {silent[0]} has no body frames" in err


def test_a_rig_outside_the_room_leaves_no_file(tmp_path, clip, capsys) -> None:
    rig = tmp_path / "far.toml"
    rig.write_text('[[sensor]]\nid = "a"\nposition_m = [6.0, 0.0, 1.0]\nlook_at_m = [0, 0, 1]\n')
    s = tmp_path / "s.sqlite"
    code, _, err = run(capsys, *sim_args(clip, s, "--rig", str(rig)))
    assert code == 2 and "outside the room" in err and str(rig) in err
    assert not s.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["far.toml"]
    # a larger room, from the command line or the rig file, takes it
    assert run(capsys, *sim_args(clip, s, "--rig", str(rig), "--room=-8,-8,8,8"))[0] == 0
    rig.write_text(rig.read_text() + "[room]\nmin_xy_m = [-8, -8]\nmax_xy_m = [8, 8]\n")
    assert run(capsys, *sim_args(clip, tmp_path / "t.sqlite", "--rig", str(rig)))[0] == 0


def test_known_foreign_extension_is_refused(tmp_path, clip, capsys) -> None:
    code, _, err = run(capsys, *sim_args(clip, tmp_path / "s.c3d"))
    assert code == 2 and "another format" in err and not (tmp_path / "s.c3d").exists()


# -- 2. writers fail loudly ----------------------------------------------------------------------


def test_fuse_into_a_missing_folder_fails_with_one_line(session, tmp_path, capsys) -> None:
    out = tmp_path / "nope" / "f.c3d"
    code, stdout, err = run(capsys, "fuse", session, "--true-calibration", "--out", out)
    assert code == 2 and "wrote" not in stdout
    assert err.count("\n") == 1 and "does not exist" in err and str(out) in err


@pytest.mark.parametrize(
    "argv",
    [
        ("fuse", "{s}", "--true-calibration", "--out", "{ro}/f.c3d"),
        ("fuse", "{s}", "--true-calibration", "--out", "{ro}/f.trc"),
        ("evaluate", "{s}", "--true-calibration", "--methods", "best", "--out", "{ro}/ev"),
        ("calibrate", "{s}", "--out", "{ro}/c.toml"),
        ("calibrate", "{s}", "--report", "{ro}/rep"),
        (
            "simulate",
            "--clip",
            "{clip}",
            "--seconds",
            "0.5",
            "--calibration-seconds",
            "0",
            "--out",
            "{ro}/x.sqlite",
        ),
        ("demo", "--out", "{ro}/demo"),
    ],
    ids=[
        "fuse-c3d",
        "fuse-trc",
        "evaluate",
        "calibrate-out",
        "calibrate-report",
        "simulate",
        "demo",
    ],
)
def test_read_only_output_folders_fail_with_one_line(
    session, clip, read_only_copy, capsys, argv
) -> None:
    ro = read_only_copy()
    args = [a.format(s=session, ro=ro, clip=clip) for a in argv]
    code, out, err = run(capsys, *args)
    assert code == 2, err
    assert "wrote" not in out and err.count("\n") == 1 and "read-only" in err
    assert list(ro.iterdir()) == []


def test_atomic_file_keeps_the_old_file_when_the_writer_fails(tmp_path) -> None:
    f = tmp_path / "out.txt"
    f.write_text("mine")
    with pytest.raises(RuntimeError), atomic_file(f, what="x", recognizer=lambda p: True) as tmp:
        tmp.write_text("half")
        raise RuntimeError("disk on fire")
    assert f.read_text() == "mine" and sorted(tmp_path.iterdir()) == [f]
    # a writer that reports success and writes nothing (as ezc3d did on a read-only folder)
    with (
        pytest.raises(OutputError, match="produced no data"),
        atomic_file(f, what="x", recognizer=lambda p: True),
    ):
        pass
    assert f.read_text() == "mine"
    foreign = pytest.raises(OutputError, match="not written by kinefuse")
    with foreign, atomic_file(f, what="x", recognizer=lambda p: False) as tmp:
        tmp.write_text("new")
    assert f.read_text() == "mine"


def test_outputs_are_private_whatever_the_umask(tmp_path) -> None:
    old = os.umask(0o022)
    try:
        with atomic_file(tmp_path / "f.txt", what="x", recognizer=lambda p: True) as tmp:
            tmp.write_text("x")
        with atomic_dir(tmp_path / "d", what="x") as tmp:
            (tmp / "a.txt").write_text("1")
    finally:
        os.umask(old)
    assert (tmp_path / "f.txt").stat().st_mode & 0o777 == 0o600  # captured data: the user's
    assert (tmp_path / "d").stat().st_mode & 0o777 == 0o700


def test_atomic_dir_swaps_only_when_complete(tmp_path) -> None:
    d = tmp_path / "out"
    with atomic_dir(d, what="x") as tmp:
        (tmp / "a.txt").write_text("1")
    assert (d / "a.txt").read_text() == "1" and (d / DIR_MARKER).is_file()
    with pytest.raises(KeyboardInterrupt), atomic_dir(d, what="x") as tmp:
        (tmp / "b.txt").write_text("2")
        raise KeyboardInterrupt  # an interrupted demo
    assert sorted(p.name for p in d.iterdir()) == [DIR_MARKER, "a.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    with atomic_dir(d, what="x") as tmp:  # a rerun replaces the whole folder
        (tmp / "c.txt").write_text("3")
    assert sorted(p.name for p in d.iterdir()) == [DIR_MARKER, "c.txt"]
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "thesis.tex").write_text("years of work")
    with pytest.raises(OutputError, match="did not write"), atomic_dir(mine, what="x"):
        pass
    assert (mine / "thesis.tex").read_text() == "years of work"


def test_exports_never_replace_foreign_files(session, tmp_path, capsys) -> None:
    for name in ("f.csv", "f.trc", "f.c3d"):
        out = tmp_path / name
        out.write_text("someone's data\n")
        code, _, err = run(capsys, "fuse", session, "--true-calibration", "--out", out)
        assert code == 2 and "not written by kinefuse" in err
        assert out.read_text() == "someone's data\n"
        out.unlink()
        assert run(capsys, "fuse", session, "--true-calibration", "--out", out)[0] == 0
        first = out.stat().st_mtime_ns
        assert run(capsys, "fuse", session, "--true-calibration", "--out", out)[0] == 0  # ours
        assert out.stat().st_mtime_ns >= first


# -- 3. sessions opened for reading are opened read-only ----------------------------------------


def test_commands_work_on_a_read_only_session(session, read_only_copy, tmp_path, capsys) -> None:
    ro = read_only_copy(session) / session.name
    os.chmod(ro, 0o444) if os.geteuid() != 0 else None
    before = digest(ro)
    code, out, err = run(capsys, "calibrate", ro, "--out", tmp_path / "c.toml", "--json")
    assert code == 0, err
    assert json.loads(out)["stored_in_session"] is False
    assert run(capsys, "fuse", ro, "--calibration", tmp_path / "c.toml",
               "--out", tmp_path / "f.trc")[0] == 0  # fmt: skip
    assert run(capsys, "fuse", ro, "--true-calibration", "--method", "paper")[0] == 0
    code, _, err = run(capsys, "evaluate", ro, "--calibration", tmp_path / "c.toml",
                       "--methods", "paper,best", "--out", tmp_path / "ev")  # fmt: skip
    assert code == 0, err
    assert run(capsys, "inspect", ro)[0] == 0
    assert digest(ro) == before
    assert sorted(p.name for p in ro.parent.iterdir()) == [session.name]  # no -wal, -shm
    # storing into a read-only session is refused with a clear message
    code, _, err = run(capsys, "calibrate", ro, "--store")
    assert code == 2 and "read-only" in err and err.count("\n") == 1


def test_reading_commands_do_not_write_into_the_session(session, tmp_path, capsys) -> None:
    s = tmp_path / "s.sqlite"
    shutil.copy2(session, s)
    before = digest(s)
    assert run(capsys, "calibrate", s, "--out", tmp_path / "c.toml")[0] == 0
    assert run(capsys, "fuse", s, "--calibration", tmp_path / "c.toml")[0] == 0
    assert digest(s) == before
    with SessionStore.open(s) as st:
        assert st.calibration_names() == [] and st.fused_methods() == []
    assert run(capsys, "calibrate", s, "--store")[0] == 0
    assert run(capsys, "fuse", s, "--store")[0] == 0  # uses the stored calibration
    with SessionStore.open(s) as st:
        assert st.calibration_names() == ["full"] and st.fused_methods() == ["best"]


# -- 6. coverage warnings --------------------------------------------------------------------


def test_a_rig_that_looks_away_is_warned_about(tmp_path, clip, capsys) -> None:
    rig = tmp_path / "away.toml"
    rig.write_text(
        '[[sensor]]\nid = "front"\nposition_m = [3.0, 0.0, 1.0]\nlook_at_m = [0.0, 0.0, 1.0]\n'
        '[[sensor]]\nid = "away"\nposition_m = [0.0, 3.0, 1.0]\nlook_at_m = [0.0, 6.0, 1.0]\n'
    )
    s = tmp_path / "s.sqlite"
    code, _, err = run(capsys, *sim_args(clip, s, "--rig", str(rig)))
    assert code == 0 and "sensor away never sees the body" in err
    assert "fewer than 2 sensors" in err  # one sensor alone: outside the common volume
    code, out, _ = run(capsys, "inspect", s, "--json")
    cov = json.loads(out)["coverage"]
    assert cov["sensors"]["away"]["body_fraction"] == 0.0
    assert cov["sensors"]["front"]["body_fraction"] > 0.9
    assert cov["outside_fraction"] > 0.9


# -- 9. smaller things ----------------------------------------------------------------------


def test_c3d_carries_residuals_and_the_time_base(session, tmp_path, capsys) -> None:
    import ezc3d

    outs = {e: tmp_path / f"f.{e}" for e in ("c3d", "csv", "trc")}
    for out in outs.values():
        assert run(capsys, "fuse", session, "--true-calibration", "--out", out)[0] == 0
    c = ezc3d.c3d(str(outs["c3d"]))
    res = c["data"]["meta_points"]["residuals"][0]  # (25, T)
    pts = c["data"]["points"][:3]
    missing = ~np.isfinite(pts).all(axis=0)
    assert (res[missing] == -1).all() and (res[~missing] >= 0).all()
    assert (res[~missing] > 0).mean() > 0.5  # the filter's uncertainty, not all 0
    csv_t = np.loadtxt(outs["csv"], delimiter=",", skiprows=1, usecols=0)
    rate = c["header"]["points"]["frame_rate"]
    c3d_t = (c["header"]["points"]["first_frame"] + np.arange(pts.shape[2])) / rate
    trc_t = np.loadtxt(outs["trc"], skiprows=6, usecols=1)
    np.testing.assert_allclose(c3d_t, csv_t, atol=1e-6)
    np.testing.assert_allclose(trc_t, csv_t, atol=1e-6)
    assert csv_t[0] > 0  # seconds from the session's start, not from the first fused frame


def test_demo_output_is_ignored_by_git() -> None:
    assert "kinefuse-demo/" in (ROOT / ".gitignore").read_text().splitlines()


def test_depth_codec_is_lossless_and_smaller_than_zlib(session) -> None:
    import zlib

    from kinefuse.formats.store.session_store import decode_depth, encode_depth

    with SessionStore.open(session) as st:
        _, _, frames = next(st.iter_depth_frames("k0", batch=4))
        sizes = st.storage_bytes()
    assert sizes["depth_frames"] > 0 and sizes["file"] >= sizes["depth_frames"]
    ours = sum(len(encode_depth(f)) for f in frames)
    plain = sum(len(zlib.compress(f.tobytes(), 1)) for f in frames)
    assert ours < 0.95 * plain
    for f in frames:
        assert np.array_equal(decode_depth(encode_depth(f), *f.shape), f)
        assert np.array_equal(decode_depth(zlib.compress(f.tobytes()), *f.shape), f)  # old rows
