"""The live ``kinefuse demo``: the whole system on one machine, over loopback, then a report.

1. **simulate** the bundled clip (or ``--clip``) seen by N virtual Kinect v2 sensors, after a wand
   phase, into ``sim.sqlite`` (the simulator's truth stays in that file);
2. **start** ``kinefuse serve`` (a free port, recording to ``recording.sqlite``, calibrating from
   the wand automatically) and one ``kinefuse sensor`` process per sensor, each playing its
   sensor of ``sim.sqlite`` in real time; with ``--net-jitter-ms`` each client talks to the
   server through its own fault-injecting proxy (:mod:`kinefuse.live.proxy`, asymmetric delays);
3. **calibrate and capture live**: the clients send wand sightings from their depth frames, the
   server registers the sensors, then fuses the body frames at 30 Hz and records everything;
4. **stop** cleanly: every client ends with its source, then the server is asked to stop (SIGINT
   = a clean stop); every process must exit with status 0 within a bounded wait, or it is killed
   and the demo fails naming it; none is left behind, also on Ctrl-C;
5. **evaluate** offline (:mod:`kinefuse.lab.live_truth`): the truth is written into the
   recording's truth tables, the recording is re-fused with ``best`` and the paper's chain,
   exported (``.c3d``, ``.trc``, ``.csv``, ``.bvh``) and scored; clock, calibration and latency
   figures.

Outputs go to a folder built beside ``--out`` and swapped in only when the run is complete
(:func:`kinefuse.core.outputs.atomic_dir`), so an interrupted demo leaves the previous one as it
was.

Why about 610 lines: the demo is one workflow (processes, their supervision, the evaluation and
the report of one run); its parts are already library calls, and what remains is their order.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from kinefuse.errors import InputError, KinefuseError

#: Length of the simulated wand phase before the motion, seconds (the wand protocol's holds come
#: first, so every client must be playing from its start).
DEMO_CALIBRATION_S = 15.0

#: Default length of the captured motion, seconds (at most the clip's).
DEMO_SECONDS = 20.0
#: The formats the demo exports the offline fusion in (one fusion, every file).
EXPORTS = (".c3d", ".trc", ".csv", ".bvh")

#: Time from starting the sensor processes to the instant every one starts playing, seconds:
#: long enough for N Python processes to start and connect on a busy 2-core machine (about
#: 1 s for 4 clients here; ``live_eval.json`` says how early each connected), so that none
#: misses the start of the wand phase.
START_SLACK_S = 2.5
START_SLACK_PER_SENSOR_S = 0.5

#: Bounded waits: the server's first line, a clean stop, a kill.
SERVER_START_TIMEOUT_S = 60.0
STOP_TIMEOUT_S = 20.0
KILL_TIMEOUT_S = 5.0

_LISTENING = re.compile(r"listening on (?P<host>[0-9.]+):(?P<port>\d+)")
_VIEWER = re.compile(r"viewer at (?P<url>http://\S+)")


class ProcessError(KinefuseError):
    """A child process of the demo failed, hung or could not start."""


@dataclass
class Child:
    """One process the demo started, with its log file."""

    name: str
    popen: subprocess.Popen[bytes]
    log: Path
    first_line: str | None = None
    ready: threading.Event = field(default_factory=threading.Event)
    #: every stdout line so far (announcing children only), and a condition to wait on them
    lines: list[str] = field(default_factory=list)
    changed: threading.Condition = field(default_factory=threading.Condition)
    ended: bool = False

    def wait_line(self, pattern: re.Pattern[str], timeout_s: float) -> re.Match[str] | None:
        """The first stdout line matching ``pattern``, waiting up to ``timeout_s``; None if the
        output ended or the time passed without one."""
        deadline = time.monotonic() + timeout_s
        with self.changed:
            while True:
                for line in self.lines:
                    m = pattern.search(line)
                    if m is not None:
                        return m
                left = deadline - time.monotonic()
                if self.ended or left <= 0:
                    return None
                self.changed.wait(left)

    def tail(self, n: int = 15) -> str:
        """The last ``n`` lines of the process's log (for error messages)."""
        with contextlib.suppress(OSError):
            lines = self.log.read_text(encoding="utf-8", errors="replace").splitlines()
            return "\n".join("    " + x for x in lines[-n:])
        return "    (no log)"


