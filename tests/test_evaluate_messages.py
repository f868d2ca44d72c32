"""``kinefuse evaluate`` on a take the subject partly leaves (two sensors close to one side of
a real CMU walk): no numpy warning reaches the user (any RuntimeWarning fails the run here) and
no figure is printed as ``nan``."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from kinefuse.app.cli.main import main

RIG = """
[[sensor]]
id = "a"
position_m = [0.0, 1.3, 1.1]
look_at_m = [0.0, 0.0, 1.0]

[[sensor]]
id = "b"
position_m = [0.6, 1.3, 1.2]
look_at_m = [0.6, 0.0, 1.0]
"""


def test_evaluate_prints_no_numpy_warning_and_no_nan(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = tmp_path / "close.toml"
    rig.write_text(RIG)
    s = tmp_path / "take.sqlite"
    assert main(["simulate", "--clip", str(shared_data / "motion/cmu/02_walk_a.amc"), "--rig",
                 str(rig), "--calibration-seconds", "0", "--out", str(s)]) == 0  # fmt: skip
    assert "leaves the common capture volume" in capsys.readouterr().err
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        code = main(["evaluate", str(s), "--true-calibration"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "best-live by joint status: " in out
    assert "nan" not in out.lower().replace("nanosecond", ""), out
    assert "Warning" not in err
