"""``kinefuse serve`` and ``kinefuse calibrate --live``: the live server and its control peer.

No argument parsing here (that is :mod:`kinefuse.cli`): these run the asyncio parts and turn
their outcome into exit codes and printed lines.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import json
import logging
import math
import os
import signal
import sys
from pathlib import Path
from typing import Any

import numpy as np

from kinefuse.errors import InputError, KinefuseError

log = logging.getLogger("kinefuse.serve")


def _setup_logging(verbose: bool) -> None:
    root = logging.getLogger("kinefuse")
    if not any(getattr(h, "_kinefuse", False) for h in root.handlers):
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter("kinefuse serve: %(levelname)s: %(message)s"))
        h._kinefuse = True  # type: ignore[attr-defined]
        root.addHandler(h)
    root.setLevel(logging.DEBUG if verbose else logging.INFO)


def token_from(arg: str | None) -> str | None:
    """``--token`` or else the ``KINEFUSE_TOKEN`` environment variable (None: no token)."""
    tok = arg if arg is not None else os.environ.get("KINEFUSE_TOKEN")
    if tok is not None and not tok:
        raise InputError("the token is empty; give a non-empty --token (or KINEFUSE_TOKEN)")
    return tok


def parse_hostport(text: str, default_port: int = 7400) -> tuple[str, int]:
    """``HOST:PORT`` (or ``HOST``) -> (host, port); IPv6 as ``[::1]:7400``."""
    host, port = text, default_port
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise InputError(f"bad address {text!r}: expected [IPV6]:PORT")
        host, rest = text[1:end], text[end + 1 :]
        if rest.startswith(":"):
            port = _port(rest[1:], text)
    elif text.count(":") == 1:
        host, p = text.split(":")
        port = _port(p, text)
    if not host:
        raise InputError(f"bad address {text!r}: expected HOST:PORT, e.g. 127.0.0.1:7400")
    return host, port


def _port(p: str, text: str) -> int:
    try:
        v = int(p)
    except ValueError:
        raise InputError(f"bad port in {text!r}: expected a number 0-65535") from None
    if not 0 <= v <= 65535:
        raise InputError(f"bad port in {text!r}: expected a number 0-65535")
    return v


def _unwrap(eg: BaseExceptionGroup[BaseException]) -> BaseException:
    """The first leaf of an exception group (what a TaskGroup raised)."""
    e: BaseException = eg
    while isinstance(e, BaseExceptionGroup):
        e = e.exceptions[0]
    return e


def run_serve(
    *,
    host: str,
    port: int,
    token: str | None,
    record: Path | None,
    calibration: Path | None,
    method: str,
    latency_budget_ms: float,
    auto_calibrate: bool,
    calibration_method: str = "full",
    wand_axis_m: float | None = None,
    viewer_port: int | None = None,
    verbose: bool = False,
) -> int:
    """Run the server until SIGINT/SIGTERM or a control peer's Shutdown; 0 on a clean stop."""
    from kinefuse.net.server.calibration import LiveCalibrationOptions
    from kinefuse.net.server.server import Server, ServerOptions

    _setup_logging(verbose)
    if not (math.isfinite(latency_budget_ms) and latency_budget_ms >= 0):
        raise InputError(f"--latency-budget-ms must be >= 0, got {latency_budget_ms}")
    if record is not None:
        from kinefuse.net.server.recorder import check_recording_path

        check_recording_path(record)
    options = ServerOptions(
        host=host,
        port=port,
        token=token,
        record=record,
        method=method,
        latency_budget_s=latency_budget_ms / 1e3,
        auto_calibrate=auto_calibrate,
        calibration=LiveCalibrationOptions(method=calibration_method, axis_length_m=wand_axis_m),
    )
    services = {}
    if viewer_port is not None:  # the live web viewer, on the server's publisher
        from kinefuse.viewer import live_viewer

        services["viewer"] = functools.partial(live_viewer, host=host, port=viewer_port)
    server = Server(options, services=services)
    if calibration is not None:
        from kinefuse.calibration.calib_file import read_calibration

        server.load_calibration(read_calibration(calibration))

    def ready(h: str, p: int) -> None:
        print(f"kinefuse serve: listening on {h}:{p}", flush=True)
        if "viewer" in server.services:
            print(f"kinefuse serve: viewer at http://{h}:{server.services['viewer']}/", flush=True)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            # (not possible outside the main thread or on some platforms: then Ctrl-C ends it)
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, server.request_stop, f"signal {sig.name}")
        await server.run(ready)

    try:
        asyncio.run(main())
    except BaseExceptionGroup as eg:
        raise _unwrap(eg) from None
    frames = server.loop.frames
    print(f"kinefuse serve: stopped ({server._stop_reason}); {frames} fused frames"
          + (f", recording {record}" if record else ""), flush=True)  # fmt: skip
    return 0


