"""Marker files in, marker maps, angle files out, source rotations of the motion readers."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from kinefuse.biomech.marker_maps import (
    apply_marker_map,
    hip_joint_centres,
    load_marker_map,
    parse_marker_map,
    select_marker_map,
    shipped_marker_maps,
)
from kinefuse.errors import InputError, MotionFormatError, OutputError
from kinefuse.formats.angles import read_angles_mot, write_angles_csv, write_angles_mot
from kinefuse.formats.markers import parse_trc, read_c3d, read_markers, read_trc, up_rotation
from kinefuse.formats.motion import read_amc, read_bvh

WALK = "markers/opensim/Pipelines_Rajagopal_ExpData_motion_capture_walk.trc"
STATIC = "markers/opensim/Pipelines_Rajagopal_ExpData_static_walk_1.trc"
TENNIS = "markers/c3d/kinematics_tennis_serve.c3d"


def _trc(rows: list[str], units: str = "mm", names: tuple[str, ...] = ("A", "B")) -> str:
    head = [
        "PathFileType\t4\t(X/Y/Z)\tx.trc",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame"
        "\tOrigNumFrames",
        f"100\t100\t{len(rows)}\t{len(names)}\t{units}\t100\t1\t{len(rows)}",
        "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(len(names))),
        "",
    ]
    return "\n".join(head + rows) + "\n"


# ------------------------------------------------------------------------------- readers


def test_rajagopal_walk_with_its_malformed_header_reads_in_metres_z_up(shared_data: Path) -> None:
    m = read_trc(shared_data / WALK)
    assert m.positions.shape == (238, 41, 3)
    assert m.rate_hz == 100.0
    assert "unit mm (from the file)" in m.notes  # ' mm' between doubled tabs
    assert "up axis +y" in m.notes[0]
    i = m.index()
    # shoulders 1.3-1.6 m above the toes, z up, metres
    rise = m.positions[:, i["R.Shoulder"], 2] - m.positions[:, i["R.Toe"], 2]
    assert 1.2 < float(np.median(rise)) < 1.7
    np.testing.assert_allclose(m.t_s[:3], [0.0, 0.01, 0.02])


def test_rajagopal_static_and_tennis_c3d(shared_data: Path) -> None:
    s = read_trc(shared_data / STATIC)
    assert s.positions.shape == (287, 64, 3)
    # ground-projected virtual markers have one zero coordinate: data, not gaps
    i = s.index()
    assert np.isfinite(s.positions[:, i["R.HeelGround"]]).all()
    assert abs(float(np.median(s.positions[:, i["R.HeelGround"], 2]))) < 1e-9  # exactly on y=0
    c = read_c3d(shared_data / TENNIS)
    assert c.positions.shape == (1092, 39, 3)
    assert c.rate_hz == 50.0
    assert "up axis +z" in " ".join(c.notes)
    assert c.names[0] == "Derrick:C7"
    head = c.positions[:, c.index()["Derrick:LFHD"], 2]
    assert 1.4 < float(np.median(head)) < 2.0  # metres, z up


def test_gaps_empty_nan_and_all_zero_become_nan_a_single_zero_stays() -> None:
    rows = [
        "1\t0.00\t1\t2\t3\t4\t5\t6",
        "2\t0.01\t\t\t\t4\t0\t6",  # A empty; B has one zero coordinate (data)
        "3\t0.02\tNaN\tNaN\tNaN\t0\t0\t0",  # A NaN; B all zero (a gap)
        "4\t0.03\t1\t2\t3",  # trailing gaps left out
    ]
    m = parse_trc(_trc(rows), up="+z")
    assert np.isfinite(m.positions[0]).all()
    assert np.isnan(m.positions[1, 0]).all() and np.isfinite(m.positions[1, 1]).all()
    assert np.isnan(m.positions[2]).all()
    assert np.isnan(m.positions[3, 1]).all()
    np.testing.assert_allclose(m.positions[0, 0], [0.001, 0.002, 0.003])  # mm -> m, z up kept


def test_a_trc_shorter_than_its_header_says_is_read_and_noted(shared_data: Path) -> None:
    lines = (shared_data / WALK).read_text().splitlines()[:20]
    m = parse_trc("\n".join(lines), up="+y")
    assert m.n_frames == 14
    assert "header says 238 frames, the file holds 14 rows" in m.notes[0]


def test_units_inferred_from_the_body_when_the_field_is_garbage(rng: np.random.Generator) -> None:
    # two markers 1.6 m apart vertically (in cm), a few cm apart sideways
    rows = [f"{k + 1}\t{k / 100:.2f}\t10\t0\t5\t12\t160\t4" for k in range(5)]
    m = parse_trc(_trc(rows, units="??"))
    assert any("unit cm" in n and "inferred" in n for n in m.notes)
    assert "up axis +y" in " ".join(m.notes)
    height = m.positions[0, 1, 2] - m.positions[0, 0, 2]
    assert height == pytest.approx(1.6)  # metres


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("hello\nworld\n", "not a TRC file"),
        (_trc(["1\t0.0\t1\t2\tx\t4\t5\t6"]), "column 5"),
        (_trc(["1\t0.0\t1\t2\t3\t4\t5\t6\t7\t8\t9"]), "more than the 6"),
        (_trc(["1\t0.0\t1\t2\t3\t4\t5\t6"]).replace("100\t100", "fast\t100", 1), "DataRate"),
        (_trc([]), "no data rows"),
    ],
)
def test_malformed_trc_names_the_line(text: str, message: str) -> None:
    with pytest.raises(MotionFormatError, match=message):
        parse_trc(text, path="bad.trc", up="+z")


def test_up_rotation_is_proper_and_sends_the_up_axis_to_z() -> None:
    for up in ("+x", "+y", "+z", "-x", "-y", "-z"):
        r = up_rotation(up)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)  # exact
        assert np.linalg.det(r) == pytest.approx(1.0)
        v = np.zeros(3)
        v["xyz".index(up[1])] = 1.0 if up[0] == "+" else -1.0
        np.testing.assert_allclose(r @ v, [0.0, 0.0, 1.0], atol=1e-15)
    with pytest.raises(InputError, match="up must be one of"):
        up_rotation("w")


def test_truncated_and_garbage_c3d_fail_clearly(shared_data: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.c3d"
    cut.write_bytes((shared_data / TENNIS).read_bytes()[:20000])
    with pytest.raises(MotionFormatError, match="truncated: its header declares 1092 frames"):
        read_c3d(cut)
    junk = tmp_path / "junk.c3d"
    junk.write_bytes(bytes(range(256)) * 20)
    with pytest.raises(MotionFormatError, match=r"junk\.c3d: not a C3D file: it starts with"):
        read_c3d(junk)
    junk.write_bytes(b"\x02P" + bytes(range(256)) * 20)  # a C3D's first bytes, then junk
    with pytest.raises(MotionFormatError, match=r"junk\.c3d: ezc3d cannot read it"):
        read_c3d(junk)


def test_unknown_marker_extension() -> None:
    with pytest.raises(InputError, match=r"\.trc, \.c3d"):
        read_markers("x.csv")


# ------------------------------------------------------------------------------- maps


def test_harrington_and_bell_equations_in_a_known_pelvis_frame() -> None:
    # pelvis frame = world: x anterior, y up... the world here is z up: build the markers so
    # that the ISB pelvis axes are x (anterior) = +x, y (superior) = +z, z (right) = -y
    rasis = np.array([0.0, -0.12, 1.0])
    lasis = np.array([0.0, 0.12, 1.0])
    back = np.array([-0.16, 0.0, 1.0])
    pw, pd = 0.24, 0.16
    left, right = hip_joint_centres(rasis, lasis, back, "harrington2007")
    x, y, z = -0.24 * pd - 0.0099, -0.30 * pw - 0.0109, 0.33 * pw + 0.0073
    np.testing.assert_allclose(right, [x, -z, 1.0 + y], atol=1e-12)  # the equations, exactly
    np.testing.assert_allclose(left, [x, z, 1.0 + y], atol=1e-12)
    left, right = hip_joint_centres(rasis, lasis, back, "bell1990")
    np.testing.assert_allclose(right, [-0.19 * pw, -0.36 * pw, 1.0 - 0.30 * pw], atol=1e-12)


def test_hip_centres_near_the_static_trials_own_virtual_centres(shared_data: Path) -> None:
    m = read_trc(shared_data / STATIC)
    mm = shipped_marker_maps()["rajagopal"]
    p, names, _ = apply_marker_map(m, mm)
    i = m.index()
    for side, virtual in (("Right", "R_HJC"), ("Left", "L_HJC")):
        d = np.linalg.norm(p[:, names.index("Hip" + side)] - m.positions[:, i[virtual]], axis=-1)
        # Harrington vs the file's (model-based) centres: 3.2-3.8 cm, mostly posterior
        assert float(d.mean()) < 0.05  # 5 cm


@pytest.mark.parametrize(
    ("rel", "name"), [(WALK, "rajagopal"), (STATIC, "rajagopal"), (TENNIS, "plug-in-gait")]
)
def test_shipped_maps_fit_the_shared_files(shared_data: Path, rel: str, name: str) -> None:
    m = read_markers(shared_data / rel)
    mm = select_marker_map(m)
    assert mm.name == name
    p, names, _ = apply_marker_map(m, mm)
    assert names[0] == "SpineBase" and "KneeLeft" in names
    d = dict(zip(names, np.moveaxis(p, 1, 0), strict=True))
    thigh = np.nanmedian(np.linalg.norm(d["HipLeft"] - d["KneeLeft"], axis=-1))
    shank = np.nanmedian(np.linalg.norm(d["KneeLeft"] - d["AnkleLeft"], axis=-1))
    assert 0.33 < thigh < 0.50 and 0.33 < shank < 0.50  # adult segment lengths, metres


def test_a_map_naming_absent_markers_names_them(shared_data: Path, tmp_path: Path) -> None:
    f = tmp_path / "my.toml"
    f.write_text(
        'name = "mine"\n[joints]\nSpineBase = { mean = ["R.ASIS", "L.ASIS"] }\n'
        'KneeLeft = [{ mean = ["L.Knee", "L.KneeMedial"] }, "L.KneePad"]\n'
    )
    mm = load_marker_map(f)
    with pytest.raises(InputError) as e:
        apply_marker_map(read_trc(shared_data / WALK), mm)
    text = str(e.value)
    assert "KneeLeft: missing L.KneeMedial | or | L.KneePad" in text
    assert "L.Knee" in text and "R.ASIS" in text  # the file's markers are listed


@pytest.mark.parametrize(
    ("toml", "message"),
    [
        ("[joints]\nKneeLeft = 'A'\n", "must give SpineBase"),
        ("[joints]\nSpineBase = 'A'\nKnee = 'B'\n", "did you mean 'KneeLeft'"),
        ("[joints]\nSpineBase = { blend = { A = 0.5, B = 0.4 } }\n", "add up to 1"),
        (
            "[joints]\nSpineBase = 'A'\nHipLeft = { hip_joint_centre = 'left' }\n",
            "needs a \\[pelvis\\]",
        ),
        ("up = 'w'\n[joints]\nSpineBase = 'A'\n", "up must be one of"),
        (
            "[pelvis]\nrasis='A'\nlasis='B'\n[joints]\nSpineBase = 'A'\n",
            "rpsis and lpsis, or sacrum",
        ),
        ("colour = 1\n[joints]\nSpineBase = 'A'\n", "unknown keys"),
    ],
)
def test_malformed_maps(toml: str, message: str) -> None:
    import tomllib

    with pytest.raises(InputError, match=message):
        parse_marker_map(tomllib.loads(toml), name="t", origin="t.toml")


def test_namespace_prefix_is_ignored_when_matching(shared_data: Path) -> None:
    c = read_c3d(shared_data / TENNIS)
    mm = shipped_marker_maps()["plug-in-gait"]
    p, names, _ = apply_marker_map(c, mm)
    i = c.index()
    # the knee centre: Plug-in Gait's chord from LKNE, LTHI and the hip centre (the map's
    # LKJC), 57 mm from the LKNE marker, found under its "Derrick:" prefix
    d = np.linalg.norm(p[:, names.index("KneeLeft")] - c.positions[:, i["Derrick:LKNE"]], axis=-1)
    np.testing.assert_allclose(d[np.isfinite(d)], 0.057, atol=1e-9)


# ------------------------------------------------------------------------------- rotations


def _local_bone_is_constant(src: object, child: str) -> float:
    names = src.names  # type: ignore[attr-defined]
    k = names.index(child)
    par = src.parents[k]  # type: ignore[attr-defined]
    bone = src.positions[:, k] - src.positions[:, par]  # type: ignore[attr-defined]
    local = np.einsum("tji,tj->ti", src.rotations[:, par], bone)  # type: ignore[attr-defined]
    return float(np.abs(local - local[0]).max())


def test_bvh_and_amc_rotations_carry_the_bones(shared_data: Path) -> None:
    b = read_bvh(shared_data / "motion/cmu/131_01_scaled_metres.bvh")
    assert b.rotations is not None and b.rotations.shape == (*b.positions.shape[:2], 3, 3)
    r = b.rotations
    np.testing.assert_allclose(
        r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape), atol=1e-9
    )
    # a child's offset is constant in its parent's frame: the rotations are the ones FK used
    assert _local_bone_is_constant(b, "LeftKnee") < 1e-9  # metres
    a = read_amc(shared_data / "motion/cmu/02_walk_a.amc", shared_data / "motion/cmu/02.asf")
    assert a.rotations is not None
    # the bone lfemur runs from its start (lfemur) to the start of ltibia, fixed in its frame
    k = a.names.index("ltibia")
    j = a.names.index("lfemur")
    bone = a.positions[:, k] - a.positions[:, j]
    local = np.einsum("tji,tj->ti", a.rotations[:, j], bone)
    assert float(np.abs(local - local[0]).max()) < 1e-9  # file units


# ------------------------------------------------------------------------------- angle files


def storage_rows(opensim: Any, path: Path) -> int:
    """Rows ``opensim.Storage`` reads (it stops a file at a value it cannot parse)."""
    return int(opensim.Storage(str(path)).getSize())


def test_mot_and_csv_round_trip_and_load_in_opensim(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    opensim = pytest.importorskip("opensim", reason="opensim (the test extra) is not installed")
    monkeypatch.chdir(tmp_path)  # OpenSim writes opensim.log into the working folder
    t = np.arange(50) / 100.0
    ang = {"knee_flexion_r": 30 * np.sin(t), "hip_flexion_r": np.where(t > 0.2, np.nan, 5.0)}
    mot = write_angles_mot(tmp_path / "a.mot", t, ang)
    _, a2, head = read_angles_mot(mot)
    # hip_flexion_r is missing on 29 of 50 frames (> half): the column is left out, not the rows
    assert head["inDegrees"] == "yes" and head["nRows"] == "50" and head["nColumns"] == "2"
    np.testing.assert_allclose(a2["knee_flexion_r"], ang["knee_flexion_r"], atol=1e-6)  # 6 dp
    table = opensim.TimeSeriesTable(str(mot))
    assert table.getNumRows() == 50
    assert list(table.getColumnLabels()) == ["knee_flexion_r"]
    assert opensim.Storage(str(mot)).isInDegrees()
    assert storage_rows(opensim, mot) == 50
    csv = write_angles_csv(
        tmp_path / "a.csv", t, ang, {"knee_flexion_r": "KneeRight", "hip_flexion_r": "HipRight"}
    )
    lines = csv.read_text().splitlines()
    assert lines[0] == "time_s,joint,angle,method,degrees,filled,status"
    assert len(lines) == 1 + 2 * 50
    assert lines[-1] == "0.490000,HipRight,hip_flexion_r,functional,,0,"  # status: not given


def test_mot_with_gaps_loads_whole_in_storage(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Short gaps are filled, long ones cut out: Storage reads every written row."""
    opensim = pytest.importorskip("opensim", reason="opensim (the test extra) is not installed")
    from kinefuse.formats.angles import plan_mot

    monkeypatch.chdir(tmp_path)
    t = np.arange(100) / 50.0  # 50 Hz, 2 s
    a = 10 * np.sin(t)
    b = 5 * np.cos(t)
    a[10:14] = np.nan  # 4 frames = 0.08 s: filled
    b[40:60] = np.nan  # 20 frames = 0.4 s: left out
    b[0] = np.nan  # an edge: never extrapolated, left out
    plan = plan_mot(t, {"a": a, "b": b})
    assert plan.filled == {"a": 4, "b": 0}
    gap = np.isin(plan.t_s, t[10:14])
    np.testing.assert_allclose(plan.columns["a"][gap], 10 * np.sin(t[10:14]), atol=0.05)
    assert plan.rows_left_out == [(0.0, 0.0), (0.8, pytest.approx(1.18))]
    mot = write_angles_mot(tmp_path / "g.mot", t, {"a": a, "b": b}, plan=plan)
    _, cols, head = read_angles_mot(mot)
    assert int(head["nRows"]) == 100 - 21 == storage_rows(opensim, mot)
    assert opensim.TimeSeriesTable(str(mot)).getNumRows() == 79
    assert all(np.isfinite(v).all() for v in cols.values())


