"""Paper B's analysis chain over many simulated sessions: the inputs nobody tuned it for (issue 24).

Run: ``python studies/analysis_sweep.py [--seeds 0 1] [--rigs level4 tiered4 tilted4]
[--clips ...] [--heldout] [--rom-s 60] [--static 10] [--tracker default|light]
[--errors-off PART[,PART]] [--sessions DIR] [--json F] [--smoke]`` (about 15-30 s a session;
``--sessions DIR`` keeps the simulated sessions and reuses them, so a rerun only analyses;
``--smoke``: one short session). ``--errors-off``: the same sessions with parts of the tracker's
error model off (``kinefuse simulate --errors-off``), what those parts cost.

Each session is the whole chain as a user runs it: ``kinefuse simulate --rom 60`` (the
range-of-motion phase at the rig's ``[actor]`` position, else the centre of the sensors' common
volume, then the clip from there) -> ``kinefuse analyze --true-calibration`` (fused with
``best``). The wand phase is left out and the true sensor poses are used (the fast path: the
calibration is not what is measured here; ``docs/calibration.md`` measures it). Sessions: every
shared clip x the rigs of ``rigs/`` x ``--seeds`` (each seed a new subject: its own tracker
joint offsets). ``--heldout`` runs instead rigs and subjects the sweep never saw, made here: a
6-sensor walkway (7 m, sensors on both sides; with its ``[actor]`` mark at the walkway's start,
at its very edge (where the phase is not seen and must be refused), and without one, so the
phase is at the volume's centre), a 5-sensor ring of 2.5 m, a
3-sensor arc of 100° (no sensor behind), seeds 100-101, with a walk and the travelling 131_01.

Per session it prints: the DJ axis error median (in brackets its floor: the session's true
motion plus its subject's tracker joint offsets alone, what a perfect fusion would deliver,
:func:`floor_figures`), the twist error median, the reconstruction error mean (the paper's
minimal parameters; its floor in brackets), knee and hip flexion RMSE left/right over the
frames after the phase in which a sensor tracked the limb and its parent (``tracked``, with the
least share of such frames of the four angles), the worst of the four over every frame after
the phase and over the frames with two or more sensors (with their share), the fraction of the
phase seen (the least seen limb) and how many of the six two-axis limbs kept two axes; then
the worst over all sessions.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from kinefuse.app.cli.args import error_parts  # noqa: E402
from kinefuse.app.workflows.analyze import run_analyze  # noqa: E402
from kinefuse.app.workflows.simulate import run_simulate  # noqa: E402
from kinefuse.errors import InputError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "motion" / "cmu"
CLIPS = ("131_01_scaled_metres.bvh", "01_01.bvh", "01_01.amc", "02_walk_a.amc", "02_walk_b.amc")
RIGS = ("level4", "tiered4", "tilted4")
ANGLES = ("knee_flexion_left", "knee_flexion_right", "hip_flexion_left", "hip_flexion_right")
#: The issue's acceptance thresholds (degrees, mm).
LIMITS = {"axis": 10.0, "twist": 7.0, "rec_mm": 1.5, "flexion": 10.0}


def _walkway(actor_x: float | None) -> str:
    """A 6-sensor walkway along x (7 m), sensors on both sides at alternating heights; an
    ``[actor]`` mark at ``(actor_x, 0)`` facing +x when given."""
    lines = []
    for i, (x, y, z) in enumerate(
        [
            (-3.0, 2.2, 0.9),
            (0.0, 2.2, 1.9),
            (3.0, 2.2, 0.9),
            (-3.0, -2.2, 1.9),
            (0.0, -2.2, 0.9),
            (3.0, -2.2, 1.9),
        ]
    ):
        tx = x + (0.8 if x < 0 else -0.8 if x > 0 else 0.0)
        lines += ["[[sensor]]", f'id = "w{i}"', f"position_m = [{x}, {y}, {z}]",
                  f"look_at_m = [{tx}, 0.0, 1.0]", ""]  # fmt: skip
    if actor_x is not None:
        lines += ["[actor]", f"position_m = [{actor_x}, 0.0]", "heading_deg = 0.0", ""]
    lines += ["[room]", "min_xy_m = [-5.0, -3.5]", "max_xy_m = [5.0, 3.5]", ""]
    return "\n".join(lines)


def _ring(n: int, radius: float) -> str:
    lines = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.3
        z = 0.8 if i % 2 else 2.0
        lines += ["[[sensor]]", f'id = "r{i}"',
                  f"position_m = [{radius * np.cos(a):.3f}, {radius * np.sin(a):.3f}, {z}]",
                  "look_at_m = [0.0, 0.0, 1.0]", ""]  # fmt: skip
    return "\n".join(lines)


def _arc(n: int, radius: float, span_deg: float) -> str:
    """``n`` sensors on an arc of ``span_deg`` in front of the actor (none behind)."""
    lines = []
    for i, a in enumerate(np.radians(np.linspace(-span_deg / 2, span_deg / 2, n))):
        z = 1.0 if i % 2 else 1.7
        lines += ["[[sensor]]", f'id = "a{i}"',
                  f"position_m = [{radius * np.cos(a):.3f}, {radius * np.sin(a):.3f}, {z}]",
                  "look_at_m = [0.0, 0.0, 1.0]", ""]  # fmt: skip
    return "\n".join(lines)


HELDOUT_CLIPS = ("02_walk_a.amc", "131_01_scaled_metres.bvh")
HELDOUT_RIGS = {
    # the mark at the walkway's start, where three sensors see the body (sensors_seeing)
    "walkway6_start": lambda: _walkway(-1.5),
    # the mark at its very edge, where two side sensors see it but occlude each other's view
    # of the limbs: analyze must refuse the limbs it did not see, not analyse them
    "walkway6_edge": lambda: _walkway(-2.5),
    "walkway6": lambda: _walkway(None),
    "ring5": lambda: _ring(5, 2.5),
    "arc3": lambda: _arc(3, 3.0, 100.0),
}


def simulated(
    clip: Path,
    rig: Path,
    seed: int,
    folder: Path,
    rom_s: float,
    seconds: float | None,
    tracker: str,
    keep: Path | None,
    static_s: float = 0.0,
    errors_off: tuple[str, ...] = (),
) -> tuple[Path, dict[str, Any]]:
    """The session of one plan entry: simulated into ``folder``, or into ``keep`` and reused
    from there when a complete one of the same parameters is already there."""
    tag = (
        ("" if tracker == "default" else f"_{tracker}")
        + (f"_static{static_s:g}" if static_s else "")
        + (f"_off-{'-'.join(errors_off)}" if errors_off else "")
    )
    stem = f"{clip.name.replace('.', '_')}_{rig.stem}_{seed}_rom{rom_s:g}{tag}"
    path = (keep or folder) / f"{stem}.sqlite"
    info = path.with_suffix(".sim.json")
    if keep is not None and path.exists() and info.exists():
        return path, dict(json.loads(info.read_text(encoding="utf-8")))
    sim = run_simulate(clip=clip, out=path, rig=rig, seed=seed, calibration_s=0.0, rom_s=rom_s,
                       seconds=seconds, force=True, tracker=tracker,
                       static_s=static_s or None, errors_off=errors_off).as_dict()  # fmt: skip
    if keep is not None:
        tmp = info.with_suffix(".tmp")
        tmp.write_text(json.dumps(sim, default=str), encoding="utf-8")
        tmp.replace(info)
    return path, sim


def session(clip: Path, rig: Path, seed: int, folder: Path, rom_s: float,
            seconds: float | None, tracker: str = "default",
            keep: Path | None = None, static_s: float = 0.0,
            errors_off: tuple[str, ...] = ()) -> dict[str, Any]:  # fmt: skip
    """Simulate with --rom (and --static, --errors-off), analyse with --true-calibration (and
    --static-window auto); the figures of the report."""
    t0 = time.perf_counter()
    path, sim = simulated(clip, rig, seed, folder, rom_s, seconds, tracker, keep, static_s,
                          errors_off)  # fmt: skip
    out = folder / f"{path.stem}_analysis"
    refused = None
    try:
        r = run_analyze([path], out=out, true_calibration=True, plots=False,
                        static_window="auto" if static_s else None).report  # fmt: skip
    except InputError as e:  # the fused standing phase is not still: analysed without it
        if not static_s:
            raise
        refused = str(e)
        r = run_analyze([path], out=out, true_calibration=True, plots=False).report
    seen = r["calibration_phase"]["seen"]
    rm, rs = r.get("angle_rmse_deg", {}), r.get("angle_rmse_seen_deg", {})
    rt, share = r.get("angle_rmse_tracked_deg", {}), r.get("tracked_fraction_after_phase", {})
    row = {
        "clip": clip.name,
        "rig": rig.stem,
        "seed": seed,
        "rom_position_m": sim.get("rom_position_m"),
        "axis_median_deg": r.get("axis_error_deg", {}).get("median"),
        "floor": floor_figures(path, seed, tracker, errors_off),
        "twist_median_deg": r.get("twist_error_deg", {}).get("median"),
        "reconstruction_mean_mm": _mm(r["reconstruction_error_m"]["mean"]),
        "flexion_rmse_deg": {a: rm.get(a) for a in ANGLES},
        "flexion_rmse_seen_deg": {a: rs.get(a) for a in ANGLES},
        "flexion_rmse_tracked_deg": {a: rt.get(a) for a in ANGLES},
        "walk_seen_fraction": min(
            r.get("seen_fraction_after_phase", {}).get(a, 0.0) for a in ANGLES
        ),
        "walk_tracked_fraction": min(share.get(a, 0.0) for a in ANGLES),
        "phase_seen_min": seen["fraction_min"],
        "not_seen": sorted(seen["not_seen"]),
        "two_axis": [r["two_axis_limbs"]["learned_two"], r["two_axis_limbs"]["asked"]],
        # with --static: the anatomical (static-trial) flexions over the tracked frames, or
        # why the standing phase was refused as a static trial
        "anatomical_flexion_rmse_tracked_deg": {
            a: r.get("anatomical_rmse_tracked_deg", {}).get(a) for a in ANGLES
        }
        if static_s and refused is None
        else None,
        "anatomical_refused": refused,
        "warnings": r["warnings"] + sim["warnings"],
        "seconds": time.perf_counter() - t0,
    }
    for p in folder.glob(f"{path.stem}*"):
        if p.is_file():
            p.unlink()
    return row


def floor_figures(
    path: Path, seed: int, tracker: str, errors_off: tuple[str, ...] = ()
) -> dict[str, float]:
    """The session's axis error median, reconstruction error mean and worst knee/hip flexion
    RMSE (over every frame after the phase) with a perfect fusion: its true motion (30 Hz) plus its
    subject's tracker joint-definition offsets alone (what every sensor shares, so no fusion
    removes it), analysed and scored as the fused take is (``analysis_accuracy.py floor`` does the
    same for ``subject_seed`` subjects; here the subject is the session's own, drawn from its
    seed)."""
    from kinefuse.app.workflows.simulate import tracker_model
    from kinefuse.biomech.kinematics import reconstruction_error
    from kinefuse.biomech.sequence import SkeletonSequence
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.analysis_truth import truth_figures
    from kinefuse.lab.fusion_truth import truth_at
    from kinefuse.pipeline.analysis_chain import AnalysisInput, analyse_sequence
    from kinefuse.sim.lab import ErrorModel, LabConfig, _seeds
    from kinefuse.sim.tracker_body import _body_axes

    with SessionStore.open(path) as store:
        a, b = store.meta()["rom_phase_server_s"]  # type: ignore[misc]
        t_true, _, _ = store.truth().motion()
        n_sensors = len(store.sensors())
        t_s = np.arange(float(t_true[0]), float(t_true[-1]), 1.0 / 30.0)
        joints = truth_at(store, t_s)
    config = LabConfig(seed=seed, errors=ErrorModel(tracker=tracker_model(tracker, errors_off)))
    offsets = _seeds(seed, n_sensors, config).subject.offsets_body_m
    axes = _body_axes(joints, np.array([0.0, 0.0, 1.0]))
    biased = joints + np.einsum("tik,jk->tji", axes, offsets)
    seq = SkeletonSequence.from_kinect(biased, t_s=t_s, source=f"{path.name} [floor]")
    inp = AnalysisInput(path=path, kind="session", seq=seq)
    phase = (float(a), float(b))
    res = analyse_sequence(seq, phase)
    fig = truth_figures(inp, res, phase, true_calibration=True)
    assert fig is not None
    rm = fig["report"]["angle_rmse_deg"]
    rec = reconstruction_error(seq, res["angles"], res["models"]["dj"], off_axis=False)
    return {
        "axis_median_deg": float(fig["report"]["axis_error_deg"]["median"]),
        "reconstruction_mean_mm": 1e3 * rec["sphere_mean"],
        "flexion_rmse_deg": max(float(rm.get(a, np.nan)) for a in ANGLES),
    }


def _limb_rec_mm(angles: Any, model: Any, name: str) -> Any:
    """One limb's minimal-parameter reconstruction error per frame, mm."""
    from kinefuse.biomech._vec import mv
    from kinefuse.biomech.parameterize import _swing_matrices

    lm = model.limbs[name]
    x = mv(_swing_matrices(lm, angles.angles[name], None, None), lm.rest)
    return 1e3 * np.linalg.norm(angles.direction[name] - x, axis=-1) * angles.length_m[name]


