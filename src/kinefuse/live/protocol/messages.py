"""The wire messages: one frozen dataclass per message type (protocol version 1.3).

Each class names its wire ``TYPE`` (the ``type`` field of the msgpack map), the roles that may
send it (``SENDERS``: ``"sensor"``, ``"control"``, ``"server"``) and, in its fields' metadata,
the :mod:`~kinefuse.live.protocol.fields` kind that encodes and checks each field.
``docs/protocol.md`` documents every field with its unit; a test checks that it names them all.

Times: ``t1``/``t4`` and ``t_server_s`` are on the server clock (seconds since the server
started); ``t2``/``t3``/``t_host_s`` on the client PC's host clock; ``t_device_s`` on the
sensor's own clock; all float64 seconds. Positions are metres in the sensor frame (x right,
y down, z forward) unless a name says ``world``.

The wire messages carry ``Message`` in their names where a core type has the same idea:
``BodyFrameMessage`` is what crosses the wire, :class:`kinefuse.core.frames.observations.BodyFrame`
what a source yields (the sensor client turns one into the other); ``FloorPlaneMessage`` carries a
:class:`kinefuse.capture.calibration.floor.FloorPlane`.
"""

# ruff: noqa: RUF009  (_f returns dataclasses.field(...) with the field's wire kind as metadata)
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.frames.observations import MAX_BODIES
from kinefuse.live.protocol.fields import (
    Array,
    Bool,
    Bytes,
    Float,
    Int,
    IntrinsicsKind,
    Kind,
    Optional,
    Records,
    Str,
    StrList,
    Version,
)
from kinefuse.live.protocol.wire_errors import FieldError

#: (major, minor) this code speaks; see docs/protocol.md "Versioning"
PROTOCOL_VERSION: tuple[int, int] = (1, 3)
#: the first version whose body frames carry every body (``body_id``, ``others``)
BODIES_VERSION: tuple[int, int] = (1, 3)

N_JOINTS = 25
ROLES = ("sensor", "control")

_SENSOR = frozenset({"sensor"})
_CONTROL = frozenset({"control"})
_SERVER = frozenset({"server"})
_ANY = frozenset({"sensor", "control", "server"})
_PEERS = frozenset({"sensor", "control"})

_T = Float(-1e12, 1e12)  # a time in seconds on some clock (finite)
_ID = Str(max_len=64, ident=True)
_TEXT = Str(max_len=1024)
_SEQ = Int(0)


def _f(
    kind: Kind, default: Any = dataclasses.MISSING, *, factory: Any = dataclasses.MISSING
) -> Any:
    if factory is not dataclasses.MISSING:
        return field(default_factory=factory, metadata={"kind": kind})
    return field(default=default, metadata={"kind": kind})


class Message:
    """Base of all wire messages (``TYPE``: wire name; ``SENDERS``: who may send it)."""

    TYPE: ClassVar[str] = ""
    SENDERS: ClassVar[frozenset[str]] = frozenset()

    def check(self) -> None:
        """Cross-field rules, checked after every field decoded (raises FieldError)."""


# ---- handshake -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Hello(Message):
    """First message of a peer: who it is and what it speaks.

    A ``sensor`` peer must give ``sensor_id`` (unique among connected sensors, kept across
    reconnects) and the depth camera's ``intrinsics``; a ``control`` peer leaves both empty.
    ``client_nonce`` (since 1.1): a peer that has a token sends a fresh random nonce here and
    the server must prove it knows the token over it (``Challenge.server_mac``); nil from a
    peer without a token or an older one.
    """

    TYPE: ClassVar[str] = "hello"
    SENDERS: ClassVar[frozenset[str]] = _PEERS

    role: str = _f(Str(choices=ROLES))
    sensor_id: str = _f(_ID, "")
    serial: str = _f(Str(max_len=128), "")
    intrinsics: Intrinsics | None = _f(Optional(IntrinsicsKind()), None)
    capabilities: tuple[str, ...] = _f(StrList(), ())
    software: str = _f(Str(max_len=128), "")
    protocol_version: tuple[int, int] = _f(Version(), PROTOCOL_VERSION)
    client_nonce: bytes | None = _f(Optional(Bytes(16, 64)), None)

    def check(self) -> None:
        if self.role == "sensor":
            if not self.sensor_id:
                raise FieldError(self.TYPE, "sensor_id", "a sensor peer must name its sensor")
            if self.intrinsics is None:
                raise FieldError(self.TYPE, "intrinsics", "a sensor peer must send intrinsics")


