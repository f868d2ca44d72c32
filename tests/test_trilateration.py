"""Trilateration solvers: synthetic truth -> observations -> solve -> compare."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.capture.fusion.status import FusionStatus, is_solved, status_counts
from kinefuse.capture.fusion.trilateration import (
    METHODS,
    fuse_geometric,
    fuse_linear,
    fuse_nonlinear,
    fuse_paper,
    sensor_centres,
    sensor_ranges,
    solve_geometric,
    solve_linear,
    solve_nonlinear,
    to_world,
    trilaterate,
)
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import invert_transform, look_at, make_transform
from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.errors import InputError

SPREAD = (0.5, 2.0, 1.0, 2.4)  # sensor heights, metres: well out of one plane
LEVEL = (1.0, 1.07, 1.13, 1.2)  # a typical level rig: nearly coplanar
FLAT = (1.1, 1.1, 1.1, 1.1)  # exactly coplanar


def rig(heights, radius_m: float = 3.0) -> np.ndarray:
    """``sensor2world (S, 4, 4)``: sensors on a circle looking at the capture centre."""
    angles = np.linspace(0, 2 * np.pi, len(heights), endpoint=False) + 0.4
    return np.stack(
        [
            look_at([radius_m * np.cos(a), radius_m * np.sin(a), h], [0.0, 0.0, 1.0])
            for a, h in zip(angles, heights, strict=True)
        ]
    )


def random_truth(rng: np.random.Generator, n_frames: int = 40) -> np.ndarray:
    """Joint-like world points ``(T, 25, 3)`` in the capture volume."""
    truth = np.empty((n_frames, N_JOINTS, 3))
    truth[..., :2] = rng.uniform(-0.7, 0.7, (n_frames, N_JOINTS, 2))
    truth[..., 2] = rng.uniform(0.05, 1.8, (n_frames, N_JOINTS))
    return truth


def observe(truth: np.ndarray, sensor2world: np.ndarray) -> np.ndarray:
    """Exact observations ``(T, S, 25, 3)`` of world points in every sensor's frame."""
    w2s = invert_transform(sensor2world)
    return np.einsum("sij,tkj->tski", w2s[:, :3, :3], truth) + w2s[None, :, None, :3, 3]