def breakdown(path: Path) -> str:
    """Per limb of one session: the minimal reconstruction's mean error (mm) over every frame,
    the phase and after it, by how observable the parent's twist was (its weight: 0 carried
    from its own parent, e.g. a straight knee; 1 from the bent child) and by how many sensors
    tracked the limb and its parent; the same on the true motion; the DJ axis error (deg) and
    the share of the phase the limb was seen in.
    What docs/analysis_measured.md says about where the reconstruction error comes from."""
    from kinefuse.app.workflows.analyze import load_input
    from kinefuse.biomech.kinematics import reconstruction_error
    from kinefuse.biomech.limbs import LIMB_INDEX, LIMB_PARENTS
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.analysis_truth import true_sequence, truth_figures
    from kinefuse.pipeline.analysis_chain import analyse_sequence, phase_seen

    inp = load_input(path, true_calibration=True)
    with SessionStore.open(path) as store:
        a, b = store.meta()["rom_phase_server_s"]  # type: ignore[misc]
    phase = (float(a), float(b))
    assert inp.limb_sensors is not None
    seen = phase_seen(inp.limb_sensors, inp.seq.t_s, phase)
    res = analyse_sequence(inp.seq, phase, not_seen=seen["not_seen"])
    fig = truth_figures(inp, res, phase, true_calibration=True)
    got = true_sequence(inp)
    assert fig is not None and got is not None
    tres = analyse_sequence(got[0], phase)
    axis = fig["report"]["axis_error_deg"]["by_limb"]
    t = inp.seq.t_s
    inside = (t >= phase[0]) & (t <= phase[1])
    ang, dj, norm = res["angles"], res["models"]["dj"], res["norm"]
    out = [f"{path.name}: reconstruction mean {_mm(reconstruction_error(inp.seq, ang, dj, off_axis=False)['sphere_mean']):.2f} mm, "  # noqa: E501
           f"on the true motion {_mm(reconstruction_error(got[0], tres['angles'], tres['models']['dj'], off_axis=False)['sphere_mean']):.2f} mm"]  # noqa: E501  # fmt: skip
    head = ("limb", "k", "all", "phase", "after", "w=0", "0<w<1", "w=1", "0 sens", "1 sens",
            "2+ sens", "truth", "axis deg", "phase seen")  # fmt: skip
    out.append("| " + " | ".join(head) + " |")
    out.append("|" + "---|" * len(head))
    frac = seen["fraction_by_limb"]
    for name, lm in dj.limbs.items():
        if not lm.usable:
            out.append(f"| {name} | {lm.status[:40]} | {100 * frac[name]:.0f} % |")
            continue
        i, par = LIMB_INDEX[name], LIMB_PARENTS[LIMB_INDEX[name]]
        e = _limb_rec_mm(ang, dj, name)
        w = norm.twist_weight[:, par]
        n = np.minimum(inp.limb_sensors[:, i], inp.limb_sensors[:, par])
        sels = (np.ones_like(inside), inside, ~inside, w == 0, (w > 0) & (w < 1), w >= 1,
                n == 0, n == 1, n >= 2)  # fmt: skip
        cells = [_f(float(np.nanmean(e[m])) if np.isfinite(e[m]).any() else np.nan, ".2f")
                 for m in sels]  # fmt: skip
        tm = tres["models"]["dj"]
        te = _limb_rec_mm(tres["angles"], tm, name) if tm.limbs[name].usable else np.full(1, np.nan)
        ax = " / ".join(_f(v) for v in axis.get(name, []))
        tail = f" | {_f(float(np.nanmean(te)), '.2f')} | {ax} | {100 * frac[name]:.0f} % |"
        out.append(f"| {name} | {lm.axes.shape[0]} | " + " | ".join(cells) + tail)
    return "\n".join(out)


