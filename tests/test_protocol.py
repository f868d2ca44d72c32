"""The wire codec: round trips, arbitrary chunking, and every way a hostile peer can be wrong."""

from __future__ import annotations

import contextlib
import itertools
import math
import struct

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.live.protocol import (
    MAX_FRAME_BYTES,
    MESSAGE_TYPES,
    AuthReply,
    BodyFrameMessage,
    CalibrationResult,
    CalibrationStart,
    CalibrationStop,
    Challenge,
    ClockProbe,
    ClockReply,
    Decoder,
    EmptyFrame,
    Error,
    FieldError,
    FloorPlaneMessage,
    FrameTooLarge,
    Goodbye,
    Heartbeat,
    Hello,
    MalformedMessage,
    Message,
    SensorInfo,
    Shutdown,
    Status,
    StatusRequest,
    TruncatedFrame,
    UnknownMessageType,
    VersionError,
    WandSighting,
    Welcome,
    WireError,
    encode,
)
from kinefuse.live.protocol.codec import to_wire
from kinefuse.live.protocol.fields import Array
from kinefuse.live.protocol.messages import message_fields


def _examples() -> list[Message]:
    rng = np.random.default_rng(7)
    joints = rng.normal(0, 1, (25, 3))
    joints[3] = np.nan
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 3.0]
    return [
        Hello(
            role="sensor",
            sensor_id="k1",
            serial="SN-001",
            intrinsics=Intrinsics(fx=366.1, cy=200.0),
            capabilities=("wand", "occlusion"),
            software="kinefuse 0.1.0",
        ),
        Hello(role="control"),
        Challenge(nonce=bytes(range(32))),
        AuthReply(mac=b"\x01" * 32),
        Welcome(session="live", t_server_s=12.5, calibrating=True, calibration_id=3),
        Error(code="duplicate_id", reason="sensor k1 is already connected"),
        Goodbye(reason="stopping"),
        Heartbeat(t_s=100.25, sent=17, dropped=2),
        ClockProbe(probe_id=9, t1=3.25),
        ClockReply(probe_id=9, t1=3.25, t2=1003.2, t3=1003.2001),
        CalibrationStart(calibration_id=1, method="paper", sensor_ids=("k0", "k1"), seconds=20.0),
        CalibrationStop(calibration_id=1, abort=True),
        WandSighting(
            seq=5,
            t_device_s=0.5,
            t_host_s=1000.5,
            centre_m=np.array([0.1, -0.2, 2.5]),
            score=0.9,
            n_points=120,
            residual_m=0.001,
            pixel_uv=np.array([250.5, 200.25]),
            stride=2,
        ),
        FloorPlaneMessage(
            normal=np.array([0.0, -0.96, 0.28]) / np.linalg.norm([0.0, -0.96, 0.28]),
            offset_m=1.2,
            n_inliers=900,
            residual_m=0.004,
            n_frames=15,
            t_device_s=3.5,
            calibration_id=1,
        ),
        BodyFrameMessage(
            seq=42,
            t_device_s=1.4,
            t_host_s=1001.4,
            joints_m=joints,
            states=rng.integers(0, 3, 25).astype(np.int8),
            occluded=rng.random(25) < 0.3,
            n_crossings=4,
            dropped=1,
        ),
        BodyFrameMessage(
            seq=43,
            t_device_s=1.5,
            t_host_s=1001.5,
            joints_m=np.zeros((25, 3)),
            states=np.zeros(25, np.int8),
        ),
        StatusRequest(request_id=4),
        Status(
            request_id=4,
            t_server_s=20.0,
            sensors=(
                SensorInfo("k0", True, 0.4, 1.5, 0.05, 30.0, 12.0, 0.9, pose),
                SensorInfo("k1", False, math.nan, math.nan, math.nan, 0.0, math.nan, 0.0),
            ),
            calibration_state="calibrated",
            calibration_grade="good",
            fused_fps=29.9,
            frames_fused=600,
            method="best-live",
            recording="/tmp/live.sqlite",
        ),
        CalibrationResult(
            calibration_id=1,
            ok=True,
            grade="good",
            method="full",
            sensor_ids=("k0", "k1"),
            sensor2world=np.stack([np.eye(4), pose]),
            residual_m=np.array([0.002, np.nan]),
            n_sightings=np.array([300, 0]),
            message="2 sensors",
        ),
        Shutdown(reason="demo done"),
    ]


