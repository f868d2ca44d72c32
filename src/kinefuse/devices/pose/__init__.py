"""The ``pose`` tracker that ships with kinefuse: skeletons from any RGB-D camera, offline.

MediaPipe Pose's full model finds 33 landmarks on the colour image (on the IR image where there
is no colour, :mod:`.model`); each is lifted to 3D with the depth registered to that image, the
body's own depth layer in a small window (:mod:`.lift`); they become the 25 Kinect v2 joints,
the ones the model lacks derived and flagged inferred (:mod:`.mapping`); and the body passes
plausibility gates before it is returned (:mod:`.gates`). Output in the depth camera's frame,
metres, as every tracker's. ``docs/tracker.md`` has the figures.

Registered as the entry point ``pose`` of ``kinefuse.trackers``; :func:`make` is its factory.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from kinefuse.devices.pose.tracker import PoseTracker
from kinefuse.errors import InputError

__all__ = ["OPTIONS", "PoseTracker", "make"]

#: the options :func:`make` takes, with what each means
OPTIONS = {
    "input_width": "px the colour image is scaled down to for the 2D model (default 640)",
    "mode": "video (the detector only when the person is lost; default) or image (every frame)",
    "detect_every": "in video mode, also run the detector every this many frames (default 0: "
    "only when the person is lost)",
    "floor": "nx,ny,nz,d: the floor plane in the depth camera's frame (n up, metres)",
    "min_visibility": "the model's visibility under which a joint is inferred (default 0.5)",
}


def make(options: Mapping[str, str]) -> PoseTracker:
    """The ``pose`` tracker with ``options`` (:data:`OPTIONS`); the model loads here."""
    from kinefuse.devices.pose.lift import LiftParams
    from kinefuse.devices.pose.model import BlazePoseModel

    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise InputError(
            f"unknown pose tracker option(s) {', '.join(unknown)}; it takes: {', '.join(OPTIONS)}"
        )
    try:
        width = int(options.get("input_width", "640"))
        detect_every = int(options.get("detect_every", "0"))
        min_vis = float(options.get("min_visibility", "0.5"))
        floor = None
        if "floor" in options:
            floor = np.array([float(v) for v in options["floor"].split(",")])
            if floor.shape != (4,) or not np.isfinite(floor).all():
                raise ValueError
            floor[:3] /= np.linalg.norm(floor[:3])
    except ValueError:
        raise InputError(
            "pose tracker options: input_width is whole pixels (e.g. 640), detect_every whole "
            "frames (e.g. 10), min_visibility a "
            "number in [0, 1], floor four numbers nx,ny,nz,d (e.g. 0,-1,0,1.2)"
        ) from None
    mode = options.get("mode", "video")
    if mode not in ("video", "image"):
        raise InputError(f"pose tracker option mode must be video or image, got {mode!r}")
    if width < 64:
        raise InputError(f"pose tracker option input_width must be at least 64 px, got {width}")
    if detect_every < 0:
        raise InputError(f"pose tracker option detect_every must be 0 or more, got {detect_every}")
    model = BlazePoseModel(input_width=width, video=mode == "video", detect_every=detect_every)
    return PoseTracker(model, lift=LiftParams(min_visibility=min_vis), floor=floor)
