"""Arm and trunk angles against OpenSim's IK, model conventions, and plausibility as a status
(issue 43 items 3 and 4), on the shared OpenSim walks; nothing is fitted to them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.errors import InputError

RAJ = "markers/opensim/Pipelines_Rajagopal_"
GAIT = "markers/opensim/Pipelines_Gait2354_Simbody_"


@pytest.fixture(scope="module")
def rajagopal(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from kinefuse.app.workflows.analyze import run_analyze

    out = tmp_path_factory.mktemp("raj") / "out"
    run_analyze([shared_data / f"{RAJ}ExpData_motion_capture_walk.trc"], out=out,
                static=shared_data / f"{RAJ}ExpData_static_walk_1.trc",
                names="opensim:rajagopal", plots=False)  # fmt: skip
    return out


@pytest.fixture(scope="module")
def rajagopal_epicondyles(shared_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The walk with every knee's axis from its static trial's epicondyle markers, however far
    from the axis the knee flexes about (the left one is 29 deg from it: docs/analysis.md):
    what an ISB-only reading gives."""
    from kinefuse.app.workflows.analyze import run_analyze
    from kinefuse.biomech import static_trial

    out = tmp_path_factory.mktemp("raj_epi") / "out"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(static_trial, "MAX_KNEE_AXIS_DISAGREEMENT_DEG", 180.0)
        run_analyze([shared_data / f"{RAJ}ExpData_motion_capture_walk.trc"], out=out,
                    static=shared_data / f"{RAJ}ExpData_static_walk_1.trc",
                    names="opensim:rajagopal", plots=False)  # fmt: skip
    return out


def _compare(out: Path, shared_data: Path) -> dict[str, dict[str, float]]:
    from kinefuse.lab.opensim_ik import compare_with_ik

    return compare_with_ik(out / "angles.mot", shared_data / f"{RAJ}OpenSimIK_walk.mot")


def test_rajagopal_arm_and_trunk_targets_that_hold(rajagopal: Path, shared_data: Path) -> None:
    """Issue 43's arm targets on both sides (degrees), lumbar extension's r, no wrap."""
    c = _compare(rajagopal, shared_data)
    for s in "rl":
        v = c[f"arm_flex_{s}"]
        assert v["r"] >= 0.95 and abs(v["offset_deg"]) <= 8.0, v
        assert v["rms_after_offset_deg"] <= 4.0, v
        e = c[f"elbow_flex_{s}"]
        assert e["r"] >= 0.95 and abs(e["offset_deg"]) <= 5.0, e
        assert e["rms_after_offset_deg"] <= 4.0, e
        a = c[f"arm_add_{s}"]
        assert a["r"] >= 0.7 and a["rms_after_offset_deg"] <= 4.0, a
        assert c[f"knee_angle_{s}"]["r"] >= 0.97  # Rajagopal's knee: positive in flexion
    assert c["lumbar_extension"]["r"] >= 0.8
    assert not any(v["wraps"] for v in c.values())


def test_rajagopal_lumbar_offset(rajagopal: Path, shared_data: Path) -> None:
    """Met since the lumbar joint's depth is scaled by the pelvis's depth, as OpenSim's Scale
    tool does (5.8 deg before, 2.3 now; docs/analysis.md)."""
    v = _compare(rajagopal, shared_data)["lumbar_extension"]["offset_deg"]
    assert abs(v) <= 5.0, v


def _gait2354(shared_data: Path, tmp_path: Path, how: str, window: tuple[float, float] | None
              ) -> dict[str, dict[str, float]]:  # fmt: skip
    """The Gait2354 walk (as is, or left-right mirrored with its IK) with --names
    opensim:gait2354 against OpenSim's IK of it."""
    from kinefuse.app.workflows.analyze import run_analyze
    from kinefuse.lab.opensim_ik import compare_with_ik, mirror_trc_text

    walk = shared_data / f"{GAIT}subject01_walk1.trc"
    static = shared_data / f"{GAIT}subject01_static.trc"
    if how == "mirrored":
        (tmp_path / "w.trc").write_text(mirror_trc_text(walk.read_text()))
        (tmp_path / "s.trc").write_text(mirror_trc_text(static.read_text()))
        walk, static = tmp_path / "w.trc", tmp_path / "s.trc"
    out = tmp_path / "out"
    run_analyze([walk], out=out, static=static, static_window=window, names="opensim:gait2354",
                plots=False)  # fmt: skip
    ik = shared_data / f"{GAIT}OutputReference_subject01_walk1_ik.mot"
    return compare_with_ik(out / "angles.mot", ik, mirrored=how == "mirrored")


