"""best-live with two sensors: the left/right facing must not depend on the frame it starts at.

With two sensors, one seeing the person's front and one the back (mirrored by its tracker),
both views are ambiguous and their facing vote is a tie; the filter's facing so far then froze
whatever the first frame decided (32 cm MAE, a mirrored skeleton, on a live demo recording).
While walking, the pelvis's direction of travel now joins such a tied vote; against the facing
so far only after the body has walked against it for a while (a turn on the spot moves the
pelvis backwards for a moment: with four sensors that all see the body obliquely, 131_01 was
mirrored for half a second by the walking vote).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method


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
    err = _live_error(sensors, sensors, start_s, t_true, p_true)
    last = err[-60:]  # the last 2 s: after any start-up, a mirrored skeleton is 25-35 cm off
    assert np.nanmean(last) < 0.12, f"{np.nanmean(last):.3f} m"  # 12 cm


def _live_error(fused, sensors, start_s, t_true, p_true):
    """best-live's per-joint error ``(T, 25)`` (m) fusing ``fused`` on ``sensors``' frame grid
    from ``start_s`` on."""
    g = frame_grid(sensors)
    grid = g[g >= g[0] + start_s - 1e-9]
    res = run_method(fused, grid, "best-live")
    truth = np.stack(
        [
            np.stack([np.interp(grid, t_true, p_true[:, j, a]) for a in range(3)], -1)
            for j in range(p_true.shape[1])
        ],
        1,
    )
    return np.linalg.norm(res.positions - truth, axis=-1)


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
    err = _live_error([*sensors, blind], sensors, start_s, t_true, p_true)
    assert np.nanmean(err[-60:]) < 0.12, f"{np.nanmean(err[-60:]):.3f} m"  # 12 cm, as above


def test_a_turn_on_the_spot_is_not_mirrored_by_the_walking_vote(shared_data, tmp_path) -> None:
    """CMU 131_01 on the level 4-sensor rig, seed 2 (a session of studies/paper_comparison.py):
    at 3.6 s the person turns round while the pelvis moves backwards at 1 m/s, and every sensor's
    view is ambiguous. The walking vote mirrored the skeleton for 0.5 s (29-46 cm; best-live
    6.2 cm against best's 4.3 cm over the clip)."""
    from kinefuse.lab.fusion_truth import truth_at

    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "turn.sqlite"
    run_simulate(clip=shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh", out=out,
                 rig=root / "rigs" / "level4.toml", seed=2, calibration_s=0.0)  # fmt: skip
    with SessionStore.open(out) as st:
        sensors = load_sensors(st, {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()})
        grid = frame_grid(sensors)
        truth = truth_at(st, grid)
    err = {
        m: np.linalg.norm(run_method(sensors, grid, m).positions - truth, axis=-1)
        for m in ("best", "best-live")
    }
    half_s = [np.nanmean(err["best-live"][k : k + 15]) for k in range(0, grid.size - 15, 5)]
    assert max(half_s) < 0.12, f"{max(half_s):.3f} m"  # 12 cm: a mirrored skeleton is 30-45 cm
    ratio = np.nanmean(err["best-live"]) / np.nanmean(err["best"])
    assert ratio < 1.1, ratio  # live within 10 % of offline here (1.02 with the fix)


def test_agreeing_back_views_do_not_overturn_a_confirmed_facing(shared_data, tmp_path) -> None:
    """CMU 131_01 after a range-of-motion phase (so its walk starts at the ring's centre and
    ends at its edge), on a 5-sensor ring of 2.5 m, seed 101. At the end the sensors at the
    side lose the body and three see only its back. Each reports a body facing it (0.5 each in
    the vote); together they outvoted the confirmed facing (1.5) and the legs stayed mirrored
    for 1.5 s: 44 cm over the worst half second, 14.8 cm over the walk. Ambiguous views that
    agree tell on which side the sensors stand, not which way the body faces: their weight is
    capped (``LiveOptions.ambiguous_vote_cap``)."""
    from kinefuse.lab.fusion_truth import truth_at

    ring = []
    for i in range(5):  # studies/analysis_sweep.py's held-out ring5
        a = 2 * np.pi * i / 5 + 0.3
        ring += ["[[sensor]]", f'id = "r{i}"',
                 f"position_m = [{2.5 * np.cos(a):.3f}, {2.5 * np.sin(a):.3f}, "
                 f"{0.8 if i % 2 else 2.0}]", "look_at_m = [0.0, 0.0, 1.0]", ""]  # fmt: skip
    rig = tmp_path / "ring5.toml"
    rig.write_text("\n".join(ring), encoding="utf-8")
    out = tmp_path / "ring.sqlite"
    run_simulate(clip=shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh", out=out,
                 rig=rig, seed=101, calibration_s=0.0, rom_s=55.0)  # fmt: skip
    with SessionStore.open(out) as st:
        sensors = load_sensors(st, {s.id: st.truth().sensor(s.id)[0] for s in st.sensors()})
        grid = frame_grid(sensors)
        truth = truth_at(st, grid)
        walk = grid > st.meta()["rom_phase_server_s"][1]  # type: ignore[index]
    for m in ("best", "best-live"):
        err = np.linalg.norm(run_method(sensors, grid, m).positions - truth, axis=-1)[walk]
        half_s = [np.nanmean(err[k : k + 15]) for k in range(0, len(err) - 15, 5)]
        # capped: 8.6 cm and 25 cm (the right leg is then only guessed by the sensor behind)
        assert np.nanmean(err) < 0.11, (m, np.nanmean(err))
        assert max(half_s) < 0.35, (m, max(half_s))