class ChildProcesses:
    """Start kinefuse processes, keep their logs, and make sure none outlives the caller.

    Each child runs ``python -m kinefuse ...`` in a session of its own (so a Ctrl-C reaches the
    demo only, which then stops the children in order); leaving the context stops every child
    still running: SIGINT (a clean stop), then SIGKILL after ``STOP_TIMEOUT_S``.
    """

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.children: list[Child] = []
        self._logs: set[Path] = set()  # the logs this object made (a restarted child appends)
        log_dir.mkdir(parents=True, exist_ok=True)

    def __enter__(self) -> ChildProcesses:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()

    def start(self, name: str, args: list[str], *, announce: bool = False) -> Child:
        """Start ``python -m kinefuse ARGS``; with ``announce`` its first stdout line is kept
        (the server prints its bound address there) and every line goes to its log."""
        log = self.log_dir / f"{name}.log"
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        cmd = [sys.executable, "-m", "kinefuse", *args]
        try:  # a log file never replaces one this object did not make
            f = log.open("ab" if log in self._logs else "xb")
        except OSError as e:
            raise ProcessError(
                f"cannot start {name}: its log {log} "
                + (
                    "exists already; give an empty log folder"
                    if isinstance(e, FileExistsError)
                    else f"cannot be written: {e.strerror or e}"
                )
            ) from None
        self._logs.add(log)
        try:
            popen = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE if announce else f,
                stderr=f,
                env=env,
                start_new_session=True,
            )
        except OSError as e:
            f.close()
            raise ProcessError(f"cannot start {name} ({' '.join(cmd)}): {e}") from None
        child = Child(name, popen, log)
        self.children.append(child)
        if announce:
            assert popen.stdout is not None
            threading.Thread(target=_copy_lines, args=(popen.stdout, f, child), daemon=True).start()
        else:
            f.close()
            child.ready.set()
        return child

    def wait_first_line(self, child: Child, timeout_s: float) -> str:
        """The child's first stdout line; a :class:`ProcessError` if it exits or times out."""
        if not child.ready.wait(timeout_s) or child.first_line is None:
            rc = child.popen.poll()
            why = f"exited with status {rc}" if rc is not None else f"said nothing in {timeout_s} s"
            raise ProcessError(f"{child.name} {why}; its log ({child.log}):\n{child.tail()}")
        return child.first_line

    def check_running(self) -> None:
        """Raise :class:`ProcessError` if a child ended with a non-zero status."""
        for c in self.children:
            rc = c.popen.poll()
            if rc is not None and rc != 0:
                raise ProcessError(
                    f"{c.name} exited with status {rc}; its log ({c.log}):\n{c.tail()}"
                )

    def stop(self, child: Child, timeout_s: float = STOP_TIMEOUT_S) -> int:
        """Ask ``child`` to stop (SIGINT) and wait; kill it after ``timeout_s``.

        Returns its exit status; a :class:`ProcessError` if it had to be killed.
        """
        p = child.popen
        if p.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                p.send_signal(signal.SIGINT)
            try:
                p.wait(timeout_s)
            except subprocess.TimeoutExpired:
                _kill(p)
                raise ProcessError(
                    f"{child.name} did not stop within {timeout_s:g} s of SIGINT and was killed; "
                    f"its log ({child.log}):\n{child.tail()}"
                ) from None
        return int(p.returncode)

    def stop_all(self) -> None:
        """Stop every child still running (SIGINT, then SIGKILL); never raises. A second Ctrl-C
        while it waits does not interrupt it (that would leave the children behind)."""
        with _sigint_ignored():
            self._stop_all()

    def _stop_all(self) -> None:
        running = [c for c in self.children if c.popen.poll() is None]
        for c in running:
            with contextlib.suppress(ProcessLookupError):
                c.popen.send_signal(signal.SIGINT)
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for c in running:
            try:
                c.popen.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                _kill(c.popen)
        for c in self.children:
            if c.popen.stdout is not None:
                with contextlib.suppress(OSError):
                    c.popen.stdout.close()


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _kill(p: subprocess.Popen[bytes]) -> None:
    with contextlib.suppress(ProcessLookupError):
        p.kill()
    with contextlib.suppress(subprocess.TimeoutExpired):
        p.wait(KILL_TIMEOUT_S)


