"""``kinefuse evaluate`` and ``kinefuse inspect`` on sessions without ground truth.

Real data: a recording made from a real two-Kinect KinectMultiTrack log, frame by frame as a
client sends it (``tests/test_live_consistency.py``), and ``kinefuse track`` of the real Azure
Kinect recording (depth only). A simulated session with its truth tables dropped stands for a
recording whose truth is known elsewhere. Every command a new message suggests is run here as
written.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import sqlite3
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.live_consistency import recording_consistency
from kinefuse.lab.report.html import is_kinefuse_report
from test_live_consistency import _log, _record

TRUTH_ONLY = ("accuracy", "time", "trajectories", "occlusion")


def _kinefuse(command: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """A ``kinefuse ...`` command line as a message prints it, run as written in ``cwd``."""
    words = shlex.split(command)
    assert words[0] == "kinefuse", command
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.run(
        [sys.executable, "-m", "kinefuse", *words[1:]],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=300,
    )


def _suggested(text: str) -> list[str]:
    """The commands a message suggests (between backticks)."""
    return [c for c in re.findall(r"`([^`]+)`", text) if c.startswith("kinefuse ")]


class _Html(HTMLParser):
    """The ids and the text of an HTML page; fails on a malformed tag."""

    def __init__(self) -> None:
        super().__init__()
        self.ids: list[str] = []
        self.text: list[str] = []
        self.open: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.ids += [v for k, v in attrs if k == "id" and v]
        if tag in ("table", "tr", "td", "th", "div", "p", "h2", "nav"):
            self.open.append(tag)

    def handle_endtag(self, tag: str) -> None:
        if tag in ("table", "tr", "td", "th", "div", "p", "h2", "nav"):
            assert self.open and self.open.pop() == tag, (tag, self.open[-3:])

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def _parse(path: Path) -> _Html:
    p = _Html()
    p.feed(path.read_text(encoding="utf-8"))
    p.close()
    assert p.open == [], p.open
    return p


@pytest.fixture(scope="module")
def real(tmp_path_factory, shared_data) -> Path:
    """A recording of a real two-Kinect log (side sensor at 45 degrees), no calibration."""
    rec = tmp_path_factory.mktemp("real") / "rec.sqlite"
    _record(_log(shared_data, "Study_4_Kinect_1_*.csv"), rec)
    return rec


def test_evaluate_a_real_recording_reports_consistency(real, tmp_path, capsys) -> None:
    out = tmp_path / "eval"
    assert main(["evaluate", str(real), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "no truth: the session has no ground truth" in text
    assert "sensor vs sensor" in text and "MAE" not in text and "nan" not in text
    report = json.loads((out / "evaluate.json").read_text())
    assert report["truth"] is False and report["registration"]["kind"] == "body"
    # the body registration is realdata's: the same correction as the recording's own figures
    ref = recording_consistency(real)
    (sid,) = ref["registration"]["by_sensor"]
    ours = report["registration"]["by_sensor"][sid]["correction_deg"]
    assert ours == pytest.approx(ref["registration"]["by_sensor"][sid]["correction_deg"], abs=1e-9)
    pair = next(iter(report["agreement"]["disagreement"]))
    med, p95 = report["agreement"]["disagreement"][pair]["all"]
    ref_med = ref["disagreement"][pair]["all"][0]
    assert 0.02 < med < 0.12 and med < p95 and med == pytest.approx(ref_med, rel=0.1)
    for m in ("linear", "paper", "best", "best-live"):
        r = report[m]
        assert 0.5 < r["placed"] <= 1 and sum(r["status"].values()) == pytest.approx(1.0)
        assert set(r["by_joint"]) >= {"SpineBase", "WristRight"} and len(r["bones"]) == 24
        for d in r["to_sensors"].values():  # each sensor nearer its fused skeleton than the other
            assert 0.005 < d["all"][0] < med
    # best keeps its bones' lengths (its bone model), the per-frame solutions do not
    assert report["best"]["bone_sd_median_m"] < 0.5 * report["linear"]["bone_sd_median_m"]
    html = out / "report.html"
    assert is_kinefuse_report(html)
    page = _parse(html)
    assert "no-truth" in page.ids and "consistency" in page.ids and "bones" in page.ids
    assert not set(TRUTH_ONLY) & set(page.ids)
    words = " ".join(page.text)
    assert "No accuracy, error over time" in words and "has no ground truth" in words
    assert "vs truth" not in words
    csv = (out / "consistency_by_joint.csv").read_text().splitlines()
    assert csv[0] == "method,joint,placed,ok,residual_median_m" and len(csv) == 1 + 6 * 25


def test_evaluate_json_without_truth(real, capsys) -> None:
    assert main(["evaluate", str(real), "--methods", "best", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["truth"] is False and "best" in report and "linear" not in report
    assert report["best"]["residual_m"][0] > 0


def test_evaluate_a_simulated_session_without_its_truth(tmp_path, shared_data, capsys) -> None:
    session = tmp_path / "walk.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    sim = ["simulate", "--clip", str(clip), "--calibration-seconds", "0", "--seed", "5"]
    assert main([*sim, "--out", str(session)]) == 0
    with SessionStore.open(session) as st:
        assert st.has_truth()
    # the store has no API to drop the truth (nothing should): sqlite on a copy we made
    with sqlite3.connect(session) as db:
        for table in ("truth_motion", "truth_sensors", "truth_observations", "truth_wand"):
            db.execute(f"DELETE FROM {table}")
    with SessionStore.open(session) as st:
        assert not st.has_truth()
    out = tmp_path / "eval"
    capsys.readouterr()
    assert main(["evaluate", str(session), "--out", str(out)]) == 0
    report = json.loads((out / "evaluate.json").read_text())
    assert report["truth"] is False and len(report["sensors_with_body"]) >= 2
    assert report["best"]["placed"] > 0.8
    page = _parse(out / "report.html")
    assert "consistency" in page.ids and not set(TRUTH_ONLY) & set(page.ids)
    # --true-calibration needs the truth: one line, exit 2
    assert main(["evaluate", str(session), "--true-calibration"]) == 2
    err = capsys.readouterr().err
    assert "has no ground truth" in err and len(err.splitlines()) == 1
    assert "leave it out" in err and _suggested(err) == []  # no command that would not run


@pytest.fixture(scope="module")
def depth_only(tmp_path_factory, shared_data) -> Path:
    """``kinefuse track`` of the real Azure Kinect recording with no tracker (depth only)."""
    pytest.importorskip("av")
    cwd = tmp_path_factory.mktemp("track")
    mkv = shared_data / "depth" / "pyk4a_recording.mkv"
    p = _kinefuse(f"kinefuse track {shlex.quote(str(mkv))} --out S.sqlite", cwd)
    assert p.returncode == 0, p.stderr
    return cwd / "S.sqlite"


def test_evaluate_with_nothing_fusable_exits_3_and_says_why(depth_only) -> None:
    p = _kinefuse("kinefuse evaluate S.sqlite", depth_only.parent)
    assert p.returncode == 3 and p.stdout == ""
    assert p.stderr.startswith("kinefuse: error: nothing to evaluate in S.sqlite: no sensor")
    assert "Traceback" not in p.stderr and len(p.stderr.splitlines()) == 1
    (cmd,) = _suggested(p.stderr)
    assert cmd == "kinefuse inspect S.sqlite"
    assert _kinefuse(cmd, depth_only.parent).returncode == 0


def test_inspect_of_a_depth_only_session_says_how_to_add_a_tracker(depth_only) -> None:
    p = _kinefuse("kinefuse inspect S.sqlite", depth_only.parent)
    assert p.returncode == 0, p.stderr
    (warning,) = [ln for ln in p.stdout.splitlines() if ln.startswith("warning:")]
    assert "depth frames only, no body tracker's frames" in warning and "--tracker" in warning
    assert "rig file" not in p.stdout
    retrack, sources = _suggested(warning)
    assert retrack.endswith("--out S-pose.sqlite --tracker pose")
    for cmd in (retrack, sources):
        run = _kinefuse(cmd, depth_only.parent)
        assert run.returncode == 0, (cmd, run.stderr)
    # the new session had a tracker that found nobody (a mug on a table): it says so instead
    again = _kinefuse("kinefuse inspect S-pose.sqlite", depth_only.parent)
    assert "the body tracker (pose) found no person in its 1 frames" in again.stdout
    assert "rig file" not in again.stdout and "--tracker" not in again.stdout


def test_inspect_of_a_real_recording_gives_no_rig_file_advice(real, tmp_path) -> None:
    """A sensor of a real recording that never saw the body: not the simulated lab's advice."""
    from kinefuse.core.camera.intrinsics import Intrinsics

    rec = tmp_path / "three.sqlite"
    rec.write_bytes(real.read_bytes())
    with SessionStore.open(rec, writable=True) as st:  # a third sensor that sent no frame
        st.add_sensor("idle", "IDLE", Intrinsics())
    p = _kinefuse(f"kinefuse inspect {shlex.quote(str(rec))}", tmp_path)
    assert p.returncode == 0, p.stderr
    assert "warning: sensor idle sent no frame: check that its client ran" in p.stdout
    assert "rig file" not in p.stdout


