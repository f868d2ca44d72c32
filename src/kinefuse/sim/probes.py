"""Clock probes over an asymmetric, congested network, and a replay that scores an online clock.

The generator behind ``tests/test_sync_online.py`` and ``benchmarks/bench_sync.py`` (here so that
the benchmark does not import a test module, and the figures it prints are the ones the tests
bound). :func:`asymmetric_probes`: the client's clock is any map of true -> client time (a
:class:`~kinefuse.sim.clock.SensorClock` plus an optional step); each one-way delay is a base of
0.4 ms plus an exponential queueing delay, with the server-to-client direction the worse one by
default (mean 3 ms against 1 ms), and 5 % of the requests queued 20-50 ms more (congestion). A
burst is 6 probes 20 ms apart, one burst a second; the client's turnaround is 0.1 ms +
exponential 0.2 ms. :func:`replay` feeds them to an :class:`~kinefuse.capture.sync.OnlineClock`; the
error of a check is the estimated offset at a reply's arrival time minus the true offset then.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from kinefuse.capture.sync import OnlineClock
from kinefuse.sim.clock import SensorClock

#: true time -> client time
Client = Callable[[np.ndarray], np.ndarray]

#: The networks the tests and the benchmark run: keyword arguments of :func:`asymmetric_probes`.
NETWORKS: dict[str, dict[str, Any]] = {
    "down-worse": {},  # server->client queue mean 3 ms, client->server 1 ms
    "up-worse": {"up_mean_s": 1e-3, "down_mean_s": 3e-3},
    "noisy-burst4": {"up_mean_s": 5e-3, "down_mean_s": 2e-3, "burst": 4},
}


def asymmetric_probes(
    client: Client,
    t_start_s: float,
    t_end_s: float,
    rng: np.random.Generator,
    *,
    up_mean_s: float = 3e-3,
    down_mean_s: float = 1e-3,
    base_s: float = 0.4e-3,
    burst: int = 6,
    spike_prob: float = 0.05,
) -> np.ndarray:
    """(N, 4) probes ``t1, t2, t3, t4`` in arrival (``t4``) order; ``client`` maps true -> client
    time; "up" is server to client."""
    starts = np.arange(t_start_s, t_end_s, 1.0)
    t1 = (starts[:, None] + 0.02 * np.arange(burst)[None, :]).reshape(-1)
    n = t1.size
    up = base_s + rng.exponential(up_mean_s, n)
    down = base_s + rng.exponential(down_mean_s, n)
    spike = rng.random(n) < spike_prob
    up[spike] += rng.uniform(0.02, 0.05, int(spike.sum()))
    turn = 1e-4 + rng.exponential(2e-4, n)
    t2, t3 = client(t1 + up), client(t1 + up + turn)
    t4 = t1 + up + turn + down
    p = np.stack([t1, t2, t3, t4], axis=1)
    return p[np.argsort(t4, kind="stable")]


def replay(est: OnlineClock, probes: np.ndarray, client: Client) -> dict[str, np.ndarray]:
    """Feed ``probes`` one by one; after each, the offset error and its standard error."""
    t, err, se, drift, status, reset = [], [], [], [], [], []
    for q in probes:
        r = est.add_probe(float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        e = est.estimate(float(q[3]))
        true = float(client(np.array(q[3]))) - float(q[3])
        t.append(q[3])
        err.append(e.offset_s - true)
        se.append(e.offset_se_s)
        drift.append(e.drift_ppm)
        status.append(r.status)
        reset.append(r.reset or "")
    return {
        "t": np.array(t),
        "err": np.array(err),
        "se": np.array(se),
        "drift_ppm": np.array(drift),
        "status": np.array(status),
        "reset": np.array(reset),
    }


def random_clock(rng: np.random.Generator) -> SensorClock:
    """A client clock with a drift of 20-80 ppm either way and an offset in [0, 1000) s."""
    drift = float(rng.choice([-1.0, 1.0]) * rng.uniform(20.0, 80.0))  # tens of ppm
    return SensorClock(offset_s=float(rng.uniform(0.0, 1000.0)), drift_ppm=drift, phase_s=0.0)
