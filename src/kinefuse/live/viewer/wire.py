"""The viewer's WebSocket messages: a small binary frame layout and JSON text messages (no I/O).

The layout is documented in ``docs/viewer.md`` (section "Wire format"); this module is its one
implementation on the server side (``static/viewer.js`` reads it in the browser) and has a
decoder for tests and benchmarks.

Binary frame (little-endian), one per shown frame::

    u8  type = 1 (FRAME)
    u8  version = 1
    u16 n_layers
    u32 seq                 the fused-frame counter (live) or frame index (replay)
    f64 t_s                 frame time, seconds (server clock; replay: session clock)
    f32 latency_ms          NaN when unknown
    n_layers x layer:
        u8  kind            0 fused, 1 raw sensor skeleton, 2 truth, 3 person
        u8  name_len        then name_len bytes of UTF-8 (method, sensor id, or a person's
                            id ``p<id>``, with `` subject`` after the subject's)
        u8  has_status      1: a status block follows the positions
        25 x 3 f32          world positions, metres, z up; NaN where missing
        25 x i8             FusionStatus codes (only if has_status)

A frame with the fused skeleton and 8 raw skeletons is about 2.9 kB. With more than one person in
the room, a live frame's fused layer is the subject and a person layer follows for every person
(the subject's included, so that the page can label them all).

Text messages are JSON objects with a ``"type"``: ``hello`` (once, on connect: mode, joint
names, bones, status names, and for a replay the timeline), ``status`` (the server's status,
about once a second). The page sends ``{"cmd": ...}`` objects to a replay (play, pause, seek,
step, speed); a live viewer ignores them.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import PurePath
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.core.skeleton import BONES, JOINT_INDEX, JOINTS, N_JOINTS
from kinefuse.live.bus import FusedFrame, Status

FRAME = 1
VERSION = 1
FUSED, RAW, TRUTH, PERSON = 0, 1, 2, 3

_HEAD = struct.Struct("<BBHIdf")
_POS_BYTES = N_JOINTS * 3 * 4


@dataclass(frozen=True, eq=False)
class Layer:
    """One skeleton of a frame: ``kind`` (FUSED, RAW, TRUTH), ``name``, positions ``(25, 3)``
    metres (world, z up, NaN where missing) and, for fused layers, ``status`` ``(25,)`` int8."""

    kind: int
    name: str
    positions_m: NDArray[np.float64]
    status: NDArray[np.int8] | None = None


@dataclass(frozen=True, eq=False)
class Frame:
    """A decoded binary frame (see the module docstring)."""

    seq: int
    t_s: float
    latency_ms: float
    layers: tuple[Layer, ...]


def encode_frame(seq: int, t_s: float, latency_ms: float, layers: Iterable[Layer]) -> bytes:
    """The binary frame of ``layers`` (see the module docstring for the layout)."""
    layers = list(layers)
    parts = [_HEAD.pack(FRAME, VERSION, len(layers), seq & 0xFFFFFFFF, t_s, latency_ms)]
    for layer in layers:
        name = layer.name.encode("utf-8")[:255]
        pos = np.asarray(layer.positions_m, dtype="<f4")
        if pos.shape != (N_JOINTS, 3):
            raise ValueError(f"layer {layer.name!r}: positions must be (25, 3), got {pos.shape}")
        has_status = layer.status is not None
        parts.append(struct.pack("<BB", layer.kind, len(name)) + name + bytes([has_status]))
        parts.append(pos.tobytes())
        if layer.status is not None:
            st = np.asarray(layer.status, dtype=np.int8)
            if st.shape != (N_JOINTS,):
                raise ValueError(f"layer {layer.name!r}: status must be (25,), got {st.shape}")
            parts.append(st.tobytes())
    return b"".join(parts)


def decode_frame(data: bytes) -> Frame:
    """Read a binary frame back (tests, benchmarks); ValueError on a malformed one."""
    if len(data) < _HEAD.size:
        raise ValueError(f"a frame has at least {_HEAD.size} bytes, got {len(data)}")
    kind, version, n, seq, t_s, lat = _HEAD.unpack_from(data, 0)
    if kind != FRAME or version != VERSION:
        raise ValueError(f"not a version-{VERSION} frame (type {kind}, version {version})")
    off = _HEAD.size
    layers = []
    try:
        for _ in range(n):
            lk, ln = data[off], data[off + 1]
            name = data[off + 2 : off + 2 + ln].decode("utf-8")
            off += 2 + ln
            has_status = data[off]
            off += 1
            pos = np.frombuffer(data, "<f4", N_JOINTS * 3, off).reshape(N_JOINTS, 3)
            off += _POS_BYTES
            st = None
            if has_status:
                st = np.frombuffer(data, np.int8, N_JOINTS, off).copy()
                off += N_JOINTS
            layers.append(Layer(lk, name, pos.astype(np.float64), st))
    except (IndexError, ValueError) as exc:
        raise ValueError(f"truncated frame: {exc}") from None
    if off != len(data):
        raise ValueError(f"frame has {len(data) - off} bytes after its last layer")
    return Frame(seq, t_s, lat, tuple(layers))


def fused_frame_bytes(frame: FusedFrame, *, method: str = "fused", people: bool = False) -> bytes:
    """The binary frame of a live :class:`~kinefuse.live.bus.FusedFrame`: the fused layer (the
    subject), then each sensor's raw skeleton (sorted by sensor id), then, when ``people`` and
    there is more than one person, every person's (by id)."""
    layers = [Layer(FUSED, method, frame.positions_m, frame.status)]
    layers += [Layer(RAW, sid, frame.raw_m[sid]) for sid in sorted(frame.raw_m)]
    if people and len(frame.people_m) > 1:
        layers += [
            Layer(PERSON, person_name(pid, pid == frame.subject), frame.people_m[pid])
            for pid in sorted(frame.people_m)
        ]
    lat = frame.latency_s * 1e3 if math.isfinite(frame.latency_s) else math.nan
    return encode_frame(frame.seq, frame.t_server_s, lat, layers)


