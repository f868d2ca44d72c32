"""load_motion: dispatch on the extension, the ASF of an AMC clip, name maps by name or file."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from kinefuse.errors import InputError, MotionFormatError, RetargetError
from kinefuse.formats.motion import BUILTIN_MAPS, find_asf_for, load_motion, load_name_map

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "motion" / "cmu"
needs_data = pytest.mark.skipif(
    not (DATA / "02.asf").is_file(), reason=f"real motion data not found at {DATA}"
)


def _touch(folder: Path, *names: str) -> None:
    for n in names:
        (folder / n).write_text("")


def test_find_asf_for_uses_the_subject_prefix_else_the_only_asf(tmp_path: Path) -> None:
    _touch(tmp_path, "11_01.amc", "11.asf", "02.asf", "02_walk_a.amc")
    assert find_asf_for(tmp_path / "11_01.amc") == tmp_path / "11.asf"
    assert find_asf_for(tmp_path / "02_walk_a.amc") == tmp_path / "02.asf"
    only = tmp_path / "only"
    only.mkdir()
    _touch(only, "07_03.amc", "subject.ASF")
    assert find_asf_for(only / "07_03.amc") == only / "subject.ASF"
    with pytest.raises(InputError) as e:
        find_asf_for(tmp_path / "35_01.amc")
    msg = str(e.value)
    assert "expected 35.asf beside it or a single .asf" in msg
    assert "found: 02.asf, 11.asf" in msg and "skeleton=" in msg
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match=r"\(found: none\)"):
        find_asf_for(empty / "01_01.amc")


@needs_data
def test_load_amc_finds_its_skeleton_and_accepts_an_explicit_one(tmp_path: Path) -> None:
    m = load_motion(DATA / "02_walk_a.amc")
    assert m.n_frames == 298 and "02.asf" in m.source and "map acclaim" in m.source
    # an explicit skeleton, from another folder and name
    shutil.copy(DATA / "02_walk_a.amc", tmp_path / "walk.amc")
    shutil.copy(DATA / "02.asf", tmp_path / "subject_two.asf")
    _touch(tmp_path, "other.asf")
    with pytest.raises(InputError, match="cannot find its ASF skeleton"):
        load_motion(tmp_path / "walk.amc")
    m2 = load_motion(tmp_path / "walk.amc", skeleton=tmp_path / "subject_two.asf")
    np.testing.assert_array_equal(m2.positions, m.positions)
    with pytest.raises(InputError, match="no such ASF skeleton file"):
        load_motion(tmp_path / "walk.amc", skeleton=tmp_path / "none.asf")
    # the rate of an AMC clip (not in the file) can be given
    assert load_motion(DATA / "02_walk_a.amc", amc_rate_hz=60.0).rate_hz == 60.0


@needs_data
def test_name_map_by_shipped_name_or_toml(tmp_path: Path) -> None:
    clip = DATA / "131_01_scaled_metres.bvh"
    auto = load_motion(clip)
    by_name = load_motion(clip, name_map="cmu-bvh11")
    np.testing.assert_array_equal(by_name.positions, auto.positions)
    assert load_motion(clip, name_map=BUILTIN_MAPS["cmu-bvh11"]).source == by_name.source
    toml = tmp_path / "m.toml"
    toml.write_text('extends = "cmu-bvh11"\n[joints]\nSpineMid = "Chest"\n')
    m = load_motion(clip, name_map=toml)
    assert "map m (" in m.source
    assert not np.allclose(m.positions[:, 1], auto.positions[:, 1])
    with pytest.raises(InputError, match=r"neither a shipped map .* nor a TOML file"):
        load_motion(clip, name_map="maya")
    # a shipped map that does not fit this skeleton
    with pytest.raises(RetargetError, match="With the name map 'acclaim' \\(built-in\\)"):
        load_motion(clip, name_map="acclaim")


def test_bad_paths_and_extensions(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such motion file"):
        load_motion(tmp_path / "none.bvh")
    (tmp_path / "clip.fbx").write_text("x")
    with pytest.raises(
        InputError, match=re.escape("unknown motion format '.fbx'; kinefuse reads .bvh and .amc")
    ):
        load_motion(tmp_path / "clip.fbx")
    (tmp_path / "clip.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    with pytest.raises(InputError, match=re.escape("skeleton= is for .amc clips")):
        load_motion(tmp_path / "clip.bvh", skeleton=tmp_path / "x.asf")
    with pytest.raises(MotionFormatError, match=r"clip\.bvh:3: .*'}' is missing"):
        load_motion(tmp_path / "clip.bvh")


def test_the_documented_toml_example_is_a_valid_map(tmp_path: Path) -> None:
    docs = Path(__file__).resolve().parents[1] / "docs" / "motion.md"
    block = re.search(r"```toml\n(.*?)```", docs.read_text(), re.DOTALL)
    assert block is not None, "docs/motion.md has no toml example"
    path = tmp_path / "my_rig.toml"
    path.write_text(block.group(1))
    m = load_name_map(path)
    assert m.name == "my-rig" and len(m.joints) == 25  # extends the mixamo map
    assert m.joints["ThumbRight"] == ((("thumb_03_r/End", 1.5), ("thumb_03_r", -0.5)),)
    assert m.joints["FootLeft"] == ((("ball_l", 1.0),), (("foot_l/End", 1.0),))
    assert m.joints["HandTipLeft"] == ((("middle_03_l/End", 1.0),),)