def _copy_lines(stream: IO[bytes], log: IO[bytes], child: Child) -> None:
    try:
        for line in stream:
            text = line.decode("utf-8", errors="replace").strip()
            if child.first_line is None:
                child.first_line = text
                child.ready.set()
            with child.changed:
                child.lines.append(text)
                child.changed.notify_all()
            log.write(line)
            log.flush()
    except (OSError, ValueError):
        pass
    finally:
        child.ready.set()
        with child.changed:
            child.ended = True
            child.changed.notify_all()
        with contextlib.suppress(OSError):
            log.close()


def parse_listening(line: str) -> tuple[str, int]:
    """``(host, port)`` from the server's first line ``kinefuse serve: listening on H:P``."""
    m = _LISTENING.search(line)
    if m is None:
        raise ProcessError(
            f"the server's first line should say where it listens ('kinefuse serve: listening on "
            f"127.0.0.1:PORT'), got {line!r}"
        )
    return m["host"], int(m["port"])


# ------------------------------------------------------------------------------------------
# the command lines of the processes


def serve_args(
    recording: Path, wand_axis_m: float | None = None, viewer_port: int | None = None
) -> list[str]:
    """``kinefuse serve`` as the demo runs it: loopback, a free port, recording, auto-calibrated,
    with the live viewer (``viewer_port``; 0: a free port, None: none); ``wand_axis_m``: the
    wand protocol's move between its holds (what the operator was told)."""
    args = ["serve", "--host", "127.0.0.1", "--port", "0", "--record", str(recording),
            "--auto-calibrate"]  # fmt: skip
    if viewer_port is not None:
        args += ["--viewer-port", str(viewer_port)]
    if wand_axis_m is not None:
        args += ["--wand-axis-m", f"{wand_axis_m:g}"]
    return args


def sensor_args(
    port: int, session: Path, sensor_id: str, truth_out: Path, epoch_monotonic: float
) -> list[str]:
    """``kinefuse sensor`` playing one simulated sensor, starting at a common instant."""
    return ["sensor", "--server", f"127.0.0.1:{port}", "--source", f"sim:{session}#{sensor_id}",
            "--truth-out", str(truth_out),
            "--epoch-monotonic", f"{epoch_monotonic:.6f}"]  # fmt: skip


# ------------------------------------------------------------------------------------------
# the live part


@dataclass(frozen=True)
class LiveRun:
    """What the live part produced: where, and how long each stage took (seconds)."""

    recording: Path
    sidecars: dict[str, Path]
    logs: dict[str, Path]
    epoch_monotonic: float
    seconds: dict[str, float]
    proxies: list[dict[str, Any]]


