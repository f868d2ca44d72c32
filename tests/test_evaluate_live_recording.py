"""``kinefuse evaluate`` of a live recording of real sensors: ``kinefuse serve --record`` and two
``kinefuse sensor --source multitrack:...`` processes replaying a real two-Kinect log on
127.0.0.1 (no wand, no calibration file). The recording has no truth; evaluate reports its
consistency figures with the poses the server found from the person, or from the body itself."""

from __future__ import annotations

import json

import pytest

from kinefuse.app.cli import main
from kinefuse.app.workflows.demo import ChildProcesses, parse_listening
from kinefuse.formats.kinect_multitrack import read_kinect_multitrack
from kinefuse.formats.store.session_store import SessionStore


def test_evaluate_a_live_recording_of_a_real_log(tmp_path, shared_data, capsys) -> None:
    logs = sorted((shared_data / "kinect" / "kinect_multitrack").glob("Study_4_Kinect_1_*.csv"))
    if not logs:
        pytest.skip("no KinectMultiTrack log in the shared data")
    ids = [s.sensor_id for s in read_kinect_multitrack(logs[0]).streams]
    rec = tmp_path / "rec.sqlite"
    with ChildProcesses(tmp_path / "logs") as procs:
        serve = ["serve", "--host", "127.0.0.1", "--port", "0", "--record", str(rec)]
        server = procs.start("server", serve, announce=True)
        port = parse_listening(procs.wait_first_line(server, 60.0))[1]
        for k, sid in enumerate(ids):
            src = f"multitrack:{logs[0]}#{sid}"
            args = ["sensor", "--server", f"127.0.0.1:{port}", "--source", src]
            procs.start(f"sensor-{k}", [*args, "--speed", "2", "--max-seconds", "20"])
        for c in procs.children[1:]:
            c.popen.wait(60)
            assert c.popen.returncode == 0, c.tail()
        assert procs.stop(procs.children[0]) == 0
    with SessionStore.open(rec) as st:
        assert st.complete and not st.has_truth()
        stored = st.calibration_names()
    out = tmp_path / "eval"
    capsys.readouterr()
    assert main(["evaluate", str(rec), "--methods", "best,best-live", "--out", str(out)]) == 0
    assert "no truth:" in capsys.readouterr().out
    report = json.loads((out / "evaluate.json").read_text())
    assert report["truth"] is False and sorted(report["sensors_with_body"]) == sorted(ids)
    # the server's calibration from the person when it stored one, else the body's
    kind = "calibration" if stored else "body"
    assert report["registration"]["kind"] == kind, (stored, report["calibration"])
    pair = next(iter(report["agreement"]["disagreement_lr"]))
    med = report["agreement"]["disagreement_lr"][pair]["all"][0]
    assert 0.02 < med < 0.15  # real sensors disagree by a few cm (realdata: 3-5 cm)
    # the log has pauses between its scenarios: best places the joints wherever a body was seen
    seen = report["agreement"]["frames_with_body"] / report["frames"]
    assert seen > 0.2 and 0.95 * seen < report["best"]["placed"] < 1.4 * seen
    assert (out / "report.html").stat().st_size > 10_000
