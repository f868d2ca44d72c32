"""Geometry and noise helpers of the body-tracker model (:mod:`kinefuse.sim.tracker`).

Visibility of joints past the capsule body (ray casting), the body frame, default poses, the
bone-length hold that keeps reported joints on a plausible body, and the correlated noise
processes. Pure numpy/scipy, vectorized over frames and joints.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import lfilter

from kinefuse.core.geometry.raycast import ray_capsules_batched
from kinefuse.core.skeleton import (
    JOINT_INDEX,
    JOINTS,
    MIRROR_INDEX,
    N_JOINTS,
    PARENTS,
    bone_index_array,
    standing_pose,
)
from kinefuse.errors import InputError
from kinefuse.sim.tracker_params import TrackerParams

Array = NDArray[np.float64]
_MIRROR: Final = np.asarray(MIRROR_INDEX)


def _ar1(rng: np.random.Generator, shape: tuple[int, ...], phi: float) -> Array:
    """Stationary unit-variance AR(1) sequences along axis 0: ``x_t = phi x_{t-1} + ...``."""
    e = rng.standard_normal(shape)
    if shape[0] == 0:
        return e
    x_prev = rng.standard_normal(shape[1:])
    b = np.array([np.sqrt(max(1.0 - phi * phi, 0.0))])
    a = np.array([1.0, -phi])
    zi = (phi * x_prev)[None, ...]
    y, _ = lfilter(b, a, e, axis=0, zi=zi)
    return np.asarray(y, dtype=np.float64)


def _phi(dt_s: float, tau_s: float) -> float:
    return float(np.exp(-dt_s / tau_s))


def _body_axes(p: Array, up: Array) -> Array:
    """Body frame ``(T, 3, 3)`` with columns (right, forward, up) from joints ``(T, 25, 3)``.

    ``up`` (3,) is the world's up direction in the frame of ``p``.
    """
    j = JOINT_INDEX
    lateral = (p[:, j["HipRight"]] - p[:, j["HipLeft"]]) + (
        p[:, j["ShoulderRight"]] - p[:, j["ShoulderLeft"]]
    )
    lateral = lateral - (lateral @ up)[:, None] * up[None, :]
    n = np.linalg.norm(lateral, axis=1, keepdims=True)
    right = np.where(n > 1e-9, lateral / np.maximum(n, 1e-12), np.array([1.0, 0.0, 0.0]))
    up_t = np.broadcast_to(up, right.shape)
    forward = np.cross(up_t, right)
    return np.stack([right, forward, up_t], axis=-1)


def _default_local(tb: Array, origin: Array) -> Array:
    """A standing pose in body coordinates (right, forward, up) from the spine base ``(T, 25,
    3)``, scaled to the believed body's spine-base-to-head length."""
    std = standing_pose()  # facing +x, z up: right is -y
    std_local = np.stack([-std[:, 1], std[:, 0], std[:, 2]], axis=-1)
    base, head = JOINT_INDEX["SpineBase"], JOINT_INDEX["Head"]
    std_local = std_local - std_local[base]
    trunk = np.linalg.norm(tb[:, head] - origin, axis=-1)
    scale = trunk / np.linalg.norm(std_local[head])
    return std_local[None] * np.nan_to_num(scale, nan=1.0)[:, None, None]


def _point_segment_distance(p: Array, a: Array, b: Array) -> Array:
    """Distance ``(T, P, C)`` from points ``(T, P, 3)`` to segments ``(T, C, 3)``."""
    ab = b - a  # (T, C, 3)
    abab = np.maximum(np.einsum("tci,tci->tc", ab, ab), 1e-18)[:, None, :]
    pab = p @ ab.transpose(0, 2, 1)  # (T, P, C)
    aab = np.einsum("tci,tci->tc", a, ab)[:, None, :]
    s = np.clip((pab - aab) / abab, 0.0, 1.0)
    pp = np.einsum("tpi,tpi->tp", p, p)[:, :, None]
    pa = p @ a.transpose(0, 2, 1)
    aa = np.einsum("tci,tci->tc", a, a)[:, None, :]
    ap2 = pp - 2.0 * pa + aa  # |p - a|^2
    d2 = ap2 - 2.0 * s * (pab - aab) + s * s * abab
    return np.asarray(np.sqrt(np.maximum(d2, 0.0)), dtype=np.float64)


def joint_radii(radii: ArrayLike) -> Array:
    """Radius of the body around each joint ``(25,)``: the mean radius of its bones' capsules."""
    r = np.asarray(radii, dtype=np.float64)
    bones = bone_index_array()
    total = np.zeros(N_JOINTS)
    count = np.zeros(N_JOINTS)
    for col in (0, 1):
        np.add.at(total, bones[:, col], r)
        np.add.at(count, bones[:, col], 1.0)
    return total / np.maximum(count, 1.0)


