"""Bad files, hostile or careless: every one is refused with one line and exit 2, or read
correctly; none costs more than a glance before it is refused (issue 45, items 7 and 8)."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from kinefuse.cli import main
from kinefuse.io.store.session import SessionStore
from kinefuse.motion.bvh import read_bvh


def run(capsys, *argv: object) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code: int, err: str, *needles: str) -> None:
    """Exit 2 and a single ``kinefuse: error:`` line holding every needle; no traceback."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert "Traceback" not in err, err
    assert lines and lines[-1].startswith("kinefuse: error:"), err
    assert sum(ln.startswith("kinefuse: error:") for ln in lines) == 1, err
    assert err.count("\n") == 1, err  # the message is one line
    for n in needles:
        assert n in lines[-1], (n, err)


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