@pytest.mark.parametrize(
    ("how", "window"), [("as is", None), ("mirrored", None), ("as is", (0.0, 2.5)),
                        ("as is", (2.5, 5.0))]
)  # fmt: skip
def test_gait2354_lumbar_offset_from_the_models_own_bodies(
    shared_data: Path, tmp_path: Path, how: str, window: tuple[float, float] | None
) -> None:
    """Met since the pelvis and torso of the gait2354 coordinates are the model's own bodies,
    fitted to the static trial by the model's marker template (8.3 deg before; -1.6 now), on
    the walk, its mirror and either half of the static trial; the hip, knee and ankle keep
    their ISB frames and figures (test_opensim_ik.py)."""
    c = _gait2354(shared_data, tmp_path, how, window)
    assert abs(c["lumbar_extension"]["offset_deg"]) <= 5.0, c["lumbar_extension"]
    assert abs(c["pelvis_tilt"]["offset_deg"]) <= 1.0, c["pelvis_tilt"]  # -3.7 with ISB's
    # the hips keep their ISB frames: 0.01 / 1.26 as before (-3.2 / -1.9 from the model pelvis)
    assert max(abs(c[f"hip_flexion_{s}"]["offset_deg"]) for s in "rl") <= 1.5


@pytest.mark.xfail(strict=True, reason="not reachable from the pelvis's three markers: the "
                   "IK's lumbar_extension spans 2.4 deg (SD 0.69), r >= 0.8 allows 0.52 deg RMS "
                   "of error, and the pelvis tilt alone differs from the IK's by 1.5 deg RMS "
                   "(docs/analysis.md)")  # fmt: skip
def test_gait2354_lumbar_r_not_met(shared_data: Path, tmp_path: Path) -> None:
    assert _gait2354(shared_data, tmp_path, "as is", None)["lumbar_extension"]["r"] >= 0.8


def test_without_the_template_markers_the_isb_frames_stand(
    rajagopal: Path, shared_data: Path, tmp_path: Path
) -> None:
    """The Rajagopal walk has none of the Gait2354 set's torso markers: under gait2354's names
    its pelvis and lumbar coordinates are the ISB ones, as under Rajagopal's."""
    from kinefuse.app.workflows.analyze import run_analyze
    from kinefuse.formats.angles import read_angles_mot

    run_analyze([shared_data / f"{RAJ}ExpData_motion_capture_walk.trc"], out=tmp_path / "o",
                static=shared_data / f"{RAJ}ExpData_static_walk_1.trc",
                names="opensim:gait2354", plots=False)  # fmt: skip
    _, gait, _ = read_angles_mot(tmp_path / "o" / "angles.mot")
    _, raj, _ = read_angles_mot(rajagopal / "angles.mot")
    for k in ("pelvis_tilt", "pelvis_list", "lumbar_extension", "lumbar_bending"):
        np.testing.assert_array_equal(gait[k], raj[k])


