"""The TOML calibration file: round trip and clear errors for malformed files."""

from __future__ import annotations

import datetime as dt
import math
import re
from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.calibration.calib_file import (
    CalibrationFile,
    calibration_from_registration,
    dumps_calibration,
    loads_calibration,
    read_calibration,
    write_calibration,
)
from kinefuse.capture.calibration.register import Registration, register_full
from kinefuse.capture.calibration.synthetic import make_rig, simulate_sightings, wand_waving
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.errors import InputError

INTR = Intrinsics()


def _calibration() -> CalibrationFile:
    rng = np.random.default_rng(61)
    poses = make_rig(3, rng)
    t, wand = wand_waving(8.0, rng)
    reg = register_full(simulate_sightings(poses, INTR, t, wand, rng), origin="sensor")
    intr = {sid: Intrinsics(fx=365.0 + k, fy=364.0 + k) for k, sid in enumerate(reg.sensor_ids)}
    return calibration_from_registration(
        reg,
        intr,
        serials={"k0": "003456165147", "k1": "011223344556"},
        created=dt.datetime(2026, 11, 21, 22, 50, tzinfo=dt.UTC),
    )


def test_round_trip(tmp_path: Path) -> None:
    cal = _calibration()
    path = tmp_path / "calib.toml"
    write_calibration(path, cal)
    text = path.read_text()
    assert 'format = "kinefuse-calibration"' in text
    assert "created = 2026-11-21 22:50:00+00:00" in text
    assert "[[sensor]]" in text and "[sensor.intrinsics]" in text
    back = read_calibration(path)
    assert back.method == "full"
    assert back.created == cal.created
    assert back.world == cal.world
    assert math.isclose(back.rms_m, cal.rms_m, abs_tol=1e-7)
    assert [s.id for s in back.sensors] == ["k0", "k1", "k2"]
    for a, b in zip(cal.sensors, back.sensors, strict=True):
        assert a.serial == b.serial
        np.testing.assert_array_equal(a.sensor2world, b.sensor2world)  # exact: repr of floats
        assert a.intrinsics == b.intrinsics
        assert a.n_sightings == b.n_sightings
        assert math.isclose(a.residual_m, b.residual_m, abs_tol=1e-7)  # stored in mm, 4 decimals
    assert back.sensor("k2").serial == ""
    np.testing.assert_array_equal(back.sensor2world["k1"], cal.sensors[1].sensor2world)
    with pytest.raises(KeyError, match="no sensor 'k5' in the calibration; it has: k0, k1, k2"):
        back.sensor("k5")
    # a string round trip gives the same text
    assert dumps_calibration(loads_calibration(dumps_calibration(cal))) == dumps_calibration(cal)


def test_nan_residual_and_date_only_are_accepted() -> None:
    reg = Registration(
        method="paper",
        sensor_ids=("a",),
        sensor2world=np.eye(4)[None],
        residual_m=np.array([np.nan]),
        n_sightings=np.array([2]),
        rms_m=float("nan"),
        world="w",
    )
    cal = calibration_from_registration(reg, {"a": INTR})
    assert cal.created.tzinfo is not None
    back = loads_calibration(dumps_calibration(cal))
    assert math.isnan(back.sensors[0].residual_m) and math.isnan(back.rms_m)
    text = re.sub(r"(?m)^created = .*$", "created = 2026-11-21", dumps_calibration(cal))
    back = loads_calibration(text)
    assert back.created == dt.datetime(2026, 11, 21, tzinfo=dt.UTC)
    with pytest.raises(InputError, match="no intrinsics given for sensor"):
        calibration_from_registration(reg, {})


def _good_text() -> str:
    return dumps_calibration(_calibration())


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: s + "\n[[[", r"calib.toml: not valid TOML"),
        (
            lambda s: s.replace('format = "kinefuse-calibration"', 'format = "other"'),
            "not a kinefuse calibration file",
        ),
        (
            lambda s: s.replace("format_version = 1", "format_version = 9"),
            "format_version 9 is newer",
        ),
        (lambda s: s.replace('method = "full"\n', ""), "missing field 'method'"),
        (
            lambda s: s.replace("sightings = ", "sightings = 'many' #", 1),
            r"sensor 'k0': field 'sightings' must be int",
        ),
        (lambda s: s.replace('id = "k1"', 'id = "k0"'), r"sensor 'k0': duplicate sensor id"),
        (lambda s: s.replace("width = 512", "width = -3", 1), r"sensor 'k0': bad intrinsics"),
        (
            lambda s: re.sub(
                r"sensor2world = \[.*?\n\]", "sensor2world = 3", s, count=1, flags=re.S
            ),
            "'sensor2world' must be list",
        ),
        (lambda s: s.split("\n[[sensor]]")[0], "missing field 'sensor'"),
    ],
)
def test_malformed_files_are_clear_errors(tmp_path: Path, edit: object, message: str) -> None:
    path = tmp_path / "calib.toml"
    path.write_text(edit(_good_text()))  # type: ignore[operator]
    with pytest.raises(InputError, match=message):
        read_calibration(path)


def test_non_rigid_pose_and_missing_file(tmp_path: Path) -> None:
    cal = _calibration()
    bad = cal.sensors[0].sensor2world.copy()
    bad[0, 0] *= 1.5
    good_row = ", ".join(repr(float(v)) for v in cal.sensors[0].sensor2world[0])
    text = _good_text()
    assert good_row in text
    text = text.replace(good_row, ", ".join(repr(float(v)) for v in bad[0]), 1)
    with pytest.raises(InputError, match="sensor 'k0': sensor2world is not a rigid transform"):
        loads_calibration(text)
    with pytest.raises(InputError, match="must be a 4x4 array of numbers"):
        loads_calibration(_good_text().replace(good_row, "1.0, 2.0", 1))
    with pytest.raises(InputError, match=r"must be a finite 4x4 array, got shape \(4, 3\)"):
        text = _good_text()
        for row in cal.sensors[0].sensor2world:
            full = ", ".join(repr(float(v)) for v in row)
            text = text.replace(full, full.rsplit(", ", 1)[0], 1)
        loads_calibration(text)
    with pytest.raises(InputError, match="calibration file not found"):
        read_calibration(tmp_path / "nope.toml")
    (tmp_path / "bin.toml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(InputError, match="not a text"):
        read_calibration(tmp_path / "bin.toml")
