"""report.html in a real browser, offline: no console errors, every image loads."""

from __future__ import annotations

from kinefuse.app.cli import main


def test_report_opens_offline_with_every_image_loaded(calibrated_session, tmp_path, page) -> None:
    out = tmp_path / "eval"
    assert main(["evaluate", str(calibrated_session), "--out", str(out)]) == 0
    requests: list[str] = []
    page.on("request", lambda r: requests.append(r.url))
    page.goto((out / "report.html").as_uri())
    page.wait_for_load_state("load")
    images = page.evaluate(
        "Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth])"
    )
    assert len(images) >= 8
    assert [alt for alt, complete, width in images if not (complete and width > 100)] == []
    assert page.errors == []
    # nothing but the file itself (and its inline images) was fetched
    assert [u for u in requests if not u.startswith(("file://", "data:"))] == []
    # the calibration section has the stored calibration with its errors against the truth
    assert "wand residual" in page.inner_text("#calibration ~ div table")
