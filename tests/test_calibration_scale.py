"""The world's scale correction is a field of the registration and of the calibration file.

A world corrected from the wand protocol's known move has every sensor position scaled by a
factor about the origin while the sensors' own measurements are not; a sensor that joins later
is registered in the unscaled world its sightings live in and then scaled the same way, so the
factor must come from the calibration itself, not from reading its ``world`` sentence.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from kinefuse.capture.calibration.calib_file import (
    CalibrationFile,
    SensorCalibration,
    dumps_calibration,
    loads_calibration,
)
from kinefuse.capture.calibration.synthetic import make_rig, simulate_sightings, wand_waving
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.errors import InputError
from kinefuse.live.server.live_calibration import LiveCalibration

IDS = ("a", "b", "c", "d")
F = 1.01  # the fixed sensors' world was scaled by this (1 %: 3 cm at 3 m)


def _toml_row(row: np.ndarray) -> str:
    return "[" + ", ".join(repr(float(v)) for v in row) + "]"


def calibration_text(poses: dict[str, np.ndarray], world: str, scale_line: str) -> str:
    """A calibration file of ``poses`` written out by hand, as kinefuse writes one."""
    out = [
        'format = "kinefuse-calibration"',
        "format_version = 1",
        'method = "full"',
        "created = 2026-01-02T03:04:05+00:00",
        f'world = "{world}"',
        "rms_mm = 1.0",
        scale_line,
    ]
    for sid, p in poses.items():
        rows = ",\n".join("    " + _toml_row(r) for r in p)
        out += ["", "[[sensor]]", f'id = "{sid}"', "residual_mm = 1.0", "sightings = 100"]
        out += [f"sensor2world = [\n{rows},\n]", "", "[sensor.intrinsics]"]
        out += [
            f"{k} = {v if isinstance(v, int) else repr(float(v))}"
            for k, v in Intrinsics().to_dict().items()
        ]
    return "\n".join(out) + "\n"


@pytest.fixture(scope="module")
def wand():
    rng = np.random.default_rng(7)
    poses = make_rig(4, rng)
    t, p = wand_waving(20.0, rng)
    sights = simulate_sightings(poses, Intrinsics(), t, p, rng, sensor_ids=IDS)
    return dict(zip(IDS, poses, strict=True)), sights


def test_a_late_joiner_is_registered_in_the_scale_its_calibration_file_records(wand) -> None:
    """The file says ``scale = 1.01``; its ``world`` line is someone's own description (no
    "scaled by" sentence): sensor d, joining later, must still end up in the scaled world."""
    truth, sights = wand
    scaled = {}
    for sid in ("a", "b", "c"):
        p = truth[sid].copy()
        p[:3, 3] *= F
        scaled[sid] = p
    text = calibration_text(scaled, "lab 2: origin at the tape cross, z up", f"scale = {F!r}")
    cal = LiveCalibration()
    cal.load(loads_calibration(text, source="lab2.toml"))
    cal.start(0.0, list(IDS))
    assert cal.targets == ("d",)
    for sid in IDS:
        s = sights[sid]
        for t, c, q in zip(s.t_server_s, s.centre_sensor_m, s.quality, strict=True):
            cal.add_sighting(sid, float(t), c, float(q))
    out = cal.solve({s: Intrinsics() for s in IDS}, {})
    assert out.ok, out.message
    want = truth["d"][:3, 3] * F
    got = cal.poses["d"][:3, 3]
    # 3.3 mm from the registration alone (the same within 0.1 mm with an unscaled world)
    assert np.linalg.norm(got - want) < 0.01, (
        f"d is {1e3 * np.linalg.norm(got - want):.1f} mm from where the scaled world puts it"
    )
    np.testing.assert_allclose(cal.poses["d"][:3, :3], truth["d"][:3, :3], atol=0.01)
    # the merged calibration keeps the factor, in memory and in its TOML
    assert out.calibration is not None and out.calibration.scale == F
    assert out.text is not None and loads_calibration(out.text).scale == F
    assert out.registration is not None and out.registration.scale == F


def _cal(world: str = "w", scale: float = 1.0) -> CalibrationFile:
    import datetime as _dt

    s = SensorCalibration("k0", "", np.eye(4), Intrinsics(), 0.001, 10)
    return CalibrationFile(
        "full", _dt.datetime(2026, 1, 2, tzinfo=_dt.UTC), (s,), world, 0.001, scale
    )


def test_the_scale_is_written_read_back_exactly_and_checked() -> None:
    f = 1.0022345678901234
    back = loads_calibration(dumps_calibration(_cal(scale=f)))
    assert back.scale == f
    assert loads_calibration(dumps_calibration(_cal())).scale == 1.0
    for bad in ("0.0", "-1.0", "nan", "inf", '"1.0"', "true"):
        text = dumps_calibration(_cal()).replace("scale = 1.0", f"scale = {bad}")
        with pytest.raises(InputError, match="scale"):
            loads_calibration(text, source="x.toml")


def test_an_old_file_without_the_field_gets_its_scale_from_what_kinefuse_wrote() -> None:
    """Files written before the field: the factor is recovered from the one sentence kinefuse
    wrote into ``world`` when it scaled; none there means the world was never scaled (1.0);
    a sentence that cannot be a kinefuse correction is refused, not guessed."""

    def old(world: str) -> str:
        text = dumps_calibration(_cal(world=world))
        return "\n".join(x for x in text.splitlines() if not x.startswith("scale =")) + "\n"

    sentence = "; scaled by 1.00220 from the protocol's known axis length"
    assert loads_calibration(old("wand: origin ..." + sentence)).scale == 1.0022
    joined = "wand: origin ..." + sentence + "; k2 registered against k0, k1"
    assert loads_calibration(old(joined)).scale == 1.0022
    assert loads_calibration(old("wand: origin below the wand")).scale == 1.0
    not_corrected = "wand; scale NOT corrected: the move between the holds found is 9.0% off"
    assert loads_calibration(old(not_corrected)).scale == 1.0
    with pytest.raises(InputError, match="scale"):
        loads_calibration(old("w; scaled by 1.50000 from the protocol's known axis length"))


def test_the_registration_carries_the_factor_it_was_scaled_by() -> None:
    from kinefuse.capture.calibration.calibration_run import scale_registration
    from kinefuse.capture.calibration.register import Registration

    reg = Registration(
        "full", ("a",), np.eye(4)[None] + 0.0, np.zeros(1), np.ones(1, np.int64), 0.0, "w"
    )
    assert reg.scale == 1.0
    s = scale_registration(reg, 1.002)
    assert s.scale == 1.002 and "scaled by 1.00200" in s.world  # the sentence stays, for people
    assert math.isclose(scale_registration(s, 1.001).scale, 1.002 * 1.001)
