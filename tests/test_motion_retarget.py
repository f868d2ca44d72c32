"""Retargeting: shipped maps for other namings, user TOML maps, unmappable skeletons, synthesis,
units, resampling and placement."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from kinefuse.core.skeleton import JOINT_INDEX, JOINTS
from kinefuse.errors import InputError, RetargetError
from kinefuse.formats.motion import (
    BUILTIN_MAPS,
    Motion,
    SourceMotion,
    estimate_height_m,
    facing_direction,
    load_name_map,
    parse_bvh,
    parse_name_map,
    place,
    resample,
    retarget,
)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "motion" / "cmu"
CLIP = DATA / "131_01_scaled_metres.bvh"
needs_data = pytest.mark.skipif(not CLIP.is_file(), reason=f"real motion data not found at {DATA}")
J = JOINT_INDEX
_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # world <- y-up source

MIXAMO = {
    "LeftHip": "LeftUpLeg", "LeftKnee": "LeftLeg", "LeftAnkle": "LeftFoot",
    "LeftToe": "LeftToeBase", "lowerback": "Spine", "Chest": "Spine1", "Chest2": "Spine2",
    "LeftCollar": "LeftShoulder", "LeftShoulder": "LeftArm", "LeftElbow": "LeftForeArm",
    "LeftWrist": "LeftHand", "lhand": "LeftHandIndex0", "LFingers": "LeftHandMiddle1",
    "LThumb": "LeftHandThumb1",
}  # fmt: skip
BIOVISION = {
    "LeftShoulder": "LeftUpArm", "LeftElbow": "LeftLowArm", "LeftWrist": "LeftHand",
    "lhand": "LeftPalm", "LFingers": "LeftFingers", "LThumb": "LeftThumb",
}  # fmt: skip


def _both_sides(m: dict[str, str]) -> dict[str, str]:
    out = dict(m)
    for k, v in m.items():
        rk = (
            k.replace("Left", "Right")
            .replace("lhand", "rhand")
            .replace("LF", "RF")
            .replace("LT", "RT")
        )
        out[rk] = v.replace("Left", "Right")
    return out


def _renamed(text: str, mapping: dict[str, str], prefix: str = "") -> str:
    """The BVH with its ROOT/JOINT names replaced (all at once) and prefixed."""

    def sub(m: re.Match[str]) -> str:
        return m.group(1) + prefix + mapping.get(m.group(2), m.group(2))

    return re.sub(r"^(\s*(?:ROOT|JOINT)\s+)(\S+)", sub, text, flags=re.MULTILINE)


@pytest.fixture(scope="module")
def text() -> str:
    if not CLIP.is_file():
        pytest.skip(f"real motion data not found at {DATA}")
    return CLIP.read_text()


@pytest.fixture(scope="module")
def reference(text: str) -> Motion:
    return retarget(parse_bvh(text, path="131.bvh"))


def _same(a: Motion, b: Motion, names: list[str]) -> None:
    for n in names:
        np.testing.assert_allclose(a.positions[:, J[n]], b.positions[:, J[n]], atol=1e-12)  # exact


CORE_SAME = ["SpineBase", "SpineShoulder", "Neck", "Head", "ShoulderLeft", "ElbowRight",
             "WristLeft", "HipRight", "KneeLeft", "AnkleRight", "FootLeft"]  # fmt: skip


@pytest.mark.parametrize("prefix", ["", "mixamorig:"])
def test_mixamo_naming_is_recognized(text: str, reference: Motion, prefix: str) -> None:
    m = retarget(parse_bvh(_renamed(text, _both_sides(MIXAMO), prefix), path="mixamo.bvh"))
    assert "map mixamo" in m.source
    _same(m, reference, CORE_SAME)
    synth = {JOINTS[i] for i in np.flatnonzero(m.synthesized)}
    assert synth == {"HandTipLeft", "HandTipRight", "ThumbLeft", "ThumbRight"}


def test_classic_biovision_naming_is_recognized(text: str, reference: Motion) -> None:
    m = retarget(parse_bvh(_renamed(text, _both_sides(BIOVISION)), path="bio.bvh"))
    assert "map biovision" in m.source
    _same(m, reference, ["SpineBase", "ShoulderLeft", "ElbowLeft", "WristRight", "KneeLeft"])
    synth = {JOINTS[i] for i in np.flatnonzero(m.synthesized)}
    hands = {f"{k}{s}" for k in ("Hand", "HandTip", "Thumb", "Foot") for s in ("Left", "Right")}
    assert synth == hands
    # synthesized hands and feet land near where the real skeleton has them
    for n, tol in [
        ("HandLeft", 0.06),
        ("HandRight", 0.06),
        ("FootLeft", 0.09),
        ("FootRight", 0.09),
    ]:
        d = np.linalg.norm(m.positions[:, J[n]] - reference.positions[:, J[n]], axis=-1)
        assert np.median(d) < tol, (n, np.median(d))  # metres


def _unknown(text: str) -> str:
    names = re.findall(r"^\s*(?:ROOT|JOINT)\s+(\S+)", text, flags=re.MULTILINE)
    return _renamed(text, {n: f"J{i:02d}" for i, n in enumerate(names)})


def test_unknown_naming_fails_listing_the_joints_and_a_map_to_write(
    text: str, reference: Motion, tmp_path: Path
) -> None:
    src = parse_bvh(_unknown(text), path="odd.bvh")
    with pytest.raises(RetargetError) as e:
        retarget(src)
    msg = str(e.value)
    assert "cannot map the skeleton of odd.bvh" in msg
    assert "could not map" in msg and "HipLeft" in msg and "ElbowRight" in msg
    assert "Source joints seen (31): J00, J01, J02" in msg
    assert "docs/motion.md" in msg
    snippet = msg.split("A minimal map:\n", 1)[1]
    parsed = tomllib.loads(snippet)  # the example is valid TOML
    assert set(parsed["joints"]) >= {"SpineBase", "HipLeft", "AnkleRight", "Head"}
    # filling in the blanks gives a working map
    names = re.findall(r"^\s*(?:ROOT|JOINT)\s+(\S+)", text, flags=re.MULTILINE)
    code = {n: f"J{i:02d}" for i, n in enumerate(names)}
    bvh11 = BUILTIN_MAPS["cmu-bvh11"].joints
    lines = ["[joints]"]
    for joint in parsed["joints"]:
        src_name = bvh11[joint][0][0][0]  # the first source joint of the shipped entry
        lines.append(f'{joint} = "{code[src_name]}"')
    path = tmp_path / "odd.toml"
    path.write_text("\n".join(lines) + "\n")
    m = retarget(src, name_map=load_name_map(path))
    assert "map odd" in m.source
    _same(m, reference, ["SpineBase", "ShoulderLeft", "ElbowLeft", "WristRight", "KneeLeft"])


def test_a_user_toml_map_with_every_spec_form(text: str, reference: Motion, tmp_path: Path) -> None:
    names = re.findall(r"^\s*(?:ROOT|JOINT)\s+(\S+)", text, flags=re.MULTILINE)
    c = {n: f"J{i:02d}" for i, n in enumerate(names)}
    pairs = [("Shoulder", "{s}Shoulder"), ("Elbow", "{s}Elbow"), ("Wrist", "{s}Wrist")]
    pairs += [("Hip", "{s}Hip"), ("Knee", "{s}Knee"), ("Ankle", "{s}Ankle")]
    limbs = [f'{k}{s} = "{c[v.format(s=s)]}"' for k, v in pairs for s in ("Left", "Right")]
    path = tmp_path / "full.toml"
    path.write_text(
        f"""name = "odd-rig"