def _mm(v: float | None) -> float:
    """Metres (None: every limb refused, nothing reconstructed) to millimetres (NaN)."""
    return float("nan") if v is None else 1e3 * v


def _f(v: object, fmt: str = ".1f") -> str:
    return format(v, fmt) if isinstance(v, int | float) and np.isfinite(v) else "n/a"


def _mx(d: dict[str, Any]) -> float:
    v = [x for x in d.values() if isinstance(x, int | float) and np.isfinite(x)]
    return max(v) if v else float("nan")


def _row_text(r: dict[str, Any]) -> str:
    ft = r["flexion_rmse_tracked_deg"]
    knee = " / ".join(_f(ft[a]) for a in ANGLES[:2])
    hip = " / ".join(_f(ft[a]) for a in ANGLES[2:])
    ns = f" not seen: {', '.join(r['not_seen'])}" if r["not_seen"] else ""
    return (f"| {r['clip']} | {r['rig']} | {r['seed']} | {_f(r['axis_median_deg'], '.2f')} "
            f"({_f(r['floor']['axis_median_deg'], '.2f')}) | "
            f"{_f(r['twist_median_deg'], '.2f')} | {_f(r['reconstruction_mean_mm'], '.2f')} "
            f"({_f(r['floor']['reconstruction_mean_mm'], '.2f')}) | "
            f"{knee} | {hip} | {_f(r['floor']['flexion_rmse_deg'])} | "
            f"{100 * r['walk_tracked_fraction']:.0f} % | "
            f"{_f(_mx(r['flexion_rmse_deg']))} / {_f(_mx(r['flexion_rmse_seen_deg']))} "
            f"({100 * r['walk_seen_fraction']:.0f} %) | {100 * r['phase_seen_min']:.0f} %{ns} | "
            f"{r['two_axis'][0]}/{r['two_axis'][1]} |" + _anatomical_cell(r))  # fmt: skip


