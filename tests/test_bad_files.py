"""Bad files, hostile or careless: every one is refused with one line and exit 2, or read
correctly; none costs more than a glance before it is refused (issue 45, items 7 and 8)."""

from __future__ import annotations

import asyncio
import gzip
import json
import os
import re
import shutil
import sqlite3
import time
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.inputs import read_text
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.errors import InputError, MotionFormatError
from kinefuse.formats.markers import read_markers
from kinefuse.formats.motion.bvh import read_bvh
from kinefuse.formats.store.live_tables import SightingRow
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.live.server.recorder import Recorder
from kinefuse.pipeline.frame_sources import open_source


def run(capsys, *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code: int, err: str, *needles: str) -> None:
    """Exit 2 and one line, ``kinefuse: error: ...`` holding every needle, after the progress
    lines (``loading ...``); no traceback."""
    lines = [ln for ln in err.splitlines() if not ln.startswith("loading ")]
    assert code == 2, err
    assert "Traceback" not in err, err
    assert len(lines) == 1 and lines[0].startswith("kinefuse: error:"), err
    for n in needles:
        assert n in lines[0], (n, err)


def clean_error(code: int, err: str, *needles: str) -> None:
    """Exit 2, no traceback, and the message's first line ``kinefuse: error: ...`` holding every
    needle (some messages go on with an example of what to write)."""
    lines = [ln for ln in err.splitlines() if not ln.startswith("loading ")]
    assert code == 2 and "Traceback" not in err, err
    assert lines and lines[0].startswith("kinefuse: error:"), err
    assert sum(ln.startswith("kinefuse: error:") for ln in lines) == 1, err
    for n in needles:
        assert n in lines[0], (n, err)


@pytest.fixture(scope="module")
def walk(shared_data) -> Path:
    return shared_data / "motion" / "cmu" / "02_walk_a.amc"


@pytest.fixture(scope="module")
def session(tmp_path_factory, walk) -> Path:
    """A short complete simulated session (1 s, no calibration phase)."""
    out = tmp_path_factory.mktemp("bad_files") / "s.sqlite"
    argv = ["simulate", "--clip", walk, "--seconds", "1", "--calibration-seconds", "0",
            "--out", out]  # fmt: skip
    assert main([str(a) for a in argv]) == 0
    return out


# -- a BVH 1,000 levels deep ------------------------------------------------------------------

DEPTH = 1000


@pytest.fixture(scope="module")
def deep_bvh(tmp_path_factory, shared_data) -> tuple[Path, Path]:
    """CMU 131_01 with a chain of 1,000 joints (no channels) hung under its Head: the file's
    frames are unchanged, its hierarchy is 1,000 levels deeper than Python's default call
    stack allows a recursive reader to go. Returns ``(deep file, original file)``."""
    original = shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh"
    lines = original.read_text(encoding="utf-8").split("\n")
    head = next(i for i, ln in enumerate(lines) if ln.strip() == "JOINT Head")
    chain: list[str] = []
    for k in range(DEPTH):
        chain += [f"JOINT Tail{k}", "{", "OFFSET 0 0.001 0", "CHANNELS 0"]
    chain += ["End Site", "{", "OFFSET 0 0.001 0", "}"] + ["}"] * DEPTH
    # after Head's '{', OFFSET and CHANNELS lines: the chain is Head's first child
    deep = tmp_path_factory.mktemp("deep") / "deep.bvh"
    deep.write_text("\n".join(lines[: head + 4] + chain + lines[head + 4 :]), encoding="utf-8")
    return deep, original


def test_a_deep_bvh_is_read_whole(deep_bvh) -> None:
    deep, original = deep_bvh
    d, o = read_bvh(deep), read_bvh(original)
    assert len(d.names) == len(o.names) + DEPTH + 1  # the chain and its End Site
    tail = d.index()[f"Tail{DEPTH - 1}"]
    parent = d.parents[tail]
    assert d.names[parent] == f"Tail{DEPTH - 2}"
    keep = [d.index()[n] for n in o.names]
    np.testing.assert_array_equal(d.positions[:, keep], o.positions)  # the chain changes nothing
    # 1,000 links of 1 mm straight up the head's frame: the tail is 1 m from the head
    head = d.index()["Head"]
    gap = np.linalg.norm(d.positions[0, tail] - d.positions[0, head])
    assert abs(gap - 0.001 * DEPTH) < 1e-6


