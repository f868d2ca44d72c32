"""The body-tracker plug-in point: a tracker turns one capture into the bodies it sees.

A tracker is registered as an entry point of the group ``kinefuse.trackers`` whose object is a
factory ``make(options: dict[str, str]) -> Tracker``; :func:`load_tracker` opens one by name,
and :func:`available_trackers` lists what is installed. A tracker whose library is missing
raises :class:`TrackerUnavailable` from its factory with one line saying what to install.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.errors import InputError

__all__ = [
    "ENTRY_POINT_GROUP",
    "TrackedBody",
    "Tracker",
    "TrackerResult",
    "TrackerUnavailable",
    "available_trackers",
    "load_tracker",
]

#: the entry-point group a tracker package registers its factory under
ENTRY_POINT_GROUP = "kinefuse.trackers"


class TrackerUnavailable(InputError):
    """A tracker's library, model or runtime is not installed; the message says what to install."""


@dataclass(frozen=True, eq=False)
class TrackedBody:
    """One body a tracker found in one capture.

    Attributes
    ----------
    body_id : int
        The tracker's own id for this body (kept while it tracks it; a new id after a loss).
    joints_m : (25, 3) float
        The 25 Kinect v2 joints (:data:`kinefuse.core.skeleton.JOINTS` order) in the depth camera's
        frame (x right, y down, z forward), metres; NaN where not tracked.
    states : (25,) int8
        :class:`~kinefuse.core.skeleton.TrackingState` per joint.
    confidence : (25,) float or None
        The tracker's own per-joint confidence in [0, 1], when it has one.
    """

    body_id: int
    joints_m: NDArray[np.float64]
    states: NDArray[np.int8]
    confidence: NDArray[np.float64] | None = None


@dataclass(frozen=True, eq=False)
class TrackerResult:
    """What a tracker made of one capture: the bodies it kept and why it refused the others.

    ``refused`` holds one short reason per detection the tracker (or its plausibility gates)
    refused, for the sensor's status and the log ("bones of 4 cm: not a person").
    """

    bodies: tuple[TrackedBody, ...] = ()
    refused: tuple[str, ...] = ()
    timings_s: Mapping[str, float] = field(default_factory=dict)


@runtime_checkable
class Tracker(Protocol):
    """A body tracker: captures in, bodies out (one call per capture, in capture order).

    What it is handed (:meth:`kinefuse.devices.sources.CameraFrameSource.for_tracker`): the
    capture's depth and IR images in the undistorted pinhole camera ``calibration.depth``, the
    same images kinefuse's depth frames carry, with a calibration whose ``distortion_depth`` is
    empty; the colour image as the device gives it (``distortion_color`` says its lens). A
    tracker that needs the device's own images and calibration (Microsoft's, which takes the
    device's raw JSON, :attr:`CameraCalibration.raw`) sets a class attribute
    ``device_images = True`` and gets the capture unchanged with the device's calibration.
    """

    name: str

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult: ...

    def close(self) -> None: ...


TrackerFactory = Callable[[Mapping[str, str]], Tracker]


def available_trackers() -> dict[str, str]:
    """Installed trackers by name, each with the entry point's target ``module:attr``."""
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def load_tracker(name: str, options: Mapping[str, str] | None = None) -> Tracker:
    """Open the tracker registered as ``name``; raise :class:`InputError` naming the choices."""
    eps = {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
    if name not in eps:
        choices = ", ".join(sorted(eps)) or "none"
        raise InputError(
            f"no tracker {name!r}; installed trackers ({ENTRY_POINT_GROUP} entry points): "
            f"{choices} (kinefuse sensor --list-sources lists them with what to install)"
        )
    factory: TrackerFactory = eps[name].load()
    return factory(dict(options or {}))
