"""kinefuse.core.affine_clock.AffineClock: the one affine clock map, and the classes that hold it.

The equivalence tests write out each holder's formula as it was before the holder delegated to
:class:`AffineClock`, and check the holder against it on seeded random clocks and times: bit for
bit where the arithmetic is the same, to float rounding where the new one groups it differently
(the online estimator's line).
"""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.capture.sync.device import DeviceClockEstimate, SensorTimebase
from kinefuse.capture.sync.envelope import ClockFit
from kinefuse.capture.sync.ntp import ClockEstimate
from kinefuse.capture.sync.online import OnlineClock, OnlineEstimate
from kinefuse.core.affine_clock import AffineClock
from kinefuse.lab.live_truth import PlaybackTruth
from kinefuse.live.client.clocks import HostClock
from kinefuse.sim.clock import SensorClock, SensorClocks

N_CASES = 50


def random_clocks(seed: int) -> list[AffineClock]:
    rng = np.random.default_rng(seed)
    return [
        AffineClock(
            origin=float(rng.uniform(-1000.0, 1000.0)),
            offset=float(rng.uniform(-1000.0, 1000.0)),
            rate=float(1.0 + rng.normal(0.0, 1e-4)),
        )
        for _ in range(N_CASES)
    ]


def random_times(seed: int, n: int = 64) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-2000.0, 2000.0, n)


def test_forward_is_the_documented_formula() -> None:
    c = AffineClock(origin=10.0, offset=500.0, rate=1.5)
    assert c.forward(12.0) == 500.0 + 1.5 * 2.0
    assert c.inverse(503.0) == 12.0
    assert AffineClock().forward(3.25) == 3.25  # the default is the identity
    assert AffineClock().drift_ppm == 0.0


def test_forward_keeps_floats_floats_and_arrays_arrays() -> None:
    c = AffineClock.from_drift_ppm(20.0, offset=3.0, origin=1.0)
    assert type(c.forward(2.0)) is float
    assert type(c.inverse(2.0)) is float
    out = c.forward(np.array([1.0, 2.0]))
    assert isinstance(out, np.ndarray) and out.shape == (2,)


def test_from_drift_ppm() -> None:
    c = AffineClock.from_drift_ppm(25.0, offset=7.0, origin=2.0)
    assert c.rate == 1.0 + 25.0 * 1e-6
    assert (c.origin, c.offset) == (2.0, 7.0)
    assert c.drift_ppm == pytest.approx(25.0, rel=1e-9)
    assert AffineClock.from_drift(25e-6).rate == 1.0 + 25e-6


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_trips(seed: int) -> None:
    t = random_times(seed + 100)
    for c in random_clocks(seed):
        np.testing.assert_allclose(c.inverse(c.forward(t)), t, rtol=0, atol=1e-11)
        np.testing.assert_allclose(c.forward(c.inverse(t)), t, rtol=0, atol=1e-11)
        inv = c.inverted()
        np.testing.assert_allclose(inv.forward(t), c.inverse(t), rtol=0, atol=1e-11)
        np.testing.assert_allclose(inv.inverse(t), c.forward(t), rtol=0, atol=1e-11)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compose_applies_inner_first_and_is_associative(seed: int) -> None:
    t = random_times(seed + 200)
    cs = random_clocks(seed)
    for a, b, c in zip(cs[0::3], cs[1::3], cs[2::3], strict=False):
        np.testing.assert_allclose(a.compose(b).forward(t), a.forward(b.forward(t)), atol=1e-9)
        left, right = a.compose(b).compose(c), a.compose(b.compose(c))
        np.testing.assert_allclose(left.forward(t), right.forward(t), rtol=0, atol=1e-9)
        assert left.rate == pytest.approx(right.rate, rel=1e-15)


@pytest.mark.parametrize("seed", [0, 1])
def test_compose_identity_and_inverse(seed: int) -> None:
    t = random_times(seed + 300)
    ident = AffineClock()
    for c in random_clocks(seed):
        np.testing.assert_allclose(c.compose(ident).forward(t), c.forward(t), rtol=0, atol=1e-11)
        np.testing.assert_allclose(ident.compose(c).forward(t), c.forward(t), rtol=0, atol=1e-12)
        np.testing.assert_allclose(c.inverted().compose(c).forward(t), t, rtol=0, atol=1e-10)
        np.testing.assert_allclose(c.compose(c.inverted()).forward(t), t, rtol=0, atol=1e-10)