def test_simulate_reads_a_deep_bvh(deep_bvh, tmp_path, capsys) -> None:
    deep, original = deep_bvh
    common = ["--seconds", "1", "--calibration-seconds", "0", "--seed", "3"]
    code, _, err = run(capsys, "simulate", "--clip", deep, *common, "--out", tmp_path / "d.sqlite")
    assert code == 0 and "Traceback" not in err, err
    assert (
        main(["simulate", "--clip", str(original), *common, "--out", str(tmp_path / "o.sqlite")])
        == 0
    )
    with (
        SessionStore.open(tmp_path / "d.sqlite") as d,
        SessionStore.open(tmp_path / "o.sqlite") as o,
    ):
        np.testing.assert_array_equal(d.truth().motion()[1], o.truth().motion()[1])


def test_analyze_reads_a_deep_bvh(deep_bvh, tmp_path, capsys) -> None:
    deep, _ = deep_bvh
    code, _, err = run(capsys, "analyze", deep, "--no-plots", "--out", tmp_path / "a")
    assert code == 0 and "Traceback" not in err, err
    assert (tmp_path / "a" / "analysis.json").is_file()


def test_an_unmappable_deep_bvh_lists_a_few_joints(tmp_path, capsys) -> None:
    """A deep skeleton no map fits: the message lists some of its joints, not all 1,001."""
    lines = ["HIERARCHY", "ROOT Hips", "{", "OFFSET 0 0 0",
             "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]  # fmt: skip
    for k in range(DEPTH):
        lines += [f"JOINT J{k}", "{", "OFFSET 0 0.01 0", "CHANNELS 0"]
    lines += ["End Site", "{", "OFFSET 0 0.01 0", "}"] + ["}"] * (DEPTH + 1)
    lines += ["MOTION", "Frames: 2", "Frame Time: 0.0083333", "0 0 0 0 0 0", "0 0 0 0 0 1"]
    clip = tmp_path / "worm.bvh"
    clip.write_text("\n".join(lines) + "\n", encoding="utf-8")
    code, _, err = run(capsys, "simulate", "--clip", clip, "--out", tmp_path / "s.sqlite")
    assert code == 2 and "Traceback" not in err and "RecursionError" not in err, err
    assert "--name-map" in err and "Source joints seen (1001)" in err and "J999" not in err
    assert not (tmp_path / "s.sqlite").exists()


# -- malformed JSON stored in a session -------------------------------------------------------


def forge(session: Path, folder: Path, sql: str, *params: object) -> Path:
    """A copy of ``session`` with one statement run on it (a damaged or forged session)."""
    bad = folder / "forged.sqlite"
    shutil.copy(session, bad)
    conn = sqlite3.connect(bad)
    conn.execute(sql, params)
    conn.commit()
    conn.close()
    return bad


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('{"fx": 36', "is not valid JSON"),
        ("[" * 100_000, "nested too deeply"),
        ("[1, 2]", "is not an object"),
        ('{"fx": 365.0}', "malformed (no 'width')"),
        ('{"width": -5, "height": 4, "fx": 1, "fy": 1, "cx": 0, "cy": 0}', "image size"),
    ],
)
@pytest.mark.parametrize("command", ["inspect", "fuse"])
def test_malformed_intrinsics_are_one_line(
    session, tmp_path, capsys, command, text, needle
) -> None:
    bad = forge(session, tmp_path, "UPDATE sensors SET intrinsics = ? WHERE id = 'k1'", text)
    argv = ["fuse", bad, "--true-calibration", "--out", tmp_path / "f.csv"]
    code, _, err = run(capsys, *(argv if command == "fuse" else ["inspect", bad]))
    one_line_error(code, err, str(bad), "sensor 'k1'", needle, "restore it from a copy")
    assert not (tmp_path / "f.csv").exists()