@dataclass(frozen=True)
class Challenge(Message):
    """Server -> peer when the server has a token: prove it with HMAC over ``nonce``.

    ``server_mac`` (since 1.1; nil when the Hello had no ``client_nonce``): the server's own
    proof, HMAC-SHA256 keyed with ``HMAC-SHA256(token, "kinefuse-server-proof-v1")`` over both
    nonces, the role and the sensor id (protocol.auth.compute_server_mac). A peer that sent a
    ``client_nonce`` checks it before it answers and refuses the server if it is nil or wrong.
    """

    TYPE: ClassVar[str] = "challenge"
    SENDERS: ClassVar[frozenset[str]] = _SERVER

    nonce: bytes = _f(Bytes(16, 64))
    algorithm: str = _f(Str(choices=("hmac-sha256",)), "hmac-sha256")
    server_mac: bytes | None = _f(Optional(Bytes(32, 32)), None)


@dataclass(frozen=True)
class AuthReply(Message):
    """Peer -> server: ``mac = HMAC-SHA256(token, nonce + context)`` (see protocol.auth)."""

    TYPE: ClassVar[str] = "auth_reply"
    SENDERS: ClassVar[frozenset[str]] = _PEERS

    mac: bytes = _f(Bytes(32, 32))


@dataclass(frozen=True)
class Welcome(Message):
    """Server -> peer: accepted. The peer may send data from now on.

    ``heartbeat_s``: each side sends a Heartbeat when it has sent nothing for this long;
    ``timeout_s``: a side that hears nothing for this long closes the connection.
    ``calibrating``: a calibration (``calibration_id``) is running, so a sensor sends sightings.
    """

    TYPE: ClassVar[str] = "welcome"
    SENDERS: ClassVar[frozenset[str]] = _SERVER

    session: str = _f(Str(max_len=128), "")
    t_server_s: float = _f(_T, 0.0)
    heartbeat_s: float = _f(Float(0.01, 600.0), 1.0)
    timeout_s: float = _f(Float(0.05, 3600.0), 5.0)
    calibrating: bool = _f(Bool(), False)
    calibration_id: int = _f(_SEQ, 0)
    capabilities: tuple[str, ...] = _f(StrList(), ())
    protocol_version: tuple[int, int] = _f(Version(), PROTOCOL_VERSION)


@dataclass(frozen=True)
class Error(Message):
    """Either side: a refusal or a fault (``code`` as in docs/protocol.md), then close."""

    TYPE: ClassVar[str] = "error"
    SENDERS: ClassVar[frozenset[str]] = _ANY

    code: str = _f(Str(max_len=32, ident=True, allow_empty=False))
    reason: str = _f(_TEXT, "")


@dataclass(frozen=True)
class Goodbye(Message):
    """Either side: a clean close (the sender closes after it; no reconnect is expected)."""

    TYPE: ClassVar[str] = "goodbye"
    SENDERS: ClassVar[frozenset[str]] = _ANY

    reason: str = _f(_TEXT, "")


@dataclass(frozen=True)
class Heartbeat(Message):
    """Either side, when it has sent nothing for ``heartbeat_s``: I am alive.

    ``t_s``: the sender's own clock (informational); ``sent``/``dropped``: data messages the
    sender sent / dropped from its bounded send queue so far on this connection;
    ``floor_error`` (a sensor; optional, nil from older peers): why the floor fit of the
    current calibration failed, nil when it did not. A sensor whose fit fails sends a heartbeat
    with it at once; the server shows it in that sensor's status until the next calibration
    starts or a floor plane arrives. ``tracker`` (a sensor whose client runs a body tracker;
    optional since 1.2, nil otherwise and from older peers): the tracker's one-line status
    (achieved rate, captures dropped because it was behind, its last refusal); such a sensor
    sends a heartbeat at least every ``heartbeat_s`` even while it sends data, and the server
    shows the line in that sensor's status.
    """

    TYPE: ClassVar[str] = "heartbeat"
    SENDERS: ClassVar[frozenset[str]] = _ANY

    t_s: float = _f(_T, 0.0)
    sent: int = _f(_SEQ, 0)
    dropped: int = _f(_SEQ, 0)
    floor_error: str | None = _f(Optional(_TEXT), None)
    tracker: str | None = _f(Optional(_TEXT), None)


