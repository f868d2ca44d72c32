"""Two body trackers registered as real ``kinefuse.trackers`` entry points (this folder's
``.dist-info``), for the tests of what carries a tracker's output (``kinefuse track``, the sensor
adapter); put ``tests/plugins`` on ``PYTHONPATH`` to install them.

- ``nobody``: finds no one and says why (as a tracker whose gates refuse a detection does);
- ``standing``: one person standing upright 2.5 m in front of the camera, every joint tracked
  (kinefuse's reference standing pose turned into the camera frame);
- ``slow``: ``standing`` taking :data:`SLOW_S` per capture (a tracker far slower than the
  camera, for the client's bounded queue), which also refuses a second detection with
  :data:`SLOW_REFUSAL` (text with HTML's special characters, for the viewer's escaping).
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from kinefuse.core.skeleton import N_JOINTS, TrackingState, standing_pose
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.trackers import TrackedBody, TrackerResult


class Nobody:
    name = "nobody"

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        return TrackerResult(refused=("bones of 4 cm: not a person",))

    def close(self) -> None:
        pass


class Standing:
    name = "standing"

    def __init__(self) -> None:
        world = standing_pose()  # x forward (the person faces +x), z up
        # camera frame: x right, y down, z forward; the person faces the camera 2.5 m away,
        # feet 1.2 m below the optical axis
        self.joints = np.stack([world[:, 1], 1.2 - world[:, 2], 2.5 - world[:, 0]], axis=1)

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        states = np.full(N_JOINTS, TrackingState.TRACKED, dtype=np.int8)
        return TrackerResult(bodies=(TrackedBody(1, self.joints.copy(), states),))

    def close(self) -> None:
        pass


#: what ``slow`` spends on each capture, seconds (a 30 Hz camera gives about 7 captures meanwhile)
SLOW_S = 0.25


#: what ``slow`` says of the detection it refuses
SLOW_REFUSAL = "a <b>mug</b> & its cartoon: not a person"


class Slow(Standing):
    name = "slow"

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        time.sleep(SLOW_S)
        bodies = super().track(capture, calibration).bodies
        return TrackerResult(bodies=bodies, refused=(SLOW_REFUSAL,))


def make_slow(options: Mapping[str, str]) -> Slow:
    return Slow()


def make_nobody(options: Mapping[str, str]) -> Nobody:
    return Nobody()


def make_standing(options: Mapping[str, str]) -> Standing:
    return Standing()
