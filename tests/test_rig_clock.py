"""Rig files, the default layout, and sensor clocks."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.errors import RigError
from kinefuse.sim.clock import ClockParams, capture_times, clock_probes, draw_clock
from kinefuse.sim.rig import default_rig, load_rig, parse_rig, rig_to_toml


def test_default_layout_circle_heights_and_facing() -> None:
    rig = default_rig(4)
    pos = np.array([s.position_m for s in rig.sensors])
    np.testing.assert_allclose(np.linalg.norm(pos[:, :2], axis=1), 3.0, atol=1e-12)
    assert pos[:, 2].min() == pytest.approx(1.0) and pos[:, 2].max() == pytest.approx(1.2)
    for s in rig.sensors:
        r = s.sensor2world[:3, :3]
        np.testing.assert_allclose(r.T @ r, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1.0)
        # optical axis points at the centre of the area, image x horizontal, image y down
        to_centre = np.array([0.0, 0.0, 1.0]) - s.position_m
        np.testing.assert_allclose(r[:, 2], to_centre / np.linalg.norm(to_centre), atol=1e-12)
        assert abs(r[2, 0]) < 1e-12 and r[2, 1] < 0


def test_rig_toml_round_trip_with_roll(tmp_path) -> None:
    text = """
[[sensor]]
id = "front"
position_m = [3.0, 0.5, 1.5]
look_at_m = [0.0, 0.0, 0.8]
roll_deg = 4.0

[[sensor]]
id = "side"
serial = "0042"
position_m = [0.0, 2.5, 1.1]
look_at_m = [0.0, 0.0, 1.0]

[actor]
position_m = [0.5, -0.2]
heading_deg = 30
"""
    path = tmp_path / "rig.toml"
    path.write_text(text)
    rig = load_rig(path)
    assert [s.id for s in rig.sensors] == ["front", "side"]
    assert rig.sensors[1].serial == "0042"
    assert rig.actor_position_m == (0.5, -0.2) and rig.actor_heading_deg == 30.0
    again = parse_rig(rig_to_toml(rig))
    for a, b in zip(rig.sensors, again.sensors, strict=True):
        np.testing.assert_allclose(a.sensor2world, b.sensor2world, atol=1e-5)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "no [[sensor]] tables"),
        ("[[sensor]]\nposition_m=[1,2,3]\nlook_at_m=[0,0,1]", "missing 'id'"),
        ('[[sensor]]\nid="a"\nposition_m=[1,2]\nlook_at_m=[0,0,1]', "list of 3 numbers"),
        ('[[sensor]]\nid="a"\nposition_m=[1,2,3]', "missing 'look_at_m'"),
        ('[[sensor]]\nid="a"\nposition_m=[0,0,1]\nlook_at_m=[0,0,1]', "coincide"),
        (
            '[[sensor]]\nid="a"\nposition_m=[1,0,1]\nlook_at_m=[0,0,1]\n'
            '[[sensor]]\nid="a"\nposition_m=[0,1,1]\nlook_at_m=[0,0,1]',
            "repeated: a",
        ),
        ('[[sensor]]\nid="a"\nposition_m=[1,0,1]\nlook_at_m=[0,0,1]\nfov=3', "unknown keys"),
        ("[[sensor]\n", "not valid TOML"),
    ],
)
def test_bad_rig_files_say_what_is_wrong(text: str, message: str) -> None:
    with pytest.raises(RigError, match=message.replace("[", r"\[")):
        parse_rig(text)


def test_missing_rig_file(tmp_path) -> None:
    with pytest.raises(RigError, match="not found"):
        load_rig(tmp_path / "nope.toml")


def test_capture_times_follow_the_sensor_clock(rng) -> None:
    params = ClockParams(frame_drop_prob=0.0, timestamp_jitter_s=0.0)
    clock = draw_clock(rng, params)
    cap = capture_times(clock, 5.0, 15.0, rng, params)
    # 30 Hz on the sensor's own clock: true-time period is 1/30 divided by the rate
    np.testing.assert_allclose(np.diff(cap.t_true_s), 1 / 30 / clock.rate, rtol=1e-9)
    np.testing.assert_allclose(clock.affine.inverse(cap.t_sensor_s), cap.t_true_s, atol=1e-9)
    assert cap.t_true_s[0] >= 5.0 and cap.t_true_s[-1] <= 15.0
    assert (cap.t_receive_server_s - cap.t_true_s).min() > 0.03  # latency is tens of ms
    np.testing.assert_array_equal(cap.seq, np.arange(cap.seq.size))


def test_dropped_frames_leave_gaps_in_seq(rng) -> None:
    params = ClockParams(frame_drop_prob=0.2)
    cap = capture_times(draw_clock(rng, params), 0.0, 20.0, rng, params)
    gaps = np.diff(cap.seq)
    assert gaps.min() >= 1 and (gaps > 1).any()


def test_ntp_probes_recover_the_offset(rng) -> None:
    params = ClockParams()
    clock = draw_clock(rng, params)
    t1, t2, t3, t4 = clock_probes(clock, 0.0, 30.0, rng, params).T
    offset = ((t2 - t1) + (t3 - t4)) / 2  # client minus server at the probe time
    true = clock.affine.forward((t1 + t4) / 2) - (t1 + t4) / 2
    # delays are asymmetric: the estimate errs by at most half the round trip
    assert np.all(np.abs(offset - true) <= ((t4 - t1) - (t3 - t2)) / 2 + 1e-9)
    assert np.median(np.abs(offset - true)) < 1e-3  # 1 ms


def test_host_stamps_arrivals_on_its_own_clock(rng) -> None:
    from kinefuse.sim.clock import draw_sensor_clocks

    params = ClockParams(frame_drop_prob=0.0)
    clocks = draw_sensor_clocks(rng, params)
    assert clocks.device != clocks.host
    cap = capture_times(
        clocks.device, 0.0, 20.0, rng, params,
        host=clocks.host, latency_offset_s=0.01,
    )  # fmt: skip
    latency = clocks.host.affine.inverse(cap.t_receive_host_s) - cap.t_true_s
    assert latency.min() >= params.latency_min_s - 1e-9
    assert np.mean(latency) == pytest.approx(params.latency_mean_s + 0.01, abs=0.001)  # 1 ms
    # the server's receive time is the same arrival plus the network
    assert np.all(cap.t_receive_server_s - cap.t_true_s >= latency)
    flat = clocks.to_dict()
    assert {"offset_s", "drift_ppm", "phase_s", "host_offset_s", "host_drift_ppm"} <= set(flat)
    # without a host clock the device clock stamps the arrivals (a client that stamps frames
    # with the probed clock)
    own = capture_times(clocks.device, 0.0, 2.0, rng, params)
    lat_own = clocks.device.affine.inverse(own.t_receive_host_s) - own.t_true_s
    assert lat_own.min() >= params.latency_min_s - 1e-9


def test_two_sensors_at_the_same_spot_are_refused(tmp_path) -> None:
    sensor = '[[sensor]]\nid = "{}"\nposition_m = [{}, 0.0, 1.1]\nlook_at_m = [0.0, 0.0, 1.0]\n'
    path = tmp_path / "rig.toml"
    path.write_text(sensor.format("a", 3.0) + sensor.format("b", -3.0) + sensor.format("c", 3.01))
    with pytest.raises(RigError, match=r"sensors 'a' and 'c' stand at the same spot .*1\.0 cm"):
        load_rig(path)
    path.write_text(sensor.format("a", 3.0) + sensor.format("c", 2.9))  # 10 cm: side by side
    assert len(load_rig(path).sensors) == 2