# ---- clock -------------------------------------------------------------------------------


@dataclass(frozen=True)
class ClockProbe(Message):
    """Server -> sensor: ``t1`` = server clock at sending (s). Answer at once."""

    TYPE: ClassVar[str] = "clock_probe"
    SENDERS: ClassVar[frozenset[str]] = _SERVER

    probe_id: int = _f(_SEQ)
    t1: float = _f(_T)


@dataclass(frozen=True)
class ClockReply(Message):
    """Sensor -> server: ``t2`` host clock at receiving the probe, ``t3`` at replying (s);
    ``t1`` echoed. The server stamps ``t4`` on arrival; offset = client - server."""

    TYPE: ClassVar[str] = "clock_reply"
    SENDERS: ClassVar[frozenset[str]] = _SENSOR

    probe_id: int = _f(_SEQ)
    t1: float = _f(_T)
    t2: float = _f(_T)
    t3: float = _f(_T)

    def check(self) -> None:
        if self.t3 < self.t2:
            raise FieldError(self.TYPE, "t3", f"replied at {self.t3} before receiving at {self.t2}")


# ---- calibration -----------------------------------------------------------------------------


@dataclass(frozen=True)
class CalibrationStart(Message):
    """Control -> server: start the wand phase; server -> sensors: send sightings now.

    ``method``: "" (the server's default), or a registration method name the server knows;
    ``sensor_ids``: the sensors to calibrate (empty = all connected); ``seconds``: the server
    ends the phase by itself after this long (s; nil = until a CalibrationStop or the server's
    own end rule). A sensor fits its floor plane from its first depth frames after each start.
    """

    TYPE: ClassVar[str] = "calibration_start"
    SENDERS: ClassVar[frozenset[str]] = frozenset({"control", "server"})

    calibration_id: int = _f(_SEQ, 0)
    method: str = _f(Str(max_len=32), "")
    sensor_ids: tuple[str, ...] = _f(StrList(), ())
    seconds: float | None = _f(Optional(Float(0.0, 86400.0)), None)


@dataclass(frozen=True)
class CalibrationStop(Message):
    """Control -> server: end the wand phase and solve (``abort``: discard, do not solve);
    server -> sensors: stop sending sightings."""

    TYPE: ClassVar[str] = "calibration_stop"
    SENDERS: ClassVar[frozenset[str]] = frozenset({"control", "server"})

    calibration_id: int = _f(_SEQ, 0)
    abort: bool = _f(Bool(), False)


@dataclass(frozen=True, eq=False)
class WandSighting(Message):
    """Sensor -> server: the wand found in one depth frame (sent only while calibrating).

    ``centre_m`` (3,): sphere centre in the sensor frame (m); ``score`` in [0, 1] (1 best);
    ``n_points``: depth samples behind it; ``residual_m``: RMS fit residual (m, NaN for the
    paper's detector); ``pixel_uv`` (2,): image position (px); ``detector``: "robust" or
    "paper"; ``stride``: the client runs detection on every ``stride``-th depth frame.
    """

    TYPE: ClassVar[str] = "wand_sighting"
    SENDERS: ClassVar[frozenset[str]] = _SENSOR

    seq: int = _f(_SEQ)
    t_device_s: float = _f(_T)
    t_host_s: float = _f(_T)
    centre_m: NDArray[np.float64] = _f(Array((3,), lo=-100.0, hi=100.0))
    score: float = _f(Float(0.0, 1.0), 1.0)
    n_points: int = _f(Int(0, 2**31 - 1), 0)
    residual_m: float = _f(Float(0.0, 100.0, allow_nan=True), float("nan"))
    pixel_uv: NDArray[np.float64] = _f(
        Array((2,), values="finite_or_nan", lo=-1e6, hi=1e6), factory=lambda: np.full(2, np.nan)
    )
    detector: str = _f(Str(choices=("robust", "paper")), "robust")
    stride: int = _f(Int(1, 10000), 1)
    calibration_id: int = _f(_SEQ, 0)