def test_model_body_offsets_recover_a_posed_template(rng: np.random.Generator) -> None:
    """The gait2354 template placed in a known pose (the torso turned about the lumbar joint)
    gives back the model bodies' frames relative to any ISB frames; a segment whose markers
    the static trial lacks is left out."""
    from scipy.spatial.transform import Rotation

    from kinefuse.biomech.anatomical import GAIT2354_TEMPLATES, model_body_offsets

    body = {k: Rotation.random(random_state=rng).as_matrix() for k in ("pelvis", "trunk")}
    isb = {k: Rotation.random(random_state=rng).as_matrix() for k in ("pelvis", "trunk")}
    origin = {"pelvis": rng.normal(size=3), "trunk": rng.normal(size=3)}  # the trunk's: the joint
    markers = {
        name: body[seg] @ np.asarray(loc) + origin[seg]
        for seg, tmpl in GAIT2354_TEMPLATES.items()
        for name, loc in tmpl.items()
    }
    lumbar = origin["trunk"]
    got = model_body_offsets(isb, markers, GAIT2354_TEMPLATES, lumbar)
    for seg in ("pelvis", "trunk"):
        np.testing.assert_allclose(isb[seg] @ got[seg], body[seg], atol=1e-9)
    del markers["Sternum"]
    assert set(model_body_offsets(isb, markers, GAIT2354_TEMPLATES, lumbar)) == {"pelvis"}


def test_the_model_decides_the_knee_sign(rajagopal: Path, shared_data: Path) -> None:
    """The same angles under gait2354's convention disagree with Rajagopal's IK: the check can
    fail, and --names picks the convention."""
    from kinefuse.biomech.anatomical import opensim_angles, opensim_model
    from kinefuse.formats.angles import read_angles_mot

    _, ours, _ = read_angles_mot(rajagopal / "angles.mot")
    _, ik, _ = read_angles_mot(shared_data / f"{RAJ}OpenSimIK_walk.mot")
    assert np.corrcoef(ours["knee_angle_r"], ik["knee_angle_r"])[0, 1] > 0.97
    flexion = {"knee_flexion_right": ours["knee_angle_r"]}
    assert (opensim_angles(flexion, "gait2354")["knee_angle_r"] == -ours["knee_angle_r"]).all()
    assert "arm_flex_r" not in opensim_angles({"shoulder_flexion_right": ours["arm_flex_r"]},
                                              "gait2392")  # fmt: skip
    assert opensim_model("opensim:Rajagopal2016") == opensim_model("opensim:rajagopal")
    with pytest.raises(InputError, match="opensim:MODEL with MODEL one of gait2354"):
        opensim_model("opensim:arm26")


def test_unknown_names_are_refused_before_any_work(shared_data: Path, tmp_path: Path) -> None:
    from kinefuse.app.cli import main

    code = main(["analyze", str(shared_data / f"{GAIT}subject01_walk1.trc"), "--names",
                 "opensim:nope", "--out", str(tmp_path / "o")])  # fmt: skip
    assert code == 2 and not (tmp_path / "o").exists()


def test_status_is_in_the_csv_the_json_and_the_report(rajagopal_epicondyles: Path) -> None:
    """Read about its static trial's epicondyle axis, the left knee's anatomical adduction
    (varus) reaches 34 deg in swing, outside its range on 15 % of the frames (the cross-talk of
    knee flexion into an axis 29 deg off): implausible, with the reason, in all three places;
    the knee's flexion is ok."""
    from kinefuse.app.workflows.analyze_one import format_report

    rajagopal = rajagopal_epicondyles
    rows = [ln.split(",") for ln in (rajagopal / "angles.csv").read_text().splitlines()]
    assert rows[0][-1] == "status"
    status = {(r[2], r[3]): r[6] for r in rows[1:]}
    assert status[("knee_adduction_left", "anatomical")] == "implausible"
    assert status[("knee_flexion_left", "anatomical")] == "ok"
    assert status[("elbow_flexion_left", "anatomical")] == "ok"
    rep = json.loads((rajagopal / "analysis.json").read_text())
    why = rep["angle_status"]["anatomical"]["knee_adduction_left"]["reasons"]
    assert any("outside its range -20..20 deg" in w for w in why)
    assert rep["anatomical"]["angle_status"]["knee_flexion_left"] == "ok"
    joints = rep["joint_status"]["anatomical"]
    assert joints["KneeLeft"].startswith("implausible: knee_adduction_left: outside its range")
    assert joints["KneeRight"] == "ok" and joints["pelvis"] == "ok"
    assert "implausible anatomical knee_adduction_left: outside" in format_report(rep)


