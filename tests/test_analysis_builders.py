"""Skeleton-sequence builders: clips with their rotations, marker files, fused sessions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.app.workflows.analyze import load_input, prepare_out
from kinefuse.errors import InputError, OutputError
from kinefuse.formats.sequences import sequence_from_markers, sequence_from_motion_file
from kinefuse.formats.store.session_store import SessionStore


def _bone_in_limb_frame(seq, limb: str, a: str, b: str) -> np.ndarray:  # type: ignore[no-untyped-def]
    r = seq.orientation(limb)
    bone = seq.positions[:, seq.index(b)] - seq.positions[:, seq.index(a)]
    return np.einsum("tji,tj->ti", r, bone)


@pytest.mark.parametrize("clip", ["131_01_scaled_metres.bvh", "02_walk_b.amc"])
def test_clip_orientations_are_the_source_rotations_in_world_axes(
    shared_data: Path, clip: str
) -> None:
    seq = sequence_from_motion_file(shared_data / "motion" / "cmu" / clip)
    assert seq.n_joints == 25 and seq.orientations is not None
    assert {"pelvis", "thigh_left", "shank_right", "upper_arm_left", "forearm_right"} <= set(
        seq.orientation_limbs
    )
    r = seq.orientations
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-9)  # proper rotations
    # the thigh bone (hip -> knee, world, metres) is fixed in the thigh's source frame: so the
    # rotations are in the same world axes as the retargeted positions
    for limb, a, b in (
        ("thigh_left", "HipLeft", "KneeLeft"),
        ("shank_right", "KneeRight", "AnkleRight"),
    ):
        local = _bone_in_limb_frame(seq, limb, a, b)
        assert float(np.abs(local - local[0]).max()) < 1e-9  # metres


def test_marker_sequences_are_the_maps_joints(shared_data: Path) -> None:
    seq = sequence_from_markers(shared_data / "markers/c3d/kinematics_tennis_serve.c3d")
    assert seq.joint_names[0] == "SpineBase" and seq.parents[0] == -1
    assert "HandTipLeft" not in seq.joint_names and "ThumbLeft" in seq.joint_names
    assert seq.rate_hz == 50.0 and seq.n_frames == 1092
    assert "plug-in-gait" in seq.source
    # the map's clusters (issue 20: thighs on the hip centre, THI and KNE, ...) orient limbs
    assert set(seq.orientation_limbs) >= {"pelvis", "thigh_left", "shank_right", "forearm_left"}


def test_session_is_fused_read_only(tmp_path: Path, shared_data: Path) -> None:
    s = tmp_path / "s.sqlite"
    clip = shared_data / "motion/cmu/02_walk_a.amc"
    assert main(["simulate", "--clip", str(clip), "--seconds", "1.5",
                 "--calibration-seconds", "0", "--out", str(s)]) == 0  # fmt: skip
    before = s.read_bytes()
    inp = load_input(s, true_calibration=True)
    assert inp.kind == "session" and inp.fusion is not None
    assert inp.seq.n_joints == 25 and 40 <= inp.seq.n_frames <= 50  # 30 Hz grid over 1.5 s
    assert inp.stored_phase_s is None
    assert s.read_bytes() == before  # nothing written into the session
    with SessionStore.open(s) as st:
        assert st.fused_methods() == []
    with pytest.raises(InputError, match="no calibration"):
        load_input(s)  # no wand phase, no calibration: says how to get one


def test_inputs_and_output_folder_are_checked(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        load_input(tmp_path / "none.bvh")
    f = tmp_path / "x.txt"
    f.write_text("hi")
    with pytest.raises(InputError, match="cannot analyse"):
        load_input(f)
    full = tmp_path / "full"
    full.mkdir()
    (full / "mine.txt").write_text("keep")
    with pytest.raises(OutputError, match="fresh folder"):
        prepare_out(full)
    assert (full / "mine.txt").read_text() == "keep"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert prepare_out(empty) == empty
    assert prepare_out(tmp_path / "new" / "deeper").is_dir()


def test_rom_phase_is_placed_where_the_clip_starts(shared_data: Path) -> None:
    from kinefuse.biomech.rom import add_rom_phase
    from kinefuse.core.skeleton import JOINT_INDEX
    from kinefuse.formats.motion import facing_direction, load_motion, place

    clip = place(load_motion(shared_data / "motion/cmu/02_walk_b.amc"), (1.0, -0.5), 75.0)
    rom = add_rom_phase(clip, 60.0, seed=3)
    m = rom.motion
    root = JOINT_INDEX["SpineBase"]
    n_rom = int(rom.rom_s * clip.rate_hz)
    # the ROM stands where the clip starts and faces its way; the clip follows unchanged
    np.testing.assert_allclose(m.positions[0, root, :2], clip.positions[0, root, :2], atol=0.01)
    f0, f1 = facing_direction(m.positions[0]), facing_direction(clip.positions[0])
    assert float(f0 @ f1) > np.cos(np.radians(5.0))
    np.testing.assert_allclose(m.positions[-clip.n_frames :], clip.positions, atol=0)
    assert m.n_frames == n_rom + 1 + round(rom.blend_s * clip.rate_hz) + clip.n_frames
    # frame-to-frame steps stay human (no jump into the clip): under 5 cm at 120 Hz
    step = np.linalg.norm(np.diff(m.positions, axis=0), axis=-1).max()
    assert step < 0.05
    truth = rom.truth
    assert set(truth["axes_parent"]) >= {"thigh_left", "upper_arm_right", "shank_left"}
    assert np.asarray(truth["axes_parent"]["thigh_left"]).shape == (2, 3)
    assert len(truth["t_s"]) == len(truth["twist_rad"]["thigh_left"])
