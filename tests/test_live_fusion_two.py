"""best-live with two sensors: the left/right facing must not depend on the frame it starts at.

With two sensors, one seeing the person's front and one the back (mirrored by its tracker),
both views are ambiguous and their facing vote is a tie; the filter's facing so far then froze
whatever the first frame decided (32 cm MAE, a mirrored skeleton, on a live demo recording).
While walking, the pelvis's direction of travel now joins such a tied vote.
"""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.app import demo_clip_path, run_simulate
from kinefuse.io.store import SessionStore
from kinefuse.pipeline import frame_grid, load_sensors, run_method


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    out = tmp_path_factory.mktemp("two") / "s.sqlite"
    run_simulate(clip=demo_clip_path(), out=out, sensors=2, seconds=4.0, calibration_s=1.0)
    with SessionStore.open(out) as st:
        truth = st.truth()
        poses = {s.id: truth.sensor(s.id)[0] for s in st.sensors()}
        sensors = load_sensors(st, poses)
        t_true, p_true, _ = truth.motion()
    return sensors, t_true, p_true


@pytest.mark.parametrize("start_s", [0.0, 0.3, 0.6, 1.0])
def test_two_sensor_best_live_does_not_mirror_whatever_its_start(two, start_s) -> None:
    sensors, t_true, p_true = two
    g = frame_grid(sensors)
    grid = g[g >= g[0] + start_s - 1e-9]
    res = run_method(sensors, grid, "best-live")
    truth = np.stack(
        [
            np.stack([np.interp(grid, t_true, p_true[:, j, a]) for a in range(3)], -1)
            for j in range(p_true.shape[1])
        ],
        1,
    )
    err = np.linalg.norm(res.positions - truth, axis=-1)
    last = err[-60:]  # the last 2 s: after any start-up, a mirrored skeleton is 25-35 cm off
    assert np.nanmean(last) < 0.12, f"{np.nanmean(last):.3f} m"  # 12 cm


@pytest.mark.parametrize("start_s", [0.0, 0.6])
def test_a_sensor_that_sees_no_body_does_not_switch_the_walking_vote_off(two, start_s) -> None:
    """A third sensor that sees nobody has no facing and no vote; the two ambiguous views are
    still a tie, so the walking direction must still join it (it did not: the sensor without a
    facing counted as unambiguous and the tie froze the first frame's guess)."""
    from dataclasses import replace

    sensors, t_true, p_true = two
    s0 = sensors[0]
    obs = s0.observations
    blind = replace(
        s0,
        observations=replace(
            obs,
            sensor_id=obs.sensor_id + "-blind",
            joints_m=np.full_like(obs.joints_m, np.nan),
            states=np.zeros_like(obs.states),
        ),
    )
    three = [*sensors, blind]
    g = frame_grid(sensors)
    grid = g[g >= g[0] + start_s - 1e-9]
    res = run_method(three, grid, "best-live")
    truth = np.stack(
        [
            np.stack([np.interp(grid, t_true, p_true[:, j, a]) for a in range(3)], -1)
            for j in range(p_true.shape[1])
        ],
        1,
    )
    err = np.linalg.norm(res.positions - truth, axis=-1)
    assert np.nanmean(err[-60:]) < 0.12, f"{np.nanmean(err[-60:]):.3f} m"  # 12 cm, as above