@dataclass(frozen=True, eq=False)
class FloorPlaneMessage(Message):
    """Sensor -> server, once per calibration: the floor ``normal . p + offset_m = 0``.

    Fitted (:func:`kinefuse.capture.calibration.floor.fit_floor_plane`) on the per-pixel median of
    the sensor's first ``n_frames`` depth frames after CalibrationStart. ``normal`` (3,): unit, up,
    sensor frame; ``offset_m``: the sensor's height above the floor (m); ``n_inliers``: plane
    samples; ``residual_m``: their RMS distance (m). Not sent when no floor is found.
    """

    TYPE: ClassVar[str] = "floor_plane"
    SENDERS: ClassVar[frozenset[str]] = _SENSOR

    normal: NDArray[np.float64] = _f(Array((3,), lo=-1.0, hi=1.0))
    offset_m: float = _f(Float(-100.0, 100.0))
    n_inliers: int = _f(Int(0, 2**31 - 1), 0)
    residual_m: float = _f(Float(0.0, 100.0, allow_nan=True), float("nan"))
    n_frames: int = _f(Int(1, 10000), 1)
    t_device_s: float = _f(_T, 0.0)
    calibration_id: int = _f(_SEQ, 0)

    def check(self) -> None:
        norm = float(np.linalg.norm(self.normal))
        if not 0.99 < norm < 1.01:
            raise FieldError(self.TYPE, "normal", f"length {norm:.4f}, expected a unit vector")


# ---- body frames -------------------------------------------------------------------------------


_JOINTS_KIND = Array(
    (N_JOINTS, 3),
    wire="<f4",
    accept=("<f4", "<f8"),
    values="finite_or_nan",
    lo=-100.0,
    hi=100.0,
)
_STATES_KIND = Array((N_JOINTS,), wire="|i1", accept=("|i1",), out="int8", values="int", lo=0, hi=2)
_OCCLUDED_KIND = Optional(
    Array((N_JOINTS,), wire="|u1", accept=("|u1",), out="bool", values="bool")
)
_CROSSINGS_KIND = Optional(Int(0, 10000))
_BODY_ID = Int(0)


@dataclass(frozen=True, eq=False)
class OtherBody:
    """One more body of a :class:`BodyFrameMessage` (its fields as the first body's)."""

    body_id: int
    joints_m: NDArray[np.float64]
    states: NDArray[np.int8]
    occluded: NDArray[np.bool_] | None = None
    n_crossings: int | None = None


_OTHER_BODIES = Records(
    fields=(
        ("body_id", _BODY_ID),
        ("joints_m", _JOINTS_KIND),
        ("states", _STATES_KIND),
        ("occluded", _OCCLUDED_KIND),
        ("n_crossings", _CROSSINGS_KIND),
    ),
    make=OtherBody,
    max_items=MAX_BODIES - 1,
    label="OtherBody",
)


