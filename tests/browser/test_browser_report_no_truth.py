"""report.html of a session without truth, in a real browser, offline: the consistency sections
render, every image loads, and the page says why the truth-only sections are absent."""

from __future__ import annotations

import json
import shutil
import sqlite3

from kinefuse.app.cli import main


def test_consistency_report_opens_offline(calibrated_session, tmp_path, page) -> None:
    session = tmp_path / "no_truth.sqlite"
    shutil.copy(calibrated_session, session)
    with sqlite3.connect(session) as db:  # a copy we made: its truth dropped
        for table in ("truth_motion", "truth_sensors", "truth_observations", "truth_wand"):
            db.execute(f"DELETE FROM {table}")
    out = tmp_path / "eval"
    assert main(["evaluate", str(session), "--out", str(out)]) == 0
    report = json.loads((out / "evaluate.json").read_text())
    # the stored wand calibration is used, not the body
    assert report["registration"]["kind"] == "calibration"
    assert report["calibration"] == "session calibration (full)"
    requests: list[str] = []
    page.on("request", lambda r: requests.append(r.url))
    page.goto((out / "report.html").as_uri())
    page.wait_for_load_state("load")
    images = page.evaluate(
        "Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth])"
    )
    assert len(images) >= 3  # the rig, the calibration residuals, the clock sync
    assert [alt for alt, complete, width in images if not (complete and width > 100)] == []
    assert page.errors == []
    assert [u for u in requests if not u.startswith(("file://", "data:"))] == []
    assert "has no ground truth" in page.inner_text("#no-truth")
    for absent in ("#accuracy", "#time", "#trajectories", "#occlusion"):
        assert page.query_selector(absent) is None
    pairs = page.inner_text("#consistency ~ table")  # sensor against sensor, every pair
    assert "after left/right correction" in pairs
    assert all(
        p.replace("|", "\t") in pairs or p in pairs for p in report["agreement"]["disagreement"]
    )
    best = page.inner_text("#joints ~ table")
    assert "SpineBase" in best and "WristRight" in best
