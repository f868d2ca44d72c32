"""``kinefuse analyze STUDY_DIR/``: a folder of real marker trials, resumed, on a Dask cluster.

The study is the shared marker trials laid out as a lab lays them out (one folder per source,
static trials beside the trials), copied, never touched in ``../shared``.
"""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.app.workflows.study import find_trials, run_study
from kinefuse.biomech.gait import CYCLE_S, cycle_curves, foot_strikes
from kinefuse.errors import InputError

OPENSIM = (
    "Pipelines_Rajagopal_ExpData_motion_capture_walk.trc",
    "Pipelines_Rajagopal_ExpData_static_walk_1.trc",
    "Pipelines_Gait2354_Simbody_subject01_walk1.trc",
    "Pipelines_Gait2354_Simbody_subject01_static.trc",
)


@pytest.fixture
def study(shared_data: Path, tmp_path: Path) -> Path:
    root = tmp_path / "study"
    (root / "opensim").mkdir(parents=True)
    (root / "optitrack").mkdir()
    for name in OPENSIM:
        shutil.copy(shared_data / "markers" / "opensim" / name, root / "opensim" / name)
    shutil.copy(shared_data / "markers" / "c3d" / "kinematics_tennis_serve.c3d", root / "optitrack")
    return root


@pytest.fixture
def small_study(shared_data: Path, tmp_path: Path) -> Path:
    """One walk and its static trial."""
    root = tmp_path / "small"
    root.mkdir()
    for name in OPENSIM[:2]:
        shutil.copy(shared_data / "markers" / "opensim" / name, root / name)
    return root


def test_the_naming_rule_pairs_each_walk_with_its_own_static(study: Path) -> None:
    trials = {t.id: t for t in find_trials(study)}
    assert set(trials) == {
        "opensim__Pipelines_Gait2354_Simbody_subject01_walk1",
        "opensim__Pipelines_Rajagopal_ExpData_motion_capture_walk",
        "optitrack__kinematics_tennis_serve",
    }
    rajagopal = trials["opensim__Pipelines_Rajagopal_ExpData_motion_capture_walk"]
    assert rajagopal.static is not None and rajagopal.static.name == OPENSIM[1]
    gait = trials["opensim__Pipelines_Gait2354_Simbody_subject01_walk1"]
    assert gait.static is not None and gait.static.name == OPENSIM[3]
    assert trials["optitrack__kinematics_tennis_serve"].static is None