def test_angle_writers_never_overwrite_and_fail_clearly(tmp_path: Path) -> None:
    t = np.arange(3) / 10.0
    f = tmp_path / "a.mot"
    f.write_text("not ours")
    with pytest.raises(OutputError, match=r"refusing to replace .*a\.mot"):
        write_angles_mot(f, t, {"x": t})
    assert f.read_text() == "not ours"
    with pytest.raises(InputError, match="OpenSim column names"):
        write_angles_mot(tmp_path / "b.mot", t, {"knee flexion": t})
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp left


def test_writing_into_a_read_only_folder_fails_with_the_path_and_reason(
    readonly_folder: Path,
) -> None:
    with pytest.raises(
        OutputError,
        match=r"a\.mot: folder .* is not writable",
    ):
        write_angles_mot(readonly_folder / "a.mot", np.arange(3.0), {"x": np.zeros(3)})
    assert list(readonly_folder.iterdir()) == []


def test_marker_clusters_give_limb_orientations(shared_data: Path) -> None:
    from kinefuse.formats.sequences import sequence_from_markers

    s = sequence_from_markers(shared_data / STATIC)
    assert set(s.orientation_limbs) == {  # every [clusters] entry of the rajagopal map
        "pelvis", "trunk", "thigh_left", "shank_left", "foot_left", "thigh_right", "shank_right",
        "foot_right", "upper_arm_left", "forearm_left", "upper_arm_right", "forearm_right",
    }  # fmt: skip
    r = s.orientation("thigh_right")
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-9)  # proper rotations
    bone = s.positions[:, s.index("KneeRight")] - s.positions[:, s.index("HipRight")]
    local = np.einsum("tji,tj->ti", r, bone)
    assert float(np.nanstd(local, axis=0).max()) < 0.005  # static trial: the thigh is rigid, m
    import tomllib

    mm = parse_marker_map(
        tomllib.loads('[joints]\nSpineBase = "S2"\n[clusters]\nthigh_left = ["A", "B", "L.TH1"]\n'),
        name="t",
        origin="t.toml",
    )
    from kinefuse.biomech.marker_maps import cluster_orientations

    with pytest.raises(InputError, match="thigh_left: A, B"):
        cluster_orientations(read_trc(shared_data / STATIC), mm)
    with pytest.raises(InputError, match="is not a limb"):
        parse_marker_map(
            tomllib.loads('[joints]\nSpineBase = "S2"\n[clusters]\nleg = ["A", "B", "C"]\n'),
            name="t",
            origin="t.toml",
        )
