"""The ``kinefuse`` command line: parse, dispatch, report errors. Heavy modules load lazily."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from kinefuse import __version__
from kinefuse.errors import KinefuseError


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def _nonneg_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def _room(text: str) -> tuple[float, float, float, float]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 4 or not (v[0] < v[2] and v[1] < v[3]):
        raise argparse.ArgumentTypeError(
            f"expected XMIN,YMIN,XMAX,YMAX in metres with XMIN < XMAX and YMIN < YMAX, got {text!r}"
        )
    return (v[0], v[1], v[2], v[3])


def _add_simulate_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--skeleton", type=Path, help="the ASF of an .amc clip (default: found beside it)"
    )
    p.add_argument(
        "--units",
        choices=["m", "cm", "mm", "in", "asf"],
        help="length unit of the clip (default: chosen so the subject's height is plausible)",
    )
    p.add_argument(
        "--name-map",
        type=Path,
        help="TOML map from the clip's joint names to Kinect joints (docs/motion.md)",
    )
    rig = p.add_mutually_exclusive_group()
    rig.add_argument("--rig", type=Path, help="rig file (TOML) with the sensors' poses")
    rig.add_argument("--sensors", type=int, default=4, help="sensors of the default layout (4)")
    p.add_argument("--seconds", type=_positive_float, help="length of the motion (default: all)")
    p.add_argument("--seed", type=int, default=0, help="random seed (0)")
    p.add_argument(
        "--subject-seed",
        type=int,
        help="seed of the subject's own tracker joint offsets: sessions with the same one are "
        "takes of the same person (default: drawn from --seed, a new person every session)",
    )
    p.add_argument(
        "--calibration-seconds",
        type=_nonneg_float,
        default=20.0,
        help="length of the wand-waving phase before the motion (20 s; 0 = none)",
    )
    p.add_argument(
        "--depth-rate",
        type=_positive_float,
        default=10.0,
        help="rate of the stored calibration depth frames, Hz (10)",
    )
    p.add_argument(
        "--room",
        type=_room,
        metavar="XMIN,YMIN,XMAX,YMAX",
        help="the room's floor rectangle XMIN,YMIN,XMAX,YMAX in metres (default: the rig's "
        "[room], else -4,-4,4,4; write --room=-5,-5,5,5); every sensor must stand inside it",
    )
    p.add_argument(
        "--rom",
        type=_positive_float,
        metavar="SECONDS",
        help="a range-of-motion calibration phase of SECONDS before the motion (docs/analysis.md)",
    )


def _cmd_simulate(args: argparse.Namespace) -> int:
    from kinefuse.workflows.common import run_simulate

    r = run_simulate(
        clip=args.clip,
        skeleton=args.skeleton,
        units=args.units,
        name_map=args.name_map,
        rig=args.rig,
        sensors=args.sensors,
        seconds=args.seconds,
        seed=args.seed,
        calibration_s=args.calibration_seconds,
        depth_rate_hz=args.depth_rate,
        room=args.room,
        out=args.out,
        force=args.force,
        progress=lambda m: print(m, file=sys.stderr),
        rom_s=args.rom,
        subject_seed=args.subject_seed,
    )
    for w in r["warnings"]:
        print(f"kinefuse: warning: {w}", file=sys.stderr)
    print(f"wrote {args.out}")
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from kinefuse.evaluation.inspect import format_inspect, inspect_session
    from kinefuse.io.store.session import SessionStore

    with SessionStore.open(args.session) as st:
        info = inspect_session(st)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print(format_inspect(info))
    return 0


def _add_calibration_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--calibration", type=Path, help="calibration file (TOML) with sensor poses")
    g.add_argument(
        "--true-calibration",
        action="store_true",
        help="use the simulator's true sensor poses (evaluation only)",
    )


def _methods(text: str) -> tuple[str, ...]:
    from kinefuse.fusion.session import METHODS

    names = tuple(m.strip() for m in text.split(",") if m.strip())
    bad = [m for m in names if m not in METHODS]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown method(s) {', '.join(bad) or '(none)'}; choose from {', '.join(METHODS)}"
        )
    return names


def _add_span_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--start",
        type=float,
        metavar="S",
        help="first frame time, seconds from the session's start",
    )
    p.add_argument(
        "--end", type=float, metavar="S", help="last frame time, seconds from the session's start"
    )


def _add_partial_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--partial",
        action="store_true",
        help="use an incomplete session (an interrupted simulation or recording) as it is",
    )


def _cmd_fuse(args: argparse.Namespace) -> int:
    from kinefuse.workflows.common import run_fuse

    info = run_fuse(
        session=args.session,
        method=args.method,
        out=args.out,
        calibration=args.calibration,
        true_calibration=args.true_calibration,
        store_result=args.store,
        allow_incomplete=args.partial,
        trc_axes=args.trc_axes,
        start_s=args.start,
        end_s=args.end,
    )
    for w in info["warnings"]:  # type: ignore[attr-defined]
        print(f"kinefuse: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        status = ", ".join(f"{k} {v}" for k, v in info["status"].items() if v)  # type: ignore[attr-defined]
        print(
            f"fused {info['frames']} frames with {info['method']} ({info['calibration']}) in "
            f"{info['seconds']:.2f} s; joint status: {status}"
        )
        if info["stored_in_session"]:
            print(f"stored the fused skeleton in {args.session} (method {info['method']})")
        if info["out"]:
            print(f"wrote {info['out']}")
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from kinefuse.workflows.common import format_evaluate, run_evaluate

    report = run_evaluate(
        session=args.session,
        methods=args.methods,
        out_dir=args.out,
        calibration=args.calibration,
        true_calibration=args.true_calibration,
        allow_incomplete=args.partial,
        start_s=args.start,
        end_s=args.end,
    )
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(format_evaluate(report, args.methods))
        for w in report.get("written", []):  # type: ignore[attr-defined]
            print(f"wrote {w}")
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from kinefuse.workflows.calibrate import format_calibrate, run_calibrate

    if args.live is not None or args.session is None:
        from kinefuse.workflows.serve import cmd_calibrate_live

        return cmd_calibrate_live(args)
    r = run_calibrate(
        session=args.session,
        method=args.method,
        out=args.out,
        report_dir=args.report,
        store_result=args.store,
        accept=args.accept,
        allow_incomplete=args.partial,
        detector=args.detector,
    )
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        print(format_calibrate(r))
        if r["stored_in_session"]:
            print(f"stored the calibration in {args.session} (as {r['method']!r})")
        for w in [r["out"], *r.get("written", [])]:
            if w:
                print(f"wrote {w}")
        if r.get("report_note"):
            print(r["report_note"])
    if r["grade"] == "failed" and not r["accepted"]:
        print(
            f"kinefuse: error: calibration failed ({'; '.join(r['reasons'])}); nothing was "
            "written (pass --accept to keep it anyway)",
            file=sys.stderr,
        )
        return 3
    return 0


def _cmd_realism(args: argparse.Namespace) -> int:
    from kinefuse.evaluation.realism import main as realism_main

    return realism_main(args.rest)


def _cmd_realdata(args: argparse.Namespace) -> int:
    from kinefuse.workflows.realdata import format_report, fuse_multitrack

    results = [
        fuse_multitrack(
            p,
            registration=args.registration,
            other_offaxis_deg=args.other_offaxis_deg,
            motion_latency=not args.no_motion_latency,
        )
        for p in args.paths
    ]
    if args.json:
        print(json.dumps(results if len(results) > 1 else results[0], indent=1))
    else:
        print("\n\n".join(format_report(r) for r in results))
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from kinefuse.workflows.view import run_view

    return run_view(args.session, host=args.host, port=args.port)


def _phase(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected START_S:END_S in seconds (e.g. 0:20), got {text!r}"
        ) from None
    if not b > a:
        raise argparse.ArgumentTypeError(f"the end must be after the start, got {text!r}")
    return a, b


def _cmd_analyze(args: argparse.Namespace) -> int:
    from kinefuse.workflows.analyze import format_analyze, json_text, run_analyze

    if not args.no_plots:
        import matplotlib

        matplotlib.use("Agg")  # the command draws to files only
    report = run_analyze(
        args.inputs,
        out=args.out,
        calibration_phase=args.calibration_phase,
        marker_map=args.map,
        method=args.method,
        calibration=args.calibration,
        true_calibration=args.true_calibration,
        plots=not args.no_plots,
        progress=lambda m: print(m, file=sys.stderr),
    )
    print(json_text(report) if args.json else format_analyze(report))
    return 0


def _add_analyze_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "analyze", help="normalized limb frames and joint angles (paper B; docs/analysis.md)"
    )
    p.add_argument(
        "inputs",
        nargs="+",
        type=Path,
        help="session (.sqlite), clip (.bvh/.amc), markers (.trc/.c3d)",
    )
    p.add_argument(
        "--calibration-phase",
        type=_phase,
        metavar="START_S:END_S",
        help="the frames to learn the movement axes from (default: a session's stored "
        "range-of-motion phase, else the whole input)",
    )
    p.add_argument(
        "--map", type=Path, help="marker map (TOML) for .trc/.c3d (default: a shipped one)"
    )
    p.add_argument(
        "--method",
        default="best",
        choices=["linear", "geometric", "nonlinear", "paper", "best"],
        help="fusion method for sessions (best)",
    )
    _add_calibration_args(p)
    p.add_argument("--out", type=Path, required=True, help="fresh output folder")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots (batch runs)")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=_cmd_analyze)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="kinefuse",
        description="Markerless motion capture with several depth sensors (simulated lab).",
    )
    parser.add_argument("--version", action="version", version=f"kinefuse {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    from kinefuse.workflows.demo import add_parser as add_demo_parser

    add_demo_parser(sub)  # kinefuse demo: the live system on this machine (docs/live.md)

    p = sub.add_parser("simulate", help="simulate a capture session of a real motion clip")
    p.add_argument("--clip", type=Path, required=True, help="motion clip (.bvh or .amc)")
    _add_simulate_args(p)
    p.add_argument("--out", type=Path, required=True, help="session store to write (.sqlite)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace --out if it is a simulated kinefuse session (never any other file)",
    )
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("calibrate", help="find every sensor's pose from the wand phase")
    p.add_argument("session", type=Path, nargs="?", help="session store (or --live HOST:PORT)")
    from kinefuse.workflows.serve import add_calibrate_live_args
    from kinefuse.workflows.serve import add_parser as add_serve_parser

    add_calibrate_live_args(p)
    p.add_argument(
        "--method", choices=["paper", "full"], default="full", help="registration (full)"
    )
    p.add_argument(
        "--detector",
        choices=["paper", "robust"],
        help="wand detector (default: the method's own: paper for paper, robust for full)",
    )
    p.add_argument("--out", type=Path, help="write the calibration file (TOML)")
    p.add_argument(
        "--store",
        action="store_true",
        help="also store the calibration in the session (otherwise the session is only read)",
    )
    p.add_argument(
        "--accept",
        action="store_true",
        help="write a calibration even when it grades as failed (exit code 0)",
    )
    p.add_argument(
        "--report",
        type=Path,
        help="folder for the paper-style error plots (sessions with truth only)",
    )
    _add_partial_arg(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_cmd_calibrate)
    add_serve_parser(sub)
    from kinefuse.workflows.proxy import add_parser as add_proxy_parser

    add_proxy_parser(sub)  # kinefuse proxy: a fault-injecting TCP proxy (docs/live.md)

    p = sub.add_parser("fuse", help="fuse a session's joints into one skeleton")
    p.add_argument("session", type=Path)
    _add_calibration_args(p)
    p.add_argument(
        "--method",
        default="best",
        choices=["linear", "geometric", "nonlinear", "paper", "best", "best-live"],
        help="fusion method (best; best-live is the causal fusion a live server runs)",
    )
    p.add_argument("--out", type=Path, help="export the fused skeleton (.c3d, .trc or .csv)")
    p.add_argument(
        "--trc-axes",
        choices=["y-up", "z-up"],
        default="y-up",
        help="axes of a .trc export: OpenSim's Y up (default) or the lab's Z up",
    )
    p.add_argument(
        "--store",
        action="store_true",
        help="also store the fused skeleton in the session (otherwise the session is only read)",
    )
    _add_span_args(p)
    _add_partial_arg(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_cmd_fuse)

    p = sub.add_parser("evaluate", help="compare fusion methods against the simulator's truth")
    p.add_argument("session", type=Path)
    _add_calibration_args(p)
    p.add_argument(
        "--methods",
        type=_methods,
        default=("linear", "geometric", "nonlinear", "paper", "best", "best-live"),
        help="comma-separated methods (all six)",
    )
    p.add_argument("--out", type=Path, help="folder for the paper-style tables and plots")
    _add_span_args(p)
    _add_partial_arg(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_cmd_evaluate)

    p = sub.add_parser(
        "realism",
        help="simulated vs real Kinect v2 two-sensor disagreement (docs/realism.md)",
        add_help=False,
    )
    p.add_argument("rest", nargs=argparse.REMAINDER, help="options of the realism report")
    p.set_defaults(func=_cmd_realism)

    p = sub.add_parser(
        "realdata",
        help="fuse the real two-Kinect recordings and report their consistency (docs/real_data.md)",
        description="Fuse real two-Kinect KinectMultiTrack logs and report their consistency.",
    )
    p.add_argument("paths", nargs="+", help="KinectMultiTrack CSV logs")
    p.add_argument("--json", action="store_true", help="print JSON instead of text")
    p.add_argument("--registration", choices=("refined", "logged"), default="refined")
    p.add_argument("--other-offaxis-deg", type=float, default=0.0)
    p.add_argument(
        "--no-motion-latency",
        action="store_true",
        help="align by the clock fit alone (no relative latency from the motion)",
    )
    p.set_defaults(func=_cmd_realdata)

    _add_analyze_parser(sub)

    p = sub.add_parser("view", help="replay a session in the web viewer (docs/viewer.md)")
    p.add_argument("session", type=Path)
    p.add_argument("--host", default="127.0.0.1", help="interface to serve on (127.0.0.1)")
    p.add_argument("--port", type=int, default=0, help="TCP port (0: a free one)")
    p.set_defaults(func=_cmd_view)

    p = sub.add_parser("inspect", help="summarize a session store")
    p.add_argument("session", type=Path)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_cmd_inspect)

    from kinefuse.workflows.sensor import add_parser as add_sensor_parser

    add_sensor_parser(sub)  # kinefuse sensor: one live sensor client (docs/live.md)
    return parser


def _exit_cleanly_on_sigterm() -> None:
    """Turn SIGTERM into SystemExit, so that temporary files are removed on the way out (a
    plain SIGTERM would end the process without running any cleanup)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return

    def stop(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, stop)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if argv[:1] == ["realism"]:
        # this report has its own option parser: hand it everything after the name
        args = argparse.Namespace(func=_cmd_realism, rest=argv[1:])
    else:
        args = parser.parse_args(argv)
    _exit_cleanly_on_sigterm()
    try:
        return int(args.func(args))
    except KinefuseError as exc:
        print(f"kinefuse: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        # a file the user named that cannot be read or written: say which and why, no traceback
        where = f" {exc.filename}" if exc.filename else ""
        print(f"kinefuse: error:{where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("kinefuse: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader of our output went away (e.g. `| head`): not an error of ours
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


def realdata_main(argv: Sequence[str]) -> int:
    """``kinefuse realdata ARGV...``: the realdata command with its own arguments only."""
    return main(["realdata", *argv])


if __name__ == "__main__":
    sys.exit(main())