# -- the holders against their formulas of before -------------------------------------------


def ppm_params(seed: int) -> list[tuple[float, float]]:
    rng = np.random.default_rng(seed)
    return [(float(rng.uniform(0.0, 1000.0)), float(rng.normal(0.0, 30.0))) for _ in range(N_CASES)]


def test_sensor_clock_as_before() -> None:
    t = random_times(1)
    for off, ppm in ppm_params(10):
        c = SensorClock(offset_s=off, drift_ppm=ppm, phase_s=0.01)
        rate = 1.0 + ppm * 1e-6
        assert c.rate == rate
        np.testing.assert_array_equal(c.affine.forward(t), off + rate * t)
        np.testing.assert_array_equal(c.affine.inverse(t), (t - off) / rate)
        assert c.to_dict() == {"offset_s": off, "drift_ppm": ppm, "phase_s": 0.01}


def test_clock_estimate_as_before() -> None:
    t = random_times(2)
    for off, ppm in ppm_params(11):
        e = ClockEstimate(offset_s=off, drift_ppm=ppm, residual_s=1e-4, n_probes=10)
        rate = 1.0 + ppm * 1e-6
        assert e.rate == rate
        np.testing.assert_array_equal(e.affine.inverse(t), (t - off) / rate)
        np.testing.assert_array_equal(e.affine.forward(t), off + rate * t)
        assert e == ClockEstimate(offset_s=off, drift_ppm=ppm, residual_s=1e-4, n_probes=10)


def test_device_clock_estimate_as_before() -> None:
    t = random_times(3)
    for off, ppm in ppm_params(12):
        e = DeviceClockEstimate(offset_s=off, drift_ppm=ppm, residual_s=1e-3, n_frames=100)
        rate = 1.0 + ppm * 1e-6
        assert e.rate == rate
        np.testing.assert_array_equal(e.affine.forward(t), off + rate * t)
    np.testing.assert_array_equal(DeviceClockEstimate.identity().affine.forward(t), t)


def test_clock_fit_as_before() -> None:
    rng = np.random.default_rng(13)
    t = random_times(4)
    for _ in range(N_CASES):
        t0, off, rate = rng.uniform(0, 1e4), rng.uniform(0, 1e4), 1.0 + rng.normal(0, 1e-4)
        f = ClockFit(
            AffineClock(origin=float(t0), offset=float(off), rate=float(rate)), 100, 5, 1e-3, 5e-3
        )
        np.testing.assert_array_equal(f.affine.forward(t), off + rate * (t - t0))
        assert f.affine.drift_ppm == (rate - 1.0) * 1e6


def test_host_clock_as_before() -> None:
    rng = np.random.default_rng(14)
    for _ in range(N_CASES):
        h0, drift, m0 = rng.uniform(0, 1e3), rng.normal(0, 5e-5), rng.uniform(0, 1e5)
        c = HostClock(float(h0), float(drift), float(m0))
        for t in rng.uniform(0, 1e5, 8).tolist():
            assert c.affine.forward(t) == h0 + (1.0 + drift) * (t - m0)
            assert c.affine.inverse(t) == m0 + (t - h0) / (1.0 + drift)
            assert type(c.affine.forward(t)) is float
        p = PlaybackTruth("k1", float(h0), float(drift), float(m0), 0.0)
        tm = rng.uniform(0, 1e5, 8)
        np.testing.assert_array_equal(p.host.forward(tm), h0 + (1.0 + drift) * (tm - m0))


def test_sim_clock_truth_as_before() -> None:
    rng = np.random.default_rng(15)
    for (off, ppm), (hoff, hppm) in zip(ppm_params(16), ppm_params(17), strict=True):
        d = {"offset_s": off, "drift_ppm": ppm, "host_offset_s": hoff, "host_drift_ppm": hppm}
        truth = SensorClocks.from_dict(d)
        for t in rng.uniform(0, 2e3, 8).tolist():
            assert truth.device.affine.inverse(t) == (t - off) / (1.0 + ppm * 1e-6)
            assert truth.host.affine.inverse(t) == (t - hoff) / (1.0 + hppm * 1e-6)


