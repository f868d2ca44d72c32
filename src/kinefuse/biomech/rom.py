"""A range-of-motion calibration phase with known truth, on a real subject's skeleton.

:func:`make_rom_motion` takes a default pose (25 Kinect joints of a real subject, e.g. the
default-pose frame of a real clip, :func:`kinefuse.biomech.find_default_pose`) and moves each
limb along its main directions one after another (trunk, head, then per side the upper arm, the
forearm, the thigh, the shank and the foot), each movement repeated, with pauses at the default
pose between movements, cosine speed profiles of a realistic peak speed (drawn per stroke,
``speed_deg_s``), and a slow whole-body sway (every limb, a few tenths of a degree to a degree,
plus the pelvis translating by millimetres) as the noise a person standing still adds.

The true axes are the anatomical templates (:mod:`kinefuse.biomech.anatomy`) tilted by a random
angle up to ``axis_tilt_deg`` (real joints do not turn about the textbook axes; Baker 2003,
Wu et al. 2005), made orthogonal to the rest direction (each movement sweeps a great circle of
the joint sphere, the paper's axis-plane model). Rotations of the shoulder and the hip about
their long axes are done with the elbow or knee bent (as a clinician tests them) so that they
are observable from positions; the forearm's pronation with the elbow at 90°.

The limb model: each limb's local rotation in its parent's frame is
``M = R(a0, t0) R(a1, t1) R(rest, twist)``, the same as :mod:`kinefuse.biomech.kinematics`
parameterizes, so the true angles are comparable one to one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.biomech import anatomy
from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS, LIMBS
from kinefuse.biomech.normalize import body_frame, limb_frame_from_body
from kinefuse.biomech.retarget import facing_direction
from kinefuse.biomech.sequence import SkeletonSequence
from kinefuse.core.frames.motion import Motion
from kinefuse.core.geometry.rotations import rodrigues, rot_z, unit
from kinefuse.core.skeleton import JOINT_INDEX, N_JOINTS
from kinefuse.errors import InputError

Array = NDArray[np.float64]

#: The movements, in order: (limb, dof, +amplitude, -amplitude) in degrees. ``dof`` is the axis
#: index in JCS order or ``"twist"``. Amplitudes are typical active ranges of motion.
MOVEMENTS: tuple[tuple[str, int | str, float, float], ...] = (
    ("trunk", 0, 40.0, 15.0),
    ("trunk", 1, 25.0, 25.0),
    ("trunk", "twist", 30.0, 30.0),
    ("head", 0, 35.0, 30.0),
    ("head", 1, 25.0, 25.0),
    *(
        m
        for s in ("left", "right")
        for m in (
            (f"upper_arm_{s}", 0, 110.0, 40.0),
            (f"upper_arm_{s}", 1, 100.0, 5.0),
            (f"upper_arm_{s}", "twist", 45.0, 45.0),
            (f"forearm_{s}", 0, 120.0, 0.0),
            (f"forearm_{s}", "twist", 60.0, 60.0),
            (f"thigh_{s}", 0, 70.0, 20.0),
            (f"thigh_{s}", 1, 15.0, 35.0),
            (f"thigh_{s}", "twist", 30.0, 30.0),
            (f"shank_{s}", 0, 100.0, 0.0),
            (f"foot_{s}", 0, 20.0, 35.0),
        )
    ),
)
#: A twist movement is done with the child bent: (limb -> (child limb, its flexion, degrees)).
_BENT_FOR_TWIST = {"upper_arm": ("forearm", 90.0), "forearm": None, "thigh": ("shank", 70.0)}


@dataclass(frozen=True, eq=False)
class RomTruth:
    """The truth of a generated calibration phase.

    Attributes
    ----------
    axes : dict limb -> (k, 3) float
        True unit axes in the parent's normalized frame (JCS order, ISB signs).
    axes_world : dict limb -> (k, 3) float
        The same axes in the world at the default pose.
    rest : dict limb -> (3,) float
        True rest direction in the parent's frame.
    angles : dict limb -> (T, k) float
        True angles about the axes, radians.
    twist : dict limb -> (T,) float
        True twist about the long axis, radians.
    movements : list of (limb, dof, start_s, end_s)
        When each movement happened.
    default_pose : (25, 3) float
        The pose the phase starts and ends in, metres, world.
    frames : (T, L, 3, 3) float
        True limb-to-world rotations (the generator's limb frames, equal to the normalized frames
        of the default pose up to the sway at the frame the normalization picks).
    rate_hz : float
        Frame rate of ``angles``, ``twist`` and ``frames``.
    """

    axes: dict[str, Array]
    axes_world: dict[str, Array]
    rest: dict[str, Array]
    angles: dict[str, Array]
    twist: dict[str, Array]
    movements: list[tuple[str, str, float, float]] = field(default_factory=list)
    default_pose: Array = field(default_factory=lambda: np.zeros((N_JOINTS, 3)))
    frames: Array = field(default_factory=lambda: np.zeros((0, 0, 3, 3)))
    rate_hz: float = 0.0

    def axes_in(self, norm_frames: Array, truth_frames: Array) -> dict[str, Array]:
        """The true axes expressed in another normalization of the true motion.

        ``norm_frames (L, 3, 3)`` are that normalization's limb frames and ``truth_frames
        (L, 3, 3)`` this truth's :attr:`frames`, both at one common instant (world frames may
        differ by a placement: use the placed truth's frames). Every limb's normalized frame is
        rigidly attached to its true frame, so the constant offset between them maps the axes.
        """
        out = {}
        for name, a in self.axes.items():
            par = LIMB_PARENTS[LIMB_INDEX[name]]
            e = norm_frames[par].T @ truth_frames[par]
            out[name] = (e @ a.T).T
        return out


def _profile(n: int) -> Array:
    """Cosine (smooth start and stop) from 0 to 1 over ``n`` samples."""
    return 0.5 - 0.5 * np.cos(np.linspace(0.0, np.pi, n))


def make_rom_motion(
    default_pose: ArrayLike,
    /,
    seconds: float | None = None,
    rng: np.random.Generator | None = None,
    *,
    rate_hz: float = 60.0,
    repeats: int = 2,
    pause_s: float = 0.8,
    speed_deg_s: tuple[float, float] = (70.0, 130.0),
    axis_tilt_deg: float = 8.0,
    sway_deg: float = 0.6,
) -> tuple[Motion, RomTruth]:
    """Generate a range-of-motion calibration phase on ``default_pose`` ``(25, 3)`` (metres).

    Parameters
    ----------
    default_pose : (25, 3) float
        A real subject's default pose (upright, arms hanging), world frame, z up.
    seconds : float, optional
        Stretch or compress the schedule in time to last this long (speeds scale with it;
        rejected if the peak speed would leave 20 to 400 °/s).
    rng : numpy.random.Generator
        Source of the axes' tilts, the stroke speeds and the sway.
    rate_hz : float
        Frame rate of the returned motion.
    repeats : int
        How often each movement is repeated (each repeat: out to +amplitude, back, out to
        -amplitude, back).

    Returns
    -------
    motion : kinefuse.core.frames.motion.Motion
    truth : RomTruth
    """
    pose = np.asarray(default_pose, dtype=np.float64)
    if pose.shape != (N_JOINTS, 3) or not np.isfinite(pose).all():
        raise InputError(
            f"default_pose must be the 25 Kinect joints (25, 3), finite, got {pose.shape}"
        )
    rng = np.random.default_rng(0) if rng is None else rng
    if repeats < 1:
        raise InputError(f"repeats must be at least 1, got {repeats}")
    body = body_frame(pose)
    n_l = len(LIMBS)
    n0 = np.zeros((n_l, 3, 3))
    for i, lb in enumerate(LIMBS):
        u = pose[lb.distal_index] - pose[lb.proximal_index]
        n0[i] = body if i == 0 else limb_frame_from_body(u, body, lb.body_axis)[0]
    # pelvis frame at rest = its normalized frame (the root carries the body frame)
    rest_vec = np.zeros((n_l, 3))
    offset = np.zeros((n_l, 3))
    q0 = np.zeros((n_l, 3, 3))
    axes: dict[str, Array] = {}
    for i, lb in enumerate(LIMBS):
        par = LIMB_PARENTS[i]
        if par < 0:
            continue
        rest_vec[i] = n0[par].T @ (pose[lb.distal_index] - pose[lb.proximal_index])
        offset[i] = n0[par].T @ (pose[lb.proximal_index] - pose[LIMBS[par].proximal_index])
        q0[i] = n0[par].T @ n0[i]
        r = unit(rest_vec[i])
        # a limb that gives its parent's twist (the forearm for the upper arm's elbow plane, the
        # shank for the thigh, the foot for the shank) must turn about an axis orthogonal to the
        # parent's long axis too, or the parent's position-only twist would move with it
        p_long = unit(n0[par].T @ (pose[LIMBS[par].distal_index] - pose[LIMBS[par].proximal_index]))
        is_ref = LIMBS[par].twist_ref[-1:] == (lb.distal,)
        tilted = []
        for _, t in anatomy.templates(lb.name)[: lb.n_axes]:
            d = unit(rng.normal(size=3))
            tilt = np.radians(axis_tilt_deg) * np.sqrt(rng.uniform())
            a = rodrigues(unit(np.cross(t, d)), tilt) @ t
            a = unit(a - (a @ r) * r)
            both = np.cross(p_long, r)
            if is_ref and np.linalg.norm(both) > np.sin(np.radians(10.0)):
                a = unit(both) * np.sign(both @ t)
            elif is_ref:
                a = unit(a - (a @ p_long) * p_long)
            tilted.append(a)
        axes[lb.name] = np.array(tilted)
    # joints at no limb's end, rigid in a limb: (limb, anchor joint, offset in the limb frame)
    attach = [("SpineMid", "pelvis", "SpineBase"), ("Neck", "head", "SpineShoulder")]
    attach += [(f"{j}{side}", f"forearm_{side.lower()}", f"Wrist{side}")
               for side in ("Left", "Right") for j in ("Hand", "HandTip", "Thumb")]  # fmt: skip
    rigid = {}
    for j, limb_name, anchor in attach:
        fi = LIMB_INDEX[limb_name]
        rigid[j] = (fi, anchor, n0[fi].T @ (pose[JOINT_INDEX[j]] - pose[JOINT_INDEX[anchor]]))

    # ---- schedule of angle targets per limb dof
    dt = 1.0 / rate_hz
    movements: list[tuple[str, str, float, float]] = []
    pause = max(round(pause_s * rate_hz), 1)

    def stroke(amp: float) -> Array:
        if amp == 0:
            return np.zeros(0)
        v = rng.uniform(*speed_deg_s)
        n = max(round(abs(amp) * np.pi / 2 / v * rate_hz), 4)  # cosine peak speed = v
        out_ = amp * _profile(n)
        return np.concatenate([out_, out_[::-1]])

    plan: list[tuple[str, int | str, Array, tuple[str, float] | None]] = []
    for limb, dof, pos_amp, neg_amp in MOVEMENTS:
        vals = [np.zeros(pause)]
        for _ in range(repeats):
            vals += [stroke(pos_amp), stroke(-neg_amp)]
        bend = None
        kind = limb.removesuffix("_left").removesuffix("_right")
        if dof == "twist" and _BENT_FOR_TWIST.get(kind):
            child, deg = _BENT_FOR_TWIST[kind]  # type: ignore[misc]
            bend = (f"{child}_{limb.rsplit('_', 1)[-1]}", deg)
        plan.append((limb, dof, np.concatenate(vals), bend))
    n_total = sum(v.size + (2 * _bend_len(rate_hz) if b else 0) for _, _, v, b in plan) + pause
    scale = 1.0
    if seconds is not None:
        scale = float(seconds) / (n_total * dt)
        lo, hi = speed_deg_s[0] / scale, speed_deg_s[1] / scale
        if lo < 20.0 or hi > 400.0:
            raise InputError(
                f"a {seconds:g} s calibration phase would move limbs at {lo:.0f}-{hi:.0f} °/s; "
                f"give between {n_total * dt * speed_deg_s[1] / 400:.0f} and "
                f"{n_total * dt * speed_deg_s[0] / 20:.0f} s"
            )
    ang = {lb.name: np.zeros((n_total, max(lb.n_axes, 0))) for lb in LIMBS[1:]}
    twist = {lb.name: np.zeros(n_total) for lb in LIMBS[1:]}
    k = pause
    for limb, dof, values, bend in plan:
        start = k
        nb = _bend_len(rate_hz) if bend else 0
        if bend:
            child, deg = bend
            ramp = np.radians(deg) * _profile(nb)
            ang[child][k : k + nb, 0] = ramp
            ang[child][k + nb : k + nb + values.size, 0] = np.radians(deg)
            ang[child][k + nb + values.size : k + 2 * nb + values.size, 0] = ramp[::-1]
        sl = slice(k + nb, k + nb + values.size)
        if dof == "twist":
            twist[limb][sl] = np.radians(values)
        else:
            ang[limb][sl, int(dof)] = np.radians(values)
        k += values.size + 2 * nb
        movements.append((limb, str(dof), start * dt * scale, k * dt * scale))
    # time scaling: resample the schedule onto the stretched time base
    t_src = np.arange(n_total) * dt * scale
    n_out = int(np.floor(t_src[-1] * rate_hz)) + 1
    t_out = np.arange(n_out) / rate_hz
    ang = {kk: np.stack([np.interp(t_out, t_src, v[:, j]) for j in range(v.shape[1])], -1)
           if v.shape[1] else np.zeros((n_out, 0)) for kk, v in ang.items()}  # fmt: skip
    twist = {kk: np.interp(t_out, t_src, v) for kk, v in twist.items()}
    # sway: slow sums of sinusoids on every dof, pelvis translation
    sway = np.radians(sway_deg)
    for name in ang:
        for jj in range(ang[name].shape[1]):
            ang[name][:, jj] += _sway(rng, t_out, sway)
        twist[name] += _sway(rng, t_out, 0.5 * sway)
    pelvis_shift = np.stack([_sway(rng, t_out, 0.004) for _ in range(3)], axis=-1)
    pelvis_rot = [_sway(rng, t_out, 0.5 * sway) for _ in range(3)]

    # ---- forward kinematics
    pos = np.zeros((n_out, N_JOINTS, 3))
    frames = np.zeros((n_out, n_l, 3, 3))
    rp = rodrigues(np.broadcast_to([1.0, 0, 0], (n_out, 3)), pelvis_rot[0])
    rp = rodrigues(np.broadcast_to([0, 1.0, 0], (n_out, 3)), pelvis_rot[1]) @ rp
    rp = rodrigues(np.broadcast_to([0, 0, 1.0], (n_out, 3)), pelvis_rot[2]) @ rp
    frames[:, 0] = rp @ n0[0]
    pos[:, JOINT_INDEX["SpineBase"]] = pose[JOINT_INDEX["SpineBase"]] + pelvis_shift
    done = np.zeros(N_JOINTS, dtype=bool)
    done[JOINT_INDEX["SpineBase"]] = True
    for i, lb in enumerate(LIMBS):
        par = LIMB_PARENTS[i]
        if par < 0:
            continue
        fp = frames[:, par]
        if not done[lb.proximal_index]:
            pos[:, lb.proximal_index] = pos[:, LIMBS[par].proximal_index] + fp @ offset[i]
            done[lb.proximal_index] = True
        r = unit(rest_vec[i])
        m = rodrigues(np.broadcast_to(r, (n_out, 3)), twist[lb.name])
        for jj in range(ang[lb.name].shape[1] - 1, -1, -1):
            ax_j = np.broadcast_to(axes[lb.name][jj], (n_out, 3))
            m = rodrigues(ax_j, ang[lb.name][:, jj]) @ m
        frames[:, i] = fp @ m @ q0[i]
        pos[:, lb.distal_index] = pos[:, lb.proximal_index] + np.einsum(
            "tij,tjk,k->ti", fp, m, rest_vec[i]
        )
        done[lb.distal_index] = True
    for j, (fi, anchor, off) in rigid.items():
        pos[:, JOINT_INDEX[j]] = pos[:, JOINT_INDEX[anchor]] + frames[:, fi] @ off
    axes_world = {kk: (n0[LIMB_PARENTS[LIMB_INDEX[kk]]] @ v.T).T for kk, v in axes.items()}
    truth = RomTruth(
        axes=axes,
        axes_world=axes_world,
        rest={lb.name: unit(rest_vec[i]) for i, lb in enumerate(LIMBS) if i > 0},
        angles=ang,
        twist=twist,
        movements=movements,
        default_pose=pose.copy(),
        frames=frames,
        rate_hz=float(rate_hz),
    )
    motion = Motion(positions=pos, rate_hz=float(rate_hz), source="kinefuse ROM generator")
    return motion, truth


def _bend_len(rate_hz: float) -> int:
    return max(round(0.8 * rate_hz), 2)


def _sway(rng: np.random.Generator, t: Array, amplitude: float) -> Array:
    """A slow random wobble: three sinusoids of 0.05 to 0.5 Hz, RMS about ``amplitude``."""
    f = rng.uniform(0.05, 0.5, size=3)
    ph = rng.uniform(0, 2 * np.pi, size=3)
    return amplitude / np.sqrt(1.5) * np.sin(2 * np.pi * f[:, None] * t + ph[:, None]).sum(0)


def prepend_rom(rom: Motion, clip: Motion, /, *, blend_s: float = 1.0) -> Motion:
    """The clip with the calibration phase before it: the ROM at the clip's rate, then a linear
    blend of ``blend_s`` seconds from the ROM's last pose to the clip's first frame.

    Generate the ROM on a default pose placed where the clip starts (same position and
    heading) so that the blend only changes the pose, not the place.
    """
    n_rom = int(np.floor(rom.duration_s * clip.rate_hz)) + 1
    rom_p = rom.at(np.arange(n_rom) / clip.rate_hz)
    nb = max(round(blend_s * clip.rate_hz), 1)
    w = _profile(nb + 2)[1:-1, None, None]
    blend = rom_p[-1] * (1 - w) + clip.positions[0] * w
    pos = np.concatenate([rom_p, blend, clip.positions])
    return Motion(
        positions=pos,
        rate_hz=clip.rate_hz,
        source=f"ROM {rom.duration_s:.1f} s + {blend_s:g} s blend + {clip.source}",
    )


#: The joints that move with each arm when :func:`standing_pose` lets it hang, shoulder first.
_ARM_CHAIN = ("Shoulder", "Elbow", "Wrist", "Hand", "HandTip", "Thumb")


def standing_pose(pose: ArrayLike, /) -> Array:
    """A static trial's upright stance ``(25, 3)`` made from a subject's pose ``(25, 3)``.

    A clip's default-pose frame (:func:`kinefuse.biomech.find_default_pose`, the paper's
    heuristics) can be a moment of a stride: 02_walk_a's has the right knee bent 72°, 131_01's
    both knees near 40°. A static trial is stood upright instead, so this keeps the trunk, head
    and hips (and every bone length) and changes the limbs:

    * each leg hangs straight down from its hip (knee included angle 0), its ``Foot`` joint
      ahead of the ankle as in the pose's supporting foot (the lower ankle): the same drop below
      the ankle, its own length, pointing where the foot pointed (the body's forward if the foot
      pointed more than 60° away from it);
    * each arm, rigid from the shoulder (the elbow keeps its bend, the hand its shape), turns by
      the smallest rotation that puts the wrist straight below the shoulder;
    * the body moves vertically so that its lowest foot joint is where the pose's was.

    Raises
    ------
    InputError
        ``pose`` is not ``(25, 3)`` or lacks a joint (NaN).
    """
    from kinefuse.core.geometry.rotations import minimal_rotation

    p = np.array(pose, dtype=np.float64)
    if p.shape != (N_JOINTS, 3) or not np.isfinite(p).all():
        raise InputError(
            f"a standing pose is made from 25 finite Kinect joints (25, 3); got shape "
            f"{p.shape} with {int((~np.isfinite(p).all(-1)).sum()) if p.ndim == 2 else '?'} "
            "missing"
        )
    j = JOINT_INDEX
    up = np.array([0.0, 0.0, 1.0])
    fwd = facing_direction(p)
    floor_z = min(p[j[f"{f}{s}"], 2] for f in ("Ankle", "Foot") for s in ("Left", "Right"))
    stance = min(("Left", "Right"), key=lambda s: p[j[f"Ankle{s}"], 2])
    drop = p[j[f"Foot{stance}"], 2] - p[j[f"Ankle{stance}"], 2]
    out = p.copy()
    for s in ("Left", "Right"):
        hip, knee, ankle, foot = (j[f"{n}{s}"] for n in ("Hip", "Knee", "Ankle", "Foot"))
        thigh = np.linalg.norm(p[knee] - p[hip])
        shank = np.linalg.norm(p[ankle] - p[knee])
        out[knee] = p[hip] - thigh * up
        out[ankle] = out[knee] - shank * up
        v = p[foot] - p[ankle]
        length = float(np.linalg.norm(v))
        h = v * np.array([1.0, 1.0, 0.0])
        hn = np.linalg.norm(h)
        heading = h / hn if hn > 1e-6 and float(h @ fwd) > 0.5 * hn else fwd
        dz = float(np.clip(drop, -length, length))
        out[foot] = out[ankle] + np.sqrt(max(length**2 - dz**2, 0.0)) * heading + dz * up
        arm = [j[f"{n}{s}"] for n in _ARM_CHAIN]
        sh = p[arm[0]]
        hang = p[j[f"Wrist{s}"]] - sh
        r = minimal_rotation(hang / np.linalg.norm(hang), -up)
        out[arm[1:]] = sh + (p[arm[1:]] - sh) @ r.T
    feet = [j[f"{f}{s}"] for f in ("Ankle", "Foot") for s in ("Left", "Right")]
    out[:, 2] += floor_z - out[feet, 2].min()
    return out


# ------------------------------------------------------------------ simulate --rom


@dataclass(frozen=True, eq=False)
class RomPhase:
    """A standing phase and/or a range-of-motion phase put before a clip (for ``kinefuse
    simulate --static/--rom``)."""

    motion: Any  # kinefuse.core.frames.motion.Motion: standing, the ROM, the blend, then the clip
    rom_s: float  # length of the ROM phase itself, seconds (the blend follows it); 0: none
    blend_s: float
    truth: dict[str, Any]  # JSON-able truth (true axes, rest, twist over time ...)
    static_s: float = 0.0  # length of the standing phase before the ROM, seconds; 0: none
    rom_start_s: float = 0.0  # where the ROM starts in ``motion`` (after standing and a blend)


#: Postural sway of the simulated standing phase: the whole body moves horizontally by a slow
#: wobble of about this RMS (quiet standing sways a few millimetres; Prieto et al. 1996 report
#: 4-6 mm RMS of the centre of pressure), metres.
STANDING_SWAY_M = 0.004


def standing_motion(pose: Any, seconds: float, rate_hz: float, rng: Any) -> Any:
    """``pose (25, 3)`` held for ``seconds`` at ``rate_hz``, the whole body swaying slowly
    (:data:`STANDING_SWAY_M` RMS, 0.05-0.5 Hz): a static trial's standing."""
    n = int(np.floor(seconds * rate_hz)) + 1
    t = np.arange(n) / rate_hz
    sway = np.zeros((n, 3))
    for k in range(2):
        f = rng.uniform(0.05, 0.5, size=3)
        ph = rng.uniform(0.0, 2.0 * np.pi, size=3)
        sway[:, k] = np.sin(2.0 * np.pi * f[:, None] * t + ph[:, None]).sum(0)
    sway *= STANDING_SWAY_M / np.sqrt(1.5) / np.sqrt(2.0)
    sway -= sway[-1]  # ends where it stands, so the next phase starts from the pose itself
    pos = np.asarray(pose, dtype=np.float64)[None] + sway[:, None, :]
    return Motion(positions=pos, rate_hz=float(rate_hz), source=f"standing {seconds:g} s")


