"""kinefuse's anatomical angles against OpenSim's own inverse kinematics, on both shared walks.

Analyses each shared OpenSim walk with its static trial (``kinefuse analyze WALK --static STATIC
--names opensim:MODEL``) and compares ``angles.mot`` with OpenSim's IK of the same walk by
coordinate name: per coordinate the correlation r, the mean offset (kinefuse - OpenSim), the RMS
after removing it and the raw RMSE, degrees, and whether it wraps; then the acceptance targets it
misses. The references: the Gait2354 walk's IK (gait2354 model, no arms) and the Rajagopal
walk's IK (Rajagopal 2016 model, arms included; ``../shared/data/MANIFEST.md``). Nothing is
fitted to these walks: ISB frames, Harrington's hip centres, the models' joint definitions.

    python studies/opensim_ik.py [--data ../shared/data] [--plot docs/img/opensim_ik.png]

``--smoke`` (CI) runs the same comparison: two short walks, a few seconds already.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GAIT = "markers/opensim/Pipelines_Gait2354_Simbody_"
RAJ = "markers/opensim/Pipelines_Rajagopal_"
#: (label, walk, static, OpenSim IK, --names)
WALKS = (
    ("gait2354", f"{GAIT}subject01_walk1.trc", f"{GAIT}subject01_static.trc",
     f"{GAIT}OutputReference_subject01_walk1_ik.mot", "opensim:gait2354"),
    ("rajagopal", f"{RAJ}ExpData_motion_capture_walk.trc", f"{RAJ}ExpData_static_walk_1.trc",
     f"{RAJ}OpenSimIK_walk.mot", "opensim:rajagopal"),
)  # fmt: skip


def run(data: Path, out: Path, which: str = "gait2354") -> dict[str, dict[str, float]]:
    """Analyse one shared walk into ``out`` and compare it with its OpenSim IK."""
    from kinefuse.app.workflows.analyze import run_analyze
    from kinefuse.lab.opensim_ik import compare_with_ik

    _, walk, static, ik, names = next(w for w in WALKS if w[0] == which)
    run_analyze([data / walk], out=out, static=data / static, names=names, plots=False)
    return compare_with_ik(out / "angles.mot", data / ik)


def lumbar_limit(mot: Path, ik: Path) -> str:
    """Why lumbar_extension's r is what it is: the IK curve's spread, the most error r >= 0.8
    allows (an error uncorrelated with the curve: r = sd / sqrt(sd^2 + e^2)), and the torso's
    and the pelvis's sagittal angles in the lab (their difference is lumbar_extension)."""
    import numpy as np

    from kinefuse.formats.angles import read_angles_mot
    from kinefuse.lab.opensim_ik import compare_angles

    (t_o, a_o, _), (t_i, a_i, _) = read_angles_mot(mot), read_angles_mot(ik)
    ref = a_i["lumbar_extension"]
    sd = float(np.std(ref))
    c = compare_angles(
        t_o,
        {"torso": a_o["pelvis_tilt"] + a_o["lumbar_extension"], "pelvis": a_o["pelvis_tilt"]},
        t_i,
        {"torso": a_i["pelvis_tilt"] + a_i["lumbar_extension"], "pelvis": a_i["pelvis_tilt"]},
    )
    return (
        f"  lumbar_extension in OpenSim's IK spans {ref.min():.1f}..{ref.max():.1f} deg "
        f"(SD {sd:.2f}): r >= 0.8 allows {0.75 * sd:.2f} deg RMS of error; the torso's "
        f"sagittal angle in the lab (pelvis_tilt + lumbar_extension) agrees, r "
        f"{c['torso']['r']:.3f}, {c['torso']['rms_after_offset_deg']:.2f} deg RMS after offset; "
        f"the pelvis's (pelvis_tilt) r {c['pelvis']['r']:.3f}, "
        f"{c['pelvis']['rms_after_offset_deg']:.2f} deg"
    )


def plot(mot: Path, ik: Path, png: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from kinefuse.formats.angles import read_angles_mot

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
    from kinefuse.core.outputs import atomic_file, is_png

    with atomic_file(png, what="plot", recognizer=is_png, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=80, format="png")


def main(argv: list[str] | None = None) -> int:
    from kinefuse.lab.opensim_ik import arm_trunk_failures, format_comparison

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--plot", type=Path, help="write the overlay of knee and hip curves (PNG)")
    ap.add_argument("--smoke", action="store_true", help="CI: the same run (it is short)")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        for label, _, _, ik, names in WALKS:
            out = Path(tmp) / label
            table = run(a.data, out, label)
            print(f"{label} walk vs OpenSim IK ({Path(ik).name}), --names {names}:")
            print(format_comparison(table))
            missed = arm_trunk_failures(table)
            print("targets missed: " + ("none" if not missed else ""))
            for m in missed:
                print(f"  {m}")
            if any("lumbar_extension: r" in m for m in missed):
                print(lumbar_limit(out / "angles.mot", a.data / ik))
            print()
            if a.plot and label == "gait2354":
                plot(out / "angles.mot", a.data / ik, a.plot)
                print(f"wrote {a.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
