"""HMAC challenge-response: the right token passes, anything else fails, nothing leaks."""

from __future__ import annotations

import hashlib
import hmac

import pytest

from kinefuse.live.protocol import AuthError, AuthReply, Challenge, Decoder, encode
from kinefuse.live.protocol.auth import NONCE_BYTES, compute_mac, new_nonce, verify_mac


def test_the_right_token_verifies():
    nonce = new_nonce()
    mac = compute_mac("s3cret", nonce, role="sensor", sensor_id="k1")
    verify_mac("s3cret", nonce, mac, role="sensor", sensor_id="k1")
    # it is the documented construction: HMAC-SHA256(token, nonce + context)
    ctx = b"kinefuse-auth-v1\x00sensor\x00k1"
    assert mac == hmac.new(b"s3cret", nonce + ctx, hashlib.sha256).digest()


@pytest.mark.parametrize(
    ("token", "nonce_flip", "role", "sensor_id"),
    [
        ("wrong", False, "sensor", "k1"),  # another token
        ("s3cret", True, "sensor", "k1"),  # a replayed reply to an old nonce
        ("s3cret", False, "sensor", "k2"),  # a reply made for another sensor
        ("s3cret", False, "control", "k1"),  # or for another role
    ],
)
def test_anything_else_fails_with_a_clear_message(token, nonce_flip, role, sensor_id):
    nonce = new_nonce()
    mac = compute_mac("s3cret", nonce, role="sensor", sensor_id="k1")
    check = bytes([nonce[0] ^ 1]) + nonce[1:] if nonce_flip else nonce
    with pytest.raises(AuthError, match="--token") as e:
        verify_mac(token, check, mac, role=role, sensor_id=sensor_id)
    assert e.value.code == "auth"


def test_nonces_are_fresh_and_the_token_never_crosses_the_wire():
    nonces = {new_nonce() for _ in range(100)}
    assert len(nonces) == 100 and all(len(n) == NONCE_BYTES for n in nonces)
    token = "a-token-that-must-stay-home"
    nonce = new_nonce()
    wire = encode(Challenge(nonce)) + encode(
        AuthReply(compute_mac(token, nonce, role="sensor", sensor_id="k1"))
    )
    assert token.encode() not in wire
    assert [type(m) for m in Decoder().feed(wire)] == [Challenge, AuthReply]


def test_a_truncated_mac_fails():
    nonce = new_nonce()
    mac = compute_mac("t", nonce, role="sensor", sensor_id="k")
    with pytest.raises(AuthError):
        verify_mac("t", nonce, mac[:16], role="sensor", sensor_id="k")


@pytest.mark.parametrize("token", ["", "x" * 1025])
def test_bad_tokens_are_refused(token):
    with pytest.raises(ValueError, match="token"):
        compute_mac(token, new_nonce(), role="sensor", sensor_id="k")
