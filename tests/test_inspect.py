"""``inspect_session`` on small stores whose figures are known exactly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import JOINTS, N_JOINTS, TrackingState
from kinefuse.errors import InputError, StoreError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.inspect import format_inspect, inspect_session

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
WALKER = DATA / "kinect" / "kinect2_tracking" / "walker.json"
MM = 1e-3


def load_walker(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Real Kinect v2 frames: first tracked body per frame, sensor frame (x right, y down)."""
    frames = json.loads(path.read_text())["bodyFrame"]
    joints = np.full((len(frames), N_JOINTS, 3), np.nan)
    states = np.zeros((len(frames), N_JOINTS), np.int8)
    for f, frame in enumerate(frames):
        body = next((b for b in frame["bodies"] if b.get("tracked")), None)
        if body is None:
            continue
        js = sorted(body["joints"], key=lambda jd: jd["jointType"])
        states[f] = [jd["trackingState"] for jd in js]
        xyz = np.array([(-jd["cameraX"], -jd["cameraY"], jd["cameraZ"]) for jd in js])
        joints[f] = np.where((states[f] != 0)[:, None], xyz, np.nan)
    return joints, states


def unit_vectors(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    v = rng.normal(size=(*shape, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def make_known_store(path: Path) -> SessionStore:
    """Two sensors with errors of known lengths in random directions.

    k0: 12 frames at 30 Hz; frames 10 and 11 have no body. In the 10 body frames joints 0..20
    are tracked and 21..24 inferred; joint j is off by (j + 1) mm. Truth says frames 1, 4 (body)
    and 11 (no body) were swapped left/right.
    k1: 10 frames at 15 Hz, all joints tracked and off by 50 mm; truth exists for seq 0..9 but
    the sensor reported seq 5..14 (only 5..9 match).
    """
    rng = np.random.default_rng(21)
    s = SessionStore.create(path)
    s.add_sensor("k0", "SIM-0", Intrinsics())
    s.add_sensor("k1", "SIM-1", Intrinsics(), rate_hz=15.0)

    true0 = rng.normal([0, 0, 2.5], 0.4, (12, N_JOINTS, 3))
    err_len = (np.arange(N_JOINTS) + 1) * MM
    obs0 = true0 + unit_vectors(rng, (12, N_JOINTS)) * err_len[:, None]
    states0 = np.full((12, N_JOINTS), TrackingState.TRACKED, np.int8)
    states0[:, 21:] = TrackingState.INFERRED
    states0[10:] = TrackingState.NOT_TRACKED
    obs0[10:] = np.nan
    seq0 = np.arange(12)
    s.append_observations("k0", seq0, 500.0 + seq0 / 30.0, obs0, states0)
    swapped = np.zeros(12, bool)
    swapped[[1, 4, 11]] = True
    vis = np.ones((12, N_JOINTS), bool)
    s.append_truth_observations("k0", seq0, seq0 / 30.0, true0, vis, swapped)

    true1 = rng.normal([0, 0, 3.0], 0.4, (10, N_JOINTS, 3))
    obs1 = true1 + unit_vectors(rng, (10, N_JOINTS)) * 50 * MM
    seq1 = np.arange(5, 15)
    s.append_truth_observations(
        "k1",
        np.arange(10),
        np.arange(10) / 15.0,
        np.concatenate([rng.normal(size=(5, N_JOINTS, 3)), true1[:5]]),
        np.ones((10, N_JOINTS), bool),
        np.ones(10, bool),
    )
    s.append_observations(
        "k1",
        seq1,
        -20.0 + seq1 / 15.0,
        np.concatenate([obs1[:5], obs1[5:]]),
        np.full((10, N_JOINTS), TrackingState.TRACKED, np.int8),
    )
    return s


def test_inspect_known_errors(tmp_path: Path) -> None:
    with make_known_store(tmp_path / "known.sqlite") as s:
        d = inspect_session(s)
    json.dumps(d, allow_nan=False)  # JSON-able as the CLI prints it
    assert d["schema_version"] == 1 and d["joints"] == 25 and d["has_truth"] is True
    k0, k1 = d["sensors"]
    assert (k0["id"], k0["frames"], k0["frames_with_body"]) == ("k0", 12, 10)
    assert (k1["id"], k1["frames"], k1["frames_with_body"]) == ("k1", 10, 10)
    assert k0["rate_hz"] == pytest.approx(30.0, rel=1e-9)
    assert k1["rate_hz"] == pytest.approx(15.0, rel=1e-9)
    assert k1["nominal_rate_hz"] == 15.0
    assert d["duration_s"] == pytest.approx(9 / 15.0, abs=1e-9)  # k1's span is the longer one

    # 22 frames x 25 joints: k0 10 x 21 tracked + 10 x 4 inferred + 2 x 25 not; k1 250 tracked
    f = d["tracking_state_fraction"]
    assert f["tracked"] == pytest.approx(460 / 550)
    assert f["inferred"] == pytest.approx(40 / 550)
    assert f["not_tracked"] == pytest.approx(50 / 550)

    e = d["observation_error_m"]
    # k0: 10 samples each of 1..25 mm; k1 matched seq 5..9: 5 x 25 samples of 50 mm
    assert e["samples"] == 250 + 125
    # sorted: 250 values <= 25 mm then 125 of 50 mm; the median is sample 187 -> 19 mm
    assert e["median"] == pytest.approx(19 * MM, abs=1e-9)  # 1 nm
    assert e["p95"] == pytest.approx(50 * MM, abs=1e-9)
    for j, name in enumerate(JOINTS):  # 10 x (j + 1) mm and 5 x 50 mm: median is (j + 1) mm
        assert e["by_joint"][name] == pytest.approx((j + 1) * MM, abs=1e-9)
    # tracked: 210 values 1..21 mm (10 each) + 125 of 50 mm: sorted index 167 -> 17 mm
    assert e["by_state"]["tracked"] == pytest.approx(17 * MM, abs=1e-9)
    assert e["by_state"]["inferred"] == pytest.approx(23.5 * MM, abs=1e-9)  # 22..25 mm
    assert k0["observation_error_m"] == pytest.approx(13 * MM, abs=1e-9)
    assert k1["observation_error_m"] == pytest.approx(50 * MM, abs=1e-9)
    # swaps among matched frames with a body: k0 2 of 10, k1 5 of 5 -> 7 / 15
    assert d["lr_swap_fraction"] == pytest.approx(7 / 15)

    text = format_inspect(d)
    assert "k0" in text and "k1" in text
    assert "median 1.9 cm, p95 5.0 cm" in text
    assert "tracked 83.6 %" in text
    assert "FootRight" in text and "2.0 cm" in text  # joint 19 -> 20 mm


def test_inspect_without_truth_from_path(tmp_path: Path) -> None:
    p = tmp_path / "live.sqlite"
    with SessionStore.create(p) as s:
        s.add_sensor("k0", "0001", Intrinsics())
        states = np.full((6, N_JOINTS), TrackingState.TRACKED, np.int8)
        seq = np.array([0, 1, 2, 4, 5, 6])  # frame 3 was dropped
        s.append_observations("k0", seq, seq / 30.0, np.ones((6, 25, 3)), states)
        s.append_depth_frames("k0", [0], [0.0], np.zeros((1, 424, 512), np.uint16))
        s.append_clock_probes("k0", [0.0], [1.0], [1.0], [0.01])
        s.write_calibration("paper", "x = 1")
    d = inspect_session(p)
    assert d["has_truth"] is False
    assert d["observation_error_m"] is None and d["lr_swap_fraction"] is None
    k0 = d["sensors"][0]
    assert k0["rate_hz"] == pytest.approx(30.0)  # a dropped frame does not change the rate
    assert (k0["depth_frames"], k0["clock_probes"]) == (1, 1)
    assert d["calibrations"] == ["paper"]
    assert d["tracking_state_fraction"]["tracked"] == 1.0
    text = format_inspect(d)
    assert "ground truth: no" in text and "observation error" not in text
    json.dumps(d, allow_nan=False)


def test_inspect_empty_store(tmp_path: Path) -> None:
    with SessionStore.create(tmp_path / "e.sqlite") as s:
        s.add_sensor("k0", "0001", Intrinsics())
        d = inspect_session(s)
    assert d["sensors"][0]["frames"] == 0 and d["sensors"][0]["rate_hz"] is None
    assert d["duration_s"] == 0.0
    assert d["tracking_state_fraction"] == {"tracked": None, "inferred": None, "not_tracked": None}
    assert "-" in format_inspect(d)


def test_inspect_bad_input(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="expected a SessionStore or the path of one, got int"):
        inspect_session(3)  # type: ignore[arg-type]
    with pytest.raises(StoreError, match="the file does not exist"):
        inspect_session(tmp_path / "missing.sqlite")


@pytest.mark.skipif(not WALKER.exists(), reason=f"real Kinect data not found at {WALKER}")
def test_inspect_real_kinect_recording(tmp_path: Path) -> None:
    joints, states = load_walker(WALKER)
    with SessionStore.create(tmp_path / "walker.sqlite") as s:
        s.add_sensor("kinect", "walker", Intrinsics())
        n = joints.shape[0]
        s.append_observations("kinect", np.arange(n), np.arange(n) / 30.0, joints, states)
        d = inspect_session(s)
    f = d["tracking_state_fraction"]
    counts = np.bincount(states.ravel(), minlength=3) / states.size
    assert f["tracked"] == pytest.approx(counts[2])
    assert f["inferred"] == pytest.approx(counts[1])
    assert f["tracked"] > 0.5  # a walker facing the sensor is mostly tracked
    assert d["sensors"][0]["frames_with_body"] == int((states != 0).any(axis=1).sum())