EXAMPLES = _examples()


def _ex(cls: type) -> Message:
    """The first example of a message class."""
    return next(m for m in EXAMPLES if type(m) is cls)


def _same(a: object, b: object) -> bool:
    """Field-by-field equality (arrays: equal with NaN == NaN, float32 rounding allowed)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        b = np.asarray(b)
        if a.shape != b.shape:
            return False
        if a.dtype.kind == "f":  # joints cross the wire as float32: 1e-6 relative
            return bool(np.allclose(a, b, rtol=1e-6, atol=1e-7, equal_nan=True))
        return bool(np.array_equal(a, b))
    if isinstance(a, float):
        return (math.isnan(a) and math.isnan(b)) or a == b  # type: ignore[arg-type]
    if isinstance(a, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))  # type: ignore[arg-type]
    if isinstance(a, Message | SensorInfo):
        return all(_same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    return a == b


def _frame(raw: object) -> bytes:
    body = msgpack.packb(raw, use_bin_type=True)
    return struct.pack(">I", len(body)) + body


def _body_raw(**change: object) -> dict:
    raw = to_wire(_ex(BodyFrameMessage))
    raw.update(change)
    return raw


def test_every_message_type_has_an_example_and_round_trips():
    assert {type(m) for m in EXAMPLES} == set(MESSAGE_TYPES.values())
    dec = Decoder()
    for msg in EXAMPLES:
        (back,) = dec.feed(encode(msg))
        assert _same(msg, back), (msg, back)
    assert dec.buffered == 0


def test_decoded_arrays_have_the_python_dtypes_and_are_read_only():
    (b,) = Decoder().feed(encode(_ex(BodyFrameMessage)))
    assert b.joints_m.dtype == np.float64 and b.joints_m.shape == (25, 3)
    assert b.states.dtype == np.int8 and b.occluded.dtype == np.bool_
    assert np.isnan(b.joints_m[3]).all()
    with pytest.raises(ValueError):
        b.joints_m[0, 0] = 1.0


def test_a_body_frame_is_compact():
    # 25x3 float32 + 25 + 25 bytes of arrays and the scalars: well under 600 bytes
    assert len(encode(_ex(BodyFrameMessage))) < 600


STREAM = b"".join(encode(m) for m in EXAMPLES)


@settings(max_examples=150, deadline=None)
@given(st.lists(st.integers(0, len(STREAM)), max_size=40))
def test_arbitrary_chunk_splits_give_the_same_messages(cuts):
    bounds = [0, *sorted(cuts), len(STREAM)]
    dec = Decoder()
    out: list[Message] = []
    for a, b in itertools.pairwise(bounds):
        out += dec.feed(STREAM[a:b])
    assert len(out) == len(EXAMPLES)
    assert all(_same(a, b) for a, b in zip(EXAMPLES, out, strict=True))
    dec.close()  # nothing left over


def test_one_byte_at_a_time():
    dec = Decoder()
    out = [m for i in range(len(STREAM)) for m in dec.feed(STREAM[i : i + 1])]
    assert [type(m) for m in out] == [type(m) for m in EXAMPLES]


def test_oversized_frame_is_refused_from_its_prefix_alone():
    dec = Decoder()
    with pytest.raises(FrameTooLarge) as e:
        dec.feed(struct.pack(">I", MAX_FRAME_BYTES + 1))
    assert e.value.code == "oversize" and str(MAX_FRAME_BYTES) in str(e.value)
    assert dec.buffered == 0
    with pytest.raises(FrameTooLarge):  # the stream is dead: no resynchronization
        dec.feed(encode(Goodbye()))


def test_a_frame_of_exactly_the_limit_is_fine_and_encode_refuses_larger():
    msg = BodyFrameMessage(
        seq=1, t_device_s=0, t_host_s=0, joints_m=np.zeros((25, 3)), states=np.zeros(25, np.int8)
    )
    n = len(encode(msg)) - 4
    assert len(Decoder(max_frame_bytes=n).feed(encode(msg))) == 1
    with pytest.raises(FrameTooLarge):
        Decoder(max_frame_bytes=n - 1).feed(encode(msg))
    with pytest.raises(FrameTooLarge):
        encode(msg, max_frame_bytes=n - 1)


def test_empty_frame():
    with pytest.raises(EmptyFrame, match="length 0"):
        Decoder().feed(b"\x00\x00\x00\x00")


def test_truncated_stream():
    data = encode(_ex(BodyFrameMessage))
    dec = Decoder()
    assert dec.feed(data[:-3]) == []
    with pytest.raises(TruncatedFrame, match="unfinished frame") as e:
        dec.close()
    assert e.value.code == "truncated"


@pytest.mark.parametrize(
    ("body", "match"),
    [
        (b"\xc1", "not valid msgpack"),  # 0xc1 is never used
        (msgpack.packb([1, 2, 3]), "msgpack map"),
        (msgpack.packb({"seq": 1}), "no string 'type'"),
        (msgpack.packb({"type": 5}), "no string 'type'"),
        (msgpack.packb({"type": "goodbye"}) + b"\x00", "not valid msgpack"),  # trailing bytes
        (msgpack.packb({"type": "goodbye", "x": msgpack.ExtType(3, b"ab")}), "extension"),
        (msgpack.packb({1: "goodbye"}), "not valid msgpack"),  # non-string key
    ],
)
def test_garbage_bodies_are_malformed_and_the_stream_goes_on(body, match):
    dec = Decoder()
    with pytest.raises(MalformedMessage, match=match) as e:
        dec.feed(struct.pack(">I", len(body)) + body + encode(Goodbye("after")))
    assert e.value.code == "malformed"
    assert dec.feed(b"") == [Goodbye("after")]


def test_messages_before_a_bad_frame_are_kept_on_the_exception():
    dec = Decoder()
    with pytest.raises(MalformedMessage) as e:
        dec.feed(encode(Heartbeat()) + _frame([0]))
    assert e.value.decoded == [Heartbeat()]


def test_nesting_bomb_is_refused_without_crashing():
    body = b"\x91" * 200_000 + b"\xc0"  # 200k nested one-element lists
    with pytest.raises(MalformedMessage):
        Decoder().feed(struct.pack(">I", len(body)) + body)


def test_unknown_type_is_an_error_unless_the_peer_is_a_newer_minor_version():
    frame = _frame({"type": "telemetry", "x": 1})
    with pytest.raises(UnknownMessageType, match="telemetry") as e:
        Decoder().feed(frame)
    assert e.value.code == "unknown_type"
    dec = Decoder()
    (hello,) = dec.feed(
        _frame({**to_wire(Hello(role="control")), "protocol_version": [1, 4], "new": 1})
    )
    assert hello.protocol_version == (1, 4) and dec.peer_version == (1, 4)
    assert dec.feed(frame + frame + encode(Goodbye())) == [Goodbye()]
    assert dec.ignored == {"telemetry": 2}


def test_another_major_version_is_refused_before_its_fields_are_read():
    with pytest.raises(VersionError, match=r"2\.0") as e:
        Decoder().feed(_frame({"type": "hello", "protocol_version": [2, 0], "role": "robot"}))
    assert e.value.code == "version"
    with pytest.raises(VersionError):
        Decoder().feed(_frame({**to_wire(Welcome()), "protocol_version": [0, 9]}))


_J = to_wire(_ex(BodyFrameMessage))["joints_m"]


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"seq": "42"}, "body_frame.seq: expected an integer, got str"),
        ({"seq": True}, "body_frame.seq: expected an integer, got bool"),
        ({"seq": -1}, "body_frame.seq: -1 is outside"),
        ({"seq": 2**64 - 1}, "body_frame.seq: .* is outside"),
        ({"t_host_s": float("nan")}, "body_frame.t_host_s: NaN is not allowed"),
        ({"t_device_s": float("inf")}, "body_frame.t_device_s: infinity"),
        ({"t_device_s": "now"}, "expected a number, got str"),
        ({"joints_m": [[0.0] * 3] * 25}, "joints_m: expected an array map"),
        ({"joints_m": {**_J, "shape": [24, 3]}}, r"joints_m: shape \(24, 3\), expected \(25, 3\)"),
        ({"joints_m": {**_J, "shape": [25]}}, "joints_m: shape .* is not 2 integers"),
        ({"joints_m": {**_J, "dtype": "<i4"}}, "joints_m: dtype '<i4' not accepted"),
        ({"joints_m": {**_J, "dtype": "O"}}, "not accepted"),
        ({"joints_m": {**_J, "data": _J["data"][:-4]}}, "joints_m: 296 data bytes"),
        (
            {"joints_m": {**_J, "data": np.full((25, 3), np.inf, "<f4").tobytes()}},
            "joints_m: holds infinity",
        ),
        (
            {"joints_m": {**_J, "data": np.full((25, 3), 1e6, "<f4").tobytes()}},
            r"joints_m: values .* leave \[-100, 100\]",
        ),
        ({"states": {"dtype": "|i1", "shape": [25], "data": b"\x03" * 25}}, "states: values 3"),
        ({"occluded": {"dtype": "|u1", "shape": [25], "data": b"\x02" * 25}}, "other than 0 and 1"),
        ({"n_crossings": -2}, "n_crossings: -2 is outside"),
        ({"n_crossings": 1.5}, "n_crossings: expected an integer, got float"),
    ],
)
def test_wrong_fields_name_the_field_and_the_reason(change, match):
    with pytest.raises(FieldError, match=match) as e:
        Decoder().feed(_frame(_body_raw(**change)))
    assert e.value.code == "field" and e.value.message_type == "body_frame"


def test_a_huge_announced_array_is_refused_without_allocating():
    raw = to_wire(_ex(CalibrationResult))
    raw["sensor2world"] = {"dtype": "<f8", "shape": [10**9, 4, 4], "data": b""}
    with pytest.raises(FieldError, match=r"shape \(1000000000, 4, 4\)"):
        Decoder().feed(_frame(raw))


@pytest.mark.parametrize(
    ("raw", "match"),
    [
        ({"type": "clock_probe", "probe_id": 1}, "clock_probe.t1: missing"),
        ({"type": "hello", "role": "sensor", "sensor_id": "k 1"}, "characters outside"),
        ({"type": "hello", "role": "sensor", "sensor_id": "k" * 65}, "65 characters"),
        ({"type": "hello", "role": "sensor", "sensor_id": "k1"}, "must send intrinsics"),
        ({"type": "hello", "role": "sensor", "intrinsics": Intrinsics().to_dict()}, "name its"),
        ({"type": "hello", "role": "admin"}, "'admin' is not one of sensor, control"),
        (
            {
                "type": "hello",
                "role": "sensor",
                "sensor_id": "k",
                "intrinsics": {**Intrinsics().to_dict(), "fx": -1.0},
            },
            r"hello.intrinsics.fx: -1.0 is outside",
        ),
        (
            {
                "type": "hello",
                "role": "sensor",
                "sensor_id": "k",
                "intrinsics": {**Intrinsics().to_dict(), "min_range_m": 9.0},
            },
            "hello.intrinsics: range must satisfy",
        ),
        ({"type": "hello", "role": "control", "capabilities": ["x"] * 65}, "65 items"),
        ({"type": "challenge", "nonce": b"short"}, "challenge.nonce: 5 bytes"),
        ({"type": "auth_reply", "mac": "00" * 32}, "expected bytes"),
        ({"type": "error", "code": "", "reason": "x"}, "error.code: must not be empty"),
        ({"type": "goodbye", "reason": "x" * 2000}, "goodbye.reason: 2000 characters"),
        ({"type": "calibration_stop", "abort": 1}, "calibration_stop.abort: expected true or"),
        ({"type": "clock_reply", "probe_id": 1, "t1": 0.0, "t2": 5.0, "t3": 4.0}, "t3: replied"),
        (
            {**to_wire(_ex(CalibrationResult)), "sensor_ids": ["k0"]},
            "calibration_result.sensor2world: 2 rows for 1 sensor_ids",
        ),
        (
            {
                **to_wire(_ex(FloorPlaneMessage)),
                "normal": to_wire(Welcome())["capabilities"],
            },
            "expected an",
        ),
        (
            {**to_wire(_ex(FloorPlaneMessage)), "normal": Array((3,)).encode([0.5, 0.0, 0.0])},
            "floor_plane.normal: length 0.5000",
        ),
        (
            {**to_wire(_ex(WandSighting)), "score": 1.5},
            r"wand_sighting.score: 1.5 is outside",
        ),
        ({**to_wire(_ex(Status)), "sensors": [{"sensor_id": "k"}]}, r"sensors\[0\].connected"),
    ],
)
def test_field_rules_of_other_messages(raw, match):
    with pytest.raises(FieldError, match=match):
        Decoder().feed(_frame(raw))


def test_unknown_fields_are_ignored():
    (g,) = Decoder().feed(_frame({"type": "goodbye", "reason": "r", "added_in_1_1": [1, 2]}))
    assert g == Goodbye("r")


def test_every_field_has_a_kind_with_a_doc():
    for cls in MESSAGE_TYPES.values():
        for name, kind in message_fields(cls):
            assert kind.doc, (cls.TYPE, name)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_random_bytes_raise_only_protocol_errors(data):
    dec = Decoder(max_frame_bytes=1000)
    with contextlib.suppress(WireError):
        dec.feed(data)
        dec.close()


_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**63), 2**64 - 1),
    st.floats(),
    st.text(max_size=8),
    st.binary(max_size=40),
)
_values = st.recursive(
    _scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)
    ),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from(sorted(MESSAGE_TYPES)),
    st.dictionaries(
        st.sampled_from(sorted({n for c in MESSAGE_TYPES.values() for n, _ in message_fields(c)})),
        _values,
        max_size=6,
    ),
)
def test_random_fields_of_known_types_raise_only_protocol_errors(type_name, fields):
    base = next(to_wire(m) for m in EXAMPLES if type_name == m.TYPE)
    with contextlib.suppress(WireError):
        Decoder().feed(_frame({**base, **fields, "type": type_name}))


def test_error_codes_are_distinct_per_kind():
    assert FrameTooLarge(2, 1).code == "oversize"
    assert {UnknownMessageType("x").code, FieldError("a", "b", "c").code, VersionError().code} == {
        "unknown_type",
        "field",
        "version",
    }


_t = st.floats(-1e9, 1e9, allow_nan=False)


@settings(max_examples=100, deadline=None)
@given(
    seq=st.integers(0, 2**63 - 1),
    t_dev=_t,
    t_host=_t,
    seed=st.integers(0, 2**32 - 1),
    crossings=st.one_of(st.none(), st.integers(0, 10000)),
)
def test_random_body_frames_round_trip(seq, t_dev, t_host, seed, crossings):
    rng = np.random.default_rng(seed)
    joints = rng.uniform(-99.0, 99.0, (25, 3))
    joints[rng.random(25) < 0.3] = np.nan
    msg = BodyFrameMessage(
        seq=seq,
        t_device_s=t_dev,
        t_host_s=t_host,
        joints_m=joints,
        states=rng.integers(0, 3, 25).astype(np.int8),
        occluded=None if crossings is None else rng.random(25) < 0.5,
        n_crossings=crossings,
    )
    (back,) = Decoder().feed(encode(msg))
    assert back.seq == seq and back.t_device_s == t_dev and back.t_host_s == t_host  # exact
    np.testing.assert_array_equal(back.joints_m, joints.astype(np.float32), strict=False)
    assert (back.states == msg.states).all() and back.n_crossings == crossings
    assert (back.occluded is None) == (msg.occluded is None)
