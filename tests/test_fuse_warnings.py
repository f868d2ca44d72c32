"""A warning said many times is said once with its count: the BVH export's per-joint "rotation
held" notes (24 joints, one text) become one line naming the joints; exact repeats get a count;
single warnings stay as they are."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinefuse.app.cli.fuse import said_once
from kinefuse.formats.export import export_skeleton
from kinefuse.formats.sequences import sequence_from_motion_file


def test_bvh_held_joints_are_one_warning(shared_data: Path, tmp_path: Path) -> None:
    seq = sequence_from_motion_file(shared_data / "motion/cmu/02_walk_a.amc")
    p = np.asarray(seq.kinect_positions(), dtype=np.float64).copy()
    p[:30] = np.nan  # no body in the first 30 frames: every rotation is held there
    notes: list[str] = []
    export_skeleton(tmp_path / "out.bvh", np.asarray(seq.t_s), p, notes=notes)
    warnings = [f"out.bvh: {n}" for n in notes]
    assert len(warnings) >= 20 and len(set(warnings)) == len(warnings)
    said = said_once(warnings)
    assert len(said) == 1, said
    assert said[0].startswith("out.bvh: rotation held on 30 of ")
    assert f"({len(warnings)} times: " in said[0]


def test_repeats_are_counted_and_singles_kept() -> None:
    w = ["sensor k1 left out of the fusion: no body frames", "a: b c", "a: b c", "a: b c"]
    assert said_once(w) == [w[0], "a: b c (said 3 times)"]