@pytest.mark.slow
def test_a_study_summarises_every_trial_and_resumes(
    study: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "results"
    assert main(["analyze", str(study), "--out", str(out), "--no-plots", "--jobs", "2"]) == 0
    said = capsys.readouterr().out
    assert "3 of 3 trials analysed (0 done in an earlier run)" in said
    with (out / "summary.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert {r["trial"] for r in rows} == {t.id for t in find_trials(study)}
    for r in rows:
        lo, hi, mean = float(r["min_deg"]), float(r["max_deg"]), float(r["mean_deg"])
        assert lo <= mean <= hi and float(r["range_deg"]) == pytest.approx(hi - lo, abs=2e-4)
        assert abs(float(r["peak_deg"])) == pytest.approx(max(abs(lo), abs(hi)), abs=1e-4)
    # the Rajagopal walk: a cycle of each foot, its knee curve flexes in swing (60-75 % of the
    # cycle) far more than at the strike
    with (out / "cycles.csv").open() as f:
        cycles = list(csv.DictReader(f))
    knee = next(
        c for c in cycles
        if c["trial"].endswith("Rajagopal_ExpData_motion_capture_walk")
        and c["angle"] == "knee_flexion_right" and c["method"] == "anatomical"
    )  # fmt: skip
    curve = np.array([float(knee[f"p{k}"]) for k in range(101)])
    assert curve[60:76].max() > curve[0] + 30.0, curve
    page = (out / "summary.html").read_text()
    assert "knee_flexion_right" in page and "data:image/png;base64," in page
    # a rerun skips what was done; the summary is the same
    before = (out / "summary.csv").read_text()
    assert main(["analyze", str(study), "--out", str(out), "--no-plots"]) == 0
    assert "3 of 3 trials analysed (3 done in an earlier run)" in capsys.readouterr().out
    assert (out / "summary.csv").read_text() == before
    # --force analyses them again
    result = run_study(study, out=out, plots=False, force=True, jobs=1)
    assert [t.status for t in result.trials] == ["done"] * 3


def test_a_study_runs_on_a_dask_cluster(small_study: Path, tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    with (
        distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True) as cluster,
    ):
        out = tmp_path / "results"
        result = run_study(small_study, out=out, plots=False, scheduler=cluster.scheduler_address)
    assert [t.status for t in result.trials] == ["done"]
    assert (out / "summary.csv").is_file()
    assert (
        json.loads((out / "trials" / result.trials[0].id / "gait.json").read_text())["written_by"]
        == "kinefuse analyze (study)"
    )


def test_a_study_with_failing_trials_says_which_and_exits_non_zero(
    small_study: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (small_study / "broken.trc").write_text("not a TRC file\n")
    out = tmp_path / "results"
    assert main(["analyze", str(small_study), "--out", str(out), "--no-plots"]) == 1
    said = capsys.readouterr().out
    assert "1 of 2 trials analysed" in said and "failed: broken" in said
    # nothing analysable at all: exit 3, and it says why
    empty = tmp_path / "bad"
    empty.mkdir()
    (empty / "broken.trc").write_text("not a TRC file\n")
    assert main(["analyze", str(empty), "--out", str(tmp_path / "r2"), "--no-plots"]) == 3
    assert "no trial of the study could be analysed" in capsys.readouterr().err


def test_study_toml_lists_trials_and_their_options(study: Path, tmp_path: Path) -> None:
    (study / "study.toml").write_text(
        '[[trial]]\nfile = "opensim/Pipelines_Rajagopal_ExpData_motion_capture_walk.trc"\n'
        'static = "opensim/Pipelines_Rajagopal_ExpData_static_walk_1.trc"\nid = "walk"\n'
        "calibration_phase = [0.0, 2.0]\n"
    )
    (trial,) = find_trials(study)
    assert trial.id == "walk" and trial.calibration_phase == (0.0, 2.0)
    (study / "study.toml").write_text('[[trial]]\nfile = "missing.trc"\n')
    with pytest.raises(InputError, match="no such file"):
        find_trials(study)


def test_options_of_one_trial_are_refused_for_a_study(
    study: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["analyze", str(study), "--out", str(tmp_path / "r")]
    assert main([*base, "--static", str(study / "opensim" / OPENSIM[1])]) == 2
    assert "--static is per trial" in capsys.readouterr().err
    assert main([*base, "--static-window", "auto"]) == 2
    assert "study.toml" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    # and the study's options are refused for a file
    one = study / "opensim" / OPENSIM[0]
    assert main(["analyze", str(one), "--out", str(tmp_path / "r"), "--jobs", "2"]) == 2


def test_foot_strikes_on_a_real_walk_and_none_on_a_static_trial(shared_data: Path) -> None:
    from kinefuse.app.workflows.analyze import load_input

    walk = load_input(shared_data / "motion" / "cmu" / "02_walk_a.amc")
    events = foot_strikes(walk.seq)
    for side in ("left", "right"):
        assert events.cycles(side), side
        for a, b in events.cycles(side):
            assert 0.8 < b - a < 1.4  # a walking stride
            assert CYCLE_S[0] <= b - a <= CYCLE_S[1]
    static = load_input(
        shared_data / "markers" / "opensim" / "Pipelines_Rajagopal_ExpData_static_walk_1.trc"
    )
    assert foot_strikes(static.seq).strikes_s == {"left": (), "right": ()}


def test_cycle_curves_resample_each_cycle_and_keep_gaps() -> None:
    t = np.linspace(0.0, 2.0, 201)
    v = np.sin(np.pi * t)  # one period per 2 s
    curves = cycle_curves(t, v, [(0.0, 2.0), (0.5, 1.5)])
    assert curves.shape == (2, 101)
    assert curves[0, 50] == pytest.approx(0.0, abs=1e-9) and curves[0, 25] == pytest.approx(1.0)
    v[100] = np.nan
    assert np.isnan(cycle_curves(t, v, [(0.5, 1.5)])).all()
