"""``kinefuse sensor``: one sensor client process (docs/live.md, "The sensor client").

Light at import (the CLI imports it to build its parser); the client loads when it runs.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from kinefuse.errors import InputError

#: what the truth sidecar says it is (a file without it is not ours: never overwritten)
SIDECAR_MARK = ("written_by", "kinefuse sensor")


def _server(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT (e.g. 127.0.0.1:7400), got {text!r}")
    return host.strip("[]"), int(port)


def _float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _positive(text: str) -> float:
    v = _float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def _count(text: str) -> int:
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return int(text)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``sensor`` to the CLI's subcommands."""
    p = sub.add_parser(
        "sensor",
        help="a sensor client: play one sensor's frames to a kinefuse server in real time",
        description="Play one sensor's frames to `kinefuse serve` as the sensor delivers them "
        "(docs/live.md). Stops cleanly on SIGINT/SIGTERM (exit 0); exit 3 when the server "
        "refuses (token, version, duplicate sensor id), 2 on bad input.",
    )
    p.add_argument("--server", type=_server, required=True, metavar="HOST:PORT")
    p.add_argument(
        "--source",
        required=True,
        help="sim:SESSION.sqlite#SENSOR_ID, multitrack:FILE.csv#KINECT_ID, kinect2json:FILE, "
        "driver:MODULE:FACTORY[?KEY=VALUE&...][#SENSOR_ID] or an installed driver NAME:ARG",
    )
    p.add_argument(
        "--token",
        default=os.environ.get("KINEFUSE_TOKEN"),
        help="the server's shared token (default: $KINEFUSE_TOKEN); it never crosses the wire",
    )
    p.add_argument(
        "--truth-out",
        type=Path,
        help="write the emulation's truth (clock and play start) to this JSON, for evaluation",
    )
    p.add_argument(
        "--clock-offset-ms",
        type=_float,
        help="emulated host clock at the play start, ms (default: the simulated sensor's, else 0)",
    )
    p.add_argument(
        "--clock-drift-ppm",
        type=_float,
        help="emulated host clock rate error, ppm (default: the simulated sensor's, else 0)",
    )
    p.add_argument(
        "--epoch-monotonic",
        type=_float,
        metavar="M",
        help="play source time T at CLOCK_MONOTONIC M + T / speed (clients in step; a late "
        "start skips to the present)",
    )
    p.add_argument("--speed", type=_positive, default=1.0, help="source s per real s (1)")
    p.add_argument(
        "--max-seconds", type=_positive, help="stop after this much source time (default: all)"
    )
    p.add_argument(
        "--detector", choices=["robust", "paper"], default="robust", help="wand detector"
    )
    p.add_argument(
        "--detect-every",
        type=_count,
        default=1,
        metavar="K",
        help="run wand detection on every K-th depth frame (1; busy frames are skipped anyway)",
    )
    p.add_argument(
        "--occlusion",
        choices=["crossing", "coverage"],
        default="crossing",
        help="occlusion rule: the paper's bone crossing (default) or capsule coverage",
    )
    p.add_argument(
        "--serial", default="", help="the device's serial number for Hello (default: the source's)"
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log every connection event")
    p.set_defaults(func=cmd_sensor)


def cmd_sensor(args: argparse.Namespace) -> int:
    """Run one sensor client until it stops; return the exit code."""
    import asyncio
    import signal

    from kinefuse import __version__
    from kinefuse.io.outputs import json_recognizer, refuse_unless_ours
    from kinefuse.net.client.client import ClientOptions, ClientRefused, SensorClient
    from kinefuse.net.client.clocks import HostClock, real_host_clock
    from kinefuse.net.client.playback import open_timeline

    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="kinefuse sensor: %(message)s",
        stream=sys.stderr,
    )
    recognizer = json_recognizer(*SIDECAR_MARK)
    if args.truth_out is not None:
        refuse_unless_ours(args.truth_out, recognizer, "truth sidecar")
    options = ClientOptions(
        server=args.server,
        token=args.token or None,
        detector=args.detector,
        detect_every=args.detect_every,
        occlusion_rule=args.occlusion,
        speed=args.speed,
        max_seconds=args.max_seconds,
        serial=args.serial,
        software=f"kinefuse {__version__}",
    )
    timeline = open_timeline(args.source)
    if not args.serial and timeline.serial:
        options = replace(options, serial=timeline.serial)
    try:
        truth = timeline.truth
        if timeline.live:
            if args.clock_offset_ms is not None or args.clock_drift_ppm is not None:
                raise InputError(
                    "a driver source stamps on this PC's clock: --clock-offset-ms and "
                    "--clock-drift-ppm are for simulated and recorded sources only"
                )
            h0, drift = 0.0, 0.0
        else:
            h0 = truth.host_offset_s if truth is not None else 0.0
            drift = truth.host_drift_ppm * 1e-6 if truth is not None else 0.0
            if args.clock_offset_ms is not None:
                h0 = args.clock_offset_ms * 1e-3
            if args.clock_drift_ppm is not None:
                drift = args.clock_drift_ppm * 1e-6
        HostClock(h0, drift, 0.0)  # checks the drift now, before connecting
    except BaseException:
        timeline.close()
        raise

    side: dict[str, Any] = {
        SIDECAR_MARK[0]: SIDECAR_MARK[1],
        "sensor_id": timeline.sensor_id,
        "source": args.source,
        "h0": h0,
        "drift": drift,
        "epoch_monotonic": args.epoch_monotonic,
        "speed": args.speed,
    }

    def write_sidecar(**more: Any) -> None:
        if args.truth_out is None:
            return
        from kinefuse.io.outputs import atomic_write_text

        side.update(more)
        atomic_write_text(
            args.truth_out,
            json.dumps(side, indent=2) + "\n",
            what="truth sidecar",
            recognizer=recognizer,
        )

    def on_play_start(m0: float, start_mono: float, start_src: float) -> None:
        extra: dict[str, Any] = {
            "m0": m0,
            "play_start_monotonic": start_mono,
            "play_start_source_s": None if math.isnan(start_src) else start_src,
        }
        if timeline.source_clock != "true":
            extra["source_clock"] = timeline.source_clock
        write_sidecar(**extra)

    def emulated(m0: float) -> HostClock:
        return HostClock(h0, drift, m0)

    host_clock: Any = real_host_clock() if timeline.live else emulated

    client = SensorClient(
        timeline,
        options,
        host_clock=host_clock,
        epoch_monotonic=args.epoch_monotonic,
        on_play_start=on_play_start,
    )
    # the loop thread must get the GIL back quickly from the detection thread: probe replies
    # are stamped on it (5 ms by default)
    sys.setswitchinterval(0.001)
    import faulthandler

    faulthandler.register(signal.SIGUSR1)  # kill -USR1 PID prints every thread's stack

    async def main() -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, client.stop, f"signal {signal.Signals(sig).name}")
        try:
            return await client.run()
        finally:
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.remove_signal_handler(sig)

    try:
        code = asyncio.run(main())
    except ClientRefused as e:
        print(f"kinefuse sensor: error: {e}", file=sys.stderr)
        return 3
    st = client.stats
    if "m0" in side:
        write_sidecar(stats=vars(st))
    logging.getLogger("kinefuse.sensor").info(
        "stopped: %d body frames sent, %d dropped, %d sightings, %d probes answered",
        st.body_sent, st.body_dropped, st.sightings_sent, st.probes_answered,
    )  # fmt: skip
    return code