[joints]
SpineBase = "{c["Hips"]}"
SpineMid = {{ blend = {{ {c["Chest"]} = 0.25, {c["Chest2"]} = 0.75 }} }}
Head = {{ mean = ["{c["Head"]}", "{c["Head"]}/End"] }}
HandLeft = {{ end_site = "{c["LFingers"]}" }}
FootLeft = ["NoSuchToe", "{c["LeftToe"]}"]
"""
        + "\n".join(limbs)
        + "\n"
    )
    src = parse_bvh(_unknown(text), path="odd.bvh")
    m = retarget(src, name_map=load_name_map(path))
    ref_src = parse_bvh(text)
    ix = ref_src.index()
    p = ref_src.positions
    np.testing.assert_allclose(
        m.positions[:, J["SpineMid"]],
        (0.25 * p[:, ix["Chest"]] + 0.75 * p[:, ix["Chest2"]]) @ _AXES.T,
        atol=1e-12,  # exact
    )
    _same(m, reference, ["Head", "HandLeft", "FootLeft", "SpineBase", "KneeRight"])
    synth = {JOINTS[i] for i in np.flatnonzero(m.synthesized)}
    assert synth == {"SpineShoulder", "Neck", "HandRight", "HandTipLeft", "HandTipRight",
                     "ThumbLeft", "ThumbRight", "FootRight"}  # fmt: skip
    assert "map odd-rig" in m.source and str(path) in m.source


def test_extends_overrides_a_shipped_map(text: str, reference: Motion, tmp_path: Path) -> None:
    path = tmp_path / "ext.toml"
    path.write_text('extends = "cmu-bvh11"\n[joints]\nHead = "Head"\n')
    m = retarget(parse_bvh(text), name_map=load_name_map(path))
    src = parse_bvh(text)
    np.testing.assert_allclose(
        m.positions[:, J["Head"]], src.positions[:, src.index()["Head"]] @ _AXES.T, atol=1e-12
    )  # exact
    _same(m, reference, ["Neck", "HandLeft", "ThumbRight"])


def test_bad_user_maps_fail_clearly(tmp_path: Path) -> None:
    cases = [
        ('bad = "toml', "not valid TOML"),
        ('name = "x"\n', "no [joints] table"),
        (
            '[joints]\nElbowleft = "A"\n',
            "'Elbowleft' is not a Kinect v2 joint; the 25 names are: SpineBase",
        ),
        (
            "[joints]\nHead = { blend = { A = 0.5, B = 0.6 } }\n",
            "blend weights must add up to 1, they add up to 1.1",
        ),
        (
            '[joints]\nHead = { blend = { A = "x", B = 1.0 } }\n',
            "blend weight of 'A' must be a number",
        ),
        ("[joints]\nHead = 3\n", "cannot read 3"),
        ('[joints]\nHead = { mean = "A" }\n', "mean must be a list of joint names"),
        (
            '[joints]\nHead = { end_site = "A", mean = ["B"] }\n',
            "exactly one of end_site, mean, blend",
        ),
        ('[joints]\nHead = [["A"]]\n', "alternatives cannot be nested lists"),
        (
            'extends = "maya"\n[joints]\nHead = "A"\n',
            "'maya' is not a shipped map; choose one of cgspeed",
        ),
        ('colour = 1\n[joints]\nHead = "A"\n', "unknown keys ['colour']"),
    ]
    for i, (body, fragment) in enumerate(cases):
        p = tmp_path / f"m{i}.toml"
        p.write_text(body)
        with pytest.raises(InputError) as e:
            load_name_map(p)
        assert fragment in str(e.value), (body, str(e.value))
        assert str(p) in str(e.value)
    with pytest.raises(InputError, match="cannot read the name map"):
        load_name_map(tmp_path / "missing.toml")


def test_unit_that_fits_no_rule_fails_listing_heights(text: str) -> None:
    src = parse_bvh(text, path="big.bvh")
    big = SourceMotion(src.names, src.parents, src.positions * 7.0, src.rate_hz, "big.bvh", "bvh")
    with pytest.raises(InputError) as e:
        retarget(big)
    msg = str(e.value)
    assert "big.bvh: cannot tell the length unit" in msg
    assert "11.4 m in m" in msg and "0.114 m in cm" in msg and "0.645 m in asf" in msg
    assert "units='cm'" in msg
    with pytest.raises(
        InputError, match="units must be one of 'm', 'cm', 'mm', 'in', 'asf', got 'ft'"
    ):
        retarget(src, units="ft")
    m = retarget(big, units="m")  # an explicit unit is taken as given
    assert estimate_height_m(m.positions) == pytest.approx(7 * 1.632, abs=0.01)


def _standing(rate_hz: float = 30.0, n: int = 60, heading_rad: float = 0.0) -> Motion:
    """A synthetic actor facing ``heading_rad`` from +x, swaying linearly in time."""
    base = np.zeros((25, 3))
    pts = {
        "SpineBase": (0, 0, 1.0), "SpineMid": (0, 0, 1.3), "SpineShoulder": (0, 0, 1.5),
        "Neck": (0, 0, 1.55), "Head": (0, 0, 1.65), "ShoulderLeft": (0, 0.18, 1.45),
        "ElbowLeft": (0, 0.2, 1.15), "WristLeft": (0, 0.2, 0.9), "HandLeft": (0, 0.2, 0.83),
        "ShoulderRight": (0, -0.18, 1.45), "ElbowRight": (0, -0.2, 1.15),
        "WristRight": (0, -0.2, 0.9), "HandRight": (0, -0.2, 0.83), "HipLeft": (0, 0.08, 0.95),
        "KneeLeft": (0, 0.09, 0.52), "AnkleLeft": (0, 0.09, 0.1), "FootLeft": (0.1, 0.09, 0.05),
        "HipRight": (0, -0.08, 0.95), "KneeRight": (0, -0.09, 0.52),
        "AnkleRight": (0, -0.09, 0.1), "FootRight": (0.1, -0.09, 0.05),
        "HandTipLeft": (0, 0.2, 0.75), "ThumbLeft": (0.05, 0.2, 0.85),
        "HandTipRight": (0, -0.2, 0.75), "ThumbRight": (0.05, -0.2, 0.85),
    }  # fmt: skip
    for k, v in pts.items():
        base[J[k]] = v
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    base = base @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    t = np.arange(n) / rate_hz
    pos = base + t[:, None, None] * np.array([0.3, -0.2, 0.0])  # a slow linear drift
    return Motion(positions=pos, rate_hz=rate_hz, source="synthetic")


def test_facing_direction_and_height() -> None:
    for heading in (0.0, 1.0, -2.5):
        m = _standing(heading_rad=heading)
        f = facing_direction(m.positions)
        np.testing.assert_allclose(
            f, np.broadcast_to([np.cos(heading), np.sin(heading), 0], f.shape), atol=1e-12
        )
    leg = 0.5 * ((0.43**2 + 0.01**2) ** 0.5 + 0.42) * 2  # hip-knee + knee-ankle, both sides
    assert estimate_height_m(_standing().positions) == pytest.approx(leg / 0.491)
    with pytest.raises(InputError, match=r"shape \(\.\.\., 25, 3\), got \(3, 24, 3\)"):
        facing_direction(np.zeros((3, 24, 3)))
    with pytest.raises(InputError, match=r"shape \(T, 25, 3\), got \(25, 3\)"):
        estimate_height_m(np.zeros((25, 3)))


def test_resample_is_linear_interpolation_at_any_rate() -> None:
    m = _standing(rate_hz=30.0, n=61)  # 2 s of motion linear in time
    for rate in (120.0, 47.0, 7.5):
        r = resample(m, rate)
        n = int(np.floor(2.0 * rate + 1e-9)) + 1
        assert r.n_frames == n and r.rate_hz == rate
        t = np.arange(n) / rate
        expected = m.positions[0] + t[:, None, None] * np.array([0.3, -0.2, 0.0])
        np.testing.assert_allclose(r.positions, expected, atol=1e-12)  # exact for linear motion
        assert f"resampled 30 -> {rate:g} Hz" in r.source
    for bad in (0, -5.0, float("nan"), True, "30"):
        with pytest.raises(
            InputError, match="rate_hz must be a positive number of frames per second"
        ):
            resample(m, bad)  # type: ignore[arg-type]


@needs_data
def test_resample_real_clip(reference: Motion) -> None:
    r = resample(reference, 30.0)
    assert r.n_frames == 249  # 994 frames at 120 Hz = 8.283 s
    np.testing.assert_allclose(r.positions, reference.positions[::4][:249], atol=1e-12)  # exact
    np.testing.assert_array_equal(r.synthesized, reference.synthesized)


@pytest.mark.parametrize("heading", [0.0, 90.0, -135.0, 200.0])
def test_place_heading_offset_and_floor(reference: Motion, heading: float) -> None:
    q = place(reference, (1.5, -0.5), heading)
    f0 = facing_direction(q.positions[0])
    got = np.degrees(np.arctan2(f0[1], f0[0]))
    assert (got - heading + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-9)  # degrees
    np.testing.assert_allclose(q.positions[0, J["SpineBase"], :2], [1.5, -0.5], atol=1e-12)  # m
    # a rigid motion of the whole clip: all distances kept
    a = reference.positions[100]
    b = q.positions[100]
    np.testing.assert_allclose(
        np.linalg.norm(a[:, None] - a[None], axis=-1),
        np.linalg.norm(b[:, None] - b[None], axis=-1),
        atol=1e-12,  # exact
    )
    # z only shifted: verticals unchanged up to the shift
    dz = q.positions[..., 2] - reference.positions[..., 2]
    assert np.ptp(dz) < 1e-12
    # the feet stand 2 cm above the floor in the first second
    feet = q.positions[:121, [J["FootLeft"], J["FootRight"]], 2]
    assert -0.03 < feet.min() < 0.03 and np.percentile(feet, 10) == pytest.approx(0.02, abs=0.02)


def test_place_synthetic_and_bad_arguments() -> None:
    m = _standing(heading_rad=0.7)
    q = place(m, (0.0, 2.0), 45.0)
    f0 = facing_direction(q.positions[0])
    assert np.degrees(np.arctan2(f0[1], f0[0])) == pytest.approx(45.0, abs=1e-9)
    assert q.positions[:, [J["FootLeft"], J["FootRight"]], 2].min() == pytest.approx(0.02)  # m
    for kwargs, fragment in [
        ({"offset_m": (1.0, 2.0, 3.0)}, "offset_m must be two finite numbers"),
        ({"offset_m": (np.nan, 0.0)}, "offset_m must be two finite numbers"),
        ({"heading_deg": float("inf")}, "heading_deg must be a finite number"),
        ({"floor_window_s": 0.0}, "floor_window_s must be positive"),
    ]:
        with pytest.raises(InputError, match=re.escape(fragment)):
            place(m, **kwargs)  # type: ignore[arg-type]


def test_synthesis_from_a_core_only_skeleton(text: str) -> None:
    """Only the 13 core joints and nothing else: every other joint is synthesized."""
    src = parse_bvh(text)
    core = {
        "Head": "Head", "ShoulderLeft": "LeftShoulder", "ElbowLeft": "LeftElbow",
        "WristLeft": "LeftWrist", "HipLeft": "LeftHip", "KneeLeft": "LeftKnee",
        "AnkleLeft": "LeftAnkle",
    }  # fmt: skip
    core.update({k.replace("Left", "Right"): v.replace("Left", "Right") for k, v in core.items()})
    m = retarget(src, name_map=parse_name_map(core, name="core"))
    assert set(np.flatnonzero(m.synthesized)) == {J[n] for n in JOINTS if n not in core}
    p = m.positions
    s = estimate_height_m(p) / 1.70

    def dist(a: str, b: str) -> np.ndarray:
        return np.linalg.norm(p[:, J[a]] - p[:, J[b]], axis=-1)

    np.testing.assert_allclose(dist("WristLeft", "HandLeft"), 0.075 * s, atol=1e-12)
    np.testing.assert_allclose(dist("HandRight", "HandTipRight"), 0.075 * s, atol=1e-12)
    np.testing.assert_allclose(
        dist("WristLeft", "ThumbLeft"), s * np.hypot(0.045, 0.075), atol=1e-12
    )
    np.testing.assert_allclose(
        dist("AnkleRight", "FootRight"), s * np.hypot(0.09, 0.04), atol=1e-12
    )
    np.testing.assert_allclose(
        p[:, J["SpineBase"]], 0.5 * (p[:, J["HipLeft"]] + p[:, J["HipRight"]]), atol=1e-12
    )
    # the neck lies on the segment SpineShoulder-Head, SpineMid on SpineBase-SpineShoulder
    np.testing.assert_allclose(
        dist("SpineShoulder", "Neck") + dist("Neck", "Head"),
        dist("SpineShoulder", "Head"),
        atol=1e-12,
    )
    # the synthesized feet point forward (the body's heading) and the thumbs away from the wrist
    fwd = facing_direction(p)
    foot = p[:, J["FootLeft"]] - p[:, J["AnkleLeft"]]
    assert np.median((foot * fwd).sum(-1)) > 0.05  # metres forward


def test_partly_mappable_skeleton_gets_a_map_with_the_known_entries(text: str) -> None:
    odd = text.replace("LeftElbow", "LeftLowerArmX").replace("LeftHip", "Lthigh")
    with pytest.raises(RetargetError) as e:
        retarget(parse_bvh(odd, path="odd.bvh"))
    msg = str(e.value)
    assert "The shipped map that fits best, 'cmu-bvh11', finds 21 of 25 Kinect joints." in msg
    assert "could not map (no rule can synthesize them): ElbowLeft, HipLeft." in msg
    assert (
        "ElbowLeft = \"?\"  # left elbow (where the forearm rotates); perhaps 'LeftLowerArmX'?"
        in msg
    )
    snippet = tomllib.loads(msg.split("A minimal map:\n", 1)[1])["joints"]
    assert snippet["Head"] == {"mean": ["Head", "Head/End"]}
    assert snippet["KneeLeft"] == "LeftKnee" and snippet["HipLeft"] == "?"
    # the message names the command-line flag, not the Python argument
    assert "--name-map MAP.toml" in msg and "name_map=" not in msg


def test_suggestions_keep_the_side_and_the_body_part(text: str) -> None:
    # a knee named oddly must not be suggested the collar of its side ("RightCollar" shares
    # most letters with "RightKnee"), nor a knee of the other side
    odd = text.replace("RightKnee", "RKneeJoint").replace("LeftHip", "Lthigh")
    odd = odd.replace("RightKnee", "RKneeJoint")
    with pytest.raises(RetargetError) as e:
        retarget(parse_bvh(odd, path="odd.bvh"))
    lines = {ln.split(" = ")[0]: ln for ln in str(e.value).splitlines() if ' = "?"' in ln}
    assert "KneeRight" in lines and "Collar" not in lines["KneeRight"]
    assert "'RKneeJoint'" in lines["KneeRight"]
    assert "Right" not in lines.get("HipLeft", "")
