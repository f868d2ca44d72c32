"""ASF/AMC reader: Acclaim kinematics against an independent implementation, units, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kinefuse.errors import MotionFormatError
from kinefuse.formats.motion import parse_amc, parse_asf, read_amc, read_asf

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "motion" / "cmu"

ASF = """# a two-bone test skeleton
:version 1.10
:name test
:units
  mass 1.0
  length 0.5
  angle deg
:root
  order TX TY TZ RX RY RZ
  axis XYZ
  position 0 0 0
  orientation 0 0 0
:bonedata
  begin
    id 1
    name upper
    direction 0 -1 0
    length 4
    axis 0 0 30 XYZ
    dof rx rz
    limits (-90 90)
           (-90 90)
  end
  begin
    id 2
    name lower
    direction 1 0 0
    length 2
    axis 10 20 0 ZYX
    dof ry
  end
  begin
    id 3
    name fixed
    direction 0 0 1
    length 1
    axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root upper fixed
    upper lower
  end
"""


def _amc(frames: np.ndarray, header: str = ":FULLY-SPECIFIED\n:DEGREES\n") -> str:
    out = [header]
    for k, f in enumerate(frames, start=1):
        v = [repr(float(x)) for x in f]
        out.append(f"{k}\nroot {' '.join(v[:6])}\nupper {v[6]} {v[7]}\nlower {v[8]}\n")
    return "".join(out)


def _expected(f: np.ndarray) -> np.ndarray:
    """Acclaim forward kinematics written out with scipy (column vectors, 'ZYX' = Rz Ry Rx)."""
    e = lambda seq, a: Rotation.from_euler(seq, a, degrees=True).as_matrix()  # noqa: E731
    root = f[:3]
    g_root = e("ZYX", [f[5], f[4], f[3]])  # RX RY RZ: x applied first
    c_up = e("ZYX", [30, 0, 0])  # axis 0 0 30 XYZ
    m_up = e("ZX", [f[7], f[6]])  # dof rx rz: x applied first
    g_up = g_root @ c_up @ m_up @ c_up.T
    knee = root + 4 * g_up @ np.array([0.0, -1.0, 0.0])
    c_lo = e("XYZ", [10, 20, 0])  # axis 10 20 0 ZYX: z applied first -> Rx Ry Rz
    g_lo = g_up @ c_lo @ e("Y", [f[8]]) @ c_lo.T
    tip = knee + 2 * g_lo @ np.array([1.0, 0.0, 0.0])
    fixed_end = root + g_root @ np.array([0.0, 0.0, 1.0])
    # names: root, upper, fixed, lower (breadth first), then the leaf ends: fixed/End, lower/End
    return np.array([root, root, root, knee, fixed_end, tip])


def test_acclaim_kinematics_match_an_independent_implementation() -> None:
    rng = np.random.default_rng(4)
    frames = rng.uniform(-80, 80, size=(3, 9))
    sk = parse_asf(ASF, path="t.asf")
    assert sk.length_mult == 0.5 and sk.angle_unit == "deg"
    m = parse_amc(_amc(frames), sk, path="t.amc", rate_hz=60.0)
    assert m.names == ("root", "upper", "fixed", "lower", "fixed/End", "lower/End")
    assert m.parents == (-1, 0, 0, 1, 2, 3)
    assert m.rate_hz == 60.0 and m.fmt == "asf/amc"
    assert m.asf_unit_m == pytest.approx(0.0254 / 0.5)
    for k in range(3):
        np.testing.assert_allclose(m.positions[k], _expected(frames[k]), atol=1e-12)  # exact


def test_radians_in_the_amc_and_in_the_asf() -> None:
    rng = np.random.default_rng(5)
    frames = rng.uniform(-80, 80, size=(2, 9))
    sk = parse_asf(ASF)
    deg = parse_amc(_amc(frames), sk)
    rad = frames.copy()
    rad[:, 3:] = np.radians(rad[:, 3:])
    m = parse_amc(_amc(rad, ":FULLY-SPECIFIED\n:RADIANS\n"), sk)
    np.testing.assert_allclose(m.positions, deg.positions, atol=1e-12)  # exact
    # axis angles in radians when the ASF says so; AMC values follow it without a header
    asf_rad = ASF.replace("angle deg", "angle rad").replace(
        "axis 0 0 30 XYZ", "axis 0 0 0.5235987755982988 XYZ"
    )
    asf_rad = asf_rad.replace(
        "axis 10 20 0 ZYX", "axis 0.17453292519943295 0.3490658503988659 0 ZYX"
    )
    m2 = parse_amc(_amc(rad, ""), parse_asf(asf_rad))
    np.testing.assert_allclose(m2.positions, deg.positions, atol=1e-12)  # exact


def _line_of(text: str, fragment: str) -> int:
    """1-based line of the first line containing ``fragment``."""
    return next(i for i, x in enumerate(text.splitlines(), start=1) if fragment in x)


def _fails_asf(text: str, line: int | None, *fragments: str) -> None:
    with pytest.raises(MotionFormatError) as e:
        parse_asf(text, path="s.asf")
    assert e.value.line == line, str(e.value)
    for f in fragments:
        assert f in str(e.value), str(e.value)


def _fails_amc(text: str, line: int, *fragments: str) -> None:
    with pytest.raises(MotionFormatError) as e:
        parse_amc(text, parse_asf(ASF), path="m.amc")
    assert e.value.line == line, str(e.value)
    assert str(e.value).startswith(f"m.amc:{line}: ")
    for f in fragments:
        assert f in str(e.value), str(e.value)


def test_asf_errors_name_the_line() -> None:
    def at(fragment: str) -> int:
        return _line_of(ASF, fragment)

    _fails_asf(ASF.replace("dof ry", "dof ry tx"), at("dof ry"), "dof tx not supported")
    _fails_asf(ASF.replace("length 2\n", "length two\n"), at("length 2"), "length needs 1 numbers")
    _fails_asf(
        ASF.replace("upper lower", "upper shin"),
        at("upper lower"),
        "'shin', which :bonedata does not define",
    )
    _fails_asf(ASF.replace("ZYX", "ZZX"), at("ZYX"), "permutation of XYZ")
    _fails_asf(
        ASF.replace("root upper fixed", "root upper"),
        at("name fixed") - 2,
        "not reached from the root in :hierarchy: fixed",
    )
    _fails_asf(ASF.replace("angle deg", "angle grad"), at("angle deg"), "'deg' or 'rad'")
    _fails_asf("hello\n", None, "no :bonedata section")


def test_amc_errors_name_the_line() -> None:
    good = _amc(np.zeros((2, 9)))
    lines = good.splitlines()
    first_lower = _line_of(good, "lower")
    _fails_amc(
        good.replace("lower 0.0\n", "lower 0.0 1.0\n", 1),
        first_lower,
        "'lower' needs 1 values, got 2",
    )
    _fails_amc(
        good.replace("lower 0.0\n", "", 1), first_lower, "frame 1 (starting at line 3) lacks lower"
    )
    _fails_amc(good.replace("lower 0.0\n", "shin 0.0\n", 1), first_lower, "'shin' is not a bone")
    _fails_amc(good.replace("lower 0.0\n", "fixed 0.0\n", 1), first_lower, "'fixed' has no dof")
    _fails_amc(good.replace("lower 0.0\n", "lower x\n", 1), first_lower, "'x' is not a number")
    _fails_amc(
        good.replace("lower 0.0\n", "lower 0.0\nlower 0.0\n", 1), first_lower + 1, "appears twice"
    )
    cut = "\n".join(lines[:-1])  # the last frame lacks 'lower'
    _fails_amc(cut, len(lines), "frame 2", "lacks lower")
    with pytest.raises(MotionFormatError, match="no frames"):
        parse_amc(":FULLY-SPECIFIED\n", parse_asf(ASF))


@pytest.mark.skipif(not (DATA / "02.asf").is_file(), reason=f"real motion data not found at {DATA}")
def test_real_asf_and_amc() -> None:
    sk = read_asf(DATA / "02.asf")
    assert sk.length_mult == 0.45 and sk.angle_unit == "deg"
    assert len(sk.bones) == 30
    m = read_amc(DATA / "02_walk_a.amc", DATA / "02.asf")
    assert m.n_frames == 298 and m.rate_hz == 120.0
    ix = m.index()
    # every bone keeps the length the ASF gives it, in every frame
    for bone, child in [("lfemur", "ltibia"), ("ltibia", "lfoot"), ("rhumerus", "rradius")]:
        length = np.linalg.norm(m.positions[:, ix[child]] - m.positions[:, ix[bone]], axis=-1)
        np.testing.assert_allclose(
            length, sk.bones[bone].length, rtol=1e-5
        )  # ASF directions: 6 digits
    assert "02.asf" in m.path