def _anatomical_cell(r: dict[str, Any]) -> str:
    """With --static: the anatomical knee and hip flexion RMSE, left / right, tracked frames."""
    a = r.get("anatomical_flexion_rmse_tracked_deg")
    if r.get("anatomical_refused"):
        return f" refused: {r['anatomical_refused'].split(': ', 1)[-1].split('. Give')[0]} |"
    if not a:
        return ""
    return (f" {_f(a[ANGLES[0]])} / {_f(a[ANGLES[1]])}, "
            f"{_f(a[ANGLES[2]])} / {_f(a[ANGLES[3]])} |")  # fmt: skip


def _anatomical_worst(rows: list[dict[str, Any]]) -> str:
    """With --static: how many sides' anatomical knee and hip flexion are under 8° (issue 20)."""
    cells = [r["anatomical_flexion_rmse_tracked_deg"] for r in rows
             if r.get("anatomical_flexion_rmse_tracked_deg")]  # fmt: skip
    refused = sum(1 for r in rows if r.get("anatomical_refused"))
    if not cells and not refused:
        return ""
    out = []
    for joint, names in (("knee", ANGLES[:2]), ("hip", ANGLES[2:])):
        v = [c[n] for c in cells for n in names
             if isinstance(c[n], int | float) and np.isfinite(c[n])]  # fmt: skip
        if v:
            out.append(f"{joint} {sum(x < 8.0 for x in v)} of {len(v)} under 8° (median "
                       f"{np.median(v):.1f}°, worst {max(v):.1f}°)")  # fmt: skip
    if refused:
        out.append(f"{refused} standing phase(s) refused as a static trial (the subject moves)")
    return "\nanatomical (static trial) flexion over the tracked frames: " + "; ".join(out)