def run_live(
    session: Path,
    work: Path,
    *,
    net_jitter_ms: float | None = None,
    seed: int = 0,
    viewer_port: int | None = None,
    say: Callable[[str], None] = print,
    on_started: Callable[[ChildProcesses, list[Child]], None] | None = None,
) -> LiveRun:
    """Run the server and one client per sensor of ``session`` until the session is played.

    ``on_started(processes, sensor_children)`` is called once everything runs (the fault tests
    use it to kill a client mid-run). Every process must exit with status 0.
    """
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.live.proxy import ProxyThread, jitter_profiles

    with SessionStore.open(session) as st:
        ids = [s.id for s in st.sensors()]
        phases = st.meta()
    end_s = float(phases["motion_phase_server_s"][1])  # type: ignore[index]
    protocol = phases.get("wand_protocol")
    axis = protocol.get("axis_length_m") if isinstance(protocol, dict) else None
    recording = work / "recording.sqlite"
    truth_dir = work / "truth"
    truth_dir.mkdir(exist_ok=True)
    sidecars = {sid: truth_dir / f"{sid}.json" for sid in ids}
    t_start = time.monotonic()
    with ChildProcesses(work / "logs") as procs, ProxyThread() as proxies:
        server = procs.start("server", serve_args(recording, axis, viewer_port), announce=True)
        _host, port = parse_listening(procs.wait_first_line(server, SERVER_START_TIMEOUT_S))
        say(f"   server listening on 127.0.0.1:{port}, recording to {recording.name}")
        if viewer_port is not None:
            m = server.wait_line(_VIEWER, 10.0)
            if m is not None:
                say(f"   live view while it runs: {m['url']} (open it in a browser)")
        links: dict[str, int] = {}
        for k, sid in enumerate(ids):
            if net_jitter_ms is None:
                links[sid] = port
            else:
                up, down = jitter_profiles(net_jitter_ms)
                links[sid] = proxies.add("127.0.0.1", port, up=up, down=down, seed=seed + k).port
        if net_jitter_ms is not None:
            say(f"   each client through its own proxy: up 0.2 ms + exponential jitter of mean "
                f"{net_jitter_ms:g} ms, down 0.2 ms + {net_jitter_ms / 2:g} ms")  # fmt: skip
        epoch = time.monotonic() + START_SLACK_S + START_SLACK_PER_SENSOR_S * len(ids)
        sensors = [
            procs.start(
                f"sensor-{sid}", sensor_args(links[sid], session, sid, sidecars[sid], epoch)
            )
            for sid in ids
        ]
        say(f"   {len(ids)} sensor clients started; playback starts in "
            f"{epoch - time.monotonic():.1f} s")  # fmt: skip
        t_up = time.monotonic()
        if on_started is not None:
            on_started(procs, sensors)
        # the clients play until their source ends; then they stop by themselves
        deadline = epoch + end_s + 15.0
        last_say = 0.0
        while any(c.popen.poll() is None for c in sensors):
            procs.check_running()
            now = time.monotonic()
            if server.popen.poll() is not None:
                raise ProcessError(
                    f"the server exited (status {server.popen.returncode}) while the clients "
                    f"were still playing; its log ({server.log}):\n{server.tail()}"
                )
            if now > deadline:
                for c in sensors:
                    procs.stop(c)
                break
            if now - last_say >= 5.0 and now > epoch:
                say(f"   live: {now - epoch:5.1f} s of {end_s:.1f} s played")
                last_say = now
            time.sleep(0.2)
        procs.check_running()
        t_played = time.monotonic()
        rc = procs.stop(server)
        if rc != 0:
            raise ProcessError(
                f"the server exited with status {rc} on a clean stop; its log ({server.log}):\n"
                f"{server.tail()}"
            )
        proxy_stats = [
            {
                "connection": c.index,
                "bytes_up": c.bytes_up,
                "bytes_down": c.bytes_down,
                "cut": c.cut,
                "mean_delay_up_ms": _mean_ms(c.delays_up_s),
                "mean_delay_down_ms": _mean_ms(c.delays_down_s),
            }
            for c in proxies.stats()
        ]
        logs = {c.name: c.log for c in procs.children}
    t_end = time.monotonic()
    missing = [sid for sid, p in sidecars.items() if not p.is_file()]
    if missing:
        raise ProcessError(
            f"sensor client(s) {', '.join(missing)} wrote no truth sidecar (--truth-out); see "
            f"their logs in {work / 'logs'}"
        )
    return LiveRun(
        recording=recording,
        sidecars=sidecars,
        logs=logs,
        epoch_monotonic=epoch,
        seconds={
            "start": t_up - t_start,
            "live": t_played - t_up,
            "stop": t_end - t_played,
        },
        proxies=proxy_stats,
    )


def _mean_ms(d: Any) -> float | None:
    return 1e3 * sum(d) / len(d) if len(d) else None


# ------------------------------------------------------------------------------------------
# the whole demo


