"""The lumbar joint's depth behind the ASIS follows the pelvis's depth, as OpenSim's Scale tool
scales the gait models' pelvis (X by the MidASIS-MidPSIS distance), checked against OpenSim's
own scaling of the shared Rajagopal subject (opensim-models, Pipelines/Rajagopal/Scale:
``scaleSet_applied_walk.xml``'s pelvis X factor 1.2446 and ``subject_scaled_walk_markerset.xml``'s
ASIS markers at x = 0.0162 m in the scaled pelvis)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinefuse.biomech.anatomical import (
    MODEL_PELVIS_DEPTH_M,
    lumbar_joint_centre,
    pelvis_frame,
)
from kinefuse.formats.markers import read_markers

STATIC = "markers/opensim/Pipelines_Rajagopal_ExpData_static_walk_1.trc"
#: The scaled model's back joint behind its ASIS markers, metres: (-0.1007 * 1.2446) - 0.0162.
OPENSIM_BACK_BEHIND_ASIS_M = 0.1007 * 1.2446 + 0.0162


def test_the_depth_places_the_lumbar_joint_where_opensim_scales_it(shared_data: Path) -> None:
    """The subject's pelvis is 25 % deeper than the generic model's and as wide (ASIS 257 mm
    apart): with its depth the lumbar joint lies within 3 mm of where OpenSim's scaled model
    puts it behind the ASIS; scaled by the width alone, 27 mm in front of it."""
    m = read_markers(shared_data / STATIC, up="+y")
    p = {n: np.nanmedian(m.positions[:, m.names.index(n)], axis=0) for n in m.names}
    back = 0.5 * (p["R.PSIS"] + p["L.PSIS"])
    frame, mid = pelvis_frame(p["R.ASIS"], p["L.ASIS"], back)
    width = float(np.linalg.norm(p["R.ASIS"] - p["L.ASIS"]))
    depth = float(np.linalg.norm(mid - back))
    assert abs(depth / MODEL_PELVIS_DEPTH_M - 1.2446) < 0.02  # OpenSim's own factor
    behind = -(frame.T @ (lumbar_joint_centre(frame, mid, width, depth) - mid))[0]
    width_only = -(frame.T @ (lumbar_joint_centre(frame, mid, width) - mid))[0]
    assert abs(behind - OPENSIM_BACK_BEHIND_ASIS_M) < 0.003, behind
    assert OPENSIM_BACK_BEHIND_ASIS_M - width_only > 0.02, width_only
