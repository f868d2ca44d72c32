"""Pictures of the real and simulated two-sensor disagreement for ``docs/realism.md``.

    python studies/realism_plots.py [--seeds 1] [--out docs/img]

Per layout (0, 45, 90 degrees), over every take of the KinectMultiTrack population: the share of
joint distances above x (log scale, the tails), real against the model and the light model
(without the failure processes and the person level, ``--tracker light``;
``realism_tails_LAYOUT.png``); and the per-take
medians and p95 of every participant beside the simulated subjects
(``realism_population.png``). A few minutes on the shared machine.
``--smoke``: participant 2's takes, pictures into a temporary folder (CI runs it).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from kinefuse.formats.kinect_multitrack import read_kinect_multitrack
from kinefuse.formats.motion import load_motion
from kinefuse.lab.realism_population import layout_key
from kinefuse.lab.realism_tails import take_tails
from kinefuse.lab.realism_takes import (
    layout_angle_deg,
    pair_figures,
    real_pair,
    simulated_pair,
    take_layout,
)

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


def _save(fig: Any, path: Path) -> None:
    """Through a temporary file and a rename; replaces an earlier figure, never another file."""
    from kinefuse.core.outputs import atomic_file, is_png

    with atomic_file(path, what="figure", recognizer=is_png, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")


def main() -> None:
    from kinefuse.sim.tracker_params import light_tracker

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img")
    ap.add_argument(
        "--smoke", action="store_true", help="participant 2's takes into a temporary folder"
    )
    args = ap.parse_args()
    if args.smoke:
        args.out = Path(tempfile.mkdtemp(prefix="realism_plots_"))
    walk = load_motion(DATA / "motion" / "cmu" / "02_walk_a.amc")
    folder = DATA / "kinect" / "kinect_multitrack_population"
    dist: dict[str, dict[str, list[np.ndarray]]] = {}
    meds: dict[str, dict[str, list[tuple[float, float]]]] = {}
    for path in sorted(folder.glob("Study_2_*.csv" if args.smoke else "*.csv")):
        rec = read_kinect_multitrack(path)
        rp = real_pair(rec)
        lay = take_layout(rec, rp)
        key = layout_key(layout_angle_deg(lay))
        pairs = {"real": [rp]}
        for s in range(args.seeds):
            pairs.setdefault("model", []).append(simulated_pair(rec, walk, s, lay))
            pairs.setdefault("light model", []).append(
                simulated_pair(rec, walk, s, lay, light_tracker())
            )
        for name, ps in pairs.items():
            for p in ps:
                d = take_tails(p).distances_m
                dist.setdefault(key, {}).setdefault(name, []).append(d[np.isfinite(d)])
                f = pair_figures(p)
                meds.setdefault(key, {}).setdefault(name, []).append((f["median_m"], f["p95_m"]))
        print(path.name, key, flush=True)
    x = np.linspace(0.0, 0.8, 161)
    style = {"real": ("k", "-"), "model": ("tab:red", "-"), "light model": ("tab:blue", "--")}
    for key, by in dist.items():
        fig = Figure(figsize=(5.5, 3.6))
        ax = fig.add_subplot()
        for name, parts in by.items():
            v = np.concatenate(parts)
            ccdf = [(v > t).mean() for t in x]
            c, ls = style[name]
            ax.semilogy(x * 100, ccdf, color=c, ls=ls, label=f"{name} ({len(parts)} takes)")
        ax.set_xlabel("joint distance after the rigid fit (cm)")
        ax.set_ylabel("share above")
        ax.set_ylim(1e-4, 1)
        ax.set_title(f"two-sensor disagreement, {key} deg layout")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        _save(fig, args.out / f"realism_tails_{key}.png")
    fig = Figure(figsize=(8, 3.4))
    for i, stat in enumerate(("median", "p95")):
        ax = fig.add_subplot(1, 2, i + 1)
        for k, key in enumerate(dist):
            for j, name in enumerate(("real", "model", "light model")):
                v = np.array(meds[key][name])[:, i] * 100
                c, _ = style[name]
                xs = k + (j - 1) * 0.25 + np.random.default_rng(k).uniform(-0.05, 0.05, v.size)
                ax.plot(xs, v, "o", color=c, ms=3, label=name if k == 0 else None)
        ax.set_xticks(range(len(dist)), [f"{k} deg" for k in dist])
        ax.set_ylabel(f"per-take {stat} (cm)")
        ax.grid(alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, args.out / "realism_population.png")
    print("wrote", args.out)


if __name__ == "__main__":
    main()
