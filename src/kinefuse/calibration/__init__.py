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
motion, sync, occlusion."""
