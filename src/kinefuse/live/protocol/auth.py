"""HMAC-SHA256 challenge-response: a peer proves it knows the shared token, which never
crosses the wire.

The server sends ``Challenge(nonce)`` with a fresh random nonce per connection; the peer replies
``AuthReply(mac)`` with ``mac = HMAC-SHA256(token, nonce + context)``, where the context binds
the reply to this protocol, the peer's role and its sensor id (so a reply recorded for one
sensor is worthless for another, and a fresh nonce makes it worthless a second time). The server
compares with :func:`hmac.compare_digest` (constant time).

Since protocol 1.1 the authentication is mutual: a peer that has a token sends its own fresh
``client_nonce`` in its Hello, and the server's Challenge carries ``server_mac`` =
:func:`compute_server_mac`, keyed with a key derived from the token for this direction only
(:func:`server_key`), over both nonces, the role and the sensor id. The peer checks it
(:func:`verify_server_mac`) before it answers or sends anything else, so a server that does not
know the token (an impostor) gets no data and no MAC. The separate key keeps the two directions
apart: a peer's MAC is never a valid server proof, nor the other way round.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import secrets
import string

from kinefuse.live.protocol.wire_errors import AuthError

#: bytes of random nonce the server sends
NONCE_BYTES = 32
#: the longest token accepted, characters
MAX_TOKEN_CHARS = 1024
_DOMAIN = b"kinefuse-auth-v1\x00"
#: the label the server-to-peer key is derived with (protocol 1.1)
SERVER_PROOF_LABEL = b"kinefuse-server-proof-v1"


def check_token(token: str) -> bytes:
    """The UTF-8 bytes of a user-given token; ValueError if empty or too long."""
    if not isinstance(token, str) or not token:
        raise ValueError("the token must be a non-empty string")
    if len(token) > MAX_TOKEN_CHARS:
        raise ValueError(f"the token has {len(token)} characters; at most {MAX_TOKEN_CHARS}")
    return token.encode("utf-8")


#: the least estimated entropy of a token a server takes without ``--allow-weak-token``, bits
MIN_TOKEN_BITS = 128
#: bytes of randomness in a token ``kinefuse token new`` writes (64 hex characters)
NEW_TOKEN_BYTES = 32


def new_token() -> str:
    """A fresh random token: ``NEW_TOKEN_BYTES`` (256 bits) from :mod:`secrets`, as hex."""
    return secrets.token_hex(NEW_TOKEN_BYTES)


def token_bits(token: str) -> float:
    """An estimate of a token's entropy, bits: ``n * log2(alphabet)``, where the
    alphabet is the character classes it uses (lower case 26, upper case 26, digits 10, any
    other 33) and ``n`` its length, counted at most three times per distinct character (so
    ``aaaa...`` or a word repeated does not pass for random). A random 64-hex-digit token
    scores about 250, ``kinect2024`` about 50: it cannot see that a long phrase of words is
    guessable, so it only refuses what is plainly too short or too repetitive."""
    if not token:
        return 0.0
    pool = 0
    for chars, size in (
        (string.ascii_lowercase, 26),
        (string.ascii_uppercase, 26),
        (string.digits, 10),
    ):
        if any(c in chars for c in token):
            pool += size
    if any(not (c.isascii() and c.isalnum()) for c in token):
        pool += 33
    n = min(len(token), 3 * len(set(token)))
    return n * math.log2(max(pool, 2))


def check_token_strength(token: str, *, allow_weak: bool = False) -> None:
    """Raise ``ValueError`` for a token under ``MIN_TOKEN_BITS`` of estimated entropy (unless
    ``allow_weak``): one recorded handshake lets anyone test guesses offline, as fast as they
    can compute HMACs, so only a token too big to guess keeps the sensors' port closed."""
    bits = token_bits(token)
    if bits < MIN_TOKEN_BITS and not allow_weak:
        raise ValueError(
            f"the token is too weak to keep the port closed (about {bits:.0f} bits of "
            f"entropy, at least {MIN_TOKEN_BITS} needed: one recorded handshake lets anyone "
            "test guesses offline); make one with `kinefuse token new FILE` and give it with "
            "--token-file FILE, or accept the risk with --allow-weak-token"
        )


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
            "start the client with the server's token (--token-file FILE)"
        )


def server_key(token: str) -> bytes:
    """The key of the server's proof: ``HMAC-SHA256(token, "kinefuse-server-proof-v1")``.

    A peer's MAC is keyed with the token itself and its message always holds
    ``kinefuse-auth-v1``, so no peer MAC can stand in for this key or for a server proof.
    """
    return hmac.new(check_token(token), SERVER_PROOF_LABEL, hashlib.sha256).digest()


def server_proof_message(
    client_nonce: bytes, server_nonce: bytes, *, role: str, sensor_id: str
) -> bytes:
    """What the server's proof covers: ``len(client_nonce) || client_nonce ||
    len(server_nonce) || server_nonce || role || 0x00 || sensor_id`` (lengths one byte each)."""
    cn, sn = bytes(client_nonce), bytes(server_nonce)
    if not (0 < len(cn) < 256 and 0 < len(sn) < 256):
        raise ValueError("nonces must have 1 to 255 bytes")
    return (
        bytes([len(cn)]) + cn + bytes([len(sn)]) + sn
        + role.encode("utf-8") + b"\x00" + sensor_id.encode("utf-8")
    )  # fmt: skip


def compute_server_mac(
    token: str, client_nonce: bytes, server_nonce: bytes, *, role: str, sensor_id: str
) -> bytes:
    """The server's proof that it knows the token (32 bytes): ``HMAC-SHA256(server_key(token),
    server_proof_message(client_nonce, server_nonce, role, sensor_id))``."""
    msg = server_proof_message(client_nonce, server_nonce, role=role, sensor_id=sensor_id)
    return hmac.new(server_key(token), msg, hashlib.sha256).digest()


def verify_server_mac(
    token: str,
    client_nonce: bytes,
    server_nonce: bytes,
    mac: bytes | None,
    *,
    role: str,
    sensor_id: str,
) -> None:
    """Raise :class:`AuthError` unless ``mac`` proves the server knows ``token`` for this very
    handshake (our fresh ``client_nonce``); a missing proof (nil) is refused too."""
    if mac is None:
        raise AuthError(
            "the server did not prove that it knows the token (its challenge has no server_mac): "
            "it is not the kinefuse server you meant, or one older than protocol 1.1 (upgrade "
            "it); nothing was sent to it"
        )
    want = compute_server_mac(token, client_nonce, server_nonce, role=role, sensor_id=sensor_id)
    if not hmac.compare_digest(want, bytes(mac)):
        raise AuthError(
            "the server could not prove that it knows the token (wrong server_mac): a server "
            "with another token, or an impostor; nothing was sent to it"
        )


def no_challenge_error() -> AuthError:
    """The refusal of a peer with a token whose server offers no authentication at all."""
    return AuthError(
        "the server offers no authentication (it welcomed us without a challenge) but this "
        "peer has a token: it is not the kinefuse server you meant, or one started without "
        "the token; nothing was sent to it"
    )
