"""Online clock estimation: accuracy, honesty of the uncertainty, recovery, and time per call.

Run: ``python benchmarks/bench_sync.py [--smoke]`` (a few seconds). Probes come from
:mod:`kinefuse.sim.probes`, the generator ``tests/test_sync_online.py`` uses (the simulator's
clocks, asymmetric exponential queues, congestion spikes; the delays are stated there), so these
are the figures the tests bound, on more seeds and longer sessions (``--smoke``: one seed, short
sessions, to check that it runs). Prints, per network, the offset error after a 5 s warm-up
(p50, p99, max), the share of checks within 3 standard errors, the recovery time after +/-80 ms
clock steps and after a reconnect, and microseconds per ``add_probe`` / ``affine.inverse``
(the row ``to_server``) / ``estimate`` against a baseline measured in the same run (a Python
function that only computes the probe's offset and delay).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kinefuse.capture.sync import OnlineClock, estimate_clock
from kinefuse.sim.probes import NETWORKS, asymmetric_probes, random_clock, replay

SEEDS = 10
SESSION_S = 300.0
SPEED_S = 600.0
WARMUP_S = 5.0


def accuracy() -> None:
    print(f"offset error after {WARMUP_S:g} s warm-up, {SEEDS} seeds x {SESSION_S:g} s per network")
    head = f"{'network':<14}{'p50 ms':>8}{'p99 ms':>8}{'max ms':>8}{'in 3 se':>9}{'se p50 ms':>11}"
    print(head + f"{'suspects':>10}{'resets':>8}{'offline p50':>13}{'offline max':>13}")
    # beyond the tests: one direction with no queue at all (every error on one side)
    networks = {**NETWORKS, "one-way-only": {"up_mean_s": 3e-3, "down_mean_s": 1e-5}}
    for name, kw in networks.items():
        err, z, se, suspects, resets, off = [], [], [], 0, 0, []
        for seed in range(SEEDS):
            rng = np.random.default_rng(1000 + seed)
            clock = random_clock(rng)
            probes = asymmetric_probes(clock.affine.forward, 0.0, SESSION_S, rng, **kw)
            out = replay(OnlineClock(), probes, clock.affine.forward)
            m = out["t"] >= WARMUP_S
            # the offline fit over the whole session (future probes included), at the same checks
            fit = estimate_clock(probes)
            t = out["t"][m]
            off.append(np.abs(fit.affine.forward(t) - clock.affine.forward(t)))
            err.append(np.abs(out["err"][m]))
            se.append(out["se"][m])
            z.append(np.abs(out["err"] / out["se"]))
            suspects += int((out["status"] == "suspect").sum())
            resets += int((out["reset"] != "").sum())
        e, zz = np.concatenate(err) * 1e3, np.concatenate(z)
        print(
            f"{name:<14}{np.median(e):>8.3f}{np.percentile(e, 99):>8.3f}{e.max():>8.3f}"
            f"{np.mean(zz <= 3):>9.4f}{np.median(np.concatenate(se)) * 1e3:>11.3f}"
            f"{suspects:>10}{resets:>8}{np.median(np.concatenate(off)) * 1e3:>13.3f}"
            f"{np.concatenate(off).max() * 1e3:>13.3f}"
        )


def recovery_s(t: np.ndarray, err: np.ndarray, t_event: float, limit_s: float = 2e-3) -> float:
    """Time from the event to the first check after which every error stays below the limit."""
    bad = np.flatnonzero((np.abs(err) >= limit_s) & (t >= t_event))
    return float(t[bad[-1] + 1] - t_event) if bad.size else float(t[t >= t_event][0] - t_event)


def recovery() -> None:
    t_event = 60.3
    jumps, reconnects = [], []
    for seed in range(SEEDS):
        for step in (0.080, -0.080):
            rng = np.random.default_rng(2000 + seed)
            clock = random_clock(rng)

            def client(t, clock=clock, step=step):  # type: ignore[no-untyped-def]
                return clock.affine.forward(t) + step * (np.asarray(t) >= t_event)

            out = replay(OnlineClock(), asymmetric_probes(client, 0.0, 120.0, rng), client)
            jumps.append(recovery_s(out["t"], out["err"], t_event))
        rng = np.random.default_rng(3000 + seed)
        old, new = random_clock(rng), random_clock(rng)
        est = OnlineClock()
        replay(est, asymmetric_probes(old.affine.forward, 0.0, t_event, rng), old.affine.forward)
        est.reset("reconnect")
        to_new = new.affine.forward
        out = replay(est, asymmetric_probes(to_new, 61.0, 120.0, rng), to_new)
        reconnects.append(recovery_s(out["t"], out["err"], t_event))
    for step in (0.0015, 0.002, 0.003, 0.005):
        detected, worst = 0, 0.0
        for seed in range(SEEDS):
            rng = np.random.default_rng(4000 + seed)
            clock = random_clock(rng)

            def client(t, clock=clock, step=step):  # type: ignore[no-untyped-def]
                return clock.affine.forward(t) + step * (np.asarray(t) >= t_event)

            est = OnlineClock()
            out = replay(est, asymmetric_probes(client, 0.0, 120.0, rng), client)
            detected += est.epoch
            worst = max(worst, float(np.abs(out["err"][out["t"] >= t_event + 5.0]).max()))
        print(
            f"step {step * 1e3:+.1f} ms: detected as a jump in {detected}/{SEEDS} runs, max error "
            f"from 5 s after it {worst * 1e3:.3f} ms"
        )
    print(
        f"recovery to < 2 ms for good: +/-80 ms step median {np.median(jumps):.2f} s, max "
        f"{max(jumps):.2f} s ({len(jumps)} runs); reconnect median {np.median(reconnects):.2f} s, "
        f"max {max(reconnects):.2f} s ({len(reconnects)} runs)"
    )


def speed() -> None:
    rng = np.random.default_rng(0)
    clock = random_clock(rng)
    probes = asymmetric_probes(clock.affine.forward, 0.0, SPEED_S, rng)
    rows = [tuple(map(float, q)) for q in probes]

    def baseline(t1: float, t2: float, t3: float, t4: float) -> tuple[float, float]:
        return ((t2 - t1) - (t4 - t3)) / 2, ((t4 - t1) - (t3 - t2)) / 2

    t0 = time.perf_counter()
    for r in rows:
        baseline(*r)
    t_base = (time.perf_counter() - t0) / len(rows)
    est = OnlineClock()
    t0 = time.perf_counter()
    for r in rows:
        est.add_probe(*r)
    t_add = (time.perf_counter() - t0) / len(rows)
    t_client = [r[1] for r in rows]
    t0 = time.perf_counter()
    for tc in t_client:
        est.affine.inverse(tc)
    t_conv = (time.perf_counter() - t0) / len(rows)
    t0 = time.perf_counter()
    for r in rows:
        est.estimate(r[3])
    t_est = (time.perf_counter() - t0) / len(rows)
    t0 = time.perf_counter()
    estimate_clock(probes)
    t_off = time.perf_counter() - t0
    print(f"time per call over {len(rows)} probes ({SPEED_S:g} s, 6-probe bursts each second):")
    for name, t in (("add_probe", t_add), ("to_server", t_conv), ("estimate", t_est)):
        print(
            f"  {name:<10}{t * 1e6:8.2f} us  ({t / t_base:5.1f} x baseline {t_base * 1e6:.2f} us)"
        )
    print(f"  offline estimate_clock over the whole session: {t_off * 1e3:.1f} ms")


def main() -> None:
    global SEEDS, SESSION_S, SPEED_S
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="one seed, short sessions (seconds)")
    if ap.parse_args().smoke:
        SEEDS, SESSION_S, SPEED_S = 1, 30.0, 60.0
    accuracy()
    recovery()
    speed()


if __name__ == "__main__":
    main()
