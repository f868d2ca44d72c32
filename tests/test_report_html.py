"""report.html: one self-contained file written by ``kinefuse evaluate --out`` (and the demo)."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.lab.report.html import is_kinefuse_report, mae_intervals

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory, shared_data) -> Path:
    """``kinefuse evaluate --out`` on a short simulated walk (true poses: no wand phase)."""
    root = tmp_path_factory.mktemp("report")
    session = root / "walk.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--calibration-seconds", "0", "--seed", "5",
                 "--out", str(session)]) == 0  # fmt: skip
    out = root / "eval"
    assert main(["evaluate", str(session), "--true-calibration", "--out", str(out)]) == 0
    return out


def test_report_is_one_self_contained_file(evaluated) -> None:
    text = (evaluated / "report.html").read_text(encoding="utf-8")
    assert is_kinefuse_report(evaluated / "report.html")
    # nothing to fetch: no external URL in any src or href, no script
    refs = re.findall(r'(?:src|href)="([^"]*)"', text)
    assert refs and all(r.startswith(("data:image/png;base64,", "#")) for r in refs), refs
    assert "<script" not in text and "http://" not in text and "https://" not in text
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(images) >= 8
    for b64 in images:
        png = base64.b64decode(b64, validate=True)
        assert png.startswith(PNG) and len(png) > 2000
    for anchor in ("setup", "calibration", "clock", "latency", "accuracy", "time",
                   "trajectories", "occlusion", "angles"):  # fmt: skip
        assert f'id="{anchor}"' in text
    # a simulated session has no live latencies: the report says so instead of inventing them
    assert "not recorded" in text
    assert "the fusion used true poses (simulator)" in text


def test_report_numbers_are_the_evaluation_s(evaluated) -> None:
    text = (evaluated / "report.html").read_text(encoding="utf-8")
    report = json.loads((evaluated / "evaluate.json").read_text())
    for m in ("linear", "paper", "best", "best-live"):
        row = re.search(rf"<tr><td>(?:<b>)?{m}(?:</b>)?</td><td>([0-9.]+)</td><td>([0-9.]+) – "
                        r"([0-9.]+)</td>", text)  # fmt: skip
        assert row is not None, m
        mae, lo, hi = (float(v) for v in row.groups())
        assert mae == pytest.approx(100 * report[m]["mae_m"], abs=0.006)  # printed to 0.01 cm
        assert lo <= mae <= hi
    occ = report["occlusion"]
    assert f"{occ['precision']:.3f}" in text and f"{occ['recall']:.3f}" in text


def test_mae_intervals_bracket_the_mean_and_shrink_with_frames(rng) -> None:
    truth = np.zeros((300, 25, 3))
    est = truth.copy()
    est[..., 0] = 0.01  # exactly 1 cm everywhere: the interval is that point
    (lo, hi), (jl, jh) = mae_intervals(est, truth)
    assert lo == pytest.approx(0.01) and hi == pytest.approx(0.01)
    np.testing.assert_allclose(jl, 0.01)
    noisy = truth + rng.normal(0, 0.02, truth.shape)
    noisy[::7, 3] = np.nan  # missing joints are left out, not counted as zero
    (lo, hi), (jl, jh) = mae_intervals(noisy, truth)
    mean = np.nanmean(np.linalg.norm(noisy - truth, axis=-1))
    assert lo < mean < hi and hi - lo < 0.002  # 2 mm wide at most for 7500 samples
    (lo_s, hi_s), _ = mae_intervals(noisy[:90], truth[:90])  # 3 blocks of 1 s
    assert hi_s - lo_s > hi - lo
    assert (jl <= jh).all() and np.isfinite(jl).all()


def test_evaluate_replaces_its_own_report_only(evaluated, tmp_path) -> None:
    other = tmp_path / "report.html"
    other.write_text("<html>someone else's</html>")
    assert not is_kinefuse_report(other)
    assert is_kinefuse_report(evaluated / "report.html")
    assert not is_kinefuse_report(tmp_path / "missing.html")