# -- kinefuse calibrate --live ---------------------------------------------------------------------


async def _control_calibrate(
    host: str, port: int, token: str | None, method: str, seconds: float | None, timeout_s: float
) -> Any:
    from kinefuse.protocol import (
        AuthReply,
        CalibrationResult,
        CalibrationStart,
        CalibrationStop,
        Challenge,
        Decoder,
        Error,
        Goodbye,
        Heartbeat,
        Hello,
        Welcome,
        encode,
    )
    from kinefuse.protocol.auth import compute_mac

    try:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), 10.0)
    except (OSError, TimeoutError) as e:
        raise KinefuseError(f"cannot reach the server at {host}:{port} ({e}); is `kinefuse "
                            "serve` running there?") from None  # fmt: skip
    dec = Decoder()
    inbox: list[Any] = []

    async def recv(t: float) -> Any:
        while not inbox:
            data = await asyncio.wait_for(reader.read(65536), t)
            if not data:
                raise KinefuseError("the server closed the connection")
            inbox.extend(dec.feed(data))
        return inbox.pop(0)

    def send(m: Any) -> None:
        writer.write(encode(m))

    try:
        send(Hello(role="control", software="kinefuse calibrate --live"))
        msg = await recv(10.0)
        if isinstance(msg, Challenge):
            if token is None:
                raise KinefuseError("the server requires a token: pass --token (or KINEFUSE_TOKEN)")
            send(AuthReply(mac=compute_mac(token, msg.nonce, role="control", sensor_id="")))
            msg = await recv(10.0)
        if isinstance(msg, Error):
            raise KinefuseError(f"the server refused: {msg.reason} ({msg.code})")
        if not isinstance(msg, Welcome):
            raise KinefuseError(f"expected welcome from the server, got {msg.TYPE}")
        beat = msg.heartbeat_s
        send(CalibrationStart(method=method, seconds=seconds))
        loop = asyncio.get_running_loop()
        t_end = loop.time() + timeout_s
        # the server ends the phase after `seconds`; a Stop a little later in case it did not
        t_stop = loop.time() + seconds + 2.0 if seconds is not None else math.inf
        while True:
            now = loop.time()
            if now > t_end:
                raise KinefuseError(f"no calibration result within {timeout_s:g} s")
            if now >= t_stop:
                send(CalibrationStop())
                t_stop = math.inf
            try:
                msg = await recv(min(beat, max(t_stop - now, 0.01)))
            except TimeoutError:
                send(Heartbeat(t_s=now))
                continue
            if isinstance(msg, CalibrationResult):
                send(Goodbye(reason="calibration done"))
                await writer.drain()
                return msg
            if isinstance(msg, Error):
                raise KinefuseError(f"the server refused: {msg.reason} ({msg.code})")
            if isinstance(msg, Goodbye):
                raise KinefuseError(f"the server said goodbye before a result: {msg.reason}")
    finally:
        writer.close()


def run_calibrate_live(
    *,
    address: str,
    method: str,
    seconds: float | None,
    token: str | None,
    timeout_s: float = 300.0,
) -> dict[str, Any]:
    """Ask a running server to calibrate; the result as
    :func:`kinefuse.workflows.calibrate.run_calibrate`'s."""
    host, port = parse_hostport(address)
    res = asyncio.run(_control_calibrate(host, port, token, method, seconds, timeout_s))
    reasons = [r.strip() for r in res.message.split(";")[1:]]
    return {
        "method": res.method,
        "detector": "client",
        "world": "",
        "rms_m": float(np.sqrt(np.nanmean(res.residual_m**2))) if len(res.residual_m) else math.nan,
        "grade": res.grade,
        "reasons": reasons,
        "accepted": bool(res.ok),
        "used_by_server": bool(res.ok),
        "message": res.message.split(";")[0],
        "sensors": [
            {
                "id": sid,
                "residual_m": float(res.residual_m[k]),
                "sightings": int(res.n_sightings[k]),
            }
            for k, sid in enumerate(res.sensor_ids)
        ],
        "out": None,
    }


