"""Run inside ``unshare -rn`` (only ``lo`` up) under strace, by tests/test_lsl.py; not a test.

A live run as the demo does it (``kinefuse serve --lsl`` recording, with one real ``kinefuse
sensor`` process per sensor of a simulated session), LSL confined to 127.0.0.1 as
../shared/design/LSL.md says (a loopback-only lsl_api.cfg through LSLAPICFG, checked in the log
before anything opens; a discovery-free inlet built from the outlet's XML with 127.0.0.1).
Writes what it measured as JSON to ``--out``; the test judges it.

    python tests/lsl_loopback_run.py --session S.sqlite --work DIR --out result.json
"""

from __future__ import annotations

import argparse
import ctypes
import json
import math
import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

#: LSL.md's configuration, verbatim (no indentation, no inline comments, no empty values)
LSL_API_CFG = """[ports]
MulticastPort = 26571
BasePort = 26572
PortRange = 32
IPv6 = disable
[multicast]
ResolveScope = machine
MachineAddresses = {127.0.0.1}
AddressesOverride = {127.0.0.1}
TTLOverride = 0
ListenAddress = 127.0.0.1
Interfaces = {127.0.0.1}
[lab]
KnownPeers = {127.0.0.1}
SessionID = kinefuse-loopback-test
[log]
level = 0
"""
NAME = "kinefuse-loopback-test"
_LSL_LINE = re.compile(r"LSL stream '(?P<name>[^']+)'")
_FRAMES = re.compile(r"stopped \(.*\); (?P<n>\d+) fused frames")


def _inlet_from_xml(pylsl: object, xml: str) -> object:
    """A StreamInlet from the outlet's XML, its address set to 127.0.0.1 (no discovery)."""
    xml = re.sub(r"<v4address\s*/>|<v4address>[^<]*</v4address>",
                 "<v4address>127.0.0.1</v4address>", xml)  # fmt: skip
    lib = pylsl.lib.lib  # type: ignore[attr-defined]  (the ctypes CDLL of liblsl)
    lib.lsl_streaminfo_from_xml.restype = ctypes.c_void_p
    lib.lsl_streaminfo_from_xml.argtypes = [ctypes.c_char_p]
    handle = lib.lsl_streaminfo_from_xml(xml.encode())
    if not handle:
        raise RuntimeError("liblsl could not read the outlet's XML")
    info = pylsl.StreamInfo(handle=handle)  # type: ignore[attr-defined]
    return pylsl.StreamInlet(info, max_buflen=360, recover=False)  # type: ignore[attr-defined]


