"""Exporters of fused skeletons: CSV, TRC, C3D round trips and bad paths."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError
from kinefuse.formats.export import export_skeleton


@pytest.fixture
def skeleton(rng):
    t = 10.0 + np.arange(12) / 30.0
    p = rng.normal(0, 1, (12, 25, 3))
    p[4, 7] = np.nan
    return t, p


def test_csv_round_trip(tmp_path, skeleton) -> None:
    t, p = skeleton
    path = export_skeleton(tmp_path / "f.csv", t, p)
    lines = path.read_text().splitlines()
    assert lines[0].split(",")[:4] == ["time_s", f"{JOINTS[0]}_x_m", f"{JOINTS[0]}_y_m",
                                       f"{JOINTS[0]}_z_m"]  # fmt: skip
    data = np.genfromtxt(path, delimiter=",", skip_header=1)
    np.testing.assert_allclose(data[:, 0], t, atol=1e-6)
    np.testing.assert_allclose(data[:, 1:].reshape(12, 25, 3), p, atol=1e-6)  # 1 um


def test_trc_is_in_mm_with_joint_labels(tmp_path, skeleton) -> None:
    t, p = skeleton
    path = export_skeleton(tmp_path / "f.trc", t, p)
    lines = path.read_text().splitlines()
    assert lines[2].split("\t")[4] == "mm" and lines[2].split("\t")[2] == "12"
    assert lines[3].split("\t")[2] == JOINTS[0]
    row = lines[6].split("\t")
    np.testing.assert_allclose(float(row[2]), p[0, 0, 0] * 1000, atol=1e-3)


def test_c3d_round_trip(tmp_path, skeleton) -> None:
    ezc3d = pytest.importorskip("ezc3d")
    t, p = skeleton
    path = export_skeleton(tmp_path / "f.c3d", t, p)
    c = ezc3d.c3d(str(path))
    assert c["parameters"]["POINT"]["LABELS"]["value"] == list(JOINTS)
    assert c["parameters"]["POINT"]["RATE"]["value"][0] == pytest.approx(30.0)
    pts = c["data"]["points"][:3].transpose(2, 1, 0) / 1000.0
    np.testing.assert_allclose(pts[np.isfinite(p)], p[np.isfinite(p)], atol=1e-4)  # 0.1 mm
    assert np.isnan(pts[4, 7]).all()


def test_unknown_format_and_bad_shapes(tmp_path, skeleton) -> None:
    t, p = skeleton
    with pytest.raises(InputError, match=r"unknown output format '\.xyz'"):
        export_skeleton(tmp_path / "f.xyz", t, p)
    with pytest.raises(InputError, match=r"positions \(T, 25, 3\)"):
        export_skeleton(tmp_path / "f.csv", t, p[:, :20])


# -- OpenSim reads every TRC kinefuse writes (issue 8) ---------------------------------------


def _opensim():
    try:
        import opensim
    except ImportError:
        pytest.skip("opensim is not installed (pip install '.[test]' on CPython 3.11, x86_64)")
    return opensim


@pytest.mark.parametrize("axes", ["y-up", "z-up"])
def test_trc_loads_in_opensim_with_every_frame_and_marker(tmp_path, axes) -> None:
    opensim = _opensim()
    from kinefuse.core.skeleton import standing_pose

    t = (90 + np.arange(40)) / 30.0  # seconds from the session's start, frames on the grid
    p = np.repeat(standing_pose()[None], 40, axis=0)
    p[:, :, 0] += np.linspace(0, 1, 40)[:, None]  # walk along x
    p[5, 24] = np.nan  # a missing marker
    p[6] = np.nan  # a frame with no data at all
    p[-1, -3:] = np.nan  # missing markers at the end of a row: OpenSim's column count
    out = export_skeleton(tmp_path / "f.trc", t, p, trc_axes=axes)
    table = opensim.TimeSeriesTableVec3(str(out))
    assert table.getNumRows() == 40 and table.getNumColumns() == 25
    assert list(table.getColumnLabels()) == list(JOINTS)
    np.testing.assert_allclose(list(table.getIndependentColumn()), t, atol=1e-6)
    assert table.getTableMetaDataAsString("Units") == "mm"
    head = table.getDependentColumn("Head")
    h = np.array([[head[i][k] for k in range(3)] for i in range(40)])
    up = 1 if axes == "y-up" else 2
    assert np.nanmedian(h[:, up]) == pytest.approx(1000 * np.nanmedian(p[:, 3, 2]), abs=1)
    assert np.isnan(h[6]).all() and np.isfinite(h[7]).all()
    thumb = table.getDependentColumn("ThumbRight")
    assert np.isnan([thumb[5][k] for k in range(3)]).all()
    if axes == "y-up":  # X = x, Y = z, Z = -y: right-handed
        spine = table.getDependentColumn("SpineBase")
        assert spine[0][0] == pytest.approx(1000 * p[0, 0, 0], abs=1e-2)
        assert spine[0][2] == pytest.approx(-1000 * p[0, 0, 1], abs=1e-2)