def test_online_estimate_as_before() -> None:
    rng = np.random.default_rng(18)
    for _ in range(N_CASES):
        at, off, ppm = rng.uniform(0, 1e4), rng.uniform(-1e3, 1e3), rng.normal(0, 50)
        e = OnlineEstimate(float(at), float(off), float(ppm), 1e-4, 0.5, 10, 0)
        b = ppm * 1e-6
        for t in rng.uniform(0, 1e4, 8).tolist():
            old_server = (t - off + b * at) / (1.0 + b)
            old_client = t + off + b * (t - at)
            assert e.affine.inverse(t) == pytest.approx(old_server, rel=0, abs=1e-11)
            assert e.affine.forward(t) == pytest.approx(old_client, rel=0, abs=1e-11)
            assert type(e.affine.inverse(t)) is float


def test_online_clock_line_as_before() -> None:
    rng = np.random.default_rng(19)
    off, b = 321.0, 55e-6
    clock = OnlineClock()
    for t1 in np.arange(0.0, 40.0, 0.5).tolist():
        up, down = 5e-4 + rng.exponential(2e-4), 5e-4 + rng.exponential(2e-4)
        t2 = off + (1.0 + b) * (t1 + up)
        clock.add_probe(t1, t2, t2 + 1e-4, t1 + up + 1e-4 + down)
    line = clock._require()
    for t in rng.uniform(0, 100, 8).tolist():
        old_server = (t - line.a + line.b * line.t_ref) / (1.0 + line.b)
        old_client = t + line.a + line.b * (t - line.t_ref)
        assert clock.affine.inverse(t) == pytest.approx(old_server, rel=0, abs=1e-11)
        assert clock.affine.forward(t) == pytest.approx(old_client, rel=0, abs=1e-11)
    t = rng.uniform(0, 100, 8)
    np.testing.assert_allclose(clock.affine.inverse(clock.affine.forward(t)), t, rtol=0, atol=1e-11)


def test_sensor_timebase_is_one_affine_clock_as_before() -> None:
    """Device -> server was the device fit then the host clock's inverse, two steps; it is
    now one composed AffineClock, within float rounding of the two steps."""
    rng = np.random.default_rng(21)
    for (doff, dppm), (hoff, hppm) in zip(ppm_params(22), ppm_params(23), strict=True):
        dev = DeviceClockEstimate(offset_s=doff, drift_ppm=dppm, residual_s=0.0, n_frames=9)
        host = ClockEstimate(offset_s=hoff, drift_ppm=hppm, residual_s=0.0, n_probes=9)
        tb = SensorTimebase(device=dev, host=host)
        assert isinstance(tb.affine, AffineClock)
        t = rng.uniform(0.0, 2e3, 50)
        two_steps = (doff + (1.0 + dppm * 1e-6) * t - hoff) / (1.0 + hppm * 1e-6)
        np.testing.assert_allclose(tb.affine.forward(t), two_steps, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    "holder",
    [
        SensorClock,
        SensorClocks,
        ClockEstimate,
        DeviceClockEstimate,
        SensorTimebase,
        ClockFit,
        OnlineEstimate,
        OnlineClock,
        HostClock,
        PlaybackTruth,
    ],
)
def test_only_affine_clock_maps_times(holder: type) -> None:
    """The estimates and the clocks that hold a map carry no mapping of their own: code that
    maps times takes the AffineClock (``.affine``, ``.host``, ``.device``)."""
    mapping = {n for n in dir(holder) if n in ("forward", "inverse", "at", "mono_at")}
    mapping |= {n for n in dir(holder) if n.startswith("to_") and n != "to_dict"}
    mapping |= {n for n in dir(holder) if n.startswith("host_at") or n.endswith("_to_true")}
    assert not mapping, f"{holder.__name__} maps times itself: {sorted(mapping)}"