def run_live_demo(
    *,
    out_dir: Path,
    sensors: int = 4,
    seconds: float | None = None,
    clip: Path | None = None,
    net_jitter_ms: float | None = None,
    seed: int = 0,
    as_json: bool = False,
    viewer_port: int | None = None,
) -> int:
    """``kinefuse demo``: simulate, run the live system, evaluate; see the module docstring."""
    from kinefuse.app.workflows.evaluate import run_evaluate
    from kinefuse.app.workflows.fuse import run_fuse
    from kinefuse.app.workflows.simulate import demo_clip_path, run_simulate
    from kinefuse.core.outputs import atomic_dir
    from kinefuse.formats.motion import load_motion
    from kinefuse.lab.live_truth import evaluate_live, format_live, write_live_truth

    if not 1 <= sensors <= 8:
        raise InputError(f"--sensors must be between 1 and 8, got {sensors}")
    if net_jitter_ms is not None and not (math.isfinite(net_jitter_ms) and net_jitter_ms >= 0):
        raise InputError(f"--net-jitter-ms must be a number >= 0, got {net_jitter_ms}")
    say: Callable[[str], None] = (lambda m: print(m, file=sys.stderr)) if as_json else print
    clip_path = demo_clip_path() if clip is None else clip
    if seconds is None:
        seconds = min(DEMO_SECONDS, load_motion(clip_path).duration_s)
    t0 = time.monotonic()
    with atomic_dir(out_dir, what="demo output folder") as tmp:
        sim = tmp / "sim.sqlite"
        say(f"== 1/4 simulate: {sensors} Kinect v2 sensors watch {clip_path.name} for "
            f"{seconds:g} s, after {DEMO_CALIBRATION_S:g} s of wand waving")  # fmt: skip
        r = run_simulate(
            clip=clip_path,
            out=sim,
            sensors=sensors,
            seconds=seconds,
            seed=seed,
            calibration_s=DEMO_CALIBRATION_S,
        )
        for w in r.warnings:
            say(f"   warning: {w}")
        say("\n== 2/4 live: a server and one client process per sensor on 127.0.0.1; the "
            "sensors calibrate from the wand, then the body is fused at 30 Hz")  # fmt: skip
        live = run_live(
            sim, tmp, net_jitter_ms=net_jitter_ms, seed=seed, viewer_port=viewer_port, say=say
        )
        t_live = time.monotonic()

        say("\n== 3/4 offline: the recording re-fused with best, exported")
        write_live_truth(live.recording, sim, live.sidecars)
        outputs = [f"fused{ext}" for ext in EXPORTS]
        fused = run_fuse(
            session=live.recording,
            method="best",
            out=tmp / outputs[0],
            also_out=tuple(tmp / o for o in outputs[1:]),
            calibration=None,
            true_calibration=False,
        )
        say(f"   {fused.frames} frames ({fused.calibration}) -> {', '.join(outputs)}")
        for w in fused.warnings:
            say(f"   warning: {w}")

        say("\n== 4/4 evaluate: live and offline against the simulator's truth")
        methods = ("paper", "best")
        report = run_evaluate(
            session=live.recording,
            methods=methods,
            out_dir=tmp / "evaluation",
            calibration=None,
            true_calibration=False,
        )
        result = evaluate_live(live.recording, offline_report=report.report)
        result["seconds"] = {
            **{k: round(v, 2) for k, v in live.seconds.items()},
            "simulate_and_live": round(t_live - t0, 2),
            "total": round(time.monotonic() - t0, 2),
        }
        result["proxies"] = live.proxies
        outputs += ["sim.sqlite", "recording.sqlite", "calibration.toml", "evaluation/",
                    "live_eval.json", "logs/"]  # fmt: skip
        _write_calibration(live.recording, tmp / "calibration.toml")
        result["outputs"] = [str(out_dir / p) for p in outputs]
        (tmp / "live_eval.json").write_text(json.dumps(result, indent=2) + "\n")
        say(format_live(result))
    if as_json:
        print(json.dumps(result, indent=2))
    else:
        say(f"\noutputs in {out_dir}/: recording.sqlite (the live recording, with the truth added "
            "after the run), sim.sqlite (the simulated session the clients played), "
            "calibration.toml (the live calibration), fused.c3d, fused.trc, fused.csv, "
            "fused.bvh, evaluation/ (tables I-III, trajectories.png), live_eval.json, "
            "logs/")  # fmt: skip
    return 0


