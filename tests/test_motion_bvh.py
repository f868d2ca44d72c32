"""BVH reader: forward kinematics against an independent implementation, T-pose frames, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kinefuse.errors import MotionFormatError
from kinefuse.formats.motion import parse_bvh, read_bvh

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "motion" / "cmu"
CLIP_131 = DATA / "131_01_scaled_metres.bvh"
needs_data = pytest.mark.skipif(
    not CLIP_131.is_file(), reason=f"real motion data not found at {DATA}"
)

SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Chest
  {
    OFFSET 0 10 0
    CHANNELS 6 Xrotation Yrotation Zrotation Xposition Yposition Zposition
    End Site
    {
      OFFSET 0 5 1
    }
  }
  JOINT Leg
  {
    OFFSET 2 -3 0
    CHANNELS 3 Yrotation Xrotation Zrotation
    End Site
    {
      OFFSET 0 -4 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
@F0@
@F1@
"""


def _small(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    frames = rng.uniform(-60, 60, size=(2, 15))
    frames[:, :3] = rng.uniform(-5, 5, size=(2, 3))
    frames[:, 9:12] = rng.uniform(-2, 12, size=(2, 3))
    text = SMALL.replace("@F0@", " ".join(repr(float(v)) for v in frames[0]))
    text = text.replace("@F1@", " ".join(repr(float(v)) for v in frames[1]))
    return text, frames


def _expected(frames: np.ndarray) -> np.ndarray:
    """Joint positions by scipy (intrinsic uppercase sequences: 'ZXY' gives Rz @ Rx @ Ry)."""
    out = []
    for f in frames:
        root = f[:3]
        r_root = Rotation.from_euler("ZXY", f[3:6], degrees=True).as_matrix()
        r_chest = Rotation.from_euler("XYZ", f[6:9], degrees=True).as_matrix()
        chest = root + r_root @ f[9:12]  # position channels replace the offset
        chest_end = chest + r_root @ r_chest @ np.array([0.0, 5.0, 1.0])
        r_leg = Rotation.from_euler("YXZ", f[12:15], degrees=True).as_matrix()
        leg = root + r_root @ np.array([2.0, -3.0, 0.0])
        leg_end = leg + r_root @ r_leg @ np.array([0.0, -4.0, 0.0])
        out.append([root, chest, chest_end, leg, leg_end])
    return np.array(out)


def test_forward_kinematics_matches_scipy_for_any_channel_order() -> None:
    rng = np.random.default_rng(1)
    for _ in range(5):
        text, frames = _small(rng)
        m = parse_bvh(text, drop_tpose=False)
        assert m.names == ("Hips", "Chest", "Chest/End", "Leg", "Leg/End")
        assert m.parents == (-1, 0, 1, 0, 3)
        np.testing.assert_allclose(m.positions, _expected(frames), atol=1e-12)  # exact
        assert m.rate_hz == 30.0  # 0.0333333 s snapped to 30 Hz


def test_values_are_read_as_float64() -> None:
    text, frames = _small(np.random.default_rng(2))
    frames[0, 0] = 0.123456789012345678
    line = " ".join(repr(float(v)) for v in frames[0])
    text = text.splitlines()
    text[-2] = line
    m = parse_bvh("\n".join(text), drop_tpose=False)
    assert m.positions.dtype == np.float64
    assert m.positions[0, 0, 0] == 0.123456789012345678


def test_braces_on_the_name_line_and_lowercase_keywords() -> None:
    text = (
        "HIERARCHY\nROOT a {\n offset 0 0 0\n channels 3 xposition yposition zposition\n"
        " JOINT b { OFFSET 1 0 0 CHANNELS 1 Zrotation End Site { OFFSET 1 0 0 } }\n}\n"
        "MOTION\nFrames: 1\nFrame Time: 0.01\n0 0 0 90\n"
    )
    m = parse_bvh(text)
    np.testing.assert_allclose(m.positions[0, 2], [1.0, 1.0, 0.0], atol=1e-12)  # exact
    assert m.rate_hz == 100.0


@needs_data
def test_inserted_tpose_frame_is_detected_and_dropped() -> None:
    lines = CLIP_131.read_text().splitlines()
    first = lines.index("MOTION") + 3
    real = lines[first].split()
    tpose = real[:3] + ["0"] * (len(real) - 3)  # same root position, all rotations zero
    n = int(lines[first - 2].split()[1])
    with_t = [*lines[: first - 2], f"Frames: {n + 1}", lines[first - 1], " ".join(tpose)]
    with_t += lines[first:]
    original = read_bvh(CLIP_131)
    assert original.notes == ()  # a real first frame is kept
    m = parse_bvh("\n".join(with_t), path="x.bvh")
    assert m.n_frames == n
    assert "dropped leading frame(s) 0" in m.notes[0]
    np.testing.assert_array_equal(m.positions, original.positions)
    kept = parse_bvh("\n".join(with_t), path="x.bvh", drop_tpose=False)
    assert kept.n_frames == n + 1 and kept.notes == ()


def _fails(text: str, line: int, *fragments: str) -> None:
    with pytest.raises(MotionFormatError) as e:
        parse_bvh(text, path="bad.bvh")
    msg = str(e.value)
    assert msg.startswith(f"bad.bvh:{line}: "), msg
    assert e.value.line == line and e.value.path == "bad.bvh"
    for f in fragments:
        assert f in msg, msg


def test_truncated_and_garbage_files_fail_with_the_line() -> None:
    text, _ = _small(np.random.default_rng(3))
    lines = text.splitlines()
    motion = lines.index("MOTION") + 1  # 1-based line of MOTION
    # cut in the middle of the last frame line
    cut = "\n".join(lines[:-1]) + "\n" + " ".join(lines[-1].split()[:7])
    _fails(cut, len(lines), "frame 2 has 7 values, expected 15")
    # cut cleanly after the first frame
    _fails("\n".join(lines[:-1]), len(lines), "'Frames: 2'", "only 1 frame lines were found")
    # a value that is not a number
    bad = lines.copy()
    bad[-1] = bad[-1].replace(bad[-1].split()[4], "1.2.3", 1)
    _fails("\n".join(bad), len(lines), "value 5 of this frame, '1.2.3', is not a number")
    # a missing closing brace: the root is still open when MOTION comes
    no_brace = lines.copy()
    del no_brace[motion - 2]
    _fails("\n".join(no_brace), motion - 1, "joint 'Hips' opened at line 3", "'}' is missing")
    # extra frame lines
    _fails(text + lines[-1] + "\n", len(lines) + 1, "more frame lines than 'Frames: 2'")
    # an unknown channel name
    _fails(
        text.replace("Yrotation Xrotation Zrotation", "Yrotation Wrotation Zrotation"),
        18,
        "unknown channel 'Wrotation' of joint 'Leg'",
    )
    # a bad Frame Time, a bad Frames count
    _fails(text.replace("Frame Time: 0.0333333", "Frame Time: fast"), motion + 2, "Frame Time")
    _fails(text.replace("Frames: 2", "Frames: two"), motion + 1, "whole number")
    # garbage
    _fails("hello world\n", 1, "expected 'HIERARCHY', got 'hello'")
    _fails("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 zero 0\n", 4, "OFFSET y of 'Hips'", "'zero'")
    _fails("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n", 4, "a '}' is missing", "end of the file")
    _fails("", 1, "expected 'HIERARCHY', reached the end of the file")


def test_truncated_real_file_names_the_line(tmp_path: Path) -> None:
    if not CLIP_131.is_file():
        pytest.skip(f"real motion data not found at {DATA}")
    data = CLIP_131.read_bytes()
    cut = tmp_path / "cut.bvh"
    cut.write_bytes(data[: len(data) // 2])
    n_lines = data[: len(data) // 2].count(b"\n") + 1
    with pytest.raises(MotionFormatError) as e:
        read_bvh(cut)
    assert e.value.line == n_lines, str(e.value)
    assert str(cut) in str(e.value)
    with pytest.raises(MotionFormatError, match="cannot read the file"):
        read_bvh(tmp_path / "missing.bvh")


def test_channel_count_and_duplicate_names() -> None:
    bad = SMALL.replace("CHANNELS 3 Yrotation", "CHANNELS 7 Yrotation")
    _fails(bad, 18, "CHANNELS count of 'Leg' must be 0 to 6")
    dup = SMALL.replace("JOINT Leg", "JOINT Chest")
    _fails(dup.replace("@F0@", "0 " * 15).replace("@F1@", "0 " * 15), 1, "repeated: Chest")