@pytest.mark.parametrize("key", ["complete", "created"])
def test_malformed_meta_is_one_line(session, tmp_path, capsys, key) -> None:
    bad = forge(session, tmp_path, "UPDATE meta SET value = '{oops' WHERE key = ?", key)
    code, _, err = run(capsys, "inspect", bad)
    one_line_error(code, err, str(bad), f"meta entry {key!r} is not valid JSON")


# -- a marker file is looked at before it is read whole ---------------------------------------


def bytes_read() -> int:
    """Bytes this process has read so far (Linux ``/proc/self/io`` ``rchar``)."""
    io = Path("/proc/self/io")
    if not io.is_file():
        pytest.skip("needs /proc/self/io (Linux) to count the bytes read")
    return next(int(ln.split()[1]) for ln in io.read_text().splitlines() if ln.startswith("rchar"))


def sparse(path: Path, size: int) -> Path:
    """A file of ``size`` bytes that takes no disk space (a hole: all zeros)."""
    with path.open("wb") as f:
        f.truncate(size)
    return path


def test_a_sparse_2gb_trc_is_refused_by_its_size(tmp_path, capsys) -> None:
    big = sparse(tmp_path / "take.trc", 2 * 2**30)
    import kinefuse.app.workflows.analyze  # noqa: F401  (its imports are not the file's bytes)

    before = bytes_read()
    code, _, err = run(capsys, "analyze", big, "--out", tmp_path / "a")
    assert bytes_read() - before < 16 * 2**20  # not the 2 GiB
    one_line_error(code, err, str(big), "the file is 2 GiB", "TRC marker file")
    assert not (tmp_path / "a").exists()


def test_a_trc_under_the_size_limit_is_refused_by_its_first_bytes(tmp_path) -> None:
    """A 100 MiB hole is under the size limit: its first bytes refuse it, the rest is not read."""
    holed = sparse(tmp_path / "holed.trc", 100 * 2**20)
    before = bytes_read()
    with pytest.raises(MotionFormatError, match=r"not a text file \(byte 1 is a NUL byte\)"):
        read_markers(holed)
    assert bytes_read() - before < 2**20
    text = tmp_path / "notes.trc"
    text.write_text("These are my notes\n" + "x" * 10**6 + "\n", encoding="utf-8")
    with pytest.raises(
        MotionFormatError, match=r"notes.trc:1: not a TRC file.*'These are my notes'"
    ):
        read_markers(text)


def test_a_gzip_bomb_is_read_no_further_than_the_limit(tmp_path) -> None:
    bomb = tmp_path / "clip.bvh.gz"
    with gzip.open(bomb, "wb") as f:
        f.write(b"HIERARCHY\n" + b"a" * 20_000)
    with pytest.raises(InputError, match="expands to more than the 10 KiB"):
        read_text(bomb, what="BVH file", max_bytes=10 * 1024)
    assert read_text(bomb, what="BVH file").startswith("HIERARCHY\naaa")


def test_a_sparse_c3d_is_refused_by_its_first_bytes(tmp_path, capsys) -> None:
    """ezc3d spends minutes on a large file of zeros: its header is checked first."""
    big = sparse(tmp_path / "take.c3d", 2 * 2**30)
    code, _, err = run(capsys, "analyze", big, "--out", tmp_path / "a")
    one_line_error(code, err, str(big), "not a C3D file")


# -- every malformed input of every command: one line, exit 2 ---------------------------------