def test_a_wrapped_elbow_is_implausible(rajagopal: Path) -> None:
    """The real elbow curve read about a reversed flexion axis (what a flipped upper-arm frame
    gives: -171..176 deg) wraps and leaves the range; the curve itself is ok."""
    from kinefuse.biomech.angle_plausibility import angle_status

    rows = [ln.split(",") for ln in (rajagopal / "angles.csv").read_text().splitlines()[1:]]
    mine = [r for r in rows if r[2] == "elbow_flexion_right" and r[3] == "anatomical" and r[4]]
    t = np.array([float(r[0]) for r in mine])
    v = np.array([float(r[4]) for r in mine])
    assert angle_status("elbow_flexion_right", t, v) == []
    flipped = (180.0 - v + 180.0) % 360.0 - 180.0  # about -Z: 180 - flexion, into (-180, 180]
    flipped = np.where(np.arange(v.size) % 7 < 3, flipped, -np.abs(flipped))
    why = angle_status("elbow_flexion_right", t, flipped)
    assert any("wraps through ±180" in w for w in why), why
    assert any("outside its range" in w for w in why), why
    # a jump no arm makes: one frame 60 deg off at 100 Hz (6000 deg/s)
    jump = v.copy()
    jump[v.size // 2] += 60.0
    assert any("jumps faster" in w for w in angle_status("elbow_flexion_right", t, jump))


@pytest.mark.parametrize("clip", ["motion/cmu/02_walk_a.amc", "motion/cmu/01_01.bvh"])
def test_pronation_where_the_forearm_has_two_styloids(
    clip: str, shared_data: Path, tmp_path: Path, rajagopal: Path
) -> None:
    """The Gait2354 set (two wrist markers) placed on a real clip gives back the clip's forearm
    pronation and its elbow as a hinge; the Rajagopal set (one wrist marker) has no pronation."""
    from kinefuse.app.workflows.analyze import load_input
    from kinefuse.lab.marker_placement import gait2354_trial, write_trc

    tr = gait2354_trial(shared_data / clip)
    t_static = np.arange(tr.static.shape[0]) / tr.rate_hz
    static = write_trc(tmp_path / "static.trc", t_static, tr.names, tr.static)
    walk = write_trc(tmp_path / "walk.trc", tr.t_s, tr.motion_names, tr.motion)
    inp = load_input(walk, marker_map="gait2354", static=static)
    assert inp.anatomical is not None
    for s in ("left", "right"):
        for k, limit in (("forearm_pronation", 2.0), ("elbow_flexion", 0.5)):
            d = inp.anatomical[f"{k}_{s}"] - tr.true_angles[f"{k}_{s}"]
            assert np.sqrt(np.nanmean(d**2)) < limit, (k, s, np.sqrt(np.nanmean(d**2)))
    csv = (rajagopal / "angles.csv").read_text()
    assert ",elbow_flexion_left,anatomical," in csv
    assert ",forearm_pronation_left,anatomical," not in csv


def test_the_html_report_has_the_status_column(rajagopal_epicondyles: Path) -> None:
    """report.html's angle table: the walk's real curves, one implausible (with why), one ok."""
    from kinefuse.lab.report.html import angle_status_table

    out = rajagopal_epicondyles
    rows = [ln.split(",") for ln in (out / "angles.csv").read_text().splitlines()[1:]]
    curves: dict[str, list[float]] = {}
    times: list[float] = []
    for r in rows:
        if r[3] != "anatomical" or r[2] not in ("knee_adduction_left", "knee_flexion_left"):
            continue
        curves.setdefault(r[2], []).append(float(r[4]) if r[4] else np.nan)
        if r[2] == "knee_flexion_left":
            times.append(float(r[0]))
    html = angle_status_table(np.array(times), {k: np.array(v) for k, v in curves.items()})
    assert "<th>status</th>" in html
    assert "<td>knee_flexion_left</td><td>ok</td>" in html
    assert "<td>knee_adduction_left</td><td>implausible</td><td>outside its range" in html


@pytest.mark.parametrize(("how", "window"), [("mirrored", None), ("as is", (0.0, 1.4)),
                                             ("as is", (1.4, 2.9))])  # fmt: skip
def test_held_out_variants_hold_the_arm_targets(
    shared_data: Path, tmp_path: Path, how: str, window: tuple[float, float] | None
) -> None:
    """The left-right mirrored walk and static trial (against the mirrored IK) and each half of
    the static trial as the static window hold the arm targets of
    :func:`test_rajagopal_arm_and_trunk_targets_that_hold`. The one at its margin:
    ``elbow_flex_l``'s offset, -4.98 deg with the whole static trial, -5.04 / -5.07 deg with
    its halves (docs/analysis.md); that offset is asserted with the whole trial only."""
    from kinefuse.app.workflows.analyze import run_analyze
    from kinefuse.lab.opensim_ik import arm_trunk_failures, compare_with_ik, mirror_trc_text

    walk = shared_data / f"{RAJ}ExpData_motion_capture_walk.trc"
    static = shared_data / f"{RAJ}ExpData_static_walk_1.trc"
    if how == "mirrored":
        (tmp_path / "w.trc").write_text(mirror_trc_text(walk.read_text()))
        (tmp_path / "s.trc").write_text(mirror_trc_text(static.read_text()))
        walk, static = tmp_path / "w.trc", tmp_path / "s.trc"
    out = tmp_path / "out"
    run_analyze([walk], out=out, static=static, static_window=window,
                names="opensim:rajagopal", plots=False)  # fmt: skip
    c = compare_with_ik(out / "angles.mot", shared_data / f"{RAJ}OpenSimIK_walk.mot",
                        mirrored=how == "mirrored")  # fmt: skip
    missed = [m for m in arm_trunk_failures(c) if m.startswith(("arm_", "elbow_"))]
    side = "r" if how == "mirrored" else "l"  # the mirrored walk's left elbow is the right's
    assert [m for m in missed if not m.startswith(f"elbow_flex_{side}: |offset|")] == []
    assert abs(c[f"elbow_flex_{side}"]["offset_deg"]) < 5.5  # degrees: the margin, above
    assert c["lumbar_extension"]["r"] >= 0.8


def test_hinge_axis_recovers_the_flexion_axis(rng: np.random.Generator) -> None:
    """A forearm turned about the humerus's Z by a, at a carrying angle b: the hinge axis from
    the two long axes and b is that Z, and the humerus frame built on it reads a back."""
    from kinefuse.biomech.anatomical import hinge_axis, humerus_from_forearm, jcs_zxy
    from kinefuse.core.geometry.rotations import rot_x, rot_z

    for _ in range(20):
        hum = rot_z(rng.uniform(-1, 1)) @ rot_x(rng.uniform(-1, 1))
        a, b = rng.uniform(np.radians(30), np.radians(140)), rng.uniform(-0.25, 0.25)
        fore = hum @ rot_z(a) @ rot_x(b)
        axis, w = hinge_axis(hum[:, 1], fore[:, 1], b)
        np.testing.assert_allclose(axis, hum[:, 2], atol=1e-9)
        assert w[0] == 1.0
        # the carried Z 40 deg off about the long axis: the hinge takes over
        off = hum @ np.array(
            [[np.cos(0.7), 0, np.sin(0.7)], [0, 1, 0], [-np.sin(0.7), 0, np.cos(0.7)]]
        )
        got = humerus_from_forearm(off, fore[:, 1], b)
        assert float(jcs_zxy(got, fore)[0]) == pytest.approx(a, abs=1e-9)
    # a straight elbow: no axis, the carried one stays
    hum = np.eye(3)
    _, w = hinge_axis(hum[:, 1], hum[:, 1], 0.0)
    assert w[0] == 0.0
    np.testing.assert_allclose(humerus_from_forearm(hum, hum[:, 1]), hum, atol=1e-12)
