"""Long commands show progress on a terminal, and only there (issue 23 B)."""

from __future__ import annotations

import io
from pathlib import Path

from kinefuse.app.cli import main
from kinefuse.app.workflows.evaluate import run_evaluate
from kinefuse.app.workflows.progress import TerminalProgress


class FakeTerminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_shows_on_a_terminal_only() -> None:
    tty, pipe = FakeTerminal(), io.StringIO()
    with TerminalProgress("evaluate", stream=tty) as p:
        p("fusing with best (1/2)")
    assert "kinefuse evaluate: fusing with best (1/2)" in tty.getvalue()
    assert tty.getvalue().endswith("\r\x1b[K")  # the line is cleared at the end
    for quiet in (
        TerminalProgress("x", stream=pipe),
        TerminalProgress("x", stream=tty, enabled=False),
    ):
        quiet("step")
        quiet.done()
    assert pipe.getvalue() == "" and tty.getvalue().count("step") == 0


def test_evaluate_reports_each_run_and_is_quiet_when_piped(
    tmp_path: Path, shared_data, capsys
) -> None:
    s = tmp_path / "s.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--seconds", "1", "--sensors", "3",
                 "--calibration-seconds", "0", "--out", str(s)]) == 0  # fmt: skip
    heard: list[str] = []
    run_evaluate(session=s, methods=("linear", "best"), out_dir=None, calibration=None,
                 true_calibration=True, progress=heard.append)  # fmt: skip
    assert heard[0].startswith("reading")
    assert any("with linear (1/10)" in m for m in heard)  # 2 methods, 8 parts of the ablation
    assert any("without temporal" in m for m in heard)
    capsys.readouterr()
    assert main(["evaluate", str(s), "--true-calibration", "--methods", "linear"]) == 0
    assert "kinefuse evaluate:" not in capsys.readouterr().err  # stderr is not a terminal here