def _worst(rows: list[dict[str, Any]]) -> str:
    analysed = [r for r in rows if not r["not_seen"]]

    def mx(key: str, sub: str | None = None) -> float:
        vals = [r[key] if sub is None else r[key][sub] for r in analysed]
        vals = [v for v in vals if isinstance(v, int | float) and np.isfinite(v)]
        return max(vals) if vals else float("nan")

    fl = max(mx("flexion_rmse_deg", a) for a in ANGLES)
    fs = max(mx("flexion_rmse_seen_deg", a) for a in ANGLES)
    ft = max(mx("flexion_rmse_tracked_deg", a) for a in ANGLES)
    share = min((r["walk_tracked_fraction"] for r in analysed), default=float("nan"))
    over = [r for r in analysed if not r["axis_median_deg"] < LIMITS["axis"]]
    over_axis = len(over)
    over_floor = sum(1 for r in over if not r["floor"]["axis_median_deg"] < LIMITS["axis"])
    rec_over = [r for r in analysed if not r["reconstruction_mean_mm"] < LIMITS["rec_mm"]]
    rec_floor = sum(1 for r in rec_over
                    if not r["floor"]["reconstruction_mean_mm"] < LIMITS["rec_mm"])  # fmt: skip
    refused = len(rows) - len(analysed)
    return (f"\nworst of {len(analysed)} analysed sessions ({refused} refused as not seen): "
            f"axis median {mx('axis_median_deg'):.2f}° (< {LIMITS['axis']:g}; sessions over it: "
            f"{over_axis}, of them with the floor itself over it: {over_floor}), twist median "
            f"{mx('twist_median_deg'):.2f}° (< {LIMITS['twist']:g}), reconstruction mean "
            f"{mx('reconstruction_mean_mm'):.2f} mm (< {LIMITS['rec_mm']:g}; sessions over it: "
            f"{len(rec_over)}, of them with the floor over it: {rec_floor}), knee/hip flexion "
            f"RMSE over the tracked frames {ft:.1f}° (< {LIMITS['flexion']:g}; tracked at "
            f"least {100 * share:.0f} % of the frames after the phase), over all frames "
            f"{fl:.1f}°, with 2+ sensors {fs:.1f}°; "
            f"phase seen at least {100 * min(r['phase_seen_min'] for r in rows):.0f} %; two-axis "
            f"limbs with two axes {sum(r['two_axis'][0] for r in rows)} of "
            f"{sum(r['two_axis'][1] for r in rows)}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--rigs", nargs="+", default=list(RIGS), help="rigs of rigs/")
    ap.add_argument("--clips", nargs="+", default=list(CLIPS), help="clips of --data")
    ap.add_argument("--heldout", action="store_true", help="rigs and subjects not in the sweep")
    ap.add_argument("--rom-s", type=float, default=60.0)
    ap.add_argument("--static", type=float, default=0.0,
                    help="a standing phase of this many seconds before the ROM (simulate "
                    "--static), and the anatomical angles from it (issue 20)")  # fmt: skip
    ap.add_argument("--tracker", default="default", choices=("default", "light"),
                    help="simulate --tracker (the tracker error model)")  # fmt: skip
    ap.add_argument("--errors-off", type=error_parts, default=(), metavar="PART[,PART]",
                    help="simulate --errors-off: tracker error-model parts off")  # fmt: skip
    ap.add_argument("--sessions", type=Path,
                    help="keep the simulated sessions here and reuse them")  # fmt: skip
    ap.add_argument("--breakdown", action="store_true",
                    help="per limb, where each session's reconstruction error is")  # fmt: skip
    ap.add_argument("--json", type=Path, help="write every row to this file")
    ap.add_argument("--smoke", action="store_true", help="one short session (seconds to run)")
    ap.add_argument("--data", type=Path, default=DATA)
    args = ap.parse_args()
    seconds = None
    if args.smoke:
        args.seeds, args.rigs, args.clips, seconds = [0], ["level4"], ["02_walk_a.amc"], 1.0
    print(
        "| clip | rig | seed | axis median ° (floor) | twist median ° | reconstruction mean mm "
        "(floor) | "
        "knee flexion RMSE L / R ° (tracked) | hip flexion RMSE L / R ° (tracked) | "
        "flexion floor (worst) ° | "
        "tracked (least) | worst flexion RMSE °: all frames / 2+ sensors (2+ share) | "
        "phase seen (least limb) | two-axis limbs |"
        + (" anatomical knee / hip flexion RMSE L / R ° (tracked) |" if args.static else "")
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if args.static else ""))
    rows: list[dict[str, Any]] = []
    lines: list[str] = []
    if args.sessions is not None:
        args.sessions.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        if args.heldout:
            plan = []
            for name, text in HELDOUT_RIGS.items():
                rig = (args.sessions or folder) / f"{name}.toml"
                rig.write_text(text(), encoding="utf-8")
                plan += [(args.data / c, rig, s) for c in HELDOUT_CLIPS
                         for s in (100, 101)]  # fmt: skip
        else:
            plan = [(args.data / c, ROOT / "rigs" / f"{g}.toml", s)
                    for s in args.seeds for c in args.clips for g in args.rigs]  # fmt: skip
        for clip, rig, seed in plan:
            r = session(clip, rig, seed, folder, 55.0 if args.smoke else args.rom_s, seconds,
                        args.tracker, args.sessions, args.static, args.errors_off)  # fmt: skip
            rows.append(r)
            print(_row_text(r), flush=True)
            if args.breakdown:
                path, _ = simulated(clip, rig, seed, folder, 55.0 if args.smoke else args.rom_s,
                                    seconds, args.tracker, args.sessions, args.static,
                                    args.errors_off)  # fmt: skip
                lines.append(breakdown(path))
                if args.sessions is None:
                    path.unlink()
    print(_worst(rows) + _anatomical_worst(rows))
    for text in lines:
        print("\n" + text)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=str) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