def stand_before(
    motion: Any, pose: Any, seconds: float, rng: Any, blend_s: float = 1.0
) -> tuple[Any, float, float]:
    """``motion`` with a static trial before it: the subject standing upright
    (:func:`kinefuse.biomech.rom.standing_pose` of ``pose (25, 3)``; a default pose can be a
    moment of a stride) for ``seconds`` with postural sway (:func:`standing_motion`), then a
    blend of ``blend_s`` into ``motion``'s first frame. Returns the motion, the standing
    phase's length and where ``motion`` now starts (seconds)."""
    stand = standing_motion(standing_pose(pose), seconds, motion.rate_hz, rng)
    both = prepend_rom(stand, motion, blend_s=blend_s)
    return both, stand.duration_s, (both.n_frames - motion.n_frames) / motion.rate_hz


def add_rom_phase(
    clip: Any,
    rom_s: float | None,
    *,
    seed: int = 0,
    blend_s: float = 1.0,
    static_s: float | None = None,
) -> RomPhase:
    """A generated range-of-motion phase of ``rom_s`` seconds before ``clip`` (placed), and
    before it a standing phase of ``static_s`` seconds (a static trial: the subject stands
    upright, :func:`kinefuse.biomech.rom.standing_pose` of the default pose, with postural sway,
    :func:`standing_motion`, then blends into the ROM's first pose in ``blend_s``). Either may be
    None (not both).

    The subject's default pose is the clip's default-pose frame
    (:func:`kinefuse.biomech.find_default_pose`), moved (translation, rotation about z) to
    where the clip starts and facing its first frame's way, so that the blend into the clip only
    changes the pose. Randomness comes from ``seed`` (its own stream, not the simulator's).
    """
    from kinefuse.biomech import find_default_pose
    from kinefuse.core.skeleton import JOINT_INDEX

    if rom_s is None and static_s is None:
        raise InputError(
            "give a range-of-motion phase (--rom), a standing phase (--static) or both"
        )
    if rom_s is not None and not (np.isfinite(rom_s) and rom_s > 0):
        raise InputError(f"--rom must be a positive number of seconds, got {rom_s!r}")
    if static_s is not None and not (np.isfinite(static_s) and static_s >= 1.0):
        raise InputError(
            f"--static must be at least 1 second (a static trial needs frames to average), "
            f"got {static_s!r}"
        )
    seq = SkeletonSequence.from_motion(clip)
    k = find_default_pose(seq)
    pose = clip.positions[k]
    f_pose, f_0 = facing_direction(pose), facing_direction(clip.positions[0])
    turn = float(np.arctan2(f_0[1], f_0[0]) - np.arctan2(f_pose[1], f_pose[0]))
    root = JOINT_INDEX["SpineBase"]
    pivot = pose[root] * np.array([1.0, 1.0, 0.0])
    placed = (pose - pivot) @ rot_z(turn).T
    placed[:, :2] += clip.positions[0, root, :2]
    info: dict[str, Any] = {}
    if rom_s is not None:
        rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x524F4D]))  # "ROM"
        rom, truth = make_rom_motion(placed, rom_s, rng)
        motion = prepend_rom(rom, clip, blend_s=blend_s)
        t_rom = np.arange(rom.n_frames) / rom.rate_hz
        info = {
            "note": "range-of-motion phase of kinefuse simulate --rom: true axes and rest "
            "directions in the parent limb's normalized frame at the default pose (JCS order, "
            "ISB signs), true angles and twists (radians) at t_s (seconds from the phase's "
            "start)",
            "default_pose_frame_of_clip": int(k),
            "axes_parent": {n: v.tolist() for n, v in truth.axes.items()},
            "axes_world": {n: v.tolist() for n, v in truth.axes_world.items()},
            "rest_parent": {n: v.tolist() for n, v in truth.rest.items()},
            "movements": [list(m) for m in truth.movements],
            "t_s": np.round(t_rom, 6).tolist(),
            "twist_rad": {n: np.round(v, 6).tolist() for n, v in truth.twist.items()},
            "angles_rad": {n: np.round(v, 6).tolist() for n, v in truth.angles.items()},
        }
        start = rom.positions[0]
    else:
        motion = clip
        start = placed
    static_len = lead = 0.0
    if static_s is not None:  # standing upright, a blend into the ROM (or the clip)
        rng_s = np.random.default_rng(np.random.SeedSequence([int(seed), 0x535441]))  # "STA"
        motion, static_len, lead = stand_before(motion, start, static_s, rng_s, blend_s)
    return RomPhase(
        motion=motion,
        rom_s=0.0 if rom_s is None else float(rom.duration_s),
        blend_s=blend_s,
        truth=info,
        static_s=static_len,
        rom_start_s=lead,
    )
