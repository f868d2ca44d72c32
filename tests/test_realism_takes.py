"""Real against simulated figures per KinectMultiTrack take (kinefuse.lab.realism_takes)."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.frames.motion import Motion
from kinefuse.core.skeleton import JOINT_INDEX, standing_pose
from kinefuse.errors import InputError
from kinefuse.formats.kinect_multitrack import read_kinect_multitrack
from kinefuse.lab.realism import PairLayout
from kinefuse.lab.realism_takes import (
    BANDS,
    FACTORS,
    FIGURE_KEYS,
    STILL_BELOW_M_S,
    STILL_LR_MAX,
    StreamPair,
    TakeResult,
    compare_take,
    layout_angle_deg,
    pair_figures,
    real_pair,
    still_frames,
    take_layout,
    take_passes,
)
from kinefuse.sim.tracker_params import TrackerParams, light_tracker

#: the real per-take figures of the population (tests/test_tracker_failures.py checks them)
POPULATION_CACHE = Path(__file__).resolve().parent / "data" / "realism_population_real.json"


@pytest.fixture(scope="module")
def takes(shared_data: Path) -> dict[str, Path]:
    folder = shared_data / "kinect" / "kinect_multitrack"
    out = {
        "90": next(folder.glob("Study_1_Kinect_2_*.csv"), None),
        "0": next(folder.glob("Study_4_Kinect_0_*.csv"), None),
        "45": next(folder.glob("Study_4_Kinect_1_*.csv"), None),
    }
    if any(v is None for v in out.values()):
        pytest.skip(f"the three KinectMultiTrack takes are not all in {folder}")
    return {k: v for k, v in out.items() if v is not None}


@pytest.fixture(scope="module")
def walk(shared_data: Path) -> Motion:
    from kinefuse.formats.motion import load_motion

    return load_motion(shared_data / "motion" / "cmu" / "02_walk_a.amc")


def _standing_copy(src: Path, dst: Path) -> Path:
    """The rows of scenario 1 (stand still) of a real take: an all-standing take."""
    lines = src.read_text().splitlines()
    col = [c.strip() for c in lines[0].split(",")].index("Scenario_Id")
    rows = [ln for ln in lines[1:] if ln.split(",")[col].strip() == "1"]
    dst.write_text("\n".join([lines[0], *rows]) + "\n")
    return dst


# -------------------------------------------------------------------------------------------
# the figures: one function for real and simulated streams


def test_still_frames_and_jitter_on_a_known_stream() -> None:
    """A pelvis that stands 2 s then walks at 1 m/s, with 0.3 mm steps while standing."""
    t = np.arange(120) / 30.0
    base = standing_pose()[None].repeat(120, axis=0) + np.array([0.0, 0.0, 2.5])
    x = np.where(t < 2.0, 0.0, t - 2.0)
    p = base + np.stack([x, 0 * x, 0 * x], axis=1)[:, None, :]
    steps = np.zeros((120, 25, 3))
    steps[1:60, :, 0] = 0.0003 * (-1.0) ** np.arange(59)[:, None]  # +/-0.3 mm, back and forth
    p += np.cumsum(steps, axis=0)
    g = np.zeros(120, dtype=np.int64)
    fresh, still = still_frames(p, t, g)
    assert fresh.all()
    assert still[5:50].all() and not still[70:].any()
    idx = np.arange(120)
    pair = StreamPair(p, p.copy(), t, t, g, g, idx, idx)
    f = pair_figures(pair)
    assert f["still_jitter_m_per_frame"] == pytest.approx(0.0003, rel=1e-6)  # 0.3 mm
    assert f["median_m"] < 1e-9  # identical streams
    assert f["bone_length_cv"] < 1e-9  # a rigid body
    assert f["lr_disagreement_fraction"] == 0.0
    # repeated rows (a log repeats the latest skeleton) are not frames
    t2 = t.copy()
    t2[10] = t2[9]
    fresh2, _ = still_frames(p, t2, g)
    assert not fresh2[10] and fresh2.sum() == 119


def test_limb_angle_disagreement_is_frame_free_and_ignores_mirroring() -> None:
    """The knee and elbow angle figure: 0 for a stream against itself moved, turned or with its
    labels mirrored (the left knee bent, so a mirrored stream reads the other side's angle);
    one knee bent further in one stream counts half (the mean over the sides)."""
    from scipy.spatial.transform import Rotation

    from kinefuse.core.skeleton import MIRROR_INDEX
    from kinefuse.lab.realism_takes import limb_angle_disagreement_deg
    from kinefuse.pipeline.analysis_chain import hinge_angle_deg

    k, a = JOINT_INDEX["KneeLeft"], JOINT_INDEX["AnkleLeft"]

    def bend_left_knee(p: np.ndarray, deg: float) -> np.ndarray:
        out = p.copy()  # the left shank swung about the knee's left-right axis
        out[:, a] = out[:, k] + Rotation.from_euler("x", deg, degrees=True).apply(
            out[:, a] - out[:, k]
        )
        return out

    stand = standing_pose()[None].repeat(10, axis=0) + np.array([0.0, 0.0, 2.5])
    p = bend_left_knee(stand, 30.0)
    left = hinge_angle_deg(p, "HipLeft", "KneeLeft", "AnkleLeft")
    right = hinge_angle_deg(p, "HipRight", "KneeRight", "AnkleRight")
    assert (np.abs(left - right) > 15.0).all()  # the two knees differ
    turned = Rotation.from_euler("zx", [70, 20], degrees=True).apply(p.reshape(-1, 3))
    q = turned.reshape(p.shape)[:, list(MIRROR_INDEX)] + 1.0  # turned, moved, labels mirrored
    idx = np.arange(10)
    g = np.zeros(10, dtype=np.int64)
    t = idx / 30.0
    same = limb_angle_disagreement_deg(StreamPair(p, q, t, t, g, g, idx, idx))
    np.testing.assert_allclose(same, 0.0, atol=1e-6)
    more = bend_left_knee(p, 20.0)
    moved = hinge_angle_deg(more, "HipLeft", "KneeLeft", "AnkleLeft")
    d = limb_angle_disagreement_deg(StreamPair(p, more, t, t, g, g, idx, idx))
    np.testing.assert_allclose(d[:, 0], np.abs(moved - left) / 2, atol=1e-9)  # knees
    np.testing.assert_allclose(d[:, 1], 0.0, atol=1e-9)  # elbows untouched
    assert 5.0 < d[0, 0] <= 10.0 + 1e-9  # about half the 20 degrees


#: The joint groups of the figures (docs/realism.md): trunk and extremities.
TRUNK = ("SpineBase", "SpineMid", "SpineShoulder", "ShoulderLeft", "ShoulderRight")
EXTREMITIES = ("WristLeft", "WristRight", "HandLeft", "HandRight",
               "AnkleLeft", "AnkleRight", "FootLeft", "FootRight")  # fmt: skip


def _independent_distances(pair: StreamPair) -> np.ndarray:
    """Per-joint distances ``(P, 25)`` of a pair's paired frames after one rotation fitted by
    scipy over every paired joint (computed here, not by the report's own fit)."""
    from scipy.spatial.transform import Rotation

    pa, pb = pair.joints_a[pair.idx_a], pair.joints_b[pair.idx_b]
    ok = np.isfinite(pa).all(-1) & np.isfinite(pb).all(-1)
    ca, cb = pa[ok].mean(axis=0), pb[ok].mean(axis=0)
    rot, _ = Rotation.align_vectors(pa[ok] - ca, pb[ok] - cb)
    d = np.linalg.norm(rot.apply((pb - cb).reshape(-1, 3)).reshape(pb.shape) + ca - pa, axis=-1)
    return np.where(ok, d, np.nan)


def _limb_bone_cv(joints: np.ndarray, t_sensor_s: np.ndarray, group: np.ndarray) -> float:
    """Median over the limb bones (upper and lower arms and legs) of each bone length's
    coefficient of variation over the distinct frames (a repeated row is not a frame)."""
    from kinefuse.core.skeleton import BONES

    new = np.ones(t_sensor_s.size, dtype=bool)
    for g in np.unique(group):
        rows = np.flatnonzero(group == g)
        new[rows[1:]] = np.diff(t_sensor_s[rows]) > 0.005  # s
    limbs = [(JOINT_INDEX[a], JOINT_INDEX[b]) for a, b in BONES
             if b.startswith(("Elbow", "Wrist", "Knee", "Ankle"))]  # fmt: skip
    assert len(limbs) == 8
    q = joints[new]
    cv = [np.nanstd(n) / np.nanmean(n) for n in (np.linalg.norm(q[:, c] - q[:, p], axis=-1)
                                                 for p, c in limbs)]  # fmt: skip
    return float(np.median(cv))


def test_real_figures_of_the_three_takes(takes: dict[str, Path]) -> None:
    pairs = {k: real_pair(read_kinect_multitrack(v)) for k, v in takes.items()}
    f = {k: pair_figures(p) for k, p in pairs.items()}

    def pooled(d: np.ndarray, names: tuple[str, ...]) -> float:
        v = d[:, [JOINT_INDEX[n] for n in names]]
        return float(np.median(v[np.isfinite(v)]))

    for k, pair in pairs.items():
        d = _independent_distances(pair)
        assert f[k]["median_m"] == pytest.approx(np.nanmedian(d), abs=1e-9), k  # 1 nm
        assert f[k]["p95_m"] == pytest.approx(np.nanpercentile(d, 95), abs=1e-9), k
        assert f[k]["trunk_median_m"] == pytest.approx(pooled(d, TRUNK), abs=1e-9), k
        assert f[k]["extremity_median_m"] == pytest.approx(pooled(d, EXTREMITIES), abs=1e-9), k
        cv = np.mean([_limb_bone_cv(pair.joints_a, pair.t_sensor_a_s, pair.group_a),
                      _limb_bone_cv(pair.joints_b, pair.t_sensor_b_s, pair.group_b)])  # fmt: skip
        assert f[k]["bone_length_cv"] == pytest.approx(cv, rel=1e-9), k
        # real Kinect limbs stretch as the person moves (a rigid body gives 0, see above)
        assert cv > 0.01, k
        # standing still: the spine's frame-to-frame jitter stays under what the still test
        # lets the pelvis move in a frame (3 cm/s at 30 Hz: 1 mm), and a real sensor is not
        # noise-free
        assert 0.0 < f[k]["still_jitter_m_per_frame"] < STILL_BELOW_M_S / 30.0, k
        assert f[k]["lr_disagreement_still_fraction"] == 0.0, k  # standing: never mirrored
        assert 0.03 < f[k]["still_p95_m"] < 0.2, k  # 3-20 cm: real inferred joints stay on the body
    # the wider the layout, the more the two views disagree, on the trunk too
    for key in ("median_m", "p95_m", "trunk_median_m"):
        assert f["0"][key] < f["45"][key] < f["90"][key], key
    # left and right: agreed side by side and at 45 deg, not while walking the square at 90
    assert f["0"]["lr_disagreement_fraction"] < 0.05 and f["45"]["lr_disagreement_fraction"] < 0.05
    assert 0.1 < f["90"]["lr_disagreement_fraction"] < 0.2


def test_layout_of_a_take_uses_the_rigid_fit(takes: dict[str, Path]) -> None:
    for name, path in takes.items():
        lay = take_layout(read_kinect_multitrack(path))
        assert layout_angle_deg(lay) == pytest.approx(float(name), abs=3.0)  # 3 deg
        assert 2.0 < lay.dist_m[0] < 2.6  # m


def test_take_passes(walk: Motion) -> None:
    mixed = take_passes(walk, 0.5, 0.5)
    stand = mixed[-1]
    assert np.abs(np.diff(stand.positions, axis=0)).max() == 0.0
    walking = sum(m.duration_s for m in mixed[:-1])
    assert stand.duration_s == pytest.approx(walking, rel=0.05)  # half the time standing
    only = take_passes(walk, 1.0, 0.0)
    assert len(only) == 1 and np.abs(np.diff(only[0].positions, axis=0)).max() == 0.0
    head = only[0].positions[0, JOINT_INDEX["Head"]]
    assert head[0] == pytest.approx(0.0, abs=0.1)  # at the person's spot
    # a standing take that sways in 0.5 % of its frames: the stand alone, as long as the walk's
    # passes (not 199 times their length to match the share)
    sway = take_passes(walk, 0.995, 0.16)
    assert len(sway) == 1 and sway[0].duration_s == pytest.approx(only[0].duration_s, rel=0.05)
    with pytest.raises(InputError, match=r"still_fraction must be in \[0, 1\]"):
        take_passes(walk, 1.2, 0.5)


def test_failures_name_what_is_missed() -> None:
    real = dict.fromkeys(FIGURE_KEYS, 0.01) | {
        "lr_disagreement_still_fraction": 0.0,
        "still_p95_m": 0.1,
        "still_fraction": 0.3,
    }
    sim = dict(real) | {"median_m": 0.02, "bone_length_cv": 0.001}
    sim["lr_disagreement_still_fraction"] = 0.05
    res = TakeResult("x.csv", 90.0, 2.4, real, sim, {k: (v, v) for k, v in sim.items()}, (0,),
                     (0.0,) * 25, (0.0,) * 25)  # fmt: skip
    text = " | ".join(res.failures())
    assert "median_m: sim/real 2.00, outside +/-25 %" in text
    assert "bone_length_cv: sim/real 0.10, outside a factor 1.5" in text
    assert "left/right disagreement while standing 5.0 % >= 1 %" in text
    ok = TakeResult("x.csv", 90.0, 2.4, real, real, {k: (v, v) for k, v in real.items()}, (0,),
                    (0.0,) * 25, (0.0,) * 25)  # fmt: skip
    assert ok.failures() == []


# -------------------------------------------------------------------------------------------
# acceptance (issue 9): the simulated copy of every take against the real take


@pytest.fixture(scope="module")
def compared(takes: dict[str, Path], walk: Motion) -> dict[str, TakeResult]:
    # 3 seeds keep the suite fast; `python studies/realism.py --seeds 5` gives the documented
    # figures. One real person against the model's typical person (the person level off): a
    # random simulated person is held to the population (`python studies/realism.py
    # --population`), not to one participant's +/-25 %
    typical = dataclasses.replace(TrackerParams(), person_log_sigma=0.0)
    return {k: compare_take(v, walk, range(3), typical) for k, v in takes.items()}


def _meets_issue_9(res: TakeResult) -> None:
    for k, band in BANDS.items():  # median 25 %, p95 40 %, trunk and extremities 35 %
        assert abs(res.simulated[k] / res.real[k] - 1.0) <= band, (k, res.simulated, res.real)
    for k, f in FACTORS.items():  # still jitter within 2x, bone-length CV within 1.5x
        assert 1.0 / f <= res.simulated[k] / res.real[k] <= f, (k, res.simulated, res.real)
    assert res.simulated["lr_disagreement_still_fraction"] < STILL_LR_MAX  # under 1 %
    # no stale guesses far from the body while standing (issue 9: 40-54 cm before, real 5-15 cm)
    assert res.simulated["still_p95_m"] < 1.5 * res.real["still_p95_m"]
    assert res.failures() == []


@pytest.mark.slow
@pytest.mark.parametrize("name", ["0", "90"])
def test_simulated_takes_match_the_real_ones(compared: dict[str, TakeResult], name: str) -> None:
    _meets_issue_9(compared[name])


@pytest.mark.slow
def test_the_45_degree_take(
    takes: dict[str, Path], walk: Motion, compared: dict[str, TakeResult]
) -> None:
    """Participant 4 is the best-tracked of the nine at 45 degrees (median 2.9 cm, the others
    3.6-11.8): the default model, fitted on the population, holds its typical person to the
    population's range there, and the light model (issue 9's fit to this very take, the model of
    before issue 21) still meets issue 9's bands on it."""
    pop = json.loads(POPULATION_CACHE.read_text())["takes"]
    real = {k: [t[k] for t in pop if t["layout"] == "45"] for k in ("median_m", "p95_m")}
    res = compared["45"]
    for k, v in real.items():
        assert min(v) <= res.simulated[k] <= max(v), (k, res.simulated[k], v)
    _meets_issue_9(compare_take(takes["45"], walk, range(3), light_tracker()))


@pytest.mark.slow
def test_the_90_degree_take_disagrees_most(compared: dict[str, TakeResult]) -> None:
    """The view-dependent errors: the wider the layout, the larger the trunk disagreement."""
    trunk = {k: r.simulated["trunk_median_m"] for k, r in compared.items()}
    assert trunk["0"] < trunk["45"] < trunk["90"]
    # the far (left) arm is worse than the near one from the side, as in the real take
    r = compared["90"]
    left = np.mean([r.sim_per_joint_m[JOINT_INDEX[n]] for n in ("ShoulderLeft", "ElbowLeft")])
    right = np.mean([r.sim_per_joint_m[JOINT_INDEX[n]] for n in ("ShoulderRight", "ElbowRight")])
    assert left > 1.3 * right


# -------------------------------------------------------------------------------------------
# the study's command (studies/realism.py)


def realism_study(argv: list[str]) -> int:
    """``python studies/realism.py ARGV``, in this process (its output is captured)."""
    path = Path(__file__).resolve().parents[1] / "studies" / "realism.py"
    spec = importlib.util.spec_from_file_location("realism_study", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return int(module.main(argv))


def test_cli_json_on_an_all_standing_take(
    takes: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    stand = _standing_copy(takes["90"], tmp_path / "standing.csv")
    rc = realism_study(["--take", str(stand), "--seeds", "2", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc in (0, 1)
    (take,) = out["takes"]
    assert set(take) == {"file", "layout", "real", "simulated"}
    assert take["file"] == str(stand)
    assert set(take["layout"]) == {"angle_deg", "distance_m"}
    # the layout: the logged side azimuth corrected by the yaw (about the vertical) of a rigid
    # fit of the stand's two streams, here scipy's
    from scipy.spatial.transform import Rotation

    rec = read_kinect_multitrack(stand)
    pair = real_pair(rec)
    pa, pb = pair.joints_a[pair.idx_a], pair.joints_b[pair.idx_b]
    ok = np.isfinite(pa).all(-1) & np.isfinite(pb).all(-1)
    r = Rotation.align_vectors(pa[ok] - pa[ok].mean(0), pb[ok] - pb[ok].mean(0))[0].as_matrix()
    logged = PairLayout.from_recording(rec)
    expected = np.degrees(
        logged.azimuth_rad[1] - np.arctan2(r[0, 2], r[2, 2]) - logged.azimuth_rad[0]
    )
    assert take["layout"]["angle_deg"] == pytest.approx(abs(expected), abs=1e-6)  # degrees
    # a still stand constrains the fit less than the whole take, but the correction still
    # works: nearer the whole take's angle than the logged angle is, within 12 deg of it
    whole_lay = take_layout(read_kinect_multitrack(takes["90"]))
    whole = layout_angle_deg(whole_lay)
    assert abs(take["layout"]["angle_deg"] - whole) < abs(layout_angle_deg(logged) - whole)
    assert take["layout"]["angle_deg"] == pytest.approx(whole, abs=12.0)
    # the stand's rows log the same initial distance as the take
    assert take["layout"]["distance_m"] == pytest.approx(whole_lay.dist_m[0])  # front sensor
    for side in ("real", "simulated"):
        assert set(FIGURE_KEYS) <= set(take[side])
        for k in FIGURE_KEYS:
            assert np.isfinite(take[side][k]), (side, k)
    sim = take["simulated"]
    assert sim["seeds"] == [0, 1]
    for k in FIGURE_KEYS:
        lo, hi = sim["range"][k]
        assert lo <= sim[k] <= hi
    assert sim["still_fraction"] > 0.5  # the simulated take stands too
    assert take["real"]["lr_disagreement_fraction"] == 0.0


def test_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert realism_study(["--take", str(tmp_path / "none.csv"), "--seeds", "1"]) == 2
    assert "no such file" in capsys.readouterr().err
    assert realism_study(["--seeds", "0"]) == 2
    assert "--seeds must be at least 1, got 0" in capsys.readouterr().err


def test_cli_population_on_a_small_folder(
    takes: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--population DIR: the per-take layout plus a per-layout population block (bounded: two
    takes cut to their stand, one seed)."""
    folder = tmp_path / "pop"
    folder.mkdir()
    _standing_copy(takes["0"], folder / "a.csv")
    _standing_copy(takes["90"], folder / "b.csv")
    rc = realism_study(["--population", str(folder), "--seeds", "1", "--json"])
    assert rc in (0, 1)
    out = json.loads(capsys.readouterr().out)
    assert {t["file"] for t in out["takes"]} == {str(folder / "a.csv"), str(folder / "b.csv")}
    assert set(out["population"]) == {"0", "90"}
    # each take its own simulated subjects: with the same seeds for every take, all takes of a
    # layout would share their person-level draws
    seeds = [tuple(t["simulated"]["seeds"]) for t in out["takes"]]
    assert len(set(seeds)) == 2, seeds
    block = out["population"]["90"]
    assert block["n_real_takes"] == 1 and block["n_simulated"] == 1
    assert block["iqr_of_medians"]["real"] == 0.0  # one take: no spread
    for stat in ("median_of_medians", "median_of_p95", "median_bone_cv"):
        e = block[stat]
        assert e["real_interval"][0] <= e["real"] <= e["real_interval"][1]
        assert e["ratio"] == pytest.approx(e["simulated"] / e["real"])


def test_a_standing_leg_reads_as_straight_as_on_the_real_front_sensors(
    shared_data: Path, walk: Motion, tmp_path: Path
) -> None:
    """The front sensor's knee angle while the person stands still (`still_knee_angle_deg`),
    over one take per real participant against two simulated subjects per take: the real
    tracker reads a straight leg 1-9° bent (median about 5°). Independent subject-level joint
    offsets (each joint's definition offset drawn on its own) read it about 12° bent in the
    median; drawn coherently along the limb (`limb_coherence`, fitted on the sensors' angle
    disagreement, not on this) they give the real figure."""
    from kinefuse.lab.realism_person import population_seeds

    folder = shared_data / "kinect" / "kinect_multitrack_population"
    firsts: dict[str, Path] = {}
    for f in sorted(folder.glob("Study_*_Kinect_*.csv")):
        firsts.setdefault(f.name.split("_")[1], f)
    if len(firsts) < 8:
        pytest.skip(f"fewer than 8 participants in {folder}")
    real, sim = [], []
    for f in firsts.values():
        stand = _standing_copy(f, tmp_path / f.name)  # scenario 1: facing the front sensor
        res = compare_take(stand, walk, population_seeds(f.name, 2))
        real.append(res.real["still_knee_angle_deg"])
        sim += [s["still_knee_angle_deg"] for s in res.per_seed]
    assert 2.0 < np.median(real) < 10.0, real
    assert 2 / 3 < np.median(sim) / np.median(real) < 1.5, (np.median(sim), np.median(real))
    assert np.percentile(sim, 90) < 2.0 * np.percentile(real, 90), (sim, real)