@dataclass(frozen=True, eq=False)
class BodyFrameMessage(Message):
    """Sensor -> server: one body-tracker frame with the client's occlusion result.

    ``seq``: the sensor's frame counter; ``t_device_s``: capture on the device clock (s);
    ``t_host_s``: arrival at the client PC on its host clock (s); ``joints_m`` (25, 3): Kinect v2
    joint order, sensor frame, metres, NaN where not tracked (float32 on the wire);
    ``states`` (25,) int8: 0 not tracked, 1 inferred, 2 tracked; ``occluded`` (25,) bool and
    ``n_crossings``: the 2-D bone-crossing test (nil if not run); ``dropped``: body frames the
    client dropped so far (bounded queue, newest wins). Since 1.3: ``body_id``, the sensor's
    tracking id of this body (0 when the tracker reports none), and ``others``, the other
    bodies the tracker reported at this instant (at most 7: 8 bodies per frame), each with its
    own ``body_id`` (unique in the frame), joints, states and occlusion result; the body the
    tracker listed first is the frame's own. A 1.2 peer's body frame has neither: it is one
    body with id 0; a 1.3 sensor talking to a 1.2 server sends its first body only.
    """

    TYPE: ClassVar[str] = "body_frame"
    SENDERS: ClassVar[frozenset[str]] = _SENSOR

    seq: int = _f(_SEQ)
    t_device_s: float = _f(_T)
    t_host_s: float = _f(_T)
    joints_m: NDArray[np.float64] = _f(_JOINTS_KIND)
    states: NDArray[np.int8] = _f(_STATES_KIND)
    occluded: NDArray[np.bool_] | None = _f(_OCCLUDED_KIND, None)
    n_crossings: int | None = _f(_CROSSINGS_KIND, None)
    dropped: int = _f(_SEQ, 0)
    body_id: int = _f(_BODY_ID, 0)
    others: tuple[OtherBody, ...] = _f(_OTHER_BODIES, ())

    def check(self) -> None:
        ids = [self.body_id, *(b.body_id for b in self.others)]
        if len(set(ids)) != len(ids):
            raise FieldError(self.TYPE, "others", f"body ids {ids} repeat; each body has its own")


# ---- control peer ------------------------------------------------------------------------------


@dataclass(frozen=True)
class StatusRequest(Message):
    """Control -> server: send a Status (echoing ``request_id``)."""

    TYPE: ClassVar[str] = "status_request"
    SENDERS: ClassVar[frozenset[str]] = _CONTROL

    request_id: int = _f(_SEQ, 0)


@dataclass(frozen=True, eq=False)
class SensorInfo:
    """One sensor in a :class:`Status` (times in ms, NaN unknown; ``sensor2world`` (4, 4) or
    None if not calibrated; ``floor_error``: why the sensor's floor fit failed, or None;
    ``stale_frames``: body frames refused because their seq did not increase on their
    connection, since the server started (None: a server older than protocol 1.2);
    ``tracker``: the sensor's body-tracker status line from its heartbeats, or None)."""

    sensor_id: str
    connected: bool
    rtt_ms: float
    clock_offset_ms: float
    clock_offset_sd_ms: float
    fps: float
    latency_ms: float
    tracked_fraction: float
    sensor2world: NDArray[np.float64] | None = None
    floor_error: str | None = None
    stale_frames: int | None = None
    tracker: str | None = None


_NANF = Float(-1e12, 1e12, allow_nan=True)

_SENSOR_INFO = Records(
    fields=(
        ("sensor_id", _ID),
        ("connected", Bool()),
        ("rtt_ms", _NANF),
        ("clock_offset_ms", _NANF),
        ("clock_offset_sd_ms", _NANF),
        ("fps", _NANF),
        ("latency_ms", _NANF),
        ("tracked_fraction", Float(0.0, 1.0, allow_nan=True)),
        ("sensor2world", Optional(Array((4, 4), lo=-1e4, hi=1e4))),
        ("floor_error", Optional(_TEXT)),
        ("stale_frames", Optional(Int(0))),
        ("tracker", Optional(_TEXT)),
    ),
    make=SensorInfo,
    label="SensorInfo",
)


