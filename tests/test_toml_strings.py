"""Every TOML kinefuse writes quotes its strings through one writer (io.toml: dumps_toml on
tomli_w for files, toml_str for the retargeting hint's fragments): a sensor id or serial with a
quote, a backslash, a newline, a control character or any unicode round-trips through the rig
and calibration writers and tomllib."""

from __future__ import annotations

import datetime as _dt
import tomllib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import look_at
from kinefuse.core.toml import toml_str
from kinefuse.errors import InputError
from kinefuse.sim.rig import Rig, SensorSpec, parse_rig, rig_to_toml

NASTY = [
    'front"',
    '"',
    "a\\b",
    "\\",
    '\\"',
    "line\nbreak",
    "tab\there",
    "cr\r\n",
    "\x00nul",
    "\x1f\x7fdel",
    "\u00e9t\u00e9 \u2603 \u4e2d\u6587",
    "\U0001f600 emoji",  # astral: JSON writes a surrogate pair, which TOML forbids
    "\u2028\u2029 separators",
    "''' triple '''",
    '""" triple """',
    "key = \"value\"\n[[sensor]]\nid = 'injected'",
    " ",
    "#comment",
]

#: any string that can be written as UTF-8 (no lone surrogates)
texts = st.text(st.characters(blacklist_categories=("Cs",)), min_size=1, max_size=40)


def rig_of(ids: list[str], serials: list[str]) -> Rig:
    sensors = tuple(
        SensorSpec(
            id=sid,
            serial=ser,
            sensor2world=look_at(
                np.array([3.0 * np.cos(k), 3.0 * np.sin(k), 1.1]), np.array([0.0, 0.0, 1.0])
            ),
        )
        for k, (sid, ser) in enumerate(zip(ids, serials, strict=True))
    )
    return Rig(sensors=sensors, actor_position_m=None, actor_heading_deg=0.0, description="t")


@pytest.mark.parametrize("text", NASTY)
def test_toml_str_round_trips_nasty_strings(text: str) -> None:
    assert tomllib.loads(f"k = {toml_str(text)}")["k"] == text
    assert tomllib.loads(f"{toml_str(text)} = 1") == {text: 1}  # as a quoted key too


@given(texts)
@settings(max_examples=300, deadline=None)
def test_toml_str_round_trips_any_string(text: str) -> None:
    assert tomllib.loads(f"k = {toml_str(text)}")["k"] == text


def test_toml_str_refuses_a_lone_surrogate() -> None:
    with pytest.raises(InputError, match="surrogate"):
        toml_str("a\ud800b")


def test_rig_to_toml_round_trips_nasty_ids_and_serials() -> None:
    ids = [f"{s}{k}" for k, s in enumerate(NASTY)]  # unique ids
    serials = list(reversed(NASTY))
    rig = rig_of(ids, serials)
    text = rig_to_toml(rig)
    data = tomllib.loads(text)
    assert [s["id"] for s in data["sensor"]] == ids
    assert [s["serial"] for s in data["sensor"]] == serials
    back = parse_rig(text)
    assert [s.id for s in back.sensors] == ids
    assert [s.serial for s in back.sensors] == serials
    for a, b in zip(rig.sensors, back.sensors, strict=True):
        np.testing.assert_allclose(a.sensor2world, b.sensor2world, atol=1e-5)


@given(st.lists(texts, min_size=1, max_size=4, unique=True), texts)
@settings(max_examples=100, deadline=None)
def test_rig_to_toml_round_trips_any_id(ids: list[str], serial: str) -> None:
    rig = rig_of(ids, [serial] * len(ids))
    back = parse_rig(rig_to_toml(rig))
    assert [s.id for s in back.sensors] == ids
    assert {s.serial for s in back.sensors} == {serial}


@given(st.lists(texts, min_size=1, max_size=3, unique=True), texts, texts, texts)
@settings(max_examples=100, deadline=None)
def test_calibration_file_round_trips_any_id_serial_method_and_world(
    ids: list[str], serial: str, method: str, world: str
) -> None:
    from kinefuse.capture.calibration.calib_file import (
        CalibrationFile,
        SensorCalibration,
        dumps_calibration,
        loads_calibration,
    )

    intr = Intrinsics(width=8, height=6, fx=5.0, fy=5.0, cx=3.5, cy=2.5)
    cal = CalibrationFile(
        method=method,
        created=_dt.datetime(2026, 1, 2, 3, 4, 5, tzinfo=_dt.UTC),
        sensors=tuple(
            SensorCalibration(
                id=sid,
                serial=serial,
                sensor2world=np.eye(4),
                intrinsics=intr,
                residual_m=0.001,
                n_sightings=10,
            )
            for sid in ids
        ),
        world=world,
        rms_m=0.002,
    )
    text = dumps_calibration(cal)
    doc = tomllib.loads(text)
    assert [s["id"] for s in doc["sensor"]] == ids
    assert (doc["method"], doc["world"]) == (method, world)
    back = loads_calibration(text)
    assert [s.id for s in back.sensors] == ids
    assert {s.serial for s in back.sensors} == {serial}


def test_retarget_hint_quotes_source_joint_names() -> None:
    from kinefuse.biomech.retarget import _spec_toml

    names = ['Hip"s', "back\\slash", "new\nline"]
    for term in (
        [(names[0], 1.0)],
        [(n, 0.5) for n in names[:2]],
        [(names[1], 0.3), (names[2], 0.7)],
    ):
        doc = tomllib.loads(f"j = {_spec_toml(term)}")
        got = doc["j"]
        if isinstance(got, str):
            assert got == term[0][0]
        elif "mean" in got:
            assert got["mean"] == [n for n, _ in term]
        else:
            assert got["blend"] == dict(term)
