"""The robust wand detector on real Azure Kinect depth (``../shared/data/depth``): nothing in the
real scene (a mug on a table), and a wand rendered into that depth at known poses with the
device's own intrinsics found within 5 mm."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from kinefuse.capture.calibration.wand_robust import detect_wand
from kinefuse.core.camera.wand import Wand
from kinefuse.devices.mkv import MkvRecording
from kinefuse.sim.depth import Scene, SurfaceLabel, render_depth, render_geometry

pytest.importorskip("av")

#: wand centres as (u px, v px, z m) in front of the scene's far part (1.4-2.2 m behind them)
POSES = ((420, 120, 1.2), (500, 200, 1.0), (380, 280, 1.3), (540, 100, 1.5), (450, 250, 0.9),
         (350, 150, 1.1), (470, 160, 1.4))  # fmt: skip


@pytest.fixture(scope="module")
def real(shared_data: Path):
    rec = MkvRecording(shared_data / "depth" / "pyk4a_recording.mkv")
    cap = next(rec.captures())
    assert cap.depth_mm is not None
    return cap.depth_mm, rec.calibration.depth


def test_the_detector_finds_no_wand_in_the_real_scene(real) -> None:
    depth, k = real
    det = detect_wand(depth, k)
    assert not det.found, det
    assert det.reason  # says why (the mug is not isolated in depth like a held sphere)


def _with_wand(depth, k, centre, handle_dir, rng):
    """The real frame with the wand (Kinect-v2-like time-of-flight noise, the simulator's model)
    drawn in front of it: each wand pixel replaces the real one where the wand is nearer."""
    scene = Scene(wand=Wand(), wand_centre=centre, wand_handle_dir=handle_dir, walls=False,
                  floor=False)  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # rays that hit nothing
        geo = render_geometry(scene, np.eye(4), k)
        noisy = render_depth(scene, np.eye(4), k, rng)
    on_wand = np.isin(geo.label, (SurfaceLabel.WAND_SPHERE, SurfaceLabel.WAND_STICK))
    behind = (depth == 0) | (geo.z_m * 1000.0 < depth)
    out = depth.copy()
    out[on_wand & behind] = noisy[on_wand & behind]
    return out


def test_a_wand_rendered_into_real_depth_is_found_within_5_mm(real) -> None:
    depth, k = real
    rng = np.random.default_rng(20261207)
    # held in front of the body toward the camera: the stick goes down and away from it
    handle = np.array([0.0, 0.5, 0.87])
    errors = []
    for u, v, z in POSES:
        centre = k.backproject((u, v), z)
        frame = _with_wand(depth, k, centre, handle, rng)
        assert (frame != depth).sum() > 1000  # the wand is in the picture
        det = detect_wand(frame, k)
        assert det.found, (u, v, z, det.reason)
        errors.append(float(np.linalg.norm(det.centre_sensor_m - centre)))
    assert max(errors) < 0.005, errors