def format_calibrate_live(r: dict[str, Any]) -> str:
    lines = [f"live calibration ({r['method']}): {r['message']}", f"grade: {r['grade']}"]
    lines += [f"  {why}" for why in r["reasons"]]
    lines.append("")
    lines.append(f"{'sensor':<8} {'sightings':>9} {'residual mm':>12}")
    for s in r["sensors"]:
        lines.append(f"{s['id']:<8} {s['sightings']:>9} {1e3 * s['residual_m']:12.2f}")
    if not r["accepted"]:
        lines.append("the server keeps its previous poses (this calibration failed)")
    return "\n".join(lines)


# -- command line ----------------------------------------------------------------------------------


def add_calibrate_live_args(p: argparse.ArgumentParser) -> None:
    """The ``--live`` options of ``kinefuse calibrate``."""
    from kinefuse.cli import _positive_float

    p.add_argument(
        "--live",
        metavar="HOST:PORT",
        help="calibrate through a running `kinefuse serve` instead of a session",
    )
    p.add_argument(
        "--seconds",
        type=_positive_float,
        help="(--live) stop the wand phase after this long (default: when the wand is put away)",
    )
    p.add_argument("--token", help="(--live) the server's token (default: KINEFUSE_TOKEN)")


def cmd_calibrate_live(args: argparse.Namespace) -> int:
    """``kinefuse calibrate --live HOST:PORT``."""

    if args.live is None:
        raise KinefuseError("give a session to calibrate, or --live HOST:PORT of a server")
    if args.session is not None:
        raise KinefuseError("give either a session or --live HOST:PORT, not both")
    r = run_calibrate_live(
        address=args.live, method=args.method, seconds=args.seconds, token=token_from(args.token)
    )
    print(json.dumps(r, indent=2) if args.json else format_calibrate_live(r))
    return 0 if r["accepted"] else 3


def cmd_serve(args: argparse.Namespace) -> int:
    """``kinefuse serve``."""

    return run_serve(
        host=args.host,
        port=args.port,
        token=token_from(args.token),
        record=args.record,
        calibration=args.calibration,
        method=args.method,
        latency_budget_ms=args.latency_budget_ms,
        auto_calibrate=args.auto_calibrate,
        calibration_method=args.calibration_method,
        wand_axis_m=args.wand_axis_m,
        viewer_port=args.viewer_port,
        verbose=args.verbose,
    )


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse serve``."""
    from kinefuse.cli import _nonneg_float, _positive_float

    p = sub.add_parser("serve", help="run the live server: sensor clients in, fused frames out")
    p.add_argument("--host", default="127.0.0.1", help="bind address (127.0.0.1: this PC only)")
    p.add_argument("--port", type=int, default=7400, help="TCP port (7400; 0: a free one)")
    p.add_argument("--token", help="shared secret clients must prove (default: KINEFUSE_TOKEN)")
    p.add_argument("--record", type=Path, help="record everything into this NEW session file")
    p.add_argument("--calibration", type=Path, help="start with these poses (calibration TOML)")
    p.add_argument(
        "--method", choices=["best-live", "paper"], default="best-live", help="live fusion"
    )
    p.add_argument(
        "--latency-budget-ms",
        type=_nonneg_float,
        default=10.0,
        metavar="MS",
        help="wait this long for late frames before predicting (10 ms)",
    )
    p.add_argument(
        "--auto-calibrate",
        action="store_true",
        help="start the wand calibration as soon as a sensor without a pose joins",
    )
    p.add_argument(
        "--calibration-method", choices=["full", "paper"], default="full", help="registration"
    )
    p.add_argument(
        "--wand-axis-m",
        type=_positive_float,
        metavar="M",
        help="the wand protocol's move between its two holds (m), to fix the scale",
    )
    p.add_argument(
        "--viewer-port",
        type=int,
        metavar="PORT",
        help="serve the live web viewer on this port (0: a free one; on --host)",
    )
    p.add_argument("--verbose", action="store_true", help="log debug messages")
    p.set_defaults(func=cmd_serve)
