"""``kinefuse sensor``: one sensor client process (docs/live.md, "The sensor client").

The options are parsed in :mod:`kinefuse.app.cli.sensor`; the client loads when it runs.
"""

from __future__ import annotations

import json
import logging
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from kinefuse.errors import InputError

#: what the truth sidecar says it is (a file without it is not ours: never overwritten)
SIDECAR_MARK = ("written_by", "kinefuse sensor")


def run_sensor(
    *,
    clock_drift_ppm: float | None,
    clock_offset_ms: float | None,
    detect_every: int,
    detector: str,
    epoch_monotonic: float | None,
    max_seconds: float | None,
    occlusion: str,
    serial: str,
    server: tuple[str, int],
    source: str,
    speed: float,
    token: str | None,
    truth_out: Path | None,
    verbose: bool,
    tracker: str | None = None,
) -> int:
    """Run one sensor client until it stops; return the exit code (0 a clean stop, 3 refused).

    The options are those of ``kinefuse sensor`` (docs/live.md, "The sensor client")."""
    import asyncio
    import signal

    from kinefuse import __version__
    from kinefuse.core.outputs import json_recognizer, refuse_unless_ours
    from kinefuse.live.client.client import ClientOptions, ClientRefused, SensorClient
    from kinefuse.live.client.clocks import HostClock, real_host_clock
    from kinefuse.live.client.playback import open_timeline

    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="kinefuse sensor: %(message)s",
        stream=sys.stderr,
    )
    recognizer = json_recognizer(*SIDECAR_MARK)
    if truth_out is not None:
        refuse_unless_ours(truth_out, recognizer, "truth sidecar")
    options = ClientOptions(
        server=server,
        token=token or None,
        detector=detector,
        detect_every=detect_every,
        occlusion_rule=occlusion,
        speed=speed,
        max_seconds=max_seconds,
        serial=serial,
        software=f"kinefuse {__version__}",
    )
    timeline = open_timeline(source, tracker, speed=speed)
    if not serial and timeline.serial:
        options = replace(options, serial=timeline.serial)
    try:
        truth = timeline.truth
        if timeline.live:
            if clock_offset_ms is not None or clock_drift_ppm is not None:
                raise InputError(
                    "a live source stamps on this PC's clock: --clock-offset-ms and "
                    "--clock-drift-ppm are for simulated and recorded sources only"
                )
            h0, drift = 0.0, 0.0
        else:
            h0 = truth.host.offset_s if truth is not None else 0.0
            drift = truth.host.drift_ppm * 1e-6 if truth is not None else 0.0
            if clock_offset_ms is not None:
                h0 = clock_offset_ms * 1e-3
            if clock_drift_ppm is not None:
                drift = clock_drift_ppm * 1e-6
        HostClock(h0, drift, 0.0)  # checks the drift now, before connecting
    except BaseException:
        timeline.close()
        raise

    side: dict[str, Any] = {
        SIDECAR_MARK[0]: SIDECAR_MARK[1],
        "sensor_id": timeline.sensor_id,
        "source": source,
        "h0": h0,
        "drift": drift,
        "epoch_monotonic": epoch_monotonic,
        "speed": speed,
    }

    def write_sidecar(**more: Any) -> None:
        if truth_out is None:
            return
        from kinefuse.core.outputs import atomic_write_text

        side.update(more)
        atomic_write_text(
            truth_out,
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
        epoch_monotonic=epoch_monotonic,
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
    tracker_line = timeline.tracker_status()
    if "m0" in side:
        write_sidecar(stats=vars(st), tracker=tracker_line)
    logging.getLogger("kinefuse.sensor").info(
        "stopped: %d body frames sent, %d dropped, %d depth frames, %d sightings, "
        "%d probes answered",
        st.body_sent, st.body_dropped, st.depth_frames, st.sightings_sent, st.probes_answered,
    )  # fmt: skip
    if tracker_line is not None:
        logging.getLogger("kinefuse.sensor").info("%s", tracker_line)
    return code


def list_sources() -> str:
    """``kinefuse sensor --list-sources``: every source kind and tracker, one per line, with
    whether it is installed here and, where not, the command that installs it."""
    from importlib.metadata import entry_points

    from kinefuse.devices.sources import list_sources as rows
    from kinefuse.live.client.playback import ENTRY_POINT_GROUP

    table = rows()
    for ep in entry_points(group=ENTRY_POINT_GROUP):  # drivers: FrameSources of their own
        table.append((ep.name, f"{ep.name}:ARG", "installed", f"driver entry point {ep.value}"))
    w0 = max(len(r[0]) for r in table)
    lines = []
    for kind, form, status, what in table:
        state, _, how = status.partition(": ")
        lines.append(f"{kind:<{w0}}  {state:<9}  {form}  ({what})")
        if how:
            lines.append(f"{'':<{w0}}  {'':<9}  install: {how}")
    return "\n".join(lines)
