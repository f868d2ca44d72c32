"""The calibration phase: an actor waving the wand through the capture volume.

The operator's protocol (it is what a person is told to do, so the system may know it):

1. hold the wand still at the origin mark (world x = y = 0) at ``origin_height_m`` for
   ``hold_s``;
2. move it 1 m along the world +y axis, hold it still again (the paper's axis gesture);
3. wave it through the volume: stop-and-go between random points (hold ``hold_s``, then a
   minimum-jerk move of ``move_s``), so every sensor pair shares many still sightings.

The actor holds the wand's handle in the right hand with the arm stretched toward it; the rest of
the body is the clip's first pose, turned to face the wand. Only the depth images of this phase
matter (the body occludes the wand for some sensors, as a real body would).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.wand import Wand
from kinefuse.core.geometry.raycast import ray_capsules
from kinefuse.core.geometry.rotations import rot_z
from kinefuse.core.skeleton import JOINT_INDEX, bone_index_array, capsule_radii

Array = NDArray[np.float64]

_J = JOINT_INDEX


@dataclass(frozen=True)
class WandProtocol:
    """The calibration gesture (see module docstring). Lengths in metres, times in seconds."""

    origin_height_m: float = 1.0
    axis_length_m: float = 1.0
    hold_s: float = 0.6
    move_s: float = 0.9
    volume_radius_m: float = 1.4
    height_range_m: tuple[float, float] = (0.5, 1.9)

    def to_dict(self) -> dict[str, object]:
        return {
            "origin_height_m": self.origin_height_m,
            "axis_length_m": self.axis_length_m,
            "hold_s": self.hold_s,
            "move_s": self.move_s,
            "volume_radius_m": self.volume_radius_m,
            "height_range_m": list(self.height_range_m),
        }


def _min_jerk(s: Array) -> Array:
    return s**3 * (10 - 15 * s + 6 * s * s)


@dataclass(frozen=True)
class WandPath:
    """A drawn wand path: waypoints visited in turn, holding and moving per the protocol."""

    waypoints: Array
    protocol: WandProtocol

    def at(self, t_s: Array) -> Array:
        """Wand centre ``(N, 3)`` in the world at times ``t_s`` ``(N,)`` from the phase start."""
        t = np.asarray(t_s, dtype=np.float64)
        p = self.protocol
        seg = p.hold_s + p.move_s
        k = np.clip((t // seg).astype(np.intp), 0, len(self.waypoints) - 2)
        s = np.clip((t - k * seg - p.hold_s) / p.move_s, 0.0, 1.0)
        w = _min_jerk(s)[:, None]
        return self.waypoints[k] * (1 - w) + self.waypoints[k + 1] * w


def make_wand_path(
    duration_s: float, rng: np.random.Generator, protocol: WandProtocol = WandProtocol()
) -> WandPath:
    """Draw the waving part of the protocol for a phase of ``duration_s`` seconds.

    Waypoints are random points in the volume, 0.5-1.2 m apart, each preferring the least covered
    part of the volume so far (so 20 s of waving reaches around the whole capture area).
    """
    p = protocol
    seg = p.hold_s + p.move_s
    n_way = int(np.ceil(max(duration_s, 0.0) / seg)) + 2
    way = np.empty((n_way, 3))
    way[0] = (0.0, 0.0, p.origin_height_m)
    way[1] = (0.0, p.axis_length_m, p.origin_height_m)
    lo, hi = p.height_range_m
    for k in range(2, n_way):
        r = p.volume_radius_m * np.sqrt(rng.random(64))
        a = rng.uniform(0, 2 * np.pi, 64)
        cand = np.stack([r * np.cos(a), r * np.sin(a), rng.uniform(lo, hi, 64)], axis=1)
        step = np.linalg.norm(cand - way[k - 1], axis=1)
        ok = (step >= 0.5) & (step <= 1.2)
        if not ok.any():
            ok[:] = True
        # farthest (horizontally) from the waypoints so far: spreads the sightings
        spread = np.min(np.linalg.norm(cand[:, None, :2] - way[None, :k, :2], axis=2), axis=1)
        way[k] = cand[np.argmax(np.where(ok, spread, -np.inf))]
    return WandPath(waypoints=way, protocol=p)


def holding_poses(
    wand_centre: Array,
    rest_pose: Array,
    wand: Wand | None = None,
    *,
    sensor_positions: Array | None = None,
    height_m: float = 1.75,
) -> tuple[Array, Array]:
    """Body poses ``(N, 25, 3)`` of an actor holding the wand, and the handle directions ``(N, 3)``.

    ``rest_pose`` ``(25, 3)`` is a standing pose (the clip's first frame, feet on the floor). The
    body faces the wand and stands back so that its straight right arm reaches the handle. Like a
    careful operator, it stands where it neither hides the wand from a sensor nor stands right
    behind it, for as many sensors as it can (``sensor_positions`` ``(S, 3)``; without them, it
    faces the wand from outside the area).
    """
    wand = Wand() if wand is None else wand
    c = np.asarray(wand_centre, dtype=np.float64).reshape(-1, 3)
    rest = np.asarray(rest_pose, dtype=np.float64)
    root = rest[_J["SpineBase"]].copy()
    root[2] = 0.0
    body = rest - root  # feet on the floor, SpineBase above the origin
    # the rest pose's facing: horizontal normal of the hip line, pointing forward
    hips = body[_J["HipLeft"]] - body[_J["HipRight"]]
    fwd = np.cross([0.0, 0.0, 1.0], hips)
    fwd[2] = 0.0
    fwd /= np.linalg.norm(fwd)
    yaw0 = np.arctan2(fwd[1], fwd[0])
    sh, el, wr, ha = (_J[n] for n in ("ShoulderRight", "ElbowRight", "WristRight", "HandRight"))
    seg_len = np.linalg.norm(np.diff(body[[sh, el, wr, ha]], axis=0), axis=1)
    arm = float(seg_len.sum())
    reach = wand.radius_m + wand.stick_length_m + 0.9 * arm
    bones = bone_index_array()
    radii = capsule_radii(height_m)

    def place(centre: Array, yaw: float) -> tuple[Array, Array]:
        b = body @ rot_z(yaw - yaw0).T
        shoulder = b[sh]
        v = centre[2] - shoulder[2]
        horiz = np.sqrt(max(reach**2 - v**2, 0.2**2))
        heading = np.array([np.cos(yaw), np.sin(yaw)])
        # the right shoulder stands `horiz` behind the wand along the heading
        b[:, :2] += centre[:2] - heading * horiz - shoulder[:2]
        shoulder = b[sh]
        u = shoulder - centre
        u /= np.linalg.norm(u)
        hand = centre + u * (wand.radius_m + wand.stick_length_m)
        d = hand - shoulder
        dist = np.linalg.norm(d)
        d /= max(dist, 1e-9)
        cum = np.concatenate([[0.0], np.cumsum(seg_len)]) * min(dist / arm, 1.0)
        b[[sh, el, wr, ha]] = shoulder + cum[:, None] * d
        b[_J["HandTipRight"]] = b[ha] + d * 0.06
        b[_J["ThumbRight"]] = b[wr] + d * 0.05 + np.array([0.0, 0.0, 0.02])
        return b, u

    def hidden_from(b: Array, centre: Array) -> int:
        if sensor_positions is None:
            return 0
        sp = np.asarray(sensor_positions, dtype=np.float64).reshape(-1, 3)
        to = centre - sp
        dist = np.linalg.norm(to, axis=1)
        # with a margin: an arm or hand next to the line of sight crowds the wand's outline
        t = ray_capsules(sp, to / dist[:, None], b[bones[:, 0]], b[bones[:, 1]], radii + 0.12)
        # the body in front of the wand hides it; right behind it, it merges with it in depth
        return int((t.min(axis=1) < dist + 0.7).sum())

    n = len(c)
    poses = np.empty((n, 25, 3))
    handle = np.empty((n, 3))
    out_dir = c[:, :2] / np.maximum(np.linalg.norm(c[:, :2], axis=1, keepdims=True), 1e-9)
    default_yaw = np.arctan2(-out_dir[:, 1], -out_dir[:, 0])  # face the wand from outside in
    candidates = np.linspace(0.0, 2 * np.pi, 12, endpoint=False)
    for i in range(n):  # a few hundred calibration frames: the loop is not a hot path
        best = place(c[i], float(default_yaw[i]))
        best_hidden = hidden_from(best[0], c[i])
        for yaw in candidates if best_hidden else ():
            cand = place(c[i], float(default_yaw[i] + yaw))
            h = hidden_from(cand[0], c[i])
            if h < best_hidden:
                best, best_hidden = cand, h
                if h == 0:
                    break
        poses[i], handle[i] = best
    return poses, handle
