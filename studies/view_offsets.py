"""Could the fusion learn the tracker's view-dependent joint offsets? The takes of
``studies/analysis_accuracy.py accuracy --save DIR`` (one folder per subject) fused three ways.

    python studies/view_offsets.py DIR [DIR ...] [--harmonics 6] [--ridge 1000]
        [--rom-s 120] [--static-s 10] [--wand-s 15]

(each DIR's subject seed is read from its name's trailing digits, ``.../s3`` -> ``--seed 3``, as
the ``accuracy`` run that saved it; the other options are that run's, its defaults here).

A Kinect's joint centres are off by an amount that depends on where it sees the body from
(``docs/error_model_tracker.md``, the view-dependent offset and the surface pull). Modelled as
a smooth function ``b_j(phi)`` per joint, in the body frame (right, forward, up from the fused
hips and shoulders), of the sensor's azimuth ``phi`` in that frame (a Fourier series of
``--harmonics`` orders without its constant, ridge ``--ridge * k^2`` on order ``k``), the same
function for every sensor:

* **self-calibrated**: fitted, with Huber weights (8 cm), to the sensors' pairwise
  disagreements frame by frame (``z_a - z_b = b(phi_a) - b(phi_b)``: what any fusion could
  do; the constant cancels and is chosen so the correction averages to zero over the
  observations), every stream corrected by it, fused again;
* **oracle**: each sensor's error against the floor (the truth plus the subject's joint
  offsets) regressed on the same series with its constant (*with the truth*: no fusion can);

mirrored-back frames are left out of the fits and not corrected. Per variant, over every take
and side and the benchmark's walk frames: the leg joints' mean error against the floor and the
anatomical knee and hip flexion RMSE against the truth's (static phase, zero at standing: the
figures of ``analysis_accuracy.py accuracy``). ``docs/analysis.md``, "What the sensors share".
About 5 s per take.
``--smoke``: makes one small ``accuracy --save`` folder first and reads it (CI runs it).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis_accuracy import saved_takes_arguments, saved_takes_of
from kinefuse import biomech as an
from kinefuse.biomech.side_consistency import angle_rmse_deg
from kinefuse.capture.sync.assembly import interpolate
from kinefuse.core.skeleton import JOINT_INDEX, TrackingState
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.poses import resolve_poses
from kinefuse.pipeline.analysis_chain import skeleton_anatomy
from kinefuse.pipeline.store_inputs import frame_grid, load_sensors, run_method

ROOT = Path(__file__).resolve().parents[1]

LEGS = [JOINT_INDEX[f"{j}{s}"] for j in ("Hip", "Knee", "Ankle") for s in ("Left", "Right")]
ANGLES = ("knee_flexion_left", "knee_flexion_right", "hip_flexion_left", "hip_flexion_right")
HUBER_M = 0.08
INFERRED_WEIGHT = 0.25


def basis(phi: np.ndarray, k: int) -> np.ndarray:
    """``(..., 2k)`` cos and sin of orders 1..k."""
    order = np.arange(1, k + 1)
    return np.concatenate([np.cos(phi[..., None] * order), np.sin(phi[..., None] * order)], -1)


def body_frames(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(T, 3, 3)`` body axes (columns right, forward, up) and ``(T, 3)`` origin (SpineBase)."""
    j = JOINT_INDEX
    right = (x[:, j["HipRight"]] - x[:, j["HipLeft"]]) + (
        x[:, j["ShoulderRight"]] - x[:, j["ShoulderLeft"]]
    )
    right[:, 2] = 0.0
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    up = np.broadcast_to([0.0, 0.0, 1.0], right.shape)
    return np.stack([right, np.cross(up, right), up], -1), x[:, j["SpineBase"]]


def azimuth(axes: np.ndarray, origin: np.ndarray, sensor_pos: np.ndarray) -> np.ndarray:
    """The sensor's azimuth in the body frame, radians (0 in front, positive to the right)."""
    d = sensor_pos - origin
    return np.arctan2((d * axes[:, :, 0]).sum(-1), (d * axes[:, :, 1]).sum(-1))


def world(sensor: Any) -> np.ndarray:
    m = sensor.sensor2world
    return sensor.observations.joints_m @ m[:3, :3].T + m[:3, 3]


