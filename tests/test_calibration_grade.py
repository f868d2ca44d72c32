"""The calibration grade's split-half check (issue 23): a calibration worse than its residuals
say (few sightings, sightings whose times are off) is doubtful or failed, not good.

Simulated wand sightings with known truth (:mod:`kinefuse.capture.calibration.synthetic`) solved by
the server's live calibration (pure state, no sockets); the truth is used only to check the grade,
never by it.
"""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.capture.calibration.compare import pose_errors
from kinefuse.capture.calibration.grade import (
    HALVES_DOUBTFUL_M,
    HalvesCheck,
    grade_calibration,
    split_halves,
)
from kinefuse.capture.calibration.register import Registration, Sightings
from kinefuse.capture.calibration.synthetic import make_rig, simulate_sightings, wand_waving
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.live.server.live_calibration import LiveCalibration, LiveCalibrationOptions

IDS = ("a", "b", "c", "d")


def solve(sights: dict[str, Sightings]):
    cal = LiveCalibration(LiveCalibrationOptions())
    cal.start(0.0, list(IDS))
    for sid in IDS:
        s = sights[sid]
        for t, c, q in zip(s.t_server_s, s.centre_sensor_m, s.quality, strict=True):
            cal.add_sighting(sid, float(t), c, float(q))
    return cal.solve({s: Intrinsics() for s in IDS}, {})


def session(seed: int, **kw: float) -> tuple[np.ndarray, dict[str, Sightings]]:
    rng = np.random.default_rng(seed)
    poses = make_rig(4, rng)
    t, p = wand_waving(15.0, rng)
    return poses, simulate_sightings(poses, Intrinsics(), t, p, rng, sensor_ids=IDS, **kw)


def worst_error_m(out, poses: np.ndarray) -> float:
    reg = out.registration
    assert reg is not None and reg.sensor_ids == IDS
    return float(pose_errors(reg.sensor2world, poses, align="rigid").position_error_m.max())


def test_split_halves_deal_alternate_blocks_over_the_whole_phase() -> None:
    t = np.arange(0.0, 10.0, 1 / 30)
    s = Sightings(t, np.zeros((t.size, 3)), np.ones(t.size))
    a, b = split_halves(s, 0.0)
    assert len(a) + len(b) == t.size and abs(len(a) - len(b)) <= 30
    assert np.all(np.floor(a.t_server_s) % 2 == 0) and np.all(np.floor(b.t_server_s) % 2 == 1)
    assert a.t_server_s[-1] - a.t_server_s[0] > 8 and b.t_server_s[-1] - b.t_server_s[0] > 8


def test_the_rule_on_given_disagreements() -> None:
    reg = Registration(
        method="full",
        sensor_ids=("a", "b"),
        sensor2world=np.stack([np.eye(4), np.eye(4)]),
        residual_m=np.array([0.001, 0.001]),
        n_sightings=np.array([300, 300]),
        rms_m=0.001,
        world="test",
    )
    assert grade_calibration(reg).grade == "good"
    assert grade_calibration(reg, halves=HalvesCheck({"a": 0.001, "b": 0.002})).grade == "good"
    g = grade_calibration(reg, halves=HalvesCheck({"a": 0.001, "b": 0.005}))
    assert g.grade == "doubtful" and "sensor b" in g.reasons[0] and "halves" in g.reasons[0]
    assert grade_calibration(reg, halves=HalvesCheck({"a": 0.03, "b": 0.001})).grade == "failed"
    assert grade_calibration(reg, halves=HalvesCheck({"a": np.nan})).grade == "failed"
    g = grade_calibration(reg, halves=HalvesCheck({}, unchecked="half 2: too few"))
    assert g.grade == "doubtful" and "could not be checked" in g.reasons[0]


def test_a_well_seen_wand_is_good_and_its_halves_agree() -> None:
    poses, sights = session(2)
    out = solve(sights)
    assert out.ok and out.grade.grade == "good", out.grade.reasons
    assert out.halves is not None and out.halves.unchecked is None
    assert max(out.halves.disagreement_m.values()) < HALVES_DOUBTFUL_M
    assert worst_error_m(out, poses) < 0.003


@pytest.mark.parametrize(
    ("what", "seed", "kw", "late_s"),
    [
        ("few sightings (60 % of the depth frames lost)", 2, {"dropout": 0.6}, 0.0),
        ("one sensor's times 14 ms late", 2, {}, 0.014),
    ],
)
def test_worse_than_its_residuals_say_is_not_good(
    what: str, seed: int, kw: dict[str, float], late_s: float
) -> None:
    poses, sights = session(seed, **kw)
    if late_s:
        s = sights["b"]
        sights["b"] = Sightings(s.t_server_s + late_s, s.centre_sensor_m, s.quality)
    out = solve(sights)
    err = worst_error_m(out, poses)
    assert err > 0.003, f"{what}: the case should be more than 3 mm off (is {1e3 * err:.1f} mm)"
    # the residuals and counts alone call it good; the halves do not
    alone = grade_calibration(out.registration)
    assert alone.grade == "good", alone.reasons
    assert out.grade.grade in ("doubtful", "failed"), (what, out.grade.reasons)
    assert any("halves" in r for r in out.grade.reasons), out.grade.reasons
