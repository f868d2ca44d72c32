"""HMAC-SHA256 challenge-response: a peer proves it knows the shared token, which never
crosses the wire.

The server sends ``Challenge(nonce)`` with a fresh random nonce per connection; the peer replies
``AuthReply(mac)`` with ``mac = HMAC-SHA256(token, nonce + context)``, where the context binds
the reply to this protocol, the peer's role and its sensor id (so a reply recorded for one
sensor is worthless for another, and a fresh nonce makes it worthless a second time). The server
compares with :func:`hmac.compare_digest` (constant time).
"""

from __future__ import annotations

import hashlib
import hmac
import secrets

from kinefuse.protocol.errors import AuthError

#: bytes of random nonce the server sends
NONCE_BYTES = 32
#: the longest token accepted, characters
MAX_TOKEN_CHARS = 1024
_DOMAIN = b"kinefuse-auth-v1\x00"


def check_token(token: str) -> bytes:
    """The UTF-8 bytes of a user-given token; ValueError if empty or too long."""
    if not isinstance(token, str) or not token:
        raise ValueError("the token must be a non-empty string")
    if len(token) > MAX_TOKEN_CHARS:
        raise ValueError(f"the token has {len(token)} characters; at most {MAX_TOKEN_CHARS}")
    return token.encode("utf-8")


def new_nonce() -> bytes:
    """A fresh random nonce (``NONCE_BYTES`` from :mod:`secrets`)."""
    return secrets.token_bytes(NONCE_BYTES)


def auth_context(role: str, sensor_id: str) -> bytes:
    """What the MAC binds besides the nonce: protocol domain, role and sensor id."""
    return _DOMAIN + role.encode("utf-8") + b"\x00" + sensor_id.encode("utf-8")


def compute_mac(token: str, nonce: bytes, *, role: str, sensor_id: str) -> bytes:
    """``HMAC-SHA256(token, nonce + auth_context(role, sensor_id))``, 32 bytes."""
    key = check_token(token)
    return hmac.new(key, bytes(nonce) + auth_context(role, sensor_id), hashlib.sha256).digest()


def verify_mac(token: str, nonce: bytes, mac: bytes, *, role: str, sensor_id: str) -> None:
    """Raise :class:`AuthError` unless ``mac`` is the right reply (constant-time comparison)."""
    want = compute_mac(token, nonce, role=role, sensor_id=sensor_id)
    if not hmac.compare_digest(want, bytes(mac)):
        raise AuthError(
            "authentication failed: the reply does not match this server's token; "
            "start the client with the server's --token"
        )