def _write_calibration(recording: Path, out: Path) -> None:
    """The calibration the server stored in the recording, as a calibration file."""
    from kinefuse.capture.calibration.calib_file import write_calibration
    from kinefuse.formats.store.session_store import SessionStore

    with SessionStore.open(recording) as st:
        for name in ("full", "paper", *st.calibration_names()):
            text = st.calibration(name)
            if text is not None:
                write_calibration(out, text)
                return
    raise ProcessError(f"{recording} holds no calibration: the live calibration did not finish")


# ------------------------------------------------------------------------------------------
# the command line


def run_demo(*, out_dir: Path, seed: int = 0) -> int:
    """The main job, end to end on the bundled clip: simulate a 4-sensor session (wand phase,
    then the motion), calibrate the sensors from the wand, fuse the skeleton, export it, and
    compare every fusion method against the truth.

    Everything is built in a fresh folder beside ``out_dir`` and swapped in only when the whole
    run succeeded, so an interrupted demo leaves the previous run's outputs as they were.
    """
    from kinefuse.app.workflows.evaluate import format_evaluate, run_evaluate
    from kinefuse.app.workflows.fuse import run_fuse
    from kinefuse.app.workflows.simulate import DEMO_CLIP, demo_clip_path, run_simulate
    from kinefuse.capture.fusion.methods import METHODS
    from kinefuse.core.outputs import atomic_dir
    from kinefuse.errors import CalibrationError
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.inspect import format_inspect, inspect_session

    say = print
    with atomic_dir(out_dir, what="demo output folder") as tmp:
        session = tmp / "session.sqlite"
        say(f"== 1/4 simulate: 4 Kinect v2 sensors watch CMU 01_01 ({DEMO_CLIP}), after 15 s "
            "of wand waving")  # fmt: skip
        sim = run_simulate(
            clip=demo_clip_path(),
            out=session,
            seed=seed,
            calibration_s=15.0,
            progress=lambda m: say("   " + m),
        )
        for w in sim.warnings:
            say(f"   warning: {w}")
        with SessionStore.open(session) as st:
            info = inspect_session(st)
        (tmp / "inspect.json").write_text(json.dumps(info, indent=2) + "\n")
        say(format_inspect(info))

        say("\n== 2/4 calibrate: every sensor's pose from the wand seen in depth")
        from kinefuse.app.workflows.calibrate import format_calibrate, run_calibrate

        cal = run_calibrate(
            session=session,
            method="full",
            out=tmp / "calibration.toml",
            report_dir=tmp / "calibration",
            store_result=True,
        )
        say(format_calibrate(cal))
        if cal.grade == "failed":
            raise CalibrationError("the demo's calibration failed; see the reasons above")

        say("\n== 3/4 fuse: one skeleton from the four sensors (method best)")
        names = [f"fused{ext}" for ext in EXPORTS]
        fused = run_fuse(
            session=session,
            method="best",
            out=tmp / names[0],
            also_out=tuple(tmp / o for o in names[1:]),
            calibration=None,
            true_calibration=False,
        )
        say(f"   {fused.frames} frames in {fused.seconds:.2f} s -> {', '.join(names)}")

        say("\n== 4/4 evaluate: the paper's methods and ours against the truth")
        report = run_evaluate(
            session=session,
            methods=METHODS,
            out_dir=tmp / "evaluation",
            calibration=None,
            true_calibration=False,
        )
        say(format_evaluate(report.report, METHODS))
    say(f"\noutputs in {out_dir}/: session.sqlite, inspect.json, calibration.toml, "
        "calibration/ (error plots), fused.c3d, fused.trc, fused.csv, fused.bvh, evaluation/ "
        "(report.html, tables I-III, trajectories.png, evaluate.json)")  # fmt: skip
    return 0
