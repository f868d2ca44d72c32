"""Every real CMU clip (BVH and ASF/AMC) becomes a plausible Kinect v2 skeleton in the lab.

Each file is parsed once per module (the 2751-frame 01_01 clips included).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.skeleton import JOINT_INDEX, JOINTS
from kinefuse.formats.motion import (
    Motion,
    SourceMotion,
    estimate_height_m,
    find_asf_for,
    place,
    read_amc,
    read_bvh,
    retarget,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "motion" / "cmu"
pytestmark = pytest.mark.skipif(
    not (DATA / "01_01.bvh").is_file(), reason=f"real motion data not found at {DATA}"
)
ASF_UNIT_M = 0.0254 / 0.45  # CMU: ':units length 0.45' -> file unit = 1/0.45 inch


@pytest.fixture(scope="module")
def sources() -> dict[str, SourceMotion]:
    out: dict[str, SourceMotion] = {}
    for p in sorted(DATA.glob("*.bvh")):
        out[p.name] = read_bvh(p)
    for p in sorted(DATA.glob("*.amc")):
        out[p.name] = read_amc(p, find_asf_for(p))
    return out


@pytest.fixture(scope="module")
def motions(sources: dict[str, SourceMotion]) -> dict[str, Motion]:
    return {name: retarget(src) for name, src in sources.items()}


def _bone(p: np.ndarray, a: str, b: str) -> np.ndarray:
    return np.linalg.norm(p[:, JOINT_INDEX[a]] - p[:, JOINT_INDEX[b]], axis=-1)


#: Plausible ranges (metres) of Kinect-joint distances for an adult; CMU conversions shorten the
#: forearm (the BVHs lack the ASF's 'lwrist' bone) and the trunk (they lack 'thorax').
PLAUSIBLE_M = {
    ("HipLeft", "KneeLeft"): (0.35, 0.50),  # femur
    ("HipRight", "KneeRight"): (0.35, 0.50),
    ("KneeLeft", "AnkleLeft"): (0.33, 0.48),  # tibia
    ("KneeRight", "AnkleRight"): (0.33, 0.48),
    ("ShoulderLeft", "ElbowLeft"): (0.22, 0.36),  # humerus
    ("ShoulderRight", "ElbowRight"): (0.22, 0.36),
    ("ElbowLeft", "WristLeft"): (0.17, 0.32),  # forearm
    ("ElbowRight", "WristRight"): (0.17, 0.32),
    ("AnkleLeft", "FootLeft"): (0.08, 0.18),
    ("AnkleRight", "FootRight"): (0.08, 0.18),
    ("WristLeft", "HandLeft"): (0.04, 0.12),
    ("HandLeft", "HandTipLeft"): (0.04, 0.12),
    ("HipLeft", "HipRight"): (0.12, 0.35),
    ("ShoulderLeft", "ShoulderRight"): (0.25, 0.50),
    ("SpineBase", "SpineShoulder"): (0.30, 0.65),
    ("SpineShoulder", "Head"): (0.10, 0.35),
}


def test_every_clip_loads_with_a_plausible_body(motions: dict[str, Motion]) -> None:
    assert set(motions) == {
        "01_01.bvh",
        "131_01_scaled_metres.bvh",
        "01_01.amc",
        "02_walk_a.amc",
        "02_walk_b.amc",
    }
    for name, m in motions.items():
        p = m.positions
        assert p.shape[1:] == (25, 3) and np.isfinite(p).all(), name
        assert m.rate_hz == 120.0, name
        assert 1.5 <= estimate_height_m(p) <= 1.9, name
        for (a, b), (lo, hi) in PLAUSIBLE_M.items():
            length = _bone(p, a, b)
            assert lo <= np.median(length) <= hi, (name, a, b, np.median(length))
        # bones taken from one rigid source bone keep their length (to the file's digits)
        for a, b in [
            ("HipLeft", "KneeLeft"),
            ("KneeRight", "AnkleRight"),
            ("ShoulderLeft", "ElbowLeft"),
        ]:
            assert np.ptp(_bone(p, a, b)) < 1e-4, (name, a, b)  # 0.1 mm
        # the head is above the pelvis, the pelvis above the knees (upright, z up)
        j = JOINT_INDEX
        assert np.median(p[:, j["Head"], 2] - p[:, j["SpineBase"], 2]) > 0.4, name
        assert np.median(p[:, j["SpineBase"], 2] - p[:, j["KneeLeft"], 2]) > 0.3, name
        # only the hand tips are synthesized from these rich skeletons
        assert [JOINTS[i] for i in np.flatnonzero(m.synthesized)] == ["HandTipLeft", "HandTipRight"]


def test_units_and_maps_are_found(motions: dict[str, Motion]) -> None:
    src = {k: m.source for k, m in motions.items()}
    assert "map cgspeed" in src["01_01.bvh"] and "units asf (auto" in src["01_01.bvh"]
    assert "map cmu-bvh11" in src["131_01_scaled_metres.bvh"]
    assert "units m (auto" in src["131_01_scaled_metres.bvh"]
    for amc in ("01_01.amc", "02_walk_a.amc", "02_walk_b.amc"):
        assert "map acclaim" in src[amc] and "units asf (auto" in src[amc], src[amc]
        assert "01.asf" in src[amc] or "02.asf" in src[amc]
    assert "dropped leading frame(s) 0 (an inserted T-pose)" in src["01_01.bvh"]


def test_feet_stand_on_the_floor_after_place(motions: dict[str, Motion]) -> None:
    j = JOINT_INDEX
    feet = [j["FootLeft"], j["FootRight"]]
    for name, m in motions.items():
        q = place(m, (0.5, -1.0), 90.0)
        low = q.positions[:, feet, 2].min(axis=1)  # lowest foot joint per frame
        one_s = int(m.rate_hz) + 1
        # during the first second the lower foot stays within 5 cm of the floor
        assert low[:one_s].min() >= -0.05 and np.median(low[:one_s]) <= 0.06, name
        # and over the clip (walks, jumps, CMU's slightly tilted floor) the feet come back to it
        assert -0.05 <= np.percentile(low, 5) <= 0.06, (name, np.percentile(low, 5))
        assert 0.75 <= q.positions[0, j["SpineBase"], 2] <= 1.1, name


def test_bvh_and_amc_of_01_01_agree(
    sources: dict[str, SourceMotion], motions: dict[str, Motion]
) -> None:
    """Both files are conversions of one capture. The BVH (cgspeed/fairmotion) drops two ASF
    bones, 'thorax' (2.065 units = 11.66 cm) and 'lwrist'/'rwrist' (5.6 cm wrist offsets); with
    those accounted for the two agree to the BVH's 4 decimals."""
    a, b = sources["01_01.amc"], sources["01_01.bvh"]
    assert a.n_frames == b.n_frames == 2751  # the BVH's inserted T-pose was dropped
    ia, ib = a.index(), b.index()

    def diff_m(x: str, y: str, minus: np.ndarray | float = 0.0) -> float:
        d = a.positions[:, ia[x]] - minus - b.positions[:, ib[y]]
        return float(np.abs(d).max() * ASF_UNIT_M)

    same = [("root", "Hips"), ("lfemur", "LeftUpLeg"), ("ltibia", "LeftLeg"), ("lfoot", "LeftFoot")]
    same += [("rtoes/End", "RightToeBase/End"), ("upperback", "Spine"), ("thorax", "Spine1")]
    for x, y in same:
        assert diff_m(x, y) < 1e-5, (x, y)  # 0.01 mm
    thorax = a.positions[:, ia["lowerneck"]] - a.positions[:, ia["thorax"]]
    np.testing.assert_allclose(np.linalg.norm(thorax, axis=-1) * ASF_UNIT_M, 0.1166, atol=1e-4)
    assert diff_m("head/End", "Head/End") > 0.1  # the upper body differs by the thorax ...
    for x, y in [("head/End", "Head/End"), ("lhumerus", "LeftArm"), ("rradius", "RightForeArm")]:
        assert diff_m(x, y, thorax) < 1e-5, (x, y)  # ... and only by it: 0.01 mm
    wrist = a.positions[:, ia["lhand"]] - a.positions[:, ia["lwrist"]]
    assert diff_m("lfingers/End", "LFingers/End", thorax + wrist) < 1e-5  # 0.01 mm
    # on the Kinect joints: the legs and lower spine agree exactly
    ka, kb = motions["01_01.amc"].positions, motions["01_01.bvh"].positions
    for name in ("SpineBase", "SpineMid", "HipLeft", "KneeRight", "AnkleLeft", "FootRight"):
        j = JOINT_INDEX[name]
        assert np.abs(ka[:, j] - kb[:, j]).max() < 1e-5, name  # 0.01 mm


def test_explicit_units_scale_the_motion(
    sources: dict[str, SourceMotion], motions: dict[str, Motion]
) -> None:
    src = sources["131_01_scaled_metres.bvh"]
    cm = retarget(src, units="cm")
    auto = motions["131_01_scaled_metres.bvh"]
    real = ~auto.synthesized
    np.testing.assert_allclose(cm.positions[:, real], auto.positions[:, real] * 0.01, atol=1e-12)
    assert "units cm (given)" in cm.source