def self_calibrated(sensors: list[Any], res: Any, k: int, ridge: float) -> tuple[Any, Any]:
    """``(25, 2k, 3)`` coefficients and ``(25, 3)`` constant from the pairwise disagreements."""
    t = res.t_server_s
    axes, origin = body_frames(res.positions)
    z, w, phi = [], [], []
    for i, s in enumerate(sensors):
        zi = interpolate(s.t_server_s, world(s), t)
        idx = np.clip(np.searchsorted(s.t_server_s, t), 0, len(s.t_server_s) - 1)
        tracked = s.observations.states[idx] == TrackingState.TRACKED
        zi[res.mirrored[:, i] | ~np.isfinite(axes).all((1, 2))] = np.nan
        z.append(zi)
        w.append(np.where(tracked, 1.0, INFERRED_WEIGHT))
        phi.append(azimuth(axes, origin, s.sensor2world[:3, 3]))
    coef, const = np.zeros((25, 2 * k, 3)), np.zeros((25, 3))
    pen = np.diag(ridge * np.tile(np.arange(1, k + 1) ** 2, 2).astype(float))
    for j in range(25):
        rows, targets, weights = [], [], []
        for a in range(len(sensors)):
            for b in range(a + 1, len(sensors)):
                d = z[a][:, j] - z[b][:, j]
                ok = np.isfinite(d).all(-1)
                rows.append(basis(phi[a][ok], k) - basis(phi[b][ok], k))
                targets.append(np.einsum("tik,ti->tk", axes[ok], d[ok]))
                weights.append(w[a][ok, j] * w[b][ok, j])
        a_, y, wt = np.concatenate(rows), np.concatenate(targets), np.concatenate(weights)
        if not len(y):
            continue
        c = np.zeros((2 * k, 3))
        for _ in range(5):  # Huber on the 3D residual
            r = np.linalg.norm(y - a_ @ c, axis=-1)
            ww = wt * np.minimum(1.0, HUBER_M / np.maximum(r, 1e-9))
            c = np.linalg.solve((a_ * ww[:, None]).T @ a_ + pen, (a_ * ww[:, None]).T @ y)
        coef[j] = c
        seen = np.concatenate([phi[i][np.isfinite(z[i][:, j]).all(-1)] for i in range(len(z))])
        const[j] = basis(seen, k).mean(0) @ c
    return coef, const


def oracle(sensors: list[Any], res: Any, floor: np.ndarray, k: int) -> tuple[Any, Any]:
    """The same series fitted to each sensor's error against the floor (with the truth)."""
    axes, origin = body_frames(floor)
    err, phi = [], []
    for i, s in enumerate(sensors):
        zi = interpolate(s.t_server_s, world(s), res.t_server_s)
        zi[res.mirrored[:, i]] = np.nan
        err.append(np.einsum("tik,tji->tjk", axes, zi - floor))
        phi.append(azimuth(axes, origin, s.sensor2world[:3, 3]))
    e_all, p_all = np.stack(err), np.stack(phi).reshape(-1)
    coef, const = np.zeros((25, 2 * k, 3)), np.zeros((25, 3))
    for j in range(25):
        e = e_all[:, :, j].reshape(-1, 3)
        ok = np.isfinite(e).all(-1) & np.isfinite(p_all) & (np.linalg.norm(e, axis=-1) < 0.3)
        a_ = np.c_[np.ones(int(ok.sum())), basis(p_all[ok], k)]
        c = np.linalg.solve(a_.T @ a_ + np.diag([0.0] + [1.0] * 2 * k), a_.T @ e[ok])
        coef[j], const[j] = c[1:], -c[0]
    return coef, const


def corrected(sensors: list[Any], res: Any, coef: Any, const: Any) -> list[Any]:
    """Every stream less its offset ``b(phi) - const``, in its own frame."""
    out = []
    for i, s in enumerate(sensors):
        axes, origin = body_frames(interpolate(res.t_server_s, res.positions, s.t_server_s))
        k = coef.shape[1] // 2
        b = np.einsum("tk,jkc->tjc", basis(azimuth(axes, origin, s.sensor2world[:3, 3]), k),
                      coef) - const  # fmt: skip
        bw = np.einsum("tic,tjc->tji", axes, b)
        idx = np.clip(np.searchsorted(res.t_server_s, s.t_server_s), 0, len(res.t_server_s) - 1)
        bw[res.mirrored[idx, i]] = 0.0
        bw[~np.isfinite(bw)] = 0.0
        m = s.sensor2world
        joints = (world(s) - bw - m[:3, 3]) @ m[:3, :3]
        out.append(replace(s, observations=replace(s.observations, joints_m=joints)))
    return out


