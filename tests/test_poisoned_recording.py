"""A recording poisoned by one bad authenticated peer (issue 23 A): test sensors that never
calibrated sent legal frames stamped +-1e12 s. Every offline command works on the real sensors
and names what it left out, and why."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.formats.store.session_store import SessionStore

REAL = ("k0", "k1", "k2")
FUZZ = ("fz0", "fz1", "fz2", "fz3")


def poison(store: SessionStore) -> None:
    """Four sensors with five frames each, through the store's own writer: fz1 and fz3 stamp
    device and host times 1e12 s ahead, fz2 1e12 s behind; fz0 stamps its device clock -1e12 s
    but its host clock is right (its frames map onto the recording: only its missing calibration
    keeps it out). fz0 and fz1 answered clock probes, fz2 and fz3 did not."""
    n = 5
    joints = np.tile(np.array([0.1, 0.2, 2.5]), (n, N_JOINTS, 1))
    states = np.full((n, N_JOINTS), 2, np.int8)
    for k, sid in enumerate(FUZZ):
        store.add_sensor(sid, f"FUZZ-{k}", Intrinsics())
        t_dev = (1e12 if k % 2 else -1e12) + np.arange(n) / 30
        t_host = 20.5 + np.arange(n) / 30 if k == 0 else t_dev
        store.append_observations(sid, np.arange(n), t_dev, joints, states, t_receive_host_s=t_host)
        if k < 2:
            store.append_clock_probes(
                sid, [1.0, 2.0], [1.001, 2.001], [1.0011, 2.0011], [1.002, 2.002]
            )


@pytest.fixture(scope="module")
def poisoned(tmp_path_factory, shared_data) -> Path:
    """A 3-sensor session, calibrated (stored in it) before the four bad sensors joined."""
    folder = tmp_path_factory.mktemp("poisoned")
    clean = folder / "clean.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--sensors", "3", "--seconds", "1",
                 "--calibration-seconds", "20", "--out", str(clean)]) == 0  # fmt: skip
    assert main(["calibrate", str(clean), "--store", "--json"]) == 0
    rec = folder / "rec.sqlite"
    shutil.copy(clean, rec)
    with SessionStore.open(rec, writable=True) as st:
        poison(st)
    return rec


def run_json(capsys, *argv: str) -> dict:
    capsys.readouterr()
    code = main([*argv, "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


def reasons(r: dict, fuzz: tuple[str, ...] = FUZZ) -> dict[str, str]:
    """The left-out sensors' reasons, checked to be exactly ``fuzz``."""
    left = {e["id"]: e["reason"] for e in r["left_out"]}
    assert sorted(left) == sorted(fuzz), left
    return left


def test_inspect_reports_the_real_sensors_and_names_the_rest(poisoned, capsys) -> None:
    r = run_json(capsys, "inspect", str(poisoned))
    # fz0's frames map onto the recording (its host clock is right): it is counted, not left out
    left = reasons(r, ("fz1", "fz2", "fz3"))
    assert all("stamped outside the recording" in why for why in left.values())
    assert {s["id"] for s in r["sensors"]} == set(REAL + FUZZ)
    assert 0.5 < r["duration_s"] < 2.0
    assert set(r["coverage"]["sensors"]) == {*REAL, "fz0"}
    assert r["coverage"]["span_server_s"][1] < 100
    assert any("fz3 left out" in w and "1e+12" in w for w in r["warnings"])
    assert main(["inspect", str(poisoned)]) == 0
    assert "warning: sensor fz2 left out: 5 of its 5 frame(s) are stamped outside" in (
        capsys.readouterr().out
    )


def test_calibrate_uses_the_real_sensors(poisoned, tmp_path, capsys) -> None:
    cal = tmp_path / "cal.toml"
    r = run_json(capsys, "calibrate", str(poisoned), "--out", str(cal))
    assert [s["id"] for s in r["sensors"]] == list(REAL)
    assert r["grade"] != "failed" and r["mean_position_error_m"] < 0.01
    left = reasons(r)
    assert "no calibration data" in left["fz0"]
    assert "stamped outside the recording" in left["fz1"]
    assert "no clock probes" in left["fz2"] and "no clock probes" in left["fz3"]
    assert main(["calibrate", str(poisoned)]) == 0
    assert "note: sensor fz3 left out: no clock probes" in capsys.readouterr().out


def test_fuse_uses_the_real_sensors(poisoned, tmp_path, capsys) -> None:
    # the calibration stored in the session covers the three real sensors only
    f = run_json(capsys, "fuse", str(poisoned), "--out", str(tmp_path / "fused.csv"))
    assert f["sensors"] == list(REAL) and f["frames"] > 20
    left = reasons(f)
    assert "no pose" in left["fz0"] and "1e+12" in left["fz1"]
    assert (tmp_path / "fused.csv").stat().st_size > 1000
    assert main(["fuse", str(poisoned), "--method", "linear"]) == 0
    assert "warning: sensor fz2 left out: no clock probes" in capsys.readouterr().err


def test_evaluate_uses_the_real_sensors(poisoned, capsys) -> None:
    e = run_json(capsys, "evaluate", str(poisoned), "--true-calibration", "--methods", "best")
    assert e["sensors"] == list(REAL) and e["best"]["mae_m"] < 0.1
    reasons(e)
    assert main(["evaluate", str(poisoned), "--methods", "linear"]) == 0  # stored calibration
    assert "note: sensor fz1 left out" in capsys.readouterr().out


def test_analyze_uses_the_real_sensors(poisoned, tmp_path, capsys) -> None:
    # analyze fuses the session itself: it screens the sensors as fuse does, and warns of each
    capsys.readouterr()
    code = main(["analyze", str(poisoned), "--out", str(tmp_path / "an"), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    r = json.loads(out)
    r = r["inputs"][0] if "inputs" in r else r
    assert sorted(r["fusion"]["left_out"]) == sorted(FUZZ)
    assert any("sensor fz1 left out of the fusion" in w for w in r["warnings"])
