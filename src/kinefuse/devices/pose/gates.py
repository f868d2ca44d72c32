"""Plausibility gates: what the 2D model found must be a person before it is sent.

A 2D model finds people in pictures of people (a cartoon on a mug, a poster); depth tells them
apart. Checked on the 25 joints, in this order, each refusal one short reason:

1. **bones of human length**: the median ratio of the measured bones (upper arms, forearms,
   thighs, shanks, shoulder and hip widths, trunk) to the reference adult's
   (:func:`kinefuse.core.skeleton.standing_pose`, 1.75 m) gives the body's scale; outside
   ``min_scale``..``max_scale`` (a person 0.9 to 2.3 m tall) the detection is refused;
2. **consistent left/right**: the shoulders' left-to-right direction and the hips' agree (a body
   whose hips face the other way is two half-detections), and the two sides' bones agree;
3. **on or over the floor** (where a floor is known): the hips not under it, and a body with
   its legs in view has its lowest joint near it (standing, walking, jumping; not floating); a
   joint lifted through the floor (a foot's landmark on the floor behind it) is dropped;
4. **limbs no longer than their bones**: shoulder to wrist and hip to ankle no longer than the
   body's scaled bones allow; a limb that is (a landmark on the wall behind) loses its end
   joints, the body is kept.

A side whose bones disagree with the other side's also loses its end joints (the side farther
from the body's scale); the body is kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, TrackingState, standing_pose

__all__ = ["GateParams", "GateResult", "check_body"]

Array = NDArray[np.float64]

_BONES: Final = {
    "left upper arm": ("ShoulderLeft", "ElbowLeft"),
    "right upper arm": ("ShoulderRight", "ElbowRight"),
    "left forearm": ("ElbowLeft", "WristLeft"),
    "right forearm": ("ElbowRight", "WristRight"),
    "left thigh": ("HipLeft", "KneeLeft"),
    "right thigh": ("HipRight", "KneeRight"),
    "left shank": ("KneeLeft", "AnkleLeft"),
    "right shank": ("KneeRight", "AnkleRight"),
    "shoulder width": ("ShoulderLeft", "ShoulderRight"),
    "hip width": ("HipLeft", "HipRight"),
    "trunk": ("SpineShoulder", "SpineBase"),
}
#: limbs: (name, joints from the root to the end); the end joints go when the limb is too long
_LIMBS: Final = (
    ("left arm", ("ShoulderLeft", "ElbowLeft", "WristLeft")),
    ("right arm", ("ShoulderRight", "ElbowRight", "WristRight")),
    ("left leg", ("HipLeft", "KneeLeft", "AnkleLeft")),
    ("right leg", ("HipRight", "KneeRight", "AnkleRight")),
)
#: what a limb's end carries with it
_BEYOND: Final = {
    "WristLeft": ("HandLeft", "HandTipLeft", "ThumbLeft"),
    "WristRight": ("HandRight", "HandTipRight", "ThumbRight"),
    "AnkleLeft": ("FootLeft",),
    "AnkleRight": ("FootRight",),
    "ElbowLeft": ("WristLeft", "HandLeft", "HandTipLeft", "ThumbLeft"),
    "ElbowRight": ("WristRight", "HandRight", "HandTipRight", "ThumbRight"),
    "KneeLeft": ("AnkleLeft", "FootLeft"),
    "KneeRight": ("AnkleRight", "FootRight"),
}


def _nominal() -> dict[str, float]:
    p = standing_pose()
    out = {}
    for name, (a, b) in _BONES.items():
        out[name] = float(np.linalg.norm(p[JOINT_INDEX[a]] - p[JOINT_INDEX[b]]))
    return out


#: the reference adult's bone lengths, metres
NOMINAL_BONES_M: Final[dict[str, float]] = _nominal()


@dataclass(frozen=True)
class GateParams:
    """Thresholds of the gates (lengths in metres).

    Attributes
    ----------
    min_scale, max_scale : float
        The body's scale against the 1.75 m reference adult: 0.5-1.3 is 0.9-2.3 m tall.
    min_bones : int
        Fewer measurable bones than this: too little of a body to check, refused.
    side_ratio_max : float
        Largest relative difference between a left and a right bone, ``|l - r| / max(l, r)``.
    twist_cos_min : float
        The shoulders' and the hips' left-to-right directions may not be further apart than
        this cosine (-0.5: 120 degrees; a spine twists less than 90).
    limb_slack : float
        A limb may be this fraction longer than its scaled bones (landmark and depth noise).
    below_floor_m : float
        No joint may be further than this under the floor.
    above_floor_m : float
        With the legs in view, the lowest joint must be within this of the floor.
    """

    min_scale: float = 0.5
    max_scale: float = 1.3
    min_bones: int = 3
    side_ratio_max: float = 0.4
    twist_cos_min: float = -0.5
    limb_slack: float = 0.25
    below_floor_m: float = 0.2
    above_floor_m: float = 1.0


@dataclass(frozen=True, eq=False)
class GateResult:
    """What the gates decided: ``refused`` is None for a person (``joints``/``states`` may have
    lost some joints), else the one-line reason."""

    joints_m: Array
    states: NDArray[np.int8]
    refused: str | None
    scale: float


def _drop(joints: Array, states: NDArray[np.int8], names: tuple[str, ...]) -> None:
    for n in names:
        for m in (n, *_BEYOND.get(n, ())):
            joints[JOINT_INDEX[m]] = np.nan
            states[JOINT_INDEX[m]] = TrackingState.NOT_TRACKED


def check_body(
    joints_m: Array,
    states: NDArray[np.int8],
    floor: Array | None = None,
    params: GateParams = GateParams(),
) -> GateResult:
    """Run the gates on one body.

    Parameters
    ----------
    joints_m : (25, 3) float
        Depth camera frame, metres, NaN where not tracked.
    states : (25,) int8
    floor : (4,) float or None
        The floor plane ``(nx, ny, nz, d)`` in the depth camera's frame, ``n`` a unit normal
        pointing up: a point's height above the floor is ``n @ p + d``. None: not known.
    params : GateParams

    Returns
    -------
    GateResult
    """
    joints = np.array(joints_m, dtype=np.float64)
    st = np.array(states, dtype=np.int8)

    def length(a: str, b: str) -> float:
        return float(np.linalg.norm(joints[JOINT_INDEX[a]] - joints[JOINT_INDEX[b]]))

    measured = {n: length(a, b) for n, (a, b) in _BONES.items()}
    measured = {n: v for n, v in measured.items() if np.isfinite(v)}
    if len(measured) < params.min_bones:
        return GateResult(joints, st, f"only {len(measured)} bones with depth: too little of a "
                          "body to check, not sent", float("nan"))  # fmt: skip
    ratios = np.array([measured[n] / NOMINAL_BONES_M[n] for n in measured])
    scale = float(np.median(ratios))
    typical = float(np.median(list(measured.values())))
    if not params.min_scale <= scale <= params.max_scale:
        lo = params.min_scale * min(NOMINAL_BONES_M.values())
        hi = params.max_scale * max(NOMINAL_BONES_M.values())
        return GateResult(
            joints, st,
            f"bones of {100 * typical:.0f} cm (median of {len(measured)}; a person's are "
            f"{100 * lo:.0f}-{100 * hi:.0f} cm): not a person",
            scale,
        )  # fmt: skip

    j = {n: joints[i] for n, i in JOINT_INDEX.items()}
    lat_s = j["ShoulderLeft"] - j["ShoulderRight"]
    lat_h = j["HipLeft"] - j["HipRight"]
    # across the image (x, y of the camera): the depth of a far side is the least sure part,
    # and a body turned to the side has short, meaningless left-to-right directions
    lat_s, lat_h = lat_s[:2], lat_h[:2]
    ns, nh = float(np.linalg.norm(lat_s)), float(np.linalg.norm(lat_h))
    wide = ns > 0.6 * scale * NOMINAL_BONES_M["shoulder width"] and (
        nh > 0.6 * scale * NOMINAL_BONES_M["hip width"]
    )
    if wide and float(lat_s @ lat_h) < params.twist_cos_min * ns * nh:
        return GateResult(joints, st, "left and right disagree: the shoulders face one way "
                          "and the hips the other", scale)  # fmt: skip

    if floor is not None:
        f = np.asarray(floor, dtype=np.float64)
        heights = joints @ f[:3] + f[3]
        trunk = [JOINT_INDEX[n] for n in ("SpineBase", "HipLeft", "HipRight")]
        low_trunk = np.nanmin(heights[trunk]) if np.isfinite(heights[trunk]).any() else np.nan
        if low_trunk < -params.below_floor_m:
            return GateResult(joints, st, f"hips {100 * -low_trunk:.0f} cm under the floor: "
                              "not a person in the room", scale)  # fmt: skip
        sunk = np.isfinite(heights) & (heights < -params.below_floor_m)
        _drop(joints, st, tuple(JOINTS[k] for k in np.flatnonzero(sunk)))  # through the floor
        heights[sunk] = np.nan
        ok = np.isfinite(heights)
        legs = [JOINT_INDEX[n] for n in ("AnkleLeft", "AnkleRight", "FootLeft", "FootRight")]
        if ok[legs].any() and float(np.min(heights[ok])) > params.above_floor_m:
            low = float(np.min(heights[ok]))
            return GateResult(joints, st, f"feet {low:.2f} m above the floor: not a person "
                              "standing or moving over it", scale)  # fmt: skip

    for kind in ("upper arm", "forearm", "thigh", "shank"):
        left, right = measured.get(f"left {kind}"), measured.get(f"right {kind}")
        if (
            left is None
            or right is None
            or abs(left - right) / max(left, right) <= (params.side_ratio_max)
        ):
            continue
        nominal = scale * NOMINAL_BONES_M[f"left {kind}"]
        worse = "left" if abs(left - nominal) > abs(right - nominal) else "right"
        _drop(joints, st, (_BONES[f"{worse} {kind}"][1],))

    for name, chain in _LIMBS:
        side, kind = name.split()
        upper, lower = ("upper arm", "forearm") if kind == "arm" else ("thigh", "shank")
        slack = (1.0 + params.limb_slack) * scale
        up_m = slack * NOMINAL_BONES_M[f"{side} {upper}"]
        low_m = slack * NOMINAL_BONES_M[f"{side} {lower}"]
        root, mid, end = (joints[JOINT_INDEX[n]] for n in chain)
        if np.linalg.norm(mid - root) > up_m:
            _drop(joints, st, (chain[1],))
        elif np.linalg.norm(end - mid) > low_m or np.linalg.norm(end - root) > up_m + low_m:
            _drop(joints, st, (chain[2],))
    return GateResult(joints, st, None, scale)
