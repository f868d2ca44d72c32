"""The figures of docs/calibration.md, "Calibration from the person".

    python studies/person_calibration.py --offline
    python studies/person_calibration.py --live Study_7_Kinect_0 Study_5_Kinect_2

``--offline``: every two-Kinect take of ``../shared/data/kinect/kinect_multitrack_population``
calibrated from the person (:func:`kinefuse.capture.calibration.body.calibrate_from_body`, at the
capture times ``kinefuse realdata`` fits) on its first 20, 30, 40 and 60 s: the grade, the trunk
residual, the spread of the path, the split-half figure, and the RMS distance between where
this calibration and the whole take's put the person's path (every trunk centre of the take):
a figure the server cannot see, to check the grade against. About 20 s.

``--live TAKE...``: each take (a file name prefix in that folder) replayed live in real time,
``kinefuse serve --record`` and one ``kinefuse sensor --source multitrack:...`` per Kinect (with
a common ``--epoch-monotonic``), as
``tests/test_live_person.py`` does: when the fusion started, the grades in turn, and the fused
skeleton against ``kinefuse realdata``'s on the same frames. About 1.5 minutes a take.

``--smoke``: ``--offline`` on the first two takes (CI runs it).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from kinefuse.app.workflows.demo import ChildProcesses, parse_listening
from kinefuse.capture.calibration.body import calibrate_from_body
from kinefuse.capture.sync.assembly import interpolate
from kinefuse.capture.sync.envelope import fit_clock_lower_envelope
from kinefuse.core.geometry.rotations import rotation_vector_deg
from kinefuse.core.geometry.transforms import apply_transform, invert_transform, kabsch
from kinefuse.core.skeleton import JOINT_INDEX, TRUNK_JOINTS
from kinefuse.formats.kinect_multitrack import read_kinect_multitrack, unique_frames
from kinefuse.formats.store.live_tables import events, live_fused, obs_times
from kinefuse.formats.store.session_store import SessionStore

ROOT = Path(__file__).resolve().parents[1]
POPULATION = ROOT.parent / "shared" / "data" / "kinect" / "kinect_multitrack_population"
_TRUNK = np.array([JOINT_INDEX[n] for n in TRUNK_JOINTS])


def _tracks(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    out = {}
    for s in read_kinect_multitrack(path).streams:
        f = unique_frames(s)
        t = fit_clock_lower_envelope(f.t_sensor_s, f.t_receive_s).affine.forward(f.t_sensor_s)
        out[s.sensor_id] = (t, f.joints_m)
    t0 = min(float(t[0]) for t, _ in out.values())
    return {k: (t - t0, p) for k, (t, p) in out.items()}


def offline(most: int | None = None) -> None:
    heads = "".join(f"{'first ' + str(n) + ' s':>34}" for n in (20, 30, 40, 60))
    print("take              " + heads)
    print(" " * 18 + "  grade res/spread/halves/off mm" * 4)
    for path in sorted(POPULATION.glob("Study_*.csv"))[:most]:
        tracks = _tracks(path)
        whole = calibrate_from_body(tracks)
        row = f"{path.name[:16]:<18}"
        for n in (20, 30, 40, 60):
            part = {k: (t[t < n], p[t < n]) for k, (t, p) in tracks.items()}
            cal = calibrate_from_body(part)
            if not cal.fits:
                row += f"{cal.grade:>12}{'-':>22}"
                continue
            (other,) = cal.fits
            f = cal.fits[other]
            ref = cal.reference
            # the whole take's path (trunk centres, the reference's frame) mapped into the other
            # sensor by both relative poses: the RMS distance
            c = np.nanmean(tracks[ref][1], axis=1)
            c = np.c_[c[np.isfinite(c).all(1)], np.ones(np.isfinite(c).all(1).sum())]
            rel = invert_transform(cal.sensor2world[ref]) @ cal.sensor2world[other]
            rel_w = invert_transform(whole.sensor2world[ref]) @ whole.sensor2world[other]
            d = (invert_transform(rel) - invert_transform(rel_w)) @ c.T
            off = float(np.sqrt(np.mean(np.sum(d[:3] ** 2, axis=0))))
            row += (
                f"{cal.grade:>12} {1e3 * f.residual_m:4.0f}/{1e3 * f.spread_m:4.0f}/"
                f"{1e3 * f.halves_m:4.0f}/{1e3 * off:5.0f}"
            )
        print(row + f"   whole: {whole.grade}", flush=True)


def realdata_agreement(rec: Path, log: Path) -> dict[str, object]:
    """The live fused skeleton against ``kinefuse realdata``'s (its ``best`` fusion of every
    scenario) on the same frames, after the rigid alignment of the two worlds; distances in m
    as ``(median, p95)`` over all joints and over the trunk."""
    import kinefuse.app.workflows.realdata as rf

    fused: list[tuple[np.ndarray, np.ndarray]] = []
    real = rf.consistency

    def keep(streams, poses, grid, **kw):  # realdata's own call, passed through unchanged
        res = real(streams, poses, grid, **kw)
        fused.append((np.asarray(grid), res["_fused"].positions))
        return res

    rf.consistency = keep  # realdata's own call, observed
    try:
        rep = rf.fuse_multitrack(log).report
    finally:
        rf.consistency = real
    ref = rep["sensors"][0]
    frames = unique_frames(read_kinect_multitrack(log).stream(ref))
    clock = fit_clock_lower_envelope(frames.t_sensor_s, frames.t_receive_s)
    with SessionStore.open(rec) as st:
        obs = st.observations(ref)
        seq, t_cap = obs_times(st, ref)  # (frames recorded but never fused have none)
        lf = live_fused(st)
    _, at, _ = np.intersect1d(obs.seq, seq, return_indices=True)
    t_dev = obs.t_device_s[at]
    t_cap = t_cap[np.searchsorted(seq, obs.seq[at])]
    dev, first = np.unique(t_dev, return_index=True)
    grid = np.concatenate([g for g, _ in fused])
    p_rd = np.concatenate([p for _, p in fused])
    t_live = np.interp(
        np.interp(grid, clock.affine.forward(dev), dev),
        dev,
        t_cap[first],
        left=np.nan,
        right=np.nan,
    )
    on = np.isfinite(t_live)
    p_live = interpolate(lf.t_server_s, lf.positions_m, t_live[on], max_gap_s=0.05)
    p_rd = p_rd[on]
    both = np.isfinite(p_live).all(-1) & np.isfinite(p_rd).all(-1)
    align = kabsch(p_live[both], p_rd[both])
    d = np.linalg.norm(apply_transform(align, p_live) - p_rd, axis=-1)
    d[~both] = np.nan

    def stats(x: np.ndarray) -> tuple[float, float]:
        x = x[np.isfinite(x)]
        return float(np.median(x)), float(np.quantile(x, 0.95))

    return {
        "frames": int(both.any(-1).sum()),
        "all": stats(d.ravel()),
        "trunk": stats(d[:, _TRUNK].ravel()),
        "align_deg": float(np.linalg.norm(rotation_vector_deg(align[:3, :3]))),
    }


def live(takes: list[str]) -> None:

    for take in takes:
        (path,) = sorted(POPULATION.glob(f"{take}_*.csv"))
        ids = [s.sensor_id for s in read_kinect_multitrack(path).streams]
        with tempfile.TemporaryDirectory() as tmp:
            rec = Path(tmp) / "rec.sqlite"
            with ChildProcesses(Path(tmp) / "logs") as procs:
                args = ["serve", "--host", "127.0.0.1", "--port", "0", "--record", str(rec)]
                server = procs.start("server", args, announce=True)
                port = parse_listening(procs.wait_first_line(server, 60.0))[1]
                epoch = f"{time.monotonic() + 4.0:.6f}"  # both logs in step
                for k, sid in enumerate(ids):
                    src = f"multitrack:{path}#{sid}"
                    args = ["sensor", "--server", f"127.0.0.1:{port}", "--source", src]
                    procs.start(f"s{k}", [*args, "--epoch-monotonic", epoch])
                for c in procs.children[1:]:
                    c.popen.wait(300)
                procs.stop(server)
            with SessionStore.open(rec) as st:
                ev = events(st)
                t_first = min(float(obs_times(st, s)[1].min()) for s in ids)
                lf = live_fused(st)
            grades = [d["grade"] for _, k, _, d in ev if k == "calibration_result"]
            ag = realdata_agreement(rec, path)
            fused = f"{lf.t_server_s[0] - t_first:.0f} s" if lf.t_server_s.size else "never"
            a, tr = ag["all"], ag["trunk"]
            print(
                f"{take}: fused {fused} after the first body frame; grades "
                f"{' '.join(g[0] for g in grades)}; vs realdata on {ag['frames']} frames: all "
                f"joints {1e3 * a[0]:.0f}/{1e3 * a[1]:.0f} mm, trunk {1e3 * tr[0]:.0f}/"  # type: ignore[index]
                f"{1e3 * tr[1]:.0f} mm (median/p95), worlds {ag['align_deg']:.1f} deg apart",  # type: ignore[index]
                flush=True,
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--offline", action="store_true", help="the population, offline")
    ap.add_argument("--live", nargs="+", metavar="TAKE", default=[], help="takes replayed live")
    ap.add_argument("--smoke", action="store_true", help="--offline on two takes (seconds)")
    a = ap.parse_args()
    if a.smoke:
        offline(2)
        return
    if not (a.offline or a.live):
        ap.error("give --offline or --live TAKE...")
    if a.offline:
        offline()
    if a.live:
        live(a.live)


if __name__ == "__main__":
    main()
