"""Exporters of fused skeletons: CSV, TRC, C3D round trips and bad paths."""

from __future__ import annotations

import numpy as np
import pytest

from kinefuse.errors import InputError
from kinefuse.io.export import export_skeleton
from kinefuse.skeleton import JOINTS


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