def test_evaluate_with_one_sensor_seeing_the_body(real, tmp_path) -> None:
    """One view: no sensor-vs-sensor figure, the rest of the figures and the report still."""
    rec = tmp_path / "one.sqlite"
    rec.write_bytes(real.read_bytes())
    with sqlite3.connect(rec) as db:  # a copy we made: the second sensor's frames dropped
        (key,) = db.execute("SELECT key FROM sensors ORDER BY key").fetchall()[1]
        db.execute("DELETE FROM observations WHERE sensor_key = ?", (key,))
    out = tmp_path / "eval"
    assert main(["evaluate", str(rec), "--methods", "best,paper", "--out", str(out)]) == 0
    report = json.loads((out / "evaluate.json").read_text())
    assert report["agreement"] is None and len(report["sensors_with_body"]) == 1
    assert report["best"]["placed"] > 0.5 and report["registration"]["kind"] == "body"
    page = _parse(out / "report.html")
    assert "no second view to compare" in " ".join(page.text)


def test_inspect_of_a_live_sensor_with_depth_only_says_to_add_a_tracker(real, tmp_path) -> None:
    """A live sensor that streamed depth only (a camera with no --tracker): how to add one."""
    from kinefuse.core.camera.intrinsics import Intrinsics

    rec = tmp_path / "depth.sqlite"
    rec.write_bytes(real.read_bytes())
    with SessionStore.open(rec, writable=True) as st:
        st.add_sensor("cam", "CAM", Intrinsics())
        st.append_depth_frames("cam", [0], [0.0], np.full((1, 424, 512), 1500, np.uint16))
    p = _kinefuse(f"kinefuse inspect {shlex.quote(str(rec))}", tmp_path)
    assert p.returncode == 0, p.stderr
    (warning,) = [ln for ln in p.stdout.splitlines() if "sensor cam" in ln]
    assert "depth frames only, no body tracker's frames: add --tracker NAME" in warning
    assert "rig file" not in p.stdout
    (cmd,) = _suggested(warning)
    run = _kinefuse(cmd, tmp_path)
    assert run.returncode == 0 and "tracker pose" in run.stdout, run.stderr
