"""The online clock estimator, probe by probe, on simulated clocks and asymmetric networks.

Probes come from :func:`kinefuse.sim.probes.asymmetric_probes` (its docstring states the delays):
the client's clock is a :class:`SensorClock` of the simulator (offset, drift) plus an optional
step. The error of a check is the estimated offset at a reply's arrival time minus the true offset
then. ``benchmarks/bench_sync.py`` runs the same generator on more seeds and longer sessions.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from kinefuse.capture.sync import OnlineClock, OnlineClockParams, ProbeStatus, estimate_clock
from kinefuse.errors import SyncError
from kinefuse.sim.clock import ClockParams, SensorClock, clock_probes, draw_clock
from kinefuse.sim.probes import NETWORKS, asymmetric_probes, random_clock, replay

WARMUP_S = 5.0


@pytest.mark.parametrize("network", NETWORKS)
def test_offset_error_after_warmup(network: str) -> None:
    errs, drift_errs = [], []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        clock = random_clock(rng)
        probes = asymmetric_probes(clock.affine.forward, 0.0, 120.0, rng, **NETWORKS[network])
        est = OnlineClock()
        out = replay(est, probes, clock.affine.forward)
        assert not out["reset"].any()  # no false jump
        errs.append(np.abs(out["err"][out["t"] >= WARMUP_S]))
        drift_errs.append(est.estimate(120.0).drift_ppm - clock.drift_ppm)
    err = np.concatenate(errs)
    assert np.median(err) < 0.5e-3  # 0.5 ms (measured 0.04-0.1 ms)
    assert err.max() < 2e-3  # 2 ms (measured 0.5-0.8 ms)
    assert np.abs(drift_errs).max() < 10.0  # ppm, over a 30 s window


@pytest.mark.parametrize("network", NETWORKS)
def test_uncertainty_is_honest(network: str) -> None:
    z, se = [], []
    for seed in range(4):
        rng = np.random.default_rng(100 + seed)
        clock = random_clock(rng)
        probes = asymmetric_probes(clock.affine.forward, 0.0, 120.0, rng, **NETWORKS[network])
        out = replay(OnlineClock(), probes, clock.affine.forward)
        z.append(out["err"] / out["se"])  # every check, warm-up included
        se.append(out["se"][out["t"] >= WARMUP_S])
    z_all = np.concatenate(z)
    assert np.mean(np.abs(z_all) <= 3.0) >= 0.99
    # and not honest by being vague: fewer errors within 1 sd than if it were 3 times too large
    # (a normal error is within 1 sd in 68 % of the checks), and a small standard error
    assert np.mean(np.abs(z_all) <= 1.0) < 0.97
    assert np.median(np.concatenate(se)) < 0.5e-3  # 0.5 ms


@pytest.mark.parametrize("step_s", [0.080, -0.080, 0.005])
def test_recovers_from_clock_jump(step_s: float) -> None:
    rng = np.random.default_rng(7)
    clock = random_clock(rng)
    t_jump = 60.3

    def client(t: np.ndarray) -> np.ndarray:
        return clock.affine.forward(t) + step_s * (np.asarray(t) >= t_jump)

    est = OnlineClock()
    out = replay(est, asymmetric_probes(client, 0.0, 120.0, rng), client)
    resets = out["reset"][out["reset"] != ""]
    assert len(resets) == 1 and "clock jump" in resets[0]
    step_ms = float(re.search(r"jump of ([+-][0-9.]+) ms", resets[0]).group(1))  # type: ignore[union-attr]
    assert step_ms == pytest.approx(step_s * 1e3, abs=3.0)  # ms: the reason names the step
    bad = np.flatnonzero(np.abs(out["err"]) >= 2e-3)
    recovered_at = out["t"][bad[-1] + 1]
    assert recovered_at - t_jump < 5.0  # s (measured 1.7 s: two bursts)
    after = out["t"] >= recovered_at
    assert np.median(np.abs(out["err"][after])) < 0.5e-3  # 0.5 ms
    assert est.epoch == 1
    # a step does not change the rate: the drift is kept through the restart
    i_reset = int(np.flatnonzero(out["reset"] != "")[0])
    assert out["drift_ppm"][i_reset] == pytest.approx(clock.drift_ppm, abs=5.0)  # ppm


def test_one_bad_burst_does_not_reset() -> None:
    rng = np.random.default_rng(3)
    clock = random_clock(rng)
    probes = asymmetric_probes(clock.affine.forward, 0.0, 90.0, rng)
    # the client stamps one whole burst 50 ms late (a stalled process), delays unchanged
    glitch = (probes[:, 0] >= 40.0) & (probes[:, 0] < 40.5)
    probes[glitch, 1:3] += 0.050
    est = OnlineClock()
    out = replay(est, probes, clock.affine.forward)
    seen = set(out["status"][glitch])
    assert ProbeStatus.SUSPECT in seen and seen <= {"suspect", "kept", "rejected-delay"}
    assert not out["reset"].any() and est.epoch == 0
    assert np.abs(out["err"][out["t"] >= WARMUP_S]).max() < 2e-3  # 2 ms


def test_reconnect_reset_and_recovery() -> None:
    rng = np.random.default_rng(11)
    old, new = random_clock(rng), random_clock(rng)
    t_reconnect = 60.3
    est = OnlineClock()
    first = asymmetric_probes(old.affine.forward, 0.0, t_reconnect, rng)
    replay(est, first, old.affine.forward)
    est.reset("client k1 reconnected")
    assert est.epoch == 1 and est.n_bursts == 0
    with pytest.raises(SyncError, match=r"no clock estimate yet.*k1 reconnected"):
        est.affine.inverse(1.0)
    # the new client's clock and a faster network (base 0.2 ms, queues 1 and 0.5 ms)
    second = asymmetric_probes(
        new.affine.forward, 61.0, 120.0, rng, base_s=0.2e-3, up_mean_s=1e-3, down_mean_s=0.5e-3
    )
    out = replay(est, second, new.affine.forward)
    bad = np.flatnonzero(np.abs(out["err"]) >= 2e-3)
    recovered_at = out["t"][bad[-1] + 1] if bad.size else out["t"][0]
    assert recovered_at - t_reconnect < 5.0  # s (measured 0.7 s: the first reply after it)
    assert np.median(np.abs(out["err"][out["t"] >= t_reconnect + 5.0])) < 0.5e-3  # 0.5 ms
    assert np.abs(out["err"][out["t"] >= t_reconnect + 5.0]).max() < 2e-3  # 2 ms


def test_unannounced_new_clock_is_taken_as_a_jump() -> None:
    rng = np.random.default_rng(12)
    old, new = random_clock(rng), random_clock(rng)
    est = OnlineClock()
    replay(est, asymmetric_probes(old.affine.forward, 0.0, 40.0, rng), old.affine.forward)
    out = replay(est, asymmetric_probes(new.affine.forward, 40.0, 80.0, rng), new.affine.forward)
    assert est.epoch == 1 and "clock jump" in est.last_reset
    assert np.abs(out["err"][out["t"] >= 45.0]).max() < 2e-3  # 2 ms


def test_online_agrees_with_offline_fit_at_session_end() -> None:
    # the project's simulator: symmetric exponential jitter, 4-probe bursts
    for seed in range(3):
        rng = np.random.default_rng(seed)
        params = ClockParams(drift_sigma_ppm=40.0)
        clock = draw_clock(rng, params)
        probes = clock_probes(clock, 0.0, 120.0, rng, params)
        est = OnlineClock(OnlineClockParams(window_s=120.0))
        for q in probes[np.argsort(probes[:, 3])]:
            est.add_probe(*map(float, q))
        off = estimate_clock(probes)
        t_end = float(probes[:, 3].max())
        online = est.estimate(t_end)
        assert online.offset_s == pytest.approx(
            float(off.affine.forward(t_end)) - t_end, abs=0.1e-3
        )
        assert online.drift_ppm == pytest.approx(off.drift_ppm, abs=1.0)  # ppm
        t_client = clock.affine.forward(np.linspace(100.0, 120.0, 5))
        np.testing.assert_allclose(
            est.affine.inverse(t_client), off.affine.inverse(t_client), atol=0.2e-3
        )


def test_burst_keeps_least_delay_probe() -> None:
    est = OnlineClock()
    off = 500.0

    def probe(t1: float, up: float, down: float) -> tuple[float, float, float, float]:
        return (t1, t1 + up + off, t1 + up + off + 1e-4, t1 + up + 1e-4 + down)

    r1 = est.add_probe(*probe(10.00, 0.004, 0.001))  # offset error +1.5 ms
    r2 = est.add_probe(*probe(10.02, 0.0005, 0.0007))  # -0.1 ms, least delay
    r3 = est.add_probe(*probe(10.04, 0.002, 0.001))  # +0.5 ms
    assert [r1.status, r2.status, r3.status] == ["best", "best", "kept"]
    assert "less delay" in r3.reason
    assert est.estimate(10.05).offset_s == pytest.approx(off - 0.0001, abs=1e-9)
    # a congested reply: 3 x the least delay (0.6 ms) + 1 ms is 2.8 ms
    r4 = est.add_probe(*probe(10.06, 0.0005, 0.010))
    assert r4.status == ProbeStatus.REJECTED_DELAY and "recent minimum" in r4.reason
    # a reply overtaken by a whole burst
    est.add_probe(*probe(11.00, 0.0006, 0.0006))
    r5 = est.add_probe(*probe(10.08, 0.0006, 0.0006))
    assert r5.status == ProbeStatus.REJECTED_STALE


def test_conversions_round_trip() -> None:
    rng = np.random.default_rng(5)
    clock = SensorClock(offset_s=321.0, drift_ppm=55.0, phase_s=0.0)
    est = OnlineClock()
    replay(est, asymmetric_probes(clock.affine.forward, 0.0, 60.0, rng), clock.affine.forward)
    t_server = np.linspace(50.0, 60.0, 7)
    np.testing.assert_allclose(
        est.affine.inverse(est.affine.forward(t_server)), t_server, atol=1e-9
    )
    np.testing.assert_allclose(
        est.affine.inverse(clock.affine.forward(t_server)), t_server, atol=1e-3
    )
    e = est.estimate(58.0)
    assert e.affine.inverse(float(clock.affine.forward(58.0))) == pytest.approx(58.0, abs=1e-3)
    assert e.affine.forward(59.0) == pytest.approx(float(est.affine.forward(59.0)), abs=1e-12)
    assert isinstance(est.affine.inverse(400.0), float)


@pytest.mark.parametrize(
    ("times", "match"),
    [
        ((0.0, np.nan, 1.0, 1.0), "must be finite"),
        ((0.0, 1.0, 1.0, np.inf), "must be finite"),
        ((1.0, 5.0, 5.1, 0.5), r"t4=0.5 is before its send time t1=1.0"),
        ((1.0, 5.1, 5.0, 1.3), r"t3=5.0 is before its receive time t2=5.1"),
        ((1.0, 5.0, 5.5, 1.1), "turnaround .* longer than the round trip"),
    ],
)
def test_bad_probes_are_clear_errors(times: tuple[float, ...], match: str) -> None:
    est = OnlineClock()
    with pytest.raises(SyncError, match=match):
        est.add_probe(*times)
    assert est.n_bursts == 0  # nothing was taken


def test_bad_params_are_clear_errors() -> None:
    with pytest.raises(SyncError, match="window_s must be a positive number"):
        OnlineClockParams(window_s=-1.0)
    with pytest.raises(SyncError, match="max_bursts must be >= 2"):
        OnlineClockParams(max_bursts=1)
    with pytest.raises(SyncError, match="no clock estimate yet"):
        OnlineClock().estimate(0.0)