#: Contents no reader should take: empty, zeros, text of another kind, binaries with and
#: without NUL bytes, UTF-16, Latin-1, a first line of 200 kB, arrays nested 50,000 deep (TOML's
#: parser recurses), and a 2 GiB hole.
MALFORMED: dict[str, bytes | int] = {
    "empty": b"",
    "zeros": bytes(100),
    "prose": b"hello world\n",
    "binary": bytes(range(256)) * 12,
    "binary-no-nul": bytes(range(1, 256)) * 12,
    "utf16": "PathFileType\t4\n[x]\n".encode("utf-16"),
    "latin1": "PathFileType\xe9\n[x]\n".encode("latin-1"),
    "one-long-line": b"x" * 200_000,
    "nested": b"x = " + b"[" * 50_000 + b"]" * 50_000 + b"\n",
    "hole": 2 * 2**30,
}


def _commands(data: Path, session: Path, out: Path) -> dict[str, tuple[str, list[str]]]:
    """``kind -> (suffix of the bad file, argv with {bad} for it)``."""
    walk = str(data / "motion" / "cmu" / "02_walk_a.amc")
    trc = str(data / "markers" / "opensim" / "Pipelines_Rajagopal_ExpData_motion_capture_walk.trc")
    sim = ["simulate", "--clip", walk, "--seconds", "0.5", "--calibration-seconds", "0"]
    return {
        "analyze trc": (".trc", ["analyze", "{bad}", "--out", f"{out}/a"]),
        "analyze c3d": (".c3d", ["analyze", "{bad}", "--out", f"{out}/a"]),
        "analyze bvh": (".bvh", ["analyze", "{bad}", "--out", f"{out}/a"]),
        "analyze --static": (".trc", ["analyze", trc, "--static", "{bad}", "--out", f"{out}/a"]),
        "analyze --map": (".toml", ["analyze", trc, "--map", "{bad}", "--out", f"{out}/a"]),
        "simulate bvh": (".bvh", ["simulate", "--clip", "{bad}", "--out", f"{out}/s.sqlite"]),
        "simulate amc": (".amc", ["simulate", "--clip", "{bad}", "--out", f"{out}/s.sqlite"]),
        "simulate --skeleton": (".asf", [*sim, "--skeleton", "{bad}", "--out", f"{out}/s.sqlite"]),
        "simulate --rig": (".toml", [*sim, "--rig", "{bad}", "--out", f"{out}/s.sqlite"]),
        "simulate --name-map": (".toml", [*sim, "--name-map", "{bad}", "--out", f"{out}/s.sqlite"]),
        "fuse --calibration": (
            ".toml",
            ["fuse", str(session), "--calibration", "{bad}", "--out", f"{out}/f.csv"],
        ),
        "fuse session": (".sqlite", ["fuse", "{bad}", "--true-calibration"]),
        "inspect session": (".sqlite", ["inspect", "{bad}"]),
        "realdata csv": (".csv", ["realdata", "{bad}"]),
    }


@pytest.mark.parametrize("content", list(MALFORMED))
def test_every_malformed_input_is_one_line(session, shared_data, tmp_path, capsys, content) -> None:
    """Each command, each kind of file it reads, each malformed content: exit 2, an error naming
    the file, no traceback, and no output left behind."""
    for kind, (suffix, argv) in _commands(shared_data, session, tmp_path).items():
        bad = tmp_path / f"{content}{suffix}"
        value = MALFORMED[content]
        if isinstance(value, int):
            sparse(bad, value)
        else:
            bad.write_bytes(value)
        code, _, err = run(capsys, *(str(bad) if a == "{bad}" else a for a in argv))
        try:
            clean_error(code, err, bad.name)
        except AssertionError as e:
            raise AssertionError(f"{kind} of {content}: {e}") from None
        assert sorted(p.name for p in tmp_path.iterdir()) == [bad.name], kind
        bad.unlink()


# -- what kinefuse writes is the user's only --------------------------------------------------


def mode(path: Path) -> int:
    return path.stat().st_mode & 0o777