def person_name(person_id: int, subject: bool) -> str:
    """A person layer's name: ``p1``, or ``p0 subject`` for the subject."""
    return f"p{person_id}" + (" subject" if subject else "")


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def status_message(status: Status) -> dict[str, Any]:
    """The ``status`` text message of a :class:`~kinefuse.live.bus.Status` (NaN: null)."""
    return {
        "type": "status",
        "t_server_s": _num(status.t_server_s),
        "calibration_state": status.calibration_state,
        "calibration_grade": status.calibration_grade,
        "calibration_message": status.calibration_message,
        "fused_fps": _num(status.fused_fps),
        "method": status.method,
        # the file's name: where it lies on the server's disk is nobody's business on the wire
        "recording": PurePath(status.recording).name if status.recording else status.recording,
        "sensors": [
            {
                "id": s.sensor_id,
                "connected": s.connected,
                "rtt_ms": _num(s.rtt_ms),
                "clock_offset_ms": _num(s.clock_offset_ms),
                "clock_offset_sd_ms": _num(s.clock_offset_sd_ms),
                "fps": _num(s.fps),
                "latency_ms": _num(s.latency_ms),
                "tracked_fraction": _num(s.tracked_fraction),
                # frames refused because their seq did not increase on their connection, and
                # why the sensor's floor fit failed: what the operator must see, not only the log
                "stale_frames": s.stale_frames,
                "floor_error": s.floor_error,
                # the sensor's body tracker: achieved rate and captures dropped (text)
                "tracker": s.tracker,
                "pose": None  # row-major 4x4, sensor -> world
                if s.sensor2world is None or not np.isfinite(s.sensor2world).all()
                else [float(v) for v in np.asarray(s.sensor2world).ravel()],
            }
            for s in status.sensors
        ],
    }


def hello_message(mode: str, **extra: Any) -> dict[str, Any]:
    """The ``hello`` text message: what the page needs to draw (topology, status names)."""
    return {
        "type": "hello",
        "mode": mode,
        "joints": list(JOINTS),
        "bones": [[JOINT_INDEX[a], JOINT_INDEX[b]] for a, b in BONES],
        "status_names": {str(int(s)): s.name for s in FusionStatus},
        **extra,
    }
