"""The 33 BlazePose landmarks of MediaPipe Pose, as the 2D model gives them.

Indices and names are MediaPipe's (``mediapipe.solutions.pose.PoseLandmark``); "left" is the
person's left, as in the Kinect's joint names. Three *virtual* landmarks follow the 33: image
points the lifting treats like the others (the centre of the head between the ears, the centre
of each hand between wrist, index and pinky), because the Kinect's Head and Hand joints sit
there and a point between two landmarks is not where either landmark's depth is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

__all__ = ["LANDMARKS", "LM", "N_LANDMARKS", "N_LIFTED", "Landmarks2D", "with_virtual"]

LANDMARKS: Final[tuple[str, ...]] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
    # virtual (see the module's docstring)
    "head_centre", "left_hand_centre", "right_hand_centre",
)  # fmt: skip
N_LANDMARKS: Final = 33  # what the model gives
N_LIFTED: Final = len(LANDMARKS)  # with the virtual ones
LM: Final[dict[str, int]] = {name: i for i, name in enumerate(LANDMARKS)}

#: virtual landmark -> the model's landmarks it is the mean of
_VIRTUAL: Final[tuple[tuple[int, tuple[int, ...]], ...]] = (
    (LM["head_centre"], (LM["left_ear"], LM["right_ear"])),
    (LM["left_hand_centre"], (LM["left_wrist"], LM["left_index"], LM["left_pinky"])),
    (LM["right_hand_centre"], (LM["right_wrist"], LM["right_index"], LM["right_pinky"])),
)


@dataclass(frozen=True, eq=False)
class Landmarks2D:
    """One person's 2D landmarks in one image.

    Attributes
    ----------
    uv_px : (33, 2) float
        Pixel coordinates in the image the model saw (``u`` right, ``v`` down, origin at the
        centre of the top-left pixel); NaN where the model gave none.
    visibility : (33,) float
        The model's probability that the landmark is visible (not occluded), in [0, 1].
    image_size : (int, int)
        ``(width, height)`` of that image.
    """

    uv_px: NDArray[np.float64]
    visibility: NDArray[np.float64]
    image_size: tuple[int, int]


def with_virtual(lm: Landmarks2D) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The 33 landmarks and the virtual ones: ``uv (36, 2)`` and ``visibility (36,)``."""
    uv = np.full((N_LIFTED, 2), np.nan)
    vis = np.zeros(N_LIFTED)
    uv[:N_LANDMARKS] = lm.uv_px
    vis[:N_LANDMARKS] = lm.visibility
    for k, parts in _VIRTUAL:
        uv[k] = lm.uv_px[list(parts)].mean(axis=0)
        vis[k] = float(np.min(lm.visibility[list(parts)]))
    return uv, vis