@pytest.fixture
def open_umask():
    """The common umask 022, under which a plain ``open(path, "w")`` makes a file world-readable."""
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_a_recording_is_private(tmp_path, open_umask) -> None:
    """The live recorder's store, and the -wal/-shm files beside it while it records."""
    path = tmp_path / "rec.sqlite"
    seen: dict[str, int] = {}

    async def record() -> None:
        rec = Recorder(path, {"recorded_by": "test"}, clock=time.monotonic)
        await rec.open()
        rec.add_sensor("k0", "S0", Intrinsics())
        await rec.flush()
        seen.update({p.name: mode(p) for p in tmp_path.iterdir()})
        await rec.close(clean=True)

    asyncio.run(record())
    assert {"rec.sqlite", "rec.sqlite-wal"} <= set(seen), seen
    assert set(seen.values()) == {0o600}, seen
    assert mode(path) == 0o600


def test_sessions_exports_and_analyses_are_private(
    session, shared_data, tmp_path, capsys, open_umask
) -> None:
    out = tmp_path / "s.sqlite"
    argv = ["simulate", "--clip", shared_data / "motion" / "cmu" / "02_walk_a.amc",
            "--seconds", "0.5", "--calibration-seconds", "0", "--out", out]  # fmt: skip
    assert run(capsys, *argv)[0] == 0
    assert mode(out) == 0o600
    for suffix in (".csv", ".trc", ".c3d", ".bvh"):
        export = tmp_path / f"f{suffix}"
        assert run(capsys, "fuse", session, "--true-calibration", "--out", export)[0] == 0
        assert mode(export) == 0o600, suffix
    trc = (
        shared_data / "markers" / "opensim" / "Pipelines_Rajagopal_ExpData_motion_capture_walk.trc"
    )
    assert run(capsys, "analyze", trc, "--no-plots", "--out", tmp_path / "a")[0] == 0
    assert mode(tmp_path / "a") == 0o700
    assert mode(tmp_path / "a" / "analysis.json") == 0o600


# -- inspect's duration: from plausible time stamps -------------------------------------------


def test_inspect_counts_the_bulk_of_the_stamps(session, tmp_path, capsys) -> None:
    """One frame stamped 2,176 s after the take, through the store's own writer, as a peer could
    send it: the duration stays the take's, and inspect says one stamp was not counted."""
    code, out, _ = run(capsys, "inspect", session, "--json")
    honest = json.loads(out)
    assert code == 0 and honest["stamps_ignored"] == 0
    with SessionStore.open(session) as st:
        obs = st.observations("k1")
        spans = [np.ptp(st.observations(s.id).t_sensor_s) for s in st.sensors()]
    assert honest["duration_s"] == pytest.approx(max(spans))  # no honest stamp is dropped
    forged = tmp_path / "forged.sqlite"
    shutil.copy(session, forged)
    with SessionStore.open(forged, writable=True) as st:
        st.append_observations(
            "k1",
            [int(obs.seq.max()) + 1],
            [float(obs.t_sensor_s.max()) + 2176.0],
            obs.joints_m[-1:],
            obs.states[-1:],
        )
    code, out, _ = run(capsys, "inspect", forged, "--json")
    info = json.loads(out)
    assert code == 0 and info["duration_s"] == pytest.approx(honest["duration_s"])
    assert info["stamps_ignored"] == 1
    assert {s["id"]: s["stamps_ignored"] for s in info["sensors"]} == {
        "k0": 0, "k1": 1, "k2": 0, "k3": 0
    }  # fmt: skip
    code, out, _ = run(capsys, "inspect", forged)
    assert code == 0 and f"duration {honest['duration_s']:.2f} s" in out
    assert "1 frame(s) stamped far outside it not counted (k1: 1;" in out


# -- a session edited by hand or by an attacker -----------------------------------------------


@pytest.fixture(scope="module")
def cal_session(tmp_path_factory, walk) -> Path:
    """A short simulated session with a calibration phase (8 s of wand, depth at 5 Hz)."""
    out = tmp_path_factory.mktemp("cal") / "c.sqlite"
    argv = ["simulate", "--clip", walk, "--seconds", "1", "--calibration-seconds", "8",
            "--depth-rate", "5", "--seed", "1", "--out", out]  # fmt: skip
    assert main([str(a) for a in argv]) == 0
    return out