@dataclass(frozen=True, eq=False)
class Status(Message):
    """Server -> control: a snapshot (answer to StatusRequest, or unasked on a change); the same
    object is what the server publishes on its bus (``request_id`` 0) for the viewer and the
    recorder, so there is one status type.

    ``calibration_state``: "none", "collecting" (also while the collected phase is solved: the
    server's ``CalibrationState.SOLVING``), "calibrated" or "failed";
    ``calibration_grade``: "good", "doubtful", "failed" or nil; ``fused_fps`` Hz;
    ``frames_fused``: fused frames published so far; ``recording``: the store path or nil;
    ``calibration_message`` (since 1.2): what the operator has to know or do about the
    calibration (e.g. "calibrating from the person: walk through the volume"), or nil;
    ``subject`` and ``subject_rule`` (since 1.3): the person the server gives by default and
    how they were chosen ("first seen", "first seen, nearest the centre", "chosen" by
    ``--subject``, "operator"), nil before anyone is seen and from older servers.
    """

    TYPE: ClassVar[str] = "status"
    SENDERS: ClassVar[frozenset[str]] = _SERVER

    request_id: int = _f(_SEQ, 0)
    t_server_s: float = _f(_T, 0.0)
    sensors: tuple[SensorInfo, ...] = _f(_SENSOR_INFO, ())
    calibration_state: str = _f(Str(max_len=32), "none")
    calibration_grade: str | None = _f(Optional(Str(max_len=32)), None)
    fused_fps: float = _f(Float(0.0, 1e4, allow_nan=True), 0.0)
    frames_fused: int = _f(_SEQ, 0)
    method: str = _f(Str(max_len=32), "")
    recording: str | None = _f(Optional(Str(max_len=4096)), None)
    calibration_message: str | None = _f(Optional(_TEXT), None)
    subject: int | None = _f(Optional(_SEQ), None)
    subject_rule: str | None = _f(Optional(Str(max_len=64)), None)


@dataclass(frozen=True, eq=False)
class CalibrationResult(Message):
    """Server -> control: the outcome of a calibration.

    ``sensor_ids`` (S) with ``sensor2world`` (S, 4, 4) (metres), ``residual_m`` (S,) each
    sensor's RMS sighting residual (m, NaN if not registered) and ``n_sightings`` (S,);
    ``grade``: "good", "doubtful" or "failed"; ``message``: human-readable summary.
    """

    TYPE: ClassVar[str] = "calibration_result"
    SENDERS: ClassVar[frozenset[str]] = _SERVER

    calibration_id: int = _f(_SEQ, 0)
    ok: bool = _f(Bool(), False)
    grade: str = _f(Str(max_len=32), "failed")
    method: str = _f(Str(max_len=32), "")
    sensor_ids: tuple[str, ...] = _f(StrList(), ())
    sensor2world: NDArray[np.float64] = _f(
        Array((-1, 4, 4), lo=-1e4, hi=1e4), factory=lambda: np.zeros((0, 4, 4))
    )
    residual_m: NDArray[np.float64] = _f(
        Array((-1,), values="finite_or_nan", lo=0.0, hi=1e3), factory=lambda: np.zeros(0)
    )
    n_sightings: NDArray[np.int64] = _f(
        Array((-1,), wire="<i8", accept=("<i8",), out="int64", values="int", lo=0, hi=2**31),
        factory=lambda: np.zeros(0, dtype=np.int64),
    )
    message: str = _f(_TEXT, "")

    def check(self) -> None:
        n = len(self.sensor_ids)
        for name in ("sensor2world", "residual_m", "n_sightings"):
            if len(getattr(self, name)) != n:
                raise FieldError(
                    self.TYPE, name, f"{len(getattr(self, name))} rows for {n} sensor_ids"
                )


@dataclass(frozen=True)
class Shutdown(Message):
    """Control -> server: stop cleanly (Goodbye to every peer, recording marked complete)."""

    TYPE: ClassVar[str] = "shutdown"
    SENDERS: ClassVar[frozenset[str]] = _CONTROL

    reason: str = _f(_TEXT, "")


#: every message class by its wire type
MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.TYPE: cls
    for cls in (
        Hello,
        Challenge,
        AuthReply,
        Welcome,
        Error,
        Goodbye,
        Heartbeat,
        ClockProbe,
        ClockReply,
        CalibrationStart,
        CalibrationStop,
        WandSighting,
        FloorPlaneMessage,
        BodyFrameMessage,
        StatusRequest,
        Status,
        CalibrationResult,
        Shutdown,
    )
}


_FIELDS: dict[type, tuple[tuple[str, Kind], ...]] = {}


def message_fields(cls: type[Message]) -> tuple[tuple[str, Kind], ...]:
    """``(name, kind)`` of each wire field of a message class, in declaration order (computed
    once per class: every frame sent or received asks)."""
    out = _FIELDS.get(cls)
    if out is None:
        out = tuple((f.name, f.metadata["kind"]) for f in dataclasses.fields(cls))  # type: ignore[arg-type]
        _FIELDS[cls] = out
    return out
