"""The one TOML writer (``io.toml.dumps_toml``, on ``tomli_w``) behind the calibration and rig
files: files written before it read back to the same numbers and are rewritten to the same
values; files written by it read with ``tomllib`` to exactly what was written, a 4x4 matrix one
row per line."""

from __future__ import annotations

import datetime as dt
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinefuse.capture.calibration.calib_file import (
    CalibrationFile,
    SensorCalibration,
    dumps_calibration,
    read_calibration,
)
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import look_at
from kinefuse.core.toml import dumps_toml
from kinefuse.errors import InputError
from kinefuse.sim.rig import load_rig, parse_rig, rig_to_toml

DATA = Path(__file__).parent / "data"
#: written by the hand-made writers this one replaced (a calibration and a rig)
OLD_CALIBRATION = DATA / "calibration_written_before_tomli_w.toml"
OLD_RIG = DATA / "rig_written_before_tomli_w.toml"


def test_a_calibration_written_before_reads_and_rewrites_to_the_same_numbers() -> None:
    old = tomllib.loads(OLD_CALIBRATION.read_text(encoding="utf-8"))
    cal = read_calibration(OLD_CALIBRATION)
    for s, raw in zip(cal.sensors, old["sensor"], strict=True):
        np.testing.assert_array_equal(s.sensor2world, np.array(raw["sensor2world"]))
    new_text = dumps_calibration(cal)
    assert tomllib.loads(new_text) == old  # every value, the matrices to the last bit


def test_a_rig_written_before_reads_and_rewrites_to_the_same_numbers() -> None:
    old = tomllib.loads(OLD_RIG.read_text(encoding="utf-8"))
    rig = load_rig(OLD_RIG)
    assert rig.actor_position_m == tuple(old["actor"]["position_m"])
    assert tomllib.loads(rig_to_toml(rig)) == old


def _matrix(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return look_at(rng.normal(size=3) * 3.0, rng.normal(size=3))


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@given(st.integers(0, 2**32 - 1), st.floats(1e-3, 1e4), finite, st.floats(1e-6, 1e6))
@settings(max_examples=60, deadline=None)
def test_a_calibration_written_now_reads_to_exactly_what_was_written(
    seed: int, fx: float, cx: float, scale: float
) -> None:
    intr = Intrinsics(width=512, height=424, fx=fx, fy=1.0 / 3.0, cx=cx, cy=211.5)
    cal = CalibrationFile(
        method="full",
        created=dt.datetime(2026, 12, 7, 23, 40, 1, tzinfo=dt.UTC),
        sensors=(
            SensorCalibration(
                id="k0",
                serial='S"0\n',
                sensor2world=_matrix(seed),
                intrinsics=intr,
                residual_m=0.00123456,
                n_sightings=7,
            ),
        ),
        world="w",
        rms_m=float("nan"),
        scale=scale,
    )
    text = dumps_calibration(cal)
    doc = tomllib.loads(text)
    s = doc["sensor"][0]
    assert s["sensor2world"] == cal.sensors[0].sensor2world.tolist()  # exact, no rounding
    assert s["intrinsics"] == intr.to_dict()
    assert (doc["scale"], doc["created"], s["serial"]) == (scale, cal.created, 'S"0\n')
    assert math.isnan(doc["rms_mm"]) and s["residual_mm"] == 1.2346  # mm to 4 decimals
    rows = re.findall(r"(?m)^    \[([^\[\]\n]*)\],$", text)  # one matrix row per line
    assert [[float(v) for v in r.split(", ")] for r in rows] == s["sensor2world"]


def test_a_rig_written_now_reads_to_exactly_what_was_written() -> None:
    rig = load_rig(Path(__file__).parents[1] / "rigs" / "tilted4.toml")
    text = rig_to_toml(rig)
    doc = tomllib.loads(text)
    for s, spec in zip(doc["sensor"], rig.sensors, strict=True):
        assert f"position_m = [{', '.join(repr(v) for v in s['position_m'])}]" in text
        np.testing.assert_allclose(s["position_m"], spec.sensor2world[:3, 3], atol=5e-7)
    again = parse_rig(text)
    assert tomllib.loads(rig_to_toml(again)) == doc  # written once, the numbers stay put


def test_dumps_toml_refuses_a_lone_surrogate_and_keeps_strings_that_look_like_numbers() -> None:
    with pytest.raises(InputError, match="lone surrogate"):
        dumps_toml({"id": "a\ud800b"})
    doc = {"ids": ["1.0", "2"], "m": [[1, 2.5], [-0.0, 1e-300]], "t": {"x": [float("inf")]}}
    text = dumps_toml(doc)
    assert tomllib.loads(text) == doc
    assert "m = [\n    [1, 2.5],\n    [-0.0, 1e-300],\n]" in text
    assert 'ids = [\n    "1.0",\n    "2",\n]' in text  # strings are never folded onto a line