def errors(result_positions: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.linalg.norm(result_positions - truth, axis=-1)


# ------------------------------------------------------------------------------ helpers


def test_to_world_and_ranges_round_trip():
    rng = np.random.default_rng(10)
    s2w = rig(SPREAD)
    truth = random_truth(rng, 5)
    obs = observe(truth, s2w)
    obs[2, 1, 4] = np.nan
    world = to_world(obs, s2w)
    expected = np.broadcast_to(truth[:, None], world.shape).copy()
    expected[2, 1, 4] = np.nan
    np.testing.assert_allclose(world, expected, atol=1e-12)  # 1e-12 m
    ranges = sensor_ranges(obs)
    centres = sensor_centres(s2w)
    want = np.linalg.norm(truth[:, None] - centres[None, :, None], axis=-1)
    want[2, 1, 4] = np.nan
    np.testing.assert_allclose(ranges, want, atol=1e-12)  # 1e-12 m


# ------------------------------------------------------------------------- exact recovery


@pytest.mark.parametrize(
    "heights", [SPREAD, LEVEL, FLAT, SPREAD[:3]], ids=["spread", "level", "flat", "three"]
)
@pytest.mark.parametrize("method", ["linear", "geometric", "nonlinear"])
def test_exact_recovery_without_noise(method, heights):
    rng = np.random.default_rng(11)
    s2w = rig(heights)
    truth = random_truth(rng)
    res = trilaterate(observe(truth, s2w), s2w, method)
    np.testing.assert_allclose(res.positions, truth, atol=1e-6)  # 1 micrometre
    assert is_solved(res.status).all()
    expected_sensors = 3 if method == "geometric" else len(heights)
    assert (res.n_sensors == expected_sensors).all()


def test_paper_exact_recovery_when_nothing_is_occluded():
    rng = np.random.default_rng(12)
    s2w = rig(SPREAD)
    truth = random_truth(rng, 10)
    occlusion = (np.zeros((10, 4, N_JOINTS), bool), np.zeros((10, 4), np.int64))
    res = fuse_paper(observe(truth, s2w), s2w, occlusion=occlusion)
    np.testing.assert_allclose(res.positions, truth, atol=1e-6)  # 1 micrometre
    assert res.used.all()


def test_status_reports_mirror_resolution():
    rng = np.random.default_rng(13)
    truth = random_truth(rng, 10)
    spread = fuse_nonlinear(observe(truth, rig(SPREAD)), rig(SPREAD))
    assert (spread.status == FusionStatus.OK).mean() > 0.5  # the ranges alone fix most points
    for heights in (LEVEL, FLAT, SPREAD[:3]):
        res = fuse_nonlinear(observe(truth, rig(heights)), rig(heights))
        assert (res.status == FusionStatus.PLANAR).all()
    geo = fuse_geometric(observe(truth, rig(SPREAD)), rig(SPREAD))
    assert (geo.status == FusionStatus.PLANAR).all()


# ----------------------------------------------------------------------------- with noise


def test_noisy_ranges_ordering_and_accuracy():
    """3 cm noise on every coordinate: nonlinear is the most accurate, all stay bounded."""
    rng = np.random.default_rng(14)
    s2w = rig(SPREAD)
    truth = random_truth(rng, 80)
    obs = observe(truth, s2w) + rng.normal(0.0, 0.03, (80, 4, N_JOINTS, 3))
    mae = {m: errors(trilaterate(obs, s2w, m).positions, truth).mean() for m in METHODS[:3]}
    assert mae["nonlinear"] < mae["linear"] < mae["geometric"]
    assert mae["nonlinear"] < 0.08  # 8 cm
    for m in METHODS[:3]:
        assert np.isfinite(trilaterate(obs, s2w, m).positions).all()


def test_level_rig_keeps_joints_on_their_side():
    """Level sensors: mirror images have equal ranges; no joint may land on the mirror side."""
    rng = np.random.default_rng(15)
    s2w = rig(LEVEL)
    truth = random_truth(rng, 80)
    obs = observe(truth, s2w) + rng.normal(0.0, 0.02, (80, 4, N_JOINTS, 3))
    for method in ("linear", "geometric", "nonlinear"):
        res = trilaterate(obs, s2w, method)
        err = errors(res.positions, truth)
        mirror = 2 * np.abs(truth[..., 2] - 1.1)
        far = mirror > 0.6
        # a mirror-side answer would be off by about 2 |z - 1.1 m|
        assert (err[far] < 0.6 * mirror[far]).all(), method
    # the plain least-squares out-of-plane coordinate is hopeless there: that is why we avoid it
    plain = fuse_linear(obs, s2w, out_of_plane="lstsq")
    auto = errors(fuse_linear(obs, s2w).positions, truth)
    assert np.median(errors(plain.positions, truth)) > 3 * np.median(auto)
    assert (plain.status == FusionStatus.DEGENERATE).all()  # and it says so
    # the nonlinear solver then starts from the reference instead, on the right side
    restart = fuse_nonlinear(obs, s2w, out_of_plane="lstsq")
    assert (restart.status == FusionStatus.PLANAR).all()
    assert np.median(errors(restart.positions, truth)) < 1.2 * np.median(auto)


def test_paper_chain_beats_nonlinear_when_hidden_joints_are_wrong():
    """Hidden joints carry 15 cm errors (as a tracker's guesses do); selection drops them."""
    rng = np.random.default_rng(16)
    s2w = rig(SPREAD)
    truth = random_truth(rng, 60)
    obs = observe(truth, s2w)
    hidden = rng.random(obs.shape[:3]) < 0.25
    direction = rng.normal(size=obs.shape)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    noisy = (
        obs + rng.normal(0.0, 0.01, obs.shape) + np.where(hidden[..., None], 0.15 * direction, 0.0)
    )
    n_int = hidden.sum(axis=2)  # more hidden joints, more crossings
    paper = fuse_paper(noisy, s2w, occlusion=(hidden, n_int))
    plain = fuse_nonlinear(noisy, s2w)
    assert errors(paper.positions, truth).mean() < 0.6 * errors(plain.positions, truth).mean()
    some_clear = ~hidden.all(axis=1)  # (T, 25)
    np.testing.assert_array_equal(
        paper.used.transpose(0, 2, 1)[some_clear], ~hidden.transpose(0, 2, 1)[some_clear]
    )
    assert (paper.n_sensors[~some_clear] == 1).all()


def _paper_selection(occluded: np.ndarray, n_int: np.ndarray) -> np.ndarray:
    """The paper's rule, written out joint by joint: every sensor that sees the joint clear; if
    none does, the one sensor with the fewest bone crossings (lowest index on a tie)."""
    n_frames, n_sensors, n_joints = occluded.shape
    sel = np.zeros_like(occluded)
    for f in range(n_frames):
        for k in range(n_joints):
            clear = [s for s in range(n_sensors) if not occluded[f, s, k]]
            if clear:
                sel[f, clear, k] = True
            else:
                sel[f, min(range(n_sensors), key=lambda s: (n_int[f, s], s)), k] = True
    return sel


def test_paper_detects_occlusion_with_intrinsics():
    """With intrinsics, paper A's chain = occlusion detection in each sensor's image, the
    paper's selection, then trilateration on the selected ranges only; checked against that
    selection written out here and scipy's least squares on the selected spheres."""
    from scipy.optimize import least_squares

    from kinefuse.capture.occlusion.segments import detect_occlusion_sensors

    rng = np.random.default_rng(17)
    s2w = rig(SPREAD)
    truth = random_truth(rng, 5)
    # 2 cm noise: every choice of sensors gives a different point, so the positions tell
    # which sensors were used
    obs = observe(truth, s2w) + rng.normal(0.0, 0.02, (5, 4, N_JOINTS, 3))
    res = fuse_paper(obs, s2w, Intrinsics(), c_threshold=1e-16)
    det = detect_occlusion_sensors(obs, Intrinsics())
    assert det.occluded.any() and not det.occluded.all()  # random points cross a lot
    sel = _paper_selection(det.occluded, det.n_intersections)
    np.testing.assert_array_equal(res.used, sel)
    np.testing.assert_array_equal(res.n_sensors, sel.sum(axis=1))
    centres = sensor_centres(s2w)
    ranges = sensor_ranges(obs)  # (T, S, 25)
    world = to_world(obs, s2w)
    checked = 0
    for f in range(5):
        for k in range(N_JOINTS):
            use = sel[f, :, k]
            if use.sum() < 3:  # too few: the mean of the chosen sensors' own points
                assert res.status[f, k] == FusionStatus.TOO_FEW_SENSORS
                np.testing.assert_allclose(
                    res.positions[f, k], world[f, use, k].mean(axis=0), atol=1e-12
                )
                continue
            if not is_solved(res.status[f, k]):  # OK, or PLANAR: the side from the reference
                continue
            c, r = centres[use], ranges[f, use, k]
            fit = least_squares(lambda q, c=c, r=r: np.linalg.norm(q - c, axis=1) - r,
                                truth[f, k], xtol=1e-15, ftol=1e-15, gtol=1e-15)  # fmt: skip
            np.testing.assert_allclose(res.positions[f, k], fit.x, atol=1e-6)  # 1 micrometre
            checked += 1
    assert checked > 60
    # the same observations with every sensor in use land elsewhere: the selection mattered
    plain = fuse_nonlinear(obs, s2w, c_threshold=1e-16)
    moved = np.linalg.norm(plain.positions - res.positions, axis=-1)
    assert (moved[(sel.sum(axis=1) >= 3) & ~sel.all(axis=1)] > 1e-4).all()  # 0.1 mm


# ------------------------------------------------------------------ degenerate and missing


def test_coplanar_sensors_with_plain_least_squares_are_degenerate():
    rng = np.random.default_rng(18)
    s2w = rig(FLAT)
    truth = random_truth(rng, 5)
    obs = observe(truth, s2w) + rng.normal(0.0, 0.01, (5, 4, N_JOINTS, 3))
    res = fuse_linear(obs, s2w, out_of_plane="lstsq")
    assert (res.status == FusionStatus.DEGENERATE).all()
    np.testing.assert_allclose(res.positions, to_world(obs, s2w).mean(axis=1), atol=1e-12)


def test_two_sensors_are_too_few():
    rng = np.random.default_rng(19)
    s2w = rig(SPREAD[:2])
    truth = random_truth(rng, 5)
    obs = observe(truth, s2w) + rng.normal(0.0, 0.01, (5, 2, N_JOINTS, 3))
    for method in METHODS[:3]:
        res = trilaterate(obs, s2w, method)
        assert (res.status == FusionStatus.TOO_FEW_SENSORS).all()
        np.testing.assert_allclose(res.positions, to_world(obs, s2w).mean(axis=1), atol=1e-12)


def test_nan_joints_and_not_tracked_states():
    rng = np.random.default_rng(20)
    s2w = rig(SPREAD)
    truth = random_truth(rng, 6)
    obs = observe(truth, s2w)
    obs[0, 0, 3] = np.nan  # one sensor lost joint 3: three remain
    obs[1, :2, 4] = np.nan  # two remain: too few
    obs[2, :, 5] = np.nan  # nobody saw joint 5
    states = np.full(obs.shape[:3], TrackingState.TRACKED, dtype=np.int8)
    states[3, 1, 6] = TrackingState.NOT_TRACKED
    for method in METHODS[:3]:
        res = trilaterate(obs, s2w, method, states=states)
        assert res.status[0, 3] == FusionStatus.PLANAR
        np.testing.assert_allclose(res.positions[0, 3], truth[0, 3], atol=1e-6)  # 1 micrometre
        assert res.status[1, 4] == FusionStatus.TOO_FEW_SENSORS
        assert res.status[2, 5] == FusionStatus.NO_DATA and np.isnan(res.positions[2, 5]).all()
        assert not res.used[3, 1, 6]
        ok = res.status != FusionStatus.NO_DATA
        assert np.isfinite(res.positions[ok]).all()
        assert np.isnan(res.positions[~ok]).all()


def test_all_occluded_joint_takes_the_sensor_with_fewest_intersections():
    rng = np.random.default_rng(21)
    s2w = rig(SPREAD)
    truth = random_truth(rng, 4)
    obs = observe(truth, s2w) + rng.normal(0.0, 0.02, (4, 4, N_JOINTS, 3))
    occluded = np.zeros((4, 4, N_JOINTS), bool)
    occluded[:, :, 7] = True  # every sensor has joint 7 occluded
    n_int = np.array([[3, 1, 2, 5]] * 4)
    res = fuse_paper(obs, s2w, occlusion=(occluded, n_int))
    assert (res.status[:, 7] == FusionStatus.TOO_FEW_SENSORS).all()
    np.testing.assert_allclose(res.positions[:, 7], to_world(obs, s2w)[:, 1, 7], atol=1e-12)
    assert res.used[:, :, 7].tolist() == [[False, True, False, False]] * 4
    assert is_solved(np.delete(res.status, 7, axis=1)).all()


def test_iteration_cap_reports_non_convergence():
    rng = np.random.default_rng(22)
    s2w = rig(SPREAD)
    truth = random_truth(rng, 5)
    centres = sensor_centres(s2w)
    ranges = sensor_ranges(observe(truth, s2w)).transpose(0, 2, 1).reshape(-1, 4)
    ref = truth.reshape(-1, 3)
    start = ref + rng.normal(0.0, 0.3, ref.shape)
    one = solve_nonlinear(centres, ranges, ref, start=start, max_iter=1)
    assert (one.status == FusionStatus.NOT_CONVERGED).all()
    assert (one.iterations == 1).all()

    def cost(p: np.ndarray) -> np.ndarray:
        return ((np.linalg.norm(p[:, None] - centres[None], axis=-1) - ranges) ** 2).sum(axis=1)

    assert (cost(one.positions) < cost(start)).all()  # the one step lowered every cost
    full = solve_nonlinear(centres, ranges, ref, start=start)
    assert is_solved(full.status).all()
    np.testing.assert_allclose(full.positions, ref, atol=1e-6)  # 1 micrometre
    assert full.iterations.max() <= 50


def test_singular_normal_matrix_is_degenerate():
    """Exactly coplanar sensors, start in their plane: J^T J has no out-of-plane row."""
    centres = np.array([[3.0, 0, 1.0], [0, 3.0, 1.0], [-3.0, 0, 1.0], [0, -3.0, 1.0]])
    truth = np.array([[0.2, 0.1, 0.3]])
    ranges = np.linalg.norm(truth[:, None] - centres[None], axis=-1)
    start = np.array([[0.2, 0.1, 1.0]])
    sol = solve_nonlinear(centres, ranges, truth, start=start)
    assert sol.status.tolist() == [FusionStatus.DEGENERATE]
    np.testing.assert_allclose(sol.positions, start)


def test_collinear_sensors_are_degenerate():
    centres = np.array([[0.0, 0, 1], [1, 0, 1], [2, 0, 1], [3, 0, 1]])
    truth = np.array([[0.5, 2.0, 0.3]])
    ranges = np.linalg.norm(truth[:, None] - centres[None], axis=-1)
    ref = np.array([[0.4, 1.9, 0.4]])
    for solve in (solve_linear, solve_geometric, solve_nonlinear):
        sol = solve(centres, ranges, ref)
        assert sol.status.tolist() == [FusionStatus.DEGENERATE], solve.__name__
        np.testing.assert_allclose(sol.positions, ref)


def test_spheres_that_do_not_meet():
    centres = np.array([[3.0, 0, 1.0], [0, 3.0, 1.0], [-3.0, 0, 1.0]])
    truth = np.array([[0.2, 0.1, 1.0]])  # in the sensors' plane
    ranges = np.linalg.norm(truth[:, None] - centres[None], axis=-1) - 0.05  # too short
    ref = np.array([[0.0, 0.0, 0.5]])
    for solve in (solve_linear, solve_geometric, solve_nonlinear):
        sol = solve(centres, ranges, ref)
        assert sol.status.tolist() == [FusionStatus.NO_INTERSECTION], solve.__name__
        assert sol.positions[0, 2] == pytest.approx(1.0, abs=1e-9)  # in the plane
        np.testing.assert_allclose(sol.positions[0, :2], truth[0, :2], atol=0.02)  # 2 cm


def test_mirror_side_follows_the_reference():
    centres = np.array([[3.0, 0, 1.0], [0, 3.0, 1.0], [-3.0, 0, 1.0]])
    below = np.array([[0.2, 0.1, 0.3]])
    ranges = np.linalg.norm(below[:, None] - centres[None], axis=-1)
    for solve in (solve_linear, solve_geometric, solve_nonlinear):
        low = solve(centres, ranges, np.array([[0.0, 0.0, 0.6]]))
        high = solve(centres, ranges, np.array([[0.0, 0.0, 1.4]]))
        np.testing.assert_allclose(low.positions, below, atol=1e-9)  # 1 nm
        np.testing.assert_allclose(high.positions, [[0.2, 0.1, 1.7]], atol=1e-9)  # the mirror
        assert low.status.tolist() == high.status.tolist() == [FusionStatus.PLANAR]
        undecided = solve(centres, ranges, np.full((1, 3), np.nan))
        assert undecided.status.tolist() == [FusionStatus.DEGENERATE]


def test_geometric_keeps_the_triple_the_other_sensors_agree_with():
    rng = np.random.default_rng(23)
    s2w = rig((0.5, 2.0, 1.0, 2.4, 1.5))
    truth = random_truth(rng, 4)
    obs = observe(truth, s2w)
    exact = fuse_geometric(obs, s2w)
    assert (exact.n_sensors == 3).all()
    np.testing.assert_allclose(exact.positions, truth, atol=1e-6)  # 1 um
    # with noisy ranges, the kept triple is the one whose point best fits every range
    noisy = obs * (1 + rng.normal(0, 0.02, obs.shape[:3]) / np.linalg.norm(obs, axis=-1))[..., None]
    res = fuse_geometric(noisy, s2w)
    centres = s2w[:, :3, 3]
    ranges = sensor_ranges(noisy)  # (T, S, 25)
    cost = ((np.linalg.norm(res.positions[:, None] - centres[None, :, None], axis=-1) - ranges)
            ** 2).sum(axis=1)  # fmt: skip
    for tri in ((0, 1, 2), (1, 3, 4), (0, 2, 4)):
        p = fuse_geometric(noisy, s2w, mask=np.isin(np.arange(5), tri)[None, :, None]
                           .repeat(4, 0).repeat(N_JOINTS, 2)).positions  # fmt: skip
        other = ((np.linalg.norm(p[:, None] - centres[None, :, None], axis=-1) - ranges)
                 ** 2).sum(axis=1)  # fmt: skip
        assert (cost <= other + 1e-12).all()


# ------------------------------------------------------------------------ status helpers


def test_status_helpers():
    c = FusionStatus
    s = np.array([c.OK, c.PLANAR, c.PLANAR, c.TOO_FEW_SENSORS, c.NO_DATA], dtype=np.int8)
    assert is_solved(s).tolist() == [True, True, True, False, False]
    counts = status_counts(s)
    assert counts["PLANAR"] == 2 and counts["NO_DATA"] == 1 and counts["DEGENERATE"] == 0
    # ordered by severity: np.maximum of two codes keeps the worse one
    assert list(FusionStatus) == sorted(FusionStatus)
    assert max(FusionStatus) == FusionStatus.NO_DATA
    assert set(counts) == {c.name for c in FusionStatus}
    assert "mirror" in FusionStatus.PLANAR.description
    assert all(c.description for c in FusionStatus)


# --------------------------------------------------------------------------- bad input


def test_session_inputs_are_validated():
    s2w = rig(SPREAD)
    obs = np.zeros((2, 4, N_JOINTS, 3))
    with pytest.raises(InputError, match=r"joints_sensor must have shape \(T, S, 25, 3\)"):
        trilaterate(np.zeros((2, N_JOINTS, 3)), s2w)
    with pytest.raises(InputError, match="sensor2world has 3 poses but the observations have 4"):
        trilaterate(obs, s2w[:3])
    with pytest.raises(InputError, match=r"sensor2world must have shape \(S, 4, 4\)"):
        trilaterate(obs, s2w[:, :3])
    bad = s2w.copy()
    bad[2, :3, :3] *= 2.0
    with pytest.raises(InputError, match=r"sensor2world \(index 2\) is not a rigid"):
        trilaterate(obs, bad)
    nan = s2w.copy()
    nan[0, 0, 3] = np.nan
    with pytest.raises(InputError, match=r"sensor2world .*is not finite"):
        trilaterate(obs, nan)
    with pytest.raises(InputError, match=r"mask must be a bool array of shape \(2, 4, 25\)"):
        trilaterate(obs, s2w, mask=np.ones((2, 4), bool))
    with pytest.raises(InputError, match=r"states must be an integer array of shape \(2, 4, 25\)"):
        trilaterate(obs, s2w, states=np.ones((2, 4, N_JOINTS)))
    with pytest.raises(
        InputError, match="unknown trilateration method 'best'; choose one of linear"
    ):
        trilaterate(obs, s2w, "best")
    with pytest.raises(InputError, match="needs the sensors' intrinsics"):
        fuse_paper(obs, s2w)
    with pytest.raises(InputError, match="occlusion must be a pair"):
        fuse_paper(obs, s2w, occlusion=(np.zeros((2, 4, N_JOINTS), bool),))  # type: ignore[arg-type]
    with pytest.raises(InputError, match="out_of_plane must be 'auto', 'lstsq' or 'ranges'"):
        fuse_linear(obs, s2w, out_of_plane="svd")  # type: ignore[arg-type]


def test_solver_inputs_are_validated():
    centres = sensor_centres(rig(SPREAD))
    ranges = np.ones((3, 4))
    ref = np.zeros((3, 3))
    with pytest.raises(InputError, match=r"centres must have shape \(K, 3\)"):
        solve_linear(centres[:, :2], ranges, ref)
    with pytest.raises(InputError, match="centres must be finite"):
        solve_linear(np.full((4, 3), np.nan), ranges, ref)
    with pytest.raises(InputError, match=r"ranges must have shape \(N, K\) with K = 4"):
        solve_geometric(centres, np.ones((3, 5)), ref)
    with pytest.raises(InputError, match="ranges must be distances >= 0"):
        solve_geometric(centres, -ranges, ref)
    with pytest.raises(InputError, match=r"reference must have shape \(3, 3\)"):
        solve_nonlinear(centres, ranges, np.zeros(3))
    with pytest.raises(InputError, match=r"mask must be a bool array of shape \(3, 4\)"):
        solve_nonlinear(centres, ranges, ref, mask=np.ones((3, 4), int))
    with pytest.raises(InputError, match="c_threshold must be a positive number"):
        solve_nonlinear(centres, ranges, ref, c_threshold=0.0)
    with pytest.raises(InputError, match="max_iter must be an integer >= 1"):
        solve_nonlinear(centres, ranges, ref, max_iter=0)
    with pytest.raises(InputError, match=r"start must have shape \(3, 3\)"):
        solve_nonlinear(centres, ranges, ref, start=np.zeros((2, 3)))


def test_identity_pose_single_frame_smoke():
    """A sensor at the world origin with identity pose is a valid rig member."""
    s2w = np.concatenate([make_transform(np.eye(3), np.zeros(3))[None], rig(SPREAD[:3])])
    truth = np.full((1, N_JOINTS, 3), [0.3, 0.2, 2.0])
    res = fuse_nonlinear(observe(truth, s2w), s2w)
    np.testing.assert_allclose(res.positions, truth, atol=1e-6)  # 1 micrometre