#: Sample directions around a joint (centre and four points on a circle facing the sensor).
_SAMPLES: Final = np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def body_visibility(
    joints_sensor: ArrayLike,
    radii: ArrayLike,
    *,
    margin_m: float = 0.02,
    sample_radius_factor: float = 1.0,
    chunk: int = 128,
) -> tuple[Array, Array]:
    """How much of each joint the sensor sees past the body, and how deep below the surface it is.

    Rays from the sensor's optical centre (the origin) go to every joint and to four points
    around it (on a circle of ``sample_radius_factor`` times the body radius at the joint,
    perpendicular to the ray), and are cast against the capsule body of the same frame. Capsules
    the joint (or the sample point) lies inside are not occluders (the joint is inside its own
    limbs); the first of the joint's capsules along the central ray is the surface the sensor
    sees in front of the joint.

    Parameters
    ----------
    joints_sensor : (T, 25, 3) float
        True joints in the sensor frame, metres.
    radii : (24,) float
        Capsule radius per bone, in :data:`kinefuse.core.skeleton.BONES` order, metres.
    margin_m : float
        A capsule hides a point only if the ray meets it at least this far in front of it.
    sample_radius_factor : float
        Radius of the sample circle around each joint, in body radii at the joint.
    chunk : int
        Frames per batch (bounds memory).

    Returns
    -------
    visible_fraction : (T, 25) float
        Share of the five rays no other body part blocks (1: fully visible, 0: hidden).
    depth_below_surface_m : (T, 25) float
        Distance along the central ray from the visible surface of the joint's own body parts to
        the joint, metres (0 when the ray does not enter them before the joint).
    """
    p = np.asarray(joints_sensor, dtype=np.float64)
    r = np.asarray(radii, dtype=np.float64)
    bones = bone_index_array()
    if p.ndim != 3 or p.shape[1:] != (N_JOINTS, 3):
        raise InputError(f"joints_sensor must have shape (T, {N_JOINTS}, 3), got {p.shape}")
    if r.shape != (len(bones),) or not np.all(r > 0):
        raise InputError(
            f"radii must be {len(bones)} positive capsule radii in metres (BONES order), "
            f"got shape {r.shape}; use kinefuse.core.skeleton.capsule_radii(height_m)"
        )
    n_t = p.shape[0]
    n_s = _SAMPLES.shape[0]
    rj = joint_radii(r) * sample_radius_factor  # (J,)
    frac = np.ones((n_t, N_JOINTS))
    depth = np.zeros((n_t, N_JOINTS))
    for s in range(0, n_t, max(int(chunk), 1)):  # chunks bound memory; work is vectorized
        q = p[s : s + chunk]
        nt = q.shape[0]
        a = q[:, bones[:, 0]]
        b = q[:, bones[:, 1]]
        dist = np.linalg.norm(q, axis=-1)  # (t, J)
        u = q / np.maximum(dist, 1e-12)[..., None]
        # two unit vectors perpendicular to each ray (e1 horizontal-ish in the image)
        e1 = np.cross(u, np.array([0.0, 1.0, 0.0]))
        e1 /= np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-12)
        e2 = np.cross(u, e1)
        pts = q[:, :, None, :] + rj[None, :, None, None] * (
            _SAMPLES[None, None, :, 0, None] * e1[:, :, None, :]
            + _SAMPLES[None, None, :, 1, None] * e2[:, :, None, :]
        )  # (t, J, S, 3)
        d_pts = np.linalg.norm(pts, axis=-1)
        dirs = (pts / d_pts[..., None]).reshape(nt, N_JOINTS * n_s, 3)
        t_hit = ray_capsules_batched(np.zeros(3), dirs, a, b, r).reshape(
            nt, N_JOINTS, n_s, -1
        )  # (t, J, S, C)
        inside = _point_segment_distance(q, a, b) < r[None, None, :]  # (t, J, C)
        # a capsule the joint or the sample point lies in is part of what is looked at
        inside_pts = _point_segment_distance(pts.reshape(nt, -1, 3), a, b) < r[None, None, :]
        own = inside[:, :, None, :] | inside_pts.reshape(nt, N_JOINTS, n_s, -1)
        blocking = ~own & (t_hit < d_pts[..., None] - margin_m)
        frac[s : s + chunk] = 1.0 - blocking.any(axis=-1).mean(axis=-1)
        t0 = t_hit[:, :, 0, :]
        entry = np.where(inside & (t0 < dist[..., None]), t0, np.inf).min(axis=-1)
        depth[s : s + chunk] = np.where(np.isfinite(entry), dist - entry, 0.0)
    return frac, depth