def figures(x: np.ndarray, z: Any, frames: np.ndarray, static: tuple[float, float]) -> list[float]:
    """Leg joints' mean error against the floor (cm), then the four flexions' RMSE (degrees)."""
    t, truth, floor = z["t_s"], z["truth"], z["floor"]
    leg = 100 * float(np.nanmean(np.linalg.norm(x[frames] - floor[frames], axis=-1)[:, LEGS]))
    tseq = an.SkeletonSequence.from_kinect(truth, t_s=t, source="truth")
    fseq = an.SkeletonSequence.from_kinect(x, t_s=t, source="fused")
    at, _ = skeleton_anatomy(tseq, an.normalize(tseq), static, "standing")
    af, _ = skeleton_anatomy(fseq, an.normalize(fseq), static, "standing")
    r = angle_rmse_deg(af, at, frames=np.flatnonzero(frames))
    return [leg] + [float(r[a]) for a in ANGLES]


def take(path: Path, walk: tuple[float, float], static: tuple[float, float],
         k: int, ridge: float) -> dict[str, list[float]]:  # fmt: skip
    z = np.load(path.with_suffix(".npz"))
    with SessionStore.open(path) as store:
        poses, _ = resolve_poses(store, None, False)
        sensors = load_sensors(store, poses)
    grid = frame_grid(sensors)
    res = run_method(sensors, grid, "best")
    if not np.array_equal(res.t_server_s, z["t_s"]):
        raise SystemExit(f"{path}: the fusion's frames are not the saved ones")
    err = np.nanmean(np.linalg.norm(res.positions - z["truth"], axis=-1), 1)
    frames = (z["t_s"] >= walk[0]) & (z["t_s"] <= walk[1]) & (err < 0.2)  # the benchmark's
    out = {"as is": figures(res.positions, z, frames, static)}
    for name, (coef, const) in (
        ("self-calibrated", self_calibrated(sensors, res, k, ridge)),
        ("oracle", oracle(sensors, res, z["floor"], k)),
    ):
        again = run_method(corrected(sensors, res, coef, const), grid, "best")
        out[name] = figures(again.positions, z, frames, static)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    saved_takes_arguments(ap)
    ap.add_argument("--harmonics", type=int, default=6)
    ap.add_argument("--ridge", type=float, default=1000.0)
    args = ap.parse_args()
    rows: dict[str, list[list[float]]] = {}
    takes = saved_takes_of(args)
    static = (args.wand_s, args.wand_s + args.static_s)
    for path, walk in takes:
        for name, row in take(path, walk, static, args.harmonics, args.ridge).items():
            rows.setdefault(name, []).append(row)
            print(f"{path} {name:15s} legs {row[0]:.2f} cm, knee L/R {row[1]:.1f}/{row[2]:.1f}°, "
                  f"hip L/R {row[3]:.1f}/{row[4]:.1f}°", file=sys.stderr, flush=True)  # fmt: skip
    n = len(next(iter(rows.values())))
    print(f"{n} takes, walk frames; anatomical flexion against the truth's, legs against the floor")
    print("| fusion | leg joints' error cm | knee flexion mean, worst (under 8°) | hip flexion "
          "mean, worst (under 8°) |")  # fmt: skip
    print("|---|---|---|---|")
    for name, r in rows.items():
        a = np.array(r)
        knee, hip = a[:, 1:3].ravel(), a[:, 3:5].ravel()
        print(f"| {name} | {a[:, 0].mean():.2f} | {knee.mean():.2f}°, {knee.max():.1f}° "
              f"({int((knee < 8).sum())} of {knee.size}) | {hip.mean():.2f}°, {hip.max():.1f}° "
              f"({int((hip < 8).sum())} of {hip.size}) |")  # fmt: skip


if __name__ == "__main__":
    main()