#: ``name -> (SQL, parameters, what the error says)``: damage SQLite itself lets through.
FORGED: dict[str, tuple[str, tuple[object, ...], str]] = {
    "a table dropped": ("DROP TABLE observations", (), "no such table: observations"),
    "text in a time column": (
        "UPDATE observations SET t_sensor_s = 'soon' WHERE seq = 6",
        (),
        "is not a number",
    ),
    "text in a clock probe": (
        "UPDATE clock_probes SET t2_client_s = 'abc' WHERE idx = 1",
        (),
        "clock probes of sensor",
    ),
    "text as a sensor's rate": (
        "UPDATE sensors SET rate_hz = 'fast' WHERE key = 1",
        (),
        "the rate of sensor 'k0'",
    ),
    "a wand out of range": (
        "UPDATE meta SET value = ? WHERE key = 'wand'",
        ('{"radius_m": -1, "stick_length_m": 0.4, "stick_radius_m": 0.01}',),
        "wand or calibration phase is malformed",
    ),
    "a huge depth frame": (
        "UPDATE depth_frames SET height = 100000, width = 100000",
        (),
        "frames of 100000x100000 pixels",
    ),
    "a depth frame that inflates": (
        "UPDATE depth_frames SET depth_mm = ? WHERE seq = 0",
        (b"KFD1" + __import__("zlib").compress(bytes(10**7)),),
        "expands past the",
    ),
}


@pytest.mark.parametrize("damage", list(FORGED))
def test_a_damaged_session_is_one_line(cal_session, tmp_path, capsys, damage) -> None:
    """calibrate (which reads everything, depth frames included), then fuse and inspect on what
    they read: exit 2 and one line naming the file, or a clean run."""
    sql, params, needle = FORGED[damage]
    bad = forge(cal_session, tmp_path, sql, *params)
    code, _, err = run(capsys, "calibrate", bad, "--out", tmp_path / "c.toml")
    one_line_error(code, err, str(bad), needle)
    assert not (tmp_path / "c.toml").exists()
    for argv in (
        ["inspect", bad],
        ["fuse", bad, "--true-calibration", "--out", tmp_path / "f.csv"],
    ):
        code, _, err = run(capsys, *argv)
        assert code in (0, 2) and "Traceback" not in err and "Exception ignored" not in err, err
        if code == 2:
            one_line_error(code, err, str(bad))


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """A small live recording, written by the server's recorder: one sensor, 30 frames, clock
    probes, a wand sighting and a floor."""
    path = tmp_path_factory.mktemp("rec") / "rec.sqlite"
    joints = np.tile([0.1, 0.2, 2.5], (N_JOINTS, 1))
    states = np.full(N_JOINTS, 2, np.int8)

    async def record() -> None:
        rec = Recorder(path, {"recorded_by": "test"}, clock=time.monotonic)
        await rec.open()
        rec.add_sensor("k0", "S0", Intrinsics())
        for seq in range(30):
            t = seq / 30
            rec.add_observation("k0", seq, t, t, t, t, joints, states, None, None)
            rec.add_probe("k0", t, t, t, t)
        rec.add_sighting(SightingRow("k0", 0, 0.5, 0.5, 0.5, (0.1, 0.2, 2.0), 0.9, 400, 0.003))
        rec.add_floor("k0", 0.5, FloorPlane(np.array([0.0, 0.0, 1.0]), 0.8, 5000, 0.004))
        await rec.flush()
        await rec.close(clean=True)

    asyncio.run(record())
    return path


