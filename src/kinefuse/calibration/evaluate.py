"""Calibration errors against the truth, as the paper evaluates them (evaluation code only).

Nothing here is used by the calibration; it reads the truth a simulated session keeps aside.

The calibrated world and the true world agree only up to a choice of frame (the calibration puts
its origin under the wand's first position, the simulator wherever its rig file says), so the
estimated poses are first mapped onto the true ones by the best transform of a chosen kind:

* ``"yaw"`` (default): rotation about the vertical plus a translation. Gravity is not
  re-estimated, so an error in the calibrated "up" shows up as rotation error, as it should;
* ``"rigid"``: full rotation and translation (for a world pinned to a sensor without gravity);
* ``"similarity"``: like ``"yaw"`` plus a uniform scale fitted on the sensor centres. A depth
  camera whose range error grows with distance (the Kinect v2's does, by a few mm per metre)
  makes a self-calibrated world slightly larger than the true one: no wand or floor seen in depth
  can tell, since the whole world scaled about itself fits the same measurements. This mode
  separates that scale (reported as ``PoseErrors.scale``) from the rest of the error;
* ``"none"``: the frames are already the same.

The alignment uses four points per sensor: its centre and the tips of its three axes at 1 m, so
it is defined for any number of sensors.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.calibration.register import Registration, Sightings
from kinefuse.errors import CalibrationError, InputError
from kinefuse.geometry.rotations import rotation_angle_deg
from kinefuse.geometry.transforms import check_transform, kabsch, make_transform
from kinefuse.io.outputs import atomic_file, never_replace

Array = NDArray[np.float64]
Align = Literal["yaw", "rigid", "similarity", "none"]


@dataclass(frozen=True, eq=False)
class PoseErrors:
    """Per-sensor pose errors after aligning the estimated world onto the true one.

    Attributes
    ----------
    position_error_m : (S,) float
        Distance between estimated and true sensor centres.
    rotation_error_deg : (S,) float
        Angle of the rotation between estimated and true orientations.
    est2true : (4, 4) float
        The aligning transform applied to the estimates (its 3x3 block includes ``scale``).
    scale : float
        Scale of the alignment (1 except for ``align="similarity"``).
    """

    position_error_m: Array
    rotation_error_deg: Array
    est2true: Array
    scale: float = 1.0

    @property
    def mean_position_error_m(self) -> float:
        return float(np.mean(self.position_error_m))

    @property
    def mean_rotation_error_deg(self) -> float:
        return float(np.mean(self.rotation_error_deg))


def _pose_points(poses: Array) -> Array:
    tips = np.concatenate([np.zeros((1, 3)), np.eye(3)])  # centre and axis tips, 1 m
    return np.asarray(np.einsum("sij,kj->ski", poses[:, :3, :3], tips) + poses[:, None, :3, 3])


def align_worlds(
    est_sensor2world: ArrayLike, true_sensor2world: ArrayLike, *, align: Align = "yaw"
) -> Array:
    """The transform ``est2true (4, 4)`` that best maps estimated poses onto true ones.

    Parameters
    ----------
    est_sensor2world, true_sensor2world : (S, 4, 4) float
    align : {"yaw", "rigid", "none"}
        Kind of transform (see the module docstring).
    """
    est = check_transform(est_sensor2world, "est_sensor2world").reshape(-1, 4, 4)
    tru = check_transform(true_sensor2world, "true_sensor2world").reshape(-1, 4, 4)
    if est.shape != tru.shape:
        raise InputError(f"estimated and true poses differ in shape: {est.shape} vs {tru.shape}")
    if align == "none":
        return np.eye(4)
    a = _pose_points(est).reshape(-1, 3)
    b = _pose_points(tru).reshape(-1, 3)
    if align == "rigid":
        return kabsch(a, b)
    if align not in ("yaw", "similarity"):
        raise InputError(f"align must be 'yaw', 'rigid', 'similarity' or 'none', got {align!r}")
    if align == "similarity":
        if len(est) < 2:
            raise InputError("align='similarity' needs at least 2 sensors")
        a, b = est[:, :3, 3], tru[:, :3, 3]  # the scale acts on positions only
    ca, cb = a.mean(0), b.mean(0)
    pa, pb = (a - ca)[:, :2], (b - cb)[:, :2]
    ang = np.arctan2(np.sum(pa[:, 0] * pb[:, 1] - pa[:, 1] * pb[:, 0]), np.sum(pa * pb))
    c, s = np.cos(ang), np.sin(ang)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    scale = 1.0
    if align == "similarity":
        scale = float(np.sum(((a - ca) @ rz.T) * (b - cb)) / np.sum((a - ca) ** 2))
    return make_transform(scale * rz, cb - scale * rz @ ca)


def pose_errors(
    est_sensor2world: ArrayLike, true_sensor2world: ArrayLike, *, align: Align = "yaw"
) -> PoseErrors:
    """Position and rotation error of every sensor after :func:`align_worlds`.

    Returns
    -------
    PoseErrors
        ``position_error_m (S,)``, ``rotation_error_deg (S,)``, the alignment used, and the means.
    """
    est = check_transform(est_sensor2world, "est_sensor2world").reshape(-1, 4, 4)
    tru = check_transform(true_sensor2world, "true_sensor2world").reshape(-1, 4, 4)
    e2t = align_worlds(est, tru, align=align)
    scale = float(np.cbrt(np.linalg.det(e2t[:3, :3])))
    pos_est = est[:, :3, 3] @ e2t[:3, :3].T + e2t[:3, 3]
    rot_est = np.einsum("ij,sjk->sik", e2t[:3, :3] / scale, est[:, :3, :3])
    pos = np.linalg.norm(pos_est - tru[:, :3, 3], axis=1)
    rot = np.atleast_1d(rotation_angle_deg(rot_est, tru[:, :3, :3]))
    return PoseErrors(position_error_m=pos, rotation_error_deg=rot, est2true=e2t, scale=scale)


@dataclass(frozen=True, eq=False)
class WandErrors:
    """Errors of individual wand sightings, with what the paper plots them against.

    Attributes
    ----------
    error_m : (N,) float
        Distance between the estimated and the true wand centre.
    distance_m : (N,) float
        True distance of the wand from the sensor.
    angle_deg : (N,) float
        True angle between the wand direction and the sensor's optical axis.
    """

    error_m: Array
    distance_m: Array
    angle_deg: Array


def wand_errors(est_m: ArrayLike, true_m: ArrayLike, true_centre_sensor_m: ArrayLike) -> WandErrors:
    """Per-sighting errors against distance and angle from the optical axis.

    Parameters
    ----------
    est_m, true_m : (N, 3) float
        Estimated and true wand centres in the same frame: the sensor frame for the detector's
        error, or the world (estimated pose mapped through ``est2true``) for the calibration's.
    true_centre_sensor_m : (N, 3) float
        True wand centre in the sensor frame (gives distance and angle).
    """
    e = np.asarray(est_m, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(true_m, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(true_centre_sensor_m, dtype=np.float64).reshape(-1, 3)
    if not (e.shape == t.shape == c.shape):
        raise InputError(f"shapes differ: {e.shape}, {t.shape}, {c.shape}")
    dist = np.linalg.norm(c, axis=1)
    ang = np.degrees(np.arccos(np.clip(c[:, 2] / np.maximum(dist, 1e-12), -1.0, 1.0)))
    return WandErrors(np.linalg.norm(e - t, axis=1), dist, ang)


def mapped_wand_errors(
    sensor2world: ArrayLike,
    est2true: ArrayLike,
    centre_sensor_m: ArrayLike,
    true_world_m: ArrayLike,
    true_centre_sensor_m: ArrayLike,
) -> WandErrors:
    """Errors of one sensor's sightings mapped to the world with its estimated pose.

    ``est2true`` is the alignment from :func:`pose_errors`; the error combines detection and
    registration, like the paper's comparison with a laser meter.
    """
    s2w = check_transform(sensor2world).reshape(4, 4)
    e2t = check_transform(est2true).reshape(4, 4)
    t = e2t @ s2w
    c = np.asarray(centre_sensor_m, dtype=np.float64).reshape(-1, 3)
    return wand_errors(c @ t[:3, :3].T + t[:3, 3], true_world_m, true_centre_sensor_m)


@dataclass(frozen=True, eq=False)
class Binned:
    """Statistics of an error in bins of a variable: centres, mean, std, quartiles, count."""

    centre: Array
    mean: Array
    std: Array
    median: Array
    q25: Array
    q75: Array
    count: NDArray[np.int64]


def binned(x: ArrayLike, err: ArrayLike, edges: ArrayLike) -> Binned:
    """Mean, std and median of ``err`` in the bins ``edges`` of ``x`` (NaN for empty bins)."""
    xv = np.asarray(x, dtype=np.float64).reshape(-1)
    ev = np.asarray(err, dtype=np.float64).reshape(-1)
    ed = np.asarray(edges, dtype=np.float64).reshape(-1)
    if xv.shape != ev.shape:
        raise InputError(f"x and err differ in length: {xv.shape} vs {ev.shape}")
    if ed.size < 2 or np.any(np.diff(ed) <= 0):
        raise InputError("edges must be at least 2 increasing values")
    ok = np.isfinite(xv) & np.isfinite(ev)
    idx = np.digitize(xv[ok], ed) - 1
    nb = ed.size - 1
    inside = (idx >= 0) & (idx < nb)
    idx, vals = idx[inside], ev[ok][inside]
    count = np.bincount(idx, minlength=nb).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(idx, weights=vals, minlength=nb) / count
        sq = np.bincount(idx, weights=vals * vals, minlength=nb) / count
    std = np.sqrt(np.maximum(sq - mean * mean, 0.0))
    order = np.argsort(idx, kind="stable")
    splits = np.split(vals[order], np.cumsum(count)[:-1])
    q = np.array([np.percentile(s, [25, 50, 75]) if s.size else [np.nan] * 3 for s in splits])
    q = q.reshape(nb, 3)
    return Binned(0.5 * (ed[1:] + ed[:-1]), mean, std, q[:, 1], q[:, 0], q[:, 2], count)


@dataclass(frozen=True, eq=False)
class SightingsCurve:
    """Mean calibration errors against the number of wand sightings used."""

    duration_s: Array
    mean_sightings: Array
    mean_position_error_m: Array
    mean_rotation_error_deg: Array


def error_vs_sightings(
    sightings: Mapping[str, Sightings],
    true_sensor2world: ArrayLike,
    register: Callable[[Mapping[str, Sightings]], Registration],
    durations_s: Sequence[float],
    *,
    align: Align = "yaw",
) -> SightingsCurve:
    """Calibrate on the first ``d`` seconds of the wand phase for each ``d``; errors vs truth.

    Parameters
    ----------
    sightings : mapping sensor id -> Sightings
    true_sensor2world : (S, 4, 4) float
        True poses in the order of ``sightings``.
    register : callable
        ``sightings -> Registration`` (e.g. ``lambda s: register_full(s, floors=floors)``).
    durations_s : sequence of float
        Lengths of the calibration phase to try.

    Returns
    -------
    SightingsCurve
        Durations where the registration succeeded, with the mean number of sightings per sensor
        and the mean errors.
    """
    true = check_transform(true_sensor2world).reshape(-1, 4, 4)
    ids = list(sightings)
    t0 = min(float(s.t_server_s[0]) for s in sightings.values() if len(s))
    rows = []
    for d in durations_s:
        sub = {
            k: Sightings(
                s.t_server_s[s.t_server_s <= t0 + d],
                s.centre_sensor_m[s.t_server_s <= t0 + d],
                s.quality[s.t_server_s <= t0 + d],
            )
            for k, s in sightings.items()
        }
        try:
            reg = register(sub)
        except CalibrationError:  # too few sightings is a data point, not a failure
            continue
        order = [reg.sensor_ids.index(k) for k in ids]
        pe = pose_errors(reg.sensor2world[order], true, align=align)
        rows.append(
            (
                d,
                float(np.mean([len(v) for v in sub.values()])),
                pe.mean_position_error_m,
                pe.mean_rotation_error_deg,
            )
        )
    arr = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return SightingsCurve(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])


def plot_calibration_errors(
    path: str | Path,
    errors: WandErrors,
    *,
    curve: SightingsCurve | None = None,
    title: str = "Calibration error",
    distance_edges_m: ArrayLike = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5),
    angle_edges_deg: ArrayLike = (0, 5, 10, 15, 20, 25, 30, 35, 40),
) -> Path:
    """Write a PNG with error vs wand distance, vs angle from the optical axis, and (optionally)
    vs number of sightings, like the paper's figures. Returns the path written."""
    from matplotlib.figure import Figure  # drawn off-screen; no global backend is changed

    n_panels = 3 if curve is not None else 2
    fig = Figure(figsize=(5 * n_panels, 4), constrained_layout=True)
    axes = fig.subplots(1, n_panels)
    for ax, x, edges, label in (
        (axes[0], errors.distance_m, distance_edges_m, "wand distance from the sensor (m)"),
        (axes[1], errors.angle_deg, angle_edges_deg, "wand angle from the optical axis (deg)"),
    ):
        b = binned(x, errors.error_m, edges)
        mm = errors.error_m * 1e3
        ax.scatter(x, mm, s=2, alpha=0.2, color="0.5", label="sightings")
        ax.errorbar(
            b.centre,
            b.median * 1e3,
            yerr=np.abs(np.stack([b.median - b.q25, b.q75 - b.median])) * 1e3,
            fmt="o-",
            color="C0",
            capsize=3,
            label="median, quartiles",
        )
        ax.plot(b.centre, b.mean * 1e3, "s--", color="C3", ms=4, label="mean")
        fin = mm[np.isfinite(mm)]
        if fin.size:  # gross outliers (shown as the count above the axis) would hide the trend
            top = 1.5 * float(np.percentile(fin, 95))
            n_out = int((fin > top).sum())
            ax.set_ylim(0.0, top)
            if n_out:
                ax.set_title(f"{n_out} sightings above {top:.0f} mm not shown", fontsize=9)
        ax.set_xlabel(label)
        ax.set_ylabel("error (mm)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left")
    if curve is not None:
        ax = axes[2]
        ax.plot(
            curve.mean_sightings, curve.mean_position_error_m * 1e3, "o-", label="position (mm)"
        )
        ax2 = ax.twinx()
        ax2.plot(
            curve.mean_sightings,
            curve.mean_rotation_error_deg,
            "s--",
            color="C1",
            label="rotation (deg)",
        )
        ax.set_xlabel("wand sightings per sensor")
        ax.set_ylabel("mean position error (mm)")
        ax2.set_ylabel("mean rotation error (deg)")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right")
        ax2.legend(loc="center right")
    fig.suptitle(title)
    out = Path(path)
    with atomic_file(out, what="plot", recognizer=never_replace, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=100, format="png")

    return out
