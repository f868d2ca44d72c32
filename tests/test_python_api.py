"""The Python API (``kinefuse.api``, re-exported by ``kinefuse``) on real files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import kinefuse as kf
from kinefuse.errors import InputError, OutputError


def test_the_package_re_exports_the_api_lazily() -> None:
    """``import kinefuse`` loads none of it; the first use of a name does."""
    code = (
        "import sys, kinefuse; assert 'kinefuse.api' not in sys.modules; "
        "kinefuse.fuse; assert 'kinefuse.api' in sys.modules; print(sorted(kinefuse.__all__))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "open_session" in out.stdout
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        _ = kf.nothing  # type: ignore[attr-defined]
    assert (Path(kf.__file__).parent / "py.typed").is_file()


def test_clip_and_markers(shared_data: Path) -> None:
    clip = kf.load_clip(shared_data / "motion" / "cmu" / "02_walk_a.amc")
    assert clip.positions_m.shape == (len(clip), 25, 3) and clip.status is None
    assert np.allclose(np.diff(clip.t_s), 1 / 120)
    with pytest.raises(InputError, match="no joint 'Tail'"):
        clip.joint("Tail")
    m = kf.load_markers(shared_data / "markers" / "c3d" / "kinematics_tennis_serve.c3d")
    assert m.positions.shape == (1092, len(m.names), 3) and m.rate_hz == 50


def test_analyze_returns_the_angles_it_wrote(shared_data: Path, tmp_path: Path) -> None:
    opensim = shared_data / "markers" / "opensim"
    res = kf.analyze(
        opensim / "Pipelines_Rajagopal_ExpData_motion_capture_walk.trc",
        tmp_path / "out",
        static=opensim / "Pipelines_Rajagopal_ExpData_static_walk_1.trc",
    )
    knee = res.angles["knee_flexion_left"]
    assert knee.shape == (238,) and np.nanmax(knee) > 45.0  # swing flexes the knee
    functional = res.angles["knee_flexion_left/functional"]
    assert not np.allclose(knee, functional, equal_nan=True)
    assert res.status["shank_left"] == "ok"
    with pytest.raises(InputError, match="no angle 'wing_flap'"):
        res.angles["wing_flap"]
    again = kf.Angles.read_csv(res.out / "angles.csv")
    assert again.columns == res.angles.columns
    assert np.array_equal(again.degrees, res.angles.degrees, equal_nan=True)


def test_fuse_a_simulated_session_and_export(shared_data: Path, tmp_path: Path) -> None:
    from kinefuse.app.cli import main

    session = tmp_path / "s.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--sensors", "3", "--out", str(session)]) == 0
    with kf.open_session(session) as s:
        assert s.sensor_ids == ("k0", "k1", "k2") and s.complete
        with pytest.raises(InputError, match="unknown fusion method"):
            s.fuse("median")
    cal = tmp_path / "cal.toml"
    assert main(["calibrate", str(session), "--method", "full", "--out", str(cal)]) == 0
    skel = kf.fuse(session, calibration=cal)
    assert skel.positions_m.shape[1:] == (25, 3) and skel.status is not None
    assert skel.export(tmp_path / "f.c3d").stat().st_size > 0
    foreign = tmp_path / "theirs.trc"
    foreign.write_text("someone else's file\n")
    with pytest.raises(OutputError):
        skel.export(foreign)
    assert foreign.read_text() == "someone else's file\n"
