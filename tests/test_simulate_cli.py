"""End to end: kinefuse simulate + inspect on real clips, reproducibility, and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.core.skeleton import JOINTS, TrackingState
from kinefuse.formats.store.session_store import SessionStore


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def walk_session(tmp_path_factory, shared_data) -> Path:
    out = tmp_path_factory.mktemp("sim") / "walk.sqlite"
    clip = shared_data / "motion" / "cmu" / "02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--calibration-seconds", "1",
                 "--depth-rate", "5", "--seed", "3", "--out", str(out)]) == 0  # fmt: skip
    return out


def test_inspect_json_has_the_promised_keys(walk_session, capsys) -> None:
    code, out, _ = run(capsys, "inspect", str(walk_session), "--json")
    assert code == 0
    d = json.loads(out)
    assert d["schema_version"] == 1 and d["joints"] == 25 and d["has_truth"] is True
    assert [s["id"] for s in d["sensors"]] == ["k0", "k1", "k2", "k3"]
    for s in d["sensors"]:
        assert s["frames"] > 60 and s["rate_hz"] == pytest.approx(30.0, rel=0.01)
    assert 2.0 < d["duration_s"] < 3.0  # the clip is 2.5 s
    err = d["observation_error_m"]
    assert 0.02 < err["median"] < 0.15 and err["p95"] > err["median"]
    assert set(err["by_joint"]) == set(JOINTS)
    frac = d["tracking_state_fraction"]
    assert sum(frac.values()) == pytest.approx(1.0)
    assert 0.0 <= d["lr_swap_fraction"] <= 1.0


def test_session_contents(walk_session) -> None:
    with SessionStore.open(walk_session) as st:
        meta = st.meta()
        assert meta["calibration_phase_server_s"] == [0.0, 1.0]
        for s in st.sensors():
            o = st.observations(s.id)
            tracked = o.states == TrackingState.NOT_TRACKED
            assert np.isnan(o.joints_m[tracked]).all()
            assert np.isfinite(o.joints_m[~tracked]).all()
            assert st.depth_frame_count(s.id) == 5  # 1 s at 5 Hz
            assert len(st.clock_probes(s.id)) > 0


@pytest.mark.parametrize(
    "clip", ["01_01.bvh", "131_01_scaled_metres.bvh", "01_01.amc", "02_walk_b.amc"]
)
def test_every_cmu_clip_simulates(tmp_path, shared_data, capsys, clip) -> None:
    out = tmp_path / "s.sqlite"
    path = str(shared_data / "motion" / "cmu" / clip)
    code, _, err = run(capsys, "simulate", "--clip", path, "--seconds", "1",
                       "--calibration-seconds", "0", "--out", str(out))  # fmt: skip
    assert code == 0, err
    code, js, _ = run(capsys, "inspect", str(out), "--json")
    assert code == 0
    # the sensor facing the actor's front sees it well; one behind it sees it mirrored
    errors = [s["observation_error_m"] for s in json.loads(js)["sensors"]]
    assert 0.02 < min(e for e in errors if e is not None) < 0.15


def test_same_seed_same_observation_bytes(tmp_path, shared_data) -> None:
    clip = str(shared_data / "motion" / "cmu" / "02_walk_b.amc")
    digests = []
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        out = tmp_path / f"{name}.sqlite"
        assert main(["simulate", "--clip", clip, "--seconds", "1", "--calibration-seconds", "0.5",
                     "--seed", str(seed), "--out", str(out)]) == 0  # fmt: skip
        with SessionStore.open(out) as st:
            digests.append(st.observations_digest())
    assert digests[0] == digests[1]
    assert digests[0] != digests[2]


def test_subject_seed_is_kept_with_the_truth(tmp_path, shared_data) -> None:
    """``--subject-seed`` changes the observations (other joint offsets) and is stored with the
    truth, where only evaluation reads it; without it nothing is stored."""
    clip = str(shared_data / "motion" / "cmu" / "02_walk_b.amc")
    digests, seeds = [], []
    for name, extra in (("plain", []), ("subject", ["--subject-seed", "5"])):
        out = tmp_path / f"{name}.sqlite"
        assert main(["simulate", "--clip", clip, "--seconds", "1", "--calibration-seconds", "0.5",
                     "--seed", "7", "--out", str(out), *extra]) == 0  # fmt: skip
        with SessionStore.open(out) as st:
            digests.append(st.observations_digest())
            seeds.append(st.truth().info("subject_seed"))
    assert digests[0] != digests[1]
    assert seeds == [None, 5]


def test_bad_inputs_fail_clearly(tmp_path, shared_data, capsys) -> None:
    bad = tmp_path / "broken.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition\n")
    code, _, err = run(capsys, "simulate", "--clip", str(bad), "--out", str(tmp_path / "x.sqlite"))
    assert code == 2 and "broken.bvh:" in err
    code, _, err = run(capsys, "simulate", "--clip", str(tmp_path / "none.bvh"),
                       "--out", str(tmp_path / "x.sqlite"))  # fmt: skip
    assert code == 2 and "no such motion file" in err
    clip = str(shared_data / "motion" / "cmu" / "02_walk_a.amc")
    code, _, err = run(capsys, "simulate", "--clip", clip, "--seconds", "99",
                       "--out", str(tmp_path / "x.sqlite"))  # fmt: skip
    assert code == 2 and "longer than the clip" in err
    rig = tmp_path / "rig.toml"
    rig.write_text('[[sensor]]\nid = "a"\nposition_m = [1, 2]\nlook_at_m = [0, 0, 1]\n')
    code, _, err = run(capsys, "simulate", "--clip", clip, "--rig", str(rig),
                       "--out", str(tmp_path / "x.sqlite"))  # fmt: skip
    assert code == 2 and "position_m" in err and "id 'a'" in err
    code, _, err = run(capsys, "inspect", str(tmp_path / "missing.sqlite"))
    assert code == 2 and "does not exist" in err


def test_unknown_naming_lists_unmapped_joints(tmp_path, shared_data, capsys) -> None:
    text = (shared_data / "motion" / "cmu" / "131_01_scaled_metres.bvh").read_text()
    for i, name in enumerate(["LeftHip", "LeftKnee", "LeftAnkle", "RightHip", "RightKnee",
                              "RightAnkle", "LeftShoulder", "RightShoulder"]):  # fmt: skip
        text = text.replace(f"JOINT {name}\n", f"JOINT bone{i:02d}\n")
    odd = tmp_path / "odd.bvh"
    odd.write_text(text)
    code, _, err = run(capsys, "simulate", "--clip", str(odd), "--out", str(tmp_path / "x.sqlite"))
    assert code == 2
    assert "KneeLeft" in err and "docs/motion.md" in err


def test_existing_sessions_are_not_overwritten_by_accident(tmp_path, shared_data, capsys) -> None:
    clip = str(shared_data / "motion" / "cmu" / "02_walk_a.amc")
    out = tmp_path / "s.sqlite"
    args = ["simulate", "--clip", clip, "--seconds", "0.3", "--calibration-seconds", "0",
            "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    code, _, err = run(capsys, *args)
    assert code == 2 and "already exists" in err and "--force" in err
    assert main([*args, "--force"]) == 0
    # a live recording (no truth) is never replaced by a simulation
    live = tmp_path / "live.sqlite"
    with SessionStore.create(live) as st:
        st.set_meta("generator", "a live recording")
    code, _, err = run(capsys, *args[:-1], str(live), "--force")
    assert code == 2 and "without ground truth" in err
    with SessionStore.open(live) as st:
        assert st.meta()["generator"] == "a live recording"