def _check_rigid(sensor2world: ArrayLike) -> Array:
    t = np.asarray(sensor2world, dtype=np.float64)
    if t.shape != (4, 4) or not np.all(np.isfinite(t)):
        raise InputError(f"sensor2world must be one finite (4, 4) transform, got shape {t.shape}")
    r = t[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise InputError(
            "sensor2world's rotation part is not a proper rotation (R^T R = I, det R = +1); "
            "build it with kinefuse.core.geometry.transforms.look_at or make_transform"
        )
    if not np.allclose(t[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"sensor2world's last row must be [0, 0, 0, 1], got {t[3]}")
    return t


def _dropout_mask(
    rng: np.random.Generator, n_t: int, dt_s: float, params: TrackerParams
) -> NDArray[np.bool_]:
    n_events = int(rng.poisson(params.dropout_rate_hz * n_t * dt_s)) if n_t else 0
    starts = rng.integers(0, max(n_t, 1), n_events)
    lengths = np.maximum(np.round(rng.exponential(params.dropout_mean_s / dt_s, n_events)), 1)
    ends = np.minimum(starts + lengths.astype(np.int64), n_t)
    marks = np.zeros(n_t + 1, dtype=np.int64)
    np.add.at(marks, starts, 1)
    np.add.at(marks, ends, -1)
    return np.asarray(np.cumsum(marks)[:n_t] > 0)


def _smooth(rng: np.random.Generator, shape: tuple[int, ...], dt_s: float, tau_s: float) -> Array:
    """Stationary unit-variance smooth noise along axis 0: white noise through two first-order
    low-pass stages of time constant ``tau_s`` (a critically damped second-order filter).

    Its autocorrelation at lag ``k`` frames is ``phi^k (1 + k (1 - phi^2) / (1 + phi^2))`` with
    ``phi = exp(-dt / tau)``: the frame-to-frame steps are far smaller than those of a first-order
    process of the same variance, as the output of a smoothing filter is. The filter starts from
    rest ``5 tau`` before the first frame (burn-in), so the sequence is stationary.
    """
    n = shape[0]
    if n == 0:
        return np.zeros(shape)
    phi = _phi(dt_s, tau_s)
    burn = int(min(np.ceil(5.0 * tau_s / dt_s), 3000))
    e = rng.standard_normal((n + burn, *shape[1:]))
    gain = np.sqrt((1.0 - phi * phi) ** 3 / (1.0 + phi * phi))
    y = lfilter([gain], [1.0, -2.0 * phi, phi * phi], e, axis=0)
    return np.asarray(y[burn:], dtype=np.float64)


def _smooth_along(
    rng: np.random.Generator, u: ArrayLike, shape_rest: tuple[int, ...], tau_u: float
) -> Array:
    """:func:`_smooth` noise sampled at the non-decreasing "times" ``u`` ``(T,)``.

    The process runs on a uniform grid of ``u`` (step ``tau_u / 20``) and is interpolated
    linearly: where ``u`` stands still, so does the noise. Returns ``(T, *shape_rest)``.
    """
    uu = np.asarray(u, dtype=np.float64)
    n_t = uu.size
    if n_t == 0:
        return np.zeros((0, *shape_rest))
    du = tau_u / 20.0
    k = (uu - uu[0]) / du
    n = int(np.floor(k[-1])) + 2
    y = _smooth(rng, (n, *shape_rest), du, tau_u)
    i = np.minimum(np.floor(k).astype(np.int64), n - 2)
    f = (k - i).reshape(n_t, *([1] * len(shape_rest)))
    return np.asarray((1.0 - f) * y[i] + f * y[i + 1], dtype=np.float64)


def _topology() -> tuple[list[int], NDArray[np.bool_]]:
    depth = np.zeros(N_JOINTS, dtype=np.int64)
    for j in range(N_JOINTS):
        k = j
        while PARENTS[k] >= 0:
            depth[j] += 1
            k = PARENTS[k]
    bones = bone_index_array()
    order = sorted(range(len(bones)), key=lambda b: int(depth[bones[b, 1]]))
    subtree = np.zeros((N_JOINTS, N_JOINTS), dtype=bool)  # subtree[j, k]: k is j or below j
    for k in range(N_JOINTS):
        a = k
        while a >= 0:
            subtree[a, k] = True
            a = PARENTS[a]
    return order, subtree


_BONE_ORDER, _SUBTREE = _topology()

#: +1 for the body's right joints, -1 for the left ones, 0 on the midline.
_SIDE_SIGN: Final = np.array(
    [1.0 if "Right" in n else -1.0 if "Left" in n else 0.0 for n in JOINTS]
)


def chain_correlate(noise: ArrayLike, rho: float) -> Array:
    """Independent per-joint noise ``(T, 25, ...)`` made coherent along the skeleton's chain.

    Parents first, each joint's noise becomes ``rho * parent + sqrt(1 - rho^2) * own``: every
    joint keeps its unit variance, and two neighbours correlate by ``rho`` (``rho^k`` for joints
    ``k`` bones apart). ``rho = 0`` returns the noise unchanged.
    """
    x = np.array(noise, dtype=np.float64)
    if rho == 0.0:
        return x
    bones = bone_index_array()
    own = np.sqrt(1.0 - rho * rho)
    for b in _BONE_ORDER:
        pa, ch = bones[b]
        x[:, ch] = rho * x[:, pa] + own * x[:, ch]
    return x


def bone_lengths(joints: ArrayLike, seen: ArrayLike | None = None) -> Array:
    """The body's bone lengths ``(24,)`` (:data:`kinefuse.core.skeleton.BONES` order), metres.

    The median over the frames of ``joints`` ``(T, 25, 3)`` in which both ends of the bone are
    ``seen`` ``(T, 25)`` bool (default: all frames). A bone never seen takes its mirrored twin's
    length, else the standing pose's scaled to the body's spine-base-to-neck length.
    """
    p = np.asarray(joints, dtype=np.float64)
    bones = bone_index_array()
    length = np.linalg.norm(p[:, bones[:, 1]] - p[:, bones[:, 0]], axis=-1)
    if seen is not None:
        m = np.asarray(seen, dtype=bool)
        length = np.where(m[:, bones[:, 0]] & m[:, bones[:, 1]], length, np.nan)
    has = np.isfinite(length).any(axis=0)
    out = np.full(len(bones), np.nan)
    out[has] = np.nanmedian(length[:, has], axis=0)
    if not has.all():
        pairs = {(int(a), int(b)): k for k, (a, b) in enumerate(bones)}
        std = standing_pose()
        std_len = np.linalg.norm(std[bones[:, 1]] - std[bones[:, 0]], axis=-1)
        base, neck = JOINT_INDEX["SpineBase"], JOINT_INDEX["Neck"]
        trunk = np.nanmedian(np.linalg.norm(p[:, neck] - p[:, base], axis=-1))
        scale = trunk / np.linalg.norm(std[neck] - std[base])
        for k in np.flatnonzero(~has):
            a, b = bones[k]
            twin = pairs.get((int(_MIRROR[a]), int(_MIRROR[b])))
            out[k] = out[twin] if twin is not None and has[twin] else std_len[k] * scale
    return np.asarray(out, dtype=np.float64)


def hold_to_body(joints: ArrayLike, nominal_m: ArrayLike, weight: ArrayLike) -> Array:
    """Pull every bone of a reported skeleton toward the body's own length.

    Parents first, each bone's child moves along the bone (its direction from the parent's
    final position kept) so that its length becomes ``w * nominal + (1 - w) * reported``
    (``w`` the child's weight). Only the child moves: a well-seen wrist below a guessed elbow
    stays where it was seen, and its own bone is held next.

    Parameters
    ----------
    joints : (T, 25, 3) float
        Reported joints, finite, metres.
    nominal_m : (24,) float
        The body's bone lengths (:func:`bone_lengths`), metres.
    weight : (T, 25) float
        Per frame and child joint, 0 (leave the bone) to 1 (the nominal length).
    """
    out = np.array(joints, dtype=np.float64)
    lengths = np.asarray(nominal_m, dtype=np.float64)
    w = np.asarray(weight, dtype=np.float64)
    bones = bone_index_array()
    for b in _BONE_ORDER:
        pa, ch = bones[b]
        v = out[:, ch] - out[:, pa]
        cur = np.linalg.norm(v, axis=-1)
        target = w[:, ch] * lengths[b] + (1.0 - w[:, ch]) * cur
        scale = np.where(cur > 1e-9, target / np.maximum(cur, 1e-9) - 1.0, 0.0)
        out[:, ch] += v * scale[:, None]
    return out


def far_side(view_rad: ArrayLike, perm: ArrayLike) -> Array:
    """How far on the hidden side of the body each reported joint is, ``(T, 25)`` in [0, 1].

    ``view_rad`` (T,) is the sensor's azimuth in the body frame (positive: the sensor is on the
    body's right); ``perm`` (T, 25) maps each reported label to the true joint it follows.
    A left joint seen from straight right is 1, a near-side or midline joint 0.
    """
    s = np.sin(np.asarray(view_rad, dtype=np.float64))
    sign = _SIDE_SIGN[np.asarray(perm)]
    return np.asarray(np.clip(-sign * s[:, None], 0.0, 1.0), dtype=np.float64)