@pytest.mark.parametrize(
    ("sql", "needle"),
    [
        ("UPDATE live_sightings SET x_m = 'left'", "the wand sightings of sensor 'k0'"),
        ("UPDATE live_floors SET nx = 'up'", "the floor of sensor 'k0'"),
        ("DROP TABLE live_floors", "no such table: live_floors"),
    ],
)
def test_a_damaged_recording_is_one_line(recording, tmp_path, capsys, sql, needle) -> None:
    bad = forge(recording, tmp_path, sql)
    code, _, err = run(capsys, "calibrate", bad, "--out", tmp_path / "c.toml")
    one_line_error(code, err, str(bad), needle)


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ("[" * 100_000, "not a kinect2-tracking JSON file (maximum recursion depth"),
        (2 * 2**30, "the file is 2 GiB"),
        ('{"bodyFrame": ', "not a kinect2-tracking JSON file (Expecting value"),
    ],
)
def test_a_bad_kinect2_json_source_is_one_error(tmp_path, content, needle) -> None:
    """``kinefuse sensor --source kinect2json:FILE``: a JSON nested 100,000 deep, a 2 GiB hole,
    a cut file."""
    bad = tmp_path / "walk.json"
    if isinstance(content, int):
        sparse(bad, content)
    else:
        bad.write_text(content, encoding="utf-8")
    with pytest.raises(InputError, match=re.escape(needle)):
        open_source(f"kinect2json:{bad}")


def test_inspect_of_a_recording_with_a_forged_stamp(tmp_path, capsys) -> None:
    """A 2-minute recording (the server's recorder, 30 Hz) in which a peer stamped one frame
    2,176 s on its device clock; the server stamped its arrival honestly."""
    path = tmp_path / "rec.sqlite"
    joints = np.tile([0.1, 0.2, 2.5], (N_JOINTS, 1))
    states = np.full(N_JOINTS, 2, np.int8)

    async def record() -> None:
        rec = Recorder(path, {"recorded_by": "test"}, clock=time.monotonic)
        await rec.open()
        rec.add_sensor("k0", "S0", Intrinsics())
        for seq in range(3600):
            t = seq / 30
            rec.add_observation("k0", seq, t, t, t + 0.01, t, joints, states, None, None)
        rec.add_observation("k0", 3600, 2176.0, 120.0, 120.01, 120.0, joints, states, None, None)
        await rec.close(clean=True)

    asyncio.run(record())
    code, out, _ = run(capsys, "inspect", path, "--json")
    info = json.loads(out)
    assert code == 0 and info["duration_s"] == pytest.approx(3599 / 30)
    assert info["stamps_ignored"] == 1 and info["sensors"][0]["stamps_ignored"] == 1
    code, out, _ = run(capsys, "inspect", path)
    assert code == 0 and "duration 119.97 s" in out and "(k0: 1;" in out


@pytest.mark.parametrize("suffix", [".csv", ".trc", ".c3d", ".bvh"])
def test_a_huge_file_at_an_output_path_is_refused_unread(session, tmp_path, capsys, suffix) -> None:
    """Whether kinefuse wrote the file it would replace is told from its first bytes: a 2 GiB
    hole is refused without being read (ezc3d alone spent a minute on one)."""
    out = sparse(tmp_path / f"take{suffix}", 2 * 2**30)
    import kinefuse.formats.export  # noqa: F401  (its imports are not the file's bytes)

    before = bytes_read()
    code, _, err = run(capsys, "fuse", session, "--true-calibration", "--out", out)
    assert bytes_read() - before < 64 * 2**20
    one_line_error(code, err, "refusing to replace", str(out))
    assert out.stat().st_size == 2 * 2**30


def test_a_forged_stored_wand_is_one_line_for_the_sensor(tmp_path: Path, shared_data: Path) -> None:
    """``kinefuse sensor --source sim:`` of a simulated session whose stored wand was forged:
    exit 2, one line, no traceback (the client reads the wand from the session's metadata)."""
    import subprocess
    import sys

    from kinefuse.app.cli import main
    from kinefuse.formats.store.session_store import SessionStore

    session = tmp_path / "s.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--sensors", "2", "--out", str(session)]) == 0
    with SessionStore.open(session, writable=True) as st:
        st.set_meta("wand", {"radius_m": -1, "bogus": 3})
    run = subprocess.run(
        [sys.executable, "-m", "kinefuse", "sensor", "--server", "127.0.0.1:9",
         "--source", f"sim:{session}#k0"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr and "stored wand is malformed" in run.stderr
