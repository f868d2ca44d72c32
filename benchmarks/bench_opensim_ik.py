"""kinefuse's anatomical angles against OpenSim's own inverse kinematics (issue 20).

Analyses the shared Gait2354 walk with its static trial (``kinefuse analyze WALK --static
STATIC --names opensim``) and compares ``angles.mot`` with OpenSim's IK result of the same walk
by coordinate name: per coordinate the correlation r, the mean offset (kinefuse - OpenSim), the
RMS after removing it and the raw RMSE, degrees. Nothing is fitted to this walk: ISB frames,
Harrington's hip centres, OpenSim's documented coordinate axes.

    python benchmarks/bench_opensim_ik.py [--data ../shared/data] [--plot docs/img/opensim_ik.png]

``--smoke`` (CI) runs the same comparison: one short walk, a few seconds already.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GAIT = "markers/opensim/Pipelines_Gait2354_Simbody_"


def run(data: Path, out: Path) -> dict[str, dict[str, float]]:
    from kinefuse.evaluation.opensim_ik import compare_with_ik
    from kinefuse.workflows.analyze import run_analyze

    run_analyze(
        [data / f"{GAIT}subject01_walk1.trc"],
        out=out,
        static=data / f"{GAIT}subject01_static.trc",
        names="opensim",
        plots=False,
    )
    return compare_with_ik(
        out / "angles.mot", data / f"{GAIT}OutputReference_subject01_walk1_ik.mot"
    )


def plot(mot: Path, ik: Path, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kinefuse.io.formats.angles import read_angles_mot

    t_o, a_o, _ = read_angles_mot(mot)
    t_i, a_i, _ = read_angles_mot(ik)
    names = ["hip_flexion_r", "hip_flexion_l", "knee_angle_r", "knee_angle_l",
             "hip_adduction_r", "hip_adduction_l"]  # fmt: skip
    fig, axes = plt.subplots(3, 2, figsize=(9, 7), sharex=True)
    for ax, n in zip(axes.ravel(), names, strict=True):
        ax.plot(t_i, a_i[n], "k-", label="OpenSim IK")
        ax.plot(t_o, a_o[n], "C0--", label="kinefuse (anatomical, --names opensim)")
        ax.set_title(n, fontsize=9)
        ax.set_ylabel("deg")
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle("Gait2354 subject01 walk1: kinefuse vs OpenSim inverse kinematics")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    from kinefuse.io.outputs import atomic_file, is_png

    with atomic_file(png, what="plot", recognizer=is_png, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=80, format="png")


def main(argv: list[str] | None = None) -> int:
    from kinefuse.evaluation.opensim_ik import format_comparison

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--plot", type=Path, help="write the overlay of knee and hip curves (PNG)")
    ap.add_argument("--smoke", action="store_true", help="CI: the same run (it is short)")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "walk"
        table = run(a.data, out)
        print(format_comparison(table))
        if a.plot:
            plot(out / "angles.mot", a.data / f"{GAIT}OutputReference_subject01_walk1_ik.mot",
                 a.plot)  # fmt: skip
            print(f"wrote {a.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