def _channels(full_info: object) -> list[dict[str, str]]:
    out = []
    ch = full_info.desc().child("channels").child("channel")  # type: ignore[attr-defined]
    while not ch.empty():
        out.append({k: ch.child_value(k) for k in ("label", "type", "unit")})
        ch = ch.next_sibling()
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--session", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    result: dict[str, object] = {"interfaces": [n for _i, n in socket.if_nameindex()]}
    cfg = a.work / "lsl_api.cfg"
    cfg.write_text(LSL_API_CFG)
    os.environ["LSLAPICFG"] = str(cfg)  # for this process and every child
    # the configuration must be read before anything opens (StreamInfo loads it, no sockets)
    probe = subprocess.run(
        [sys.executable, "-c", "import pylsl; pylsl.StreamInfo('probe', 'MoCap', 1)"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    result["config_loaded"] = f"Configuration loaded from {cfg}" in probe.stderr
    if not result["config_loaded"]:
        result["probe_stderr"] = probe.stderr[-2000:]
        a.out.write_text(json.dumps(result))
        return 1
    import pylsl

    from kinefuse.app.workflows.demo import ChildProcesses, parse_listening, sensor_args
    from kinefuse.formats.store.live_tables import live_fused
    from kinefuse.formats.store.session_store import SessionStore

    result["monotonic_minus_local_clock_s"] = min(
        (time.monotonic() - pylsl.local_clock() for _ in range(20)), key=abs
    )
    with SessionStore.open(a.session) as st:
        ids = [s.id for s in st.sensors()]
        end_s = float(st.meta()["motion_phase_server_s"][1])  # type: ignore[index]
    rec, xml_path = a.work / "rec.sqlite", a.work / "stream.xml"
    received: list[tuple[float, list[float]]] = []
    stop = threading.Event()
    with ChildProcesses(a.work / "logs") as procs:
        server = procs.start(
            "server",
            ["serve", "--host", "127.0.0.1", "--port", "0", "--record", str(rec),
             "--auto-calibrate", "--lsl", NAME, "--lsl-xml", str(xml_path)],
            announce=True,
        )  # fmt: skip
        port = parse_listening(procs.wait_first_line(server, 60.0))[1]
        m = server.wait_line(_LSL_LINE, 30.0)
        if m is None:
            raise RuntimeError(f"the server announced no LSL stream:\n{server.tail()}")
        inlet = _inlet_from_xml(pylsl, xml_path.read_text())
        inlet.open_stream(timeout=10.0)  # type: ignore[attr-defined]
        full = inlet.info(timeout=10.0)  # type: ignore[attr-defined]
        result["stream"] = {
            "name": full.name(), "type": full.type(), "channel_count": full.channel_count(),
            "nominal_srate": full.nominal_srate(), "channel_format": full.channel_format(),
            "reference_frame": full.desc().child_value("reference_frame"),
            "offset_s": float(full.desc().child("kinefuse_clock").child_value("offset_s")),
        }  # fmt: skip
        result["channels"] = _channels(full)
        result["cf_float32"] = pylsl.cf_float32

        def pull() -> None:
            while not stop.is_set():
                try:
                    sample, ts = inlet.pull_sample(timeout=0.2)  # type: ignore[attr-defined]
                except pylsl.LostError:
                    return
                if ts is not None:
                    received.append((ts, sample))

        puller = threading.Thread(target=pull, daemon=True)
        puller.start()
        epoch = time.monotonic() + 2.5 + 0.5 * len(ids)
        sensors = []
        for sid in ids:
            args = sensor_args(port, a.session, sid, a.work / f"{sid}.json", epoch)
            sensors.append(procs.start(f"sensor-{sid}", args))
        deadline = epoch + end_s + 30.0
        while any(c.popen.poll() is None for c in sensors) and time.monotonic() < deadline:
            time.sleep(0.2)
        result["sensor_rcs"] = [c.popen.poll() for c in sensors]
        result["server_rc"] = procs.stop(server)
        time.sleep(0.5)
        stop.set()
        puller.join(5.0)
        log = server.log.read_text(encoding="utf-8", errors="replace")
        result["server_config_loaded"] = f"Configuration loaded from {cfg}" in log
        mf = _FRAMES.search(log)
        result["fused_frames_said"] = int(mf["n"]) if mf else None
    with SessionStore.open(rec) as st:
        fused = live_fused(st)
        t0 = float(st.meta()["server_t0_monotonic"])  # type: ignore[arg-type]
    offset = float(result["stream"]["offset_s"])  # type: ignore[index]
    result["offset_minus_server_t0_monotonic_s"] = offset - t0
    ts = np.array([r[0] for r in received])
    samples = np.array([r[1] for r in received], dtype=np.float32).reshape(len(received), -1)
    t = fused.t_server_s
    idx = np.clip(np.searchsorted(t, ts - offset), 1, max(len(t) - 1, 1))
    idx = np.where(np.abs(t[idx - 1] - (ts - offset)) < np.abs(t[idx] - (ts - offset)),
                   idx - 1, idx)  # fmt: skip
    err = (ts - offset) - t[idx]
    want = np.concatenate(
        [fused.positions_m[idx].reshape(len(idx), -1), fused.status[idx].astype(float)], axis=1
    ).astype(np.float32)
    same = np.all((samples == want) | (np.isnan(samples) & np.isnan(want)), axis=1)
    result.update(
        fused_frames_recorded=len(t),
        samples_received=len(received),
        frames_matched=len(set(fused.frame[idx[same]].tolist())),
        samples_not_matching_their_frame=int((~same).sum()),
        max_abs_time_error_s=float(np.max(np.abs(err))) if len(err) else math.inf,
        # where the person was seen: some samples carry positions
        samples_with_positions=int(np.isfinite(samples[:, :75]).any(axis=1).sum()),
    )
    a.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
