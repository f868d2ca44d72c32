"""Self-calibration: wand detection in depth frames and registration of the sensors.

Pure functions (arrays in, arrays and frozen dataclasses out); the CLI and the session store wire
them. See ``docs/calibration.md``.

Client side (one depth frame at a time):
    :func:`detect_wand` (robust sphere detector), :func:`detect_wand_paper` (paper A's),
    :func:`fit_floor_plane` (gravity and height).
Server side:
    :func:`register_full` (6 DoF, joint robust refinement, gravity), :func:`register_paper`
    (paper A's level-sensor method), the TOML calibration file, and evaluation against truth.

May import: errors, io (safe writes, TOML), skeleton, geometry, camera, frames, protocol,
motion, sync, occlusion.
"""

from kinefuse.calibration.calib_file import (
    CalibrationFile,
    SensorCalibration,
    calibration_from_registration,
    dumps_calibration,
    loads_calibration,
    read_calibration,
    write_calibration,
)
from kinefuse.calibration.common import WandDetection, WandTrack, check_depth_frame
from kinefuse.calibration.floor import FloorPlane, fit_floor_plane
from kinefuse.calibration.register import (
    Registration,
    Sightings,
    paper_positions_from_sightings,
    register_full,
    register_paper,
)
from kinefuse.calibration.wand_paper import detect_wand_paper, paper_filter
from kinefuse.calibration.wand_robust import (
    RobustDetectorParams,
    detect_wand,
    detect_wand_sequence,
)

__all__ = [
    "CalibrationFile",
    "FloorPlane",
    "Registration",
    "RobustDetectorParams",
    "SensorCalibration",
    "Sightings",
    "WandDetection",
    "WandTrack",
    "calibration_from_registration",
    "check_depth_frame",
    "detect_wand",
    "detect_wand_paper",
    "detect_wand_sequence",
    "dumps_calibration",
    "fit_floor_plane",
    "loads_calibration",
    "paper_filter",
    "paper_positions_from_sightings",
    "read_calibration",
    "register_full",
    "register_paper",
    "write_calibration",
]
