"""The docs that are generated from the code stay true."""

from __future__ import annotations

from pathlib import Path

from kinefuse.sim.lab import describe_error_model

ROOT = Path(__file__).resolve().parents[1]


def test_error_model_doc_matches_the_code() -> None:
    text = (ROOT / "docs" / "error_model.md").read_text()
    body = text.split("<!-- BEGIN GENERATED -->\n", 1)[1].split("<!-- END GENERATED -->", 1)[0]
    assert body.strip() == describe_error_model().strip(), (
        "docs/error_model.md is stale: regenerate its parameter section from "
        "kinefuse.sim.lab.describe_error_model()"
    )
