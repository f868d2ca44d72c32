"""Protocol 1.3: a body frame carries every body the tracker reported, bounded; a 1.2 peer's
body frame is one body with tracking id 0."""

from __future__ import annotations

import struct

import msgpack
import numpy as np
import pytest

from kinefuse.core.skeleton import N_JOINTS, standing_pose
from kinefuse.live.protocol import (
    MAX_BODIES,
    PROTOCOL_VERSION,
    BodyFrameMessage,
    Decoder,
    FieldError,
    MalformedMessage,
    OtherBody,
    encode,
)
from kinefuse.live.protocol.codec import HEADER, decode_body, to_wire


def _frame(n_others: int, *, ids: list[int] | None = None) -> BodyFrameMessage:
    pose = standing_pose() + np.array([0.0, 0.0, 2.5])
    ids = ids or list(range(11, 11 + n_others))
    states = np.full(N_JOINTS, 2, np.int8)
    states[20:] = 1
    others = tuple(
        OtherBody(
            i,
            pose + np.array([0.8 * (k + 1), 0.0, 0.0]),
            states,
            np.arange(N_JOINTS) % 3 == k % 3,
            k,
        )
        for k, i in enumerate(ids)
    )
    return BodyFrameMessage(
        seq=4, t_device_s=1.5, t_host_s=1.6, joints_m=pose, states=np.full(N_JOINTS, 2, np.int8),
        occluded=np.zeros(N_JOINTS, bool), n_crossings=0, body_id=5, others=others,
    )  # fmt: skip


def _decode(data: bytes) -> list:
    return Decoder().feed(data)


def test_every_body_crosses_the_wire() -> None:
    assert PROTOCOL_VERSION >= (1, 3)
    sent = _frame(MAX_BODIES - 1)
    (got,) = _decode(encode(sent))
    assert got.body_id == 5 and len(got.others) == MAX_BODIES - 1
    for a, b in zip(sent.others, got.others, strict=True):
        assert a.body_id == b.body_id and a.n_crossings == b.n_crossings
        np.testing.assert_allclose(a.joints_m, b.joints_m, atol=1e-6)  # float32 on the wire
        np.testing.assert_array_equal(a.states, b.states)
        np.testing.assert_array_equal(a.occluded, b.occluded)


def test_a_1_2_body_frame_is_one_body_with_id_0() -> None:
    wire = to_wire(_frame(2))
    del wire["body_id"], wire["others"]  # what a 1.2 sensor sends
    got = decode_body(msgpack.packb(wire, use_bin_type=True), peer_version=(1, 2))
    assert isinstance(got, BodyFrameMessage)
    assert got.body_id == 0 and got.others == ()
    # other bodies without their optional occlusion fields decode (nil flags, no count)
    wire = to_wire(_frame(1))
    del wire["others"][0]["occluded"], wire["others"][0]["n_crossings"]
    got = decode_body(msgpack.packb(wire, use_bin_type=True))
    assert got.others[0].occluded is None and got.others[0].n_crossings is None


def test_more_bodies_than_the_limit_are_refused() -> None:
    with pytest.raises(FieldError, match=f"{MAX_BODIES} items, at most {MAX_BODIES - 1}"):
        _decode(encode(_frame(MAX_BODIES)))
    with pytest.raises(FieldError, match=r"body ids \[5, 11, 5\] repeat"):
        _decode(encode(_frame(2, ids=[11, 5])))
    # a peer announcing a million bodies is refused from the list's header, nothing allocated
    wire = msgpack.packb({"type": "body_frame", "others": []}, use_bin_type=True)
    body = wire[:-1] + b"\xdd" + struct.pack(">I", 10**6) + b"\x80" * 16
    with pytest.raises(MalformedMessage, match="not valid msgpack"):
        _decode(HEADER.pack(len(body)) + body)
    # a body of the list with a bad field names its place
    wire = to_wire(_frame(2))
    wire["others"][1]["states"] = wire["others"][1]["joints_m"]
    with pytest.raises(FieldError, match=r"others\[1\]\.states"):
        decode_body(msgpack.packb(wire, use_bin_type=True))
