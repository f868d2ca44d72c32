"""The sans-I/O handshake state machine alone (live/protocol/handshake.py): a server side and a peer
side talk to each other through the real codec (bytes in between), every legal path ends
welcomed, and every message the table does not allow is refused with its message."""

from __future__ import annotations

import itertools

import pytest

from kinefuse.core.camera import Intrinsics
from kinefuse.live.protocol import (
    AuthReply,
    Challenge,
    Decoder,
    Error,
    Goodbye,
    Heartbeat,
    Hello,
    Message,
    Welcome,
    encode,
)
from kinefuse.live.protocol.auth import compute_mac, compute_server_mac
from kinefuse.live.protocol.handshake import TRANSITIONS, Handshake, State, TokenRequired
from kinefuse.live.protocol.wire_errors import AuthError, OutOfOrder, RemoteError, VersionError

TOKEN = "a-shared-token-for-the-handshake-tests-0123456789abcdef"
HELLO = Hello(role="sensor", sensor_id="k0", intrinsics=Intrinsics())
WELCOME = Welcome(session="s", heartbeat_s=0.5)


def wire(msg: Message) -> Message:
    """``msg`` as the other side decodes it from its bytes."""
    (got,) = Decoder().feed(encode(msg))
    return got


def talk(server_token: str | None, peer_token: str | None) -> tuple[Handshake, Handshake]:
    """A whole handshake between two machines; returns (server, peer)."""
    server, peer = Handshake("server", server_token), Handshake("peer", peer_token)
    answer = server.receive(wire(peer.send(HELLO)))
    if answer is not None:
        reply = peer.receive(wire(answer))
        assert reply is not None
        assert server.receive(wire(reply)) is None
    assert peer.receive(wire(server.send(WELCOME))) is None
    return server, peer


@pytest.mark.parametrize(("server_token", "peer_token"), [(TOKEN, TOKEN), (None, None)])
def test_both_sides_end_welcomed(server_token: str | None, peer_token: str | None) -> None:
    server, peer = talk(server_token, peer_token)
    assert server.state is State.DONE and peer.state is State.DONE
    assert server.hello is not None and server.hello.sensor_id == "k0"
    assert peer.welcome is not None and peer.welcome.heartbeat_s == 0.5
    assert (peer.client_nonce is not None) == (peer_token is not None)
    assert server.hello.client_nonce == peer.client_nonce
    assert peer.sends_every_body and server.sends_every_body


def test_the_proofs_are_the_auth_modules() -> None:
    nonces = iter([b"s" * 32, b"c" * 32])
    server = Handshake("server", TOKEN, new_nonce=lambda: next(nonces))
    peer = Handshake("peer", TOKEN, new_nonce=lambda: next(nonces))
    sent = wire(peer.send(HELLO))
    assert isinstance(sent, Hello) and sent.client_nonce is not None
    challenge = server.receive(sent)
    assert isinstance(challenge, Challenge)
    want = compute_server_mac(
        TOKEN, sent.client_nonce, challenge.nonce, role="sensor", sensor_id="k0"
    )
    assert challenge.server_mac == want
    reply = peer.receive(wire(challenge))
    assert isinstance(reply, AuthReply)
    assert reply.mac == compute_mac(TOKEN, challenge.nonce, role="sensor", sensor_id="k0")


def test_a_wrong_token_is_refused_by_each_side() -> None:
    server, peer = Handshake("server", TOKEN), Handshake("peer", TOKEN + "x")
    challenge = server.receive(wire(peer.send(HELLO)))
    with pytest.raises(AuthError, match="could not prove") as e:
        peer.receive(wire(challenge))  # type: ignore[arg-type]
    assert e.value.reply == Error("auth", "the server did not prove that it knows the token")
    assert peer.state is State.CLOSED
    # a peer without a client nonce (1.0) gets no proof, and its wrong MAC is refused
    server = Handshake("server", TOKEN)
    challenge = server.receive(wire(HELLO))
    assert isinstance(challenge, Challenge) and challenge.server_mac is None
    with pytest.raises(AuthError, match="authentication failed"):
        server.receive(wire(AuthReply(mac=bytes(32))))
    assert server.state is State.CHALLENGED


def test_a_peer_without_a_token_that_is_challenged_says_goodbye() -> None:
    server, peer = Handshake("server", TOKEN), Handshake("peer", None)
    challenge = server.receive(wire(peer.send(HELLO)))
    with pytest.raises(TokenRequired, match="requires a token") as e:
        peer.receive(wire(challenge))  # type: ignore[arg-type]
    assert e.value.reply == Goodbye("no token")


def test_a_peer_with_a_token_refuses_a_welcome_without_challenge() -> None:
    server, peer = Handshake("server", None), Handshake("peer", TOKEN)
    assert server.receive(wire(peer.send(HELLO))) is None
    with pytest.raises(AuthError, match="offers no authentication") as e:
        peer.receive(wire(server.send(WELCOME)))
    assert e.value.reply == Error("auth", "this sensor has a token and the server asked for none")
    control = Handshake("peer", TOKEN)
    control.send(Hello(role="control"))
    with pytest.raises(AuthError) as e:
        control.receive(WELCOME)
    assert e.value.reply.reason == "this peer has a token and the server asked for none"


def test_another_major_version_is_refused_both_ways() -> None:
    with pytest.raises(VersionError, match="major versions must match"):
        Handshake("server").receive(Hello(role="control", protocol_version=(2, 0)))
    peer = Handshake("peer")
    peer.send(HELLO)
    with pytest.raises(VersionError, match="major versions must match"):
        peer.receive(Welcome(protocol_version=(2, 0)))


@pytest.mark.parametrize(("minor", "every"), [(2, False), (3, True), (9, True)])
def test_the_bodies_rule_follows_the_other_sides_version(minor: int, every: bool) -> None:
    peer = Handshake("peer")
    peer.send(HELLO)
    peer.receive(Welcome(protocol_version=(1, minor)))
    assert peer.peer_version == (1, minor) and peer.sends_every_body is every
    server = Handshake("server")
    server.receive(Hello(role="control", protocol_version=(1, minor)))
    assert server.sends_every_body is every


def test_the_server_error_and_goodbye_end_the_peers_handshake() -> None:
    peer = Handshake("peer")
    peer.send(HELLO)
    with pytest.raises(RemoteError, match="duplicate") as e:
        peer.receive(Error("duplicate_id", "sensor k0 is already connected"))
    assert e.value.code == "duplicate_id" and peer.state is State.CLOSED
    peer = Handshake("peer")
    peer.send(HELLO)
    assert peer.receive(Goodbye("shutting down")) is None
    assert peer.state is State.CLOSED


# -- every transition the table does not allow -------------------------------------------------

SAMPLES: dict[str, Message] = {
    "hello": HELLO,
    "challenge": Challenge(nonce=bytes(32)),
    "auth_reply": AuthReply(mac=bytes(32)),
    "welcome": WELCOME,
    "heartbeat": Heartbeat(),
}
EXPECTED = {
    State.IDLE: "the first message must be hello",
    State.HELLO: "expected challenge or welcome",
    State.CHALLENGED: "expected auth_reply after the challenge",
    State.PROVED: "expected welcome",
    State.DONE: "the handshake is over",
    State.CLOSED: "the handshake was closed",
}


def at(side: str, state: State) -> Handshake:
    """A machine of ``side`` brought to ``state`` by legal messages (both sides have tokens,
    except a server in HELLO: only a server without one waits there to welcome)."""
    if side == "server" and state is State.HELLO:
        server = Handshake("server", None)
        server.receive(HELLO)
        return server
    hs = Handshake(side, TOKEN)  # type: ignore[arg-type]
    other = Handshake("peer" if side == "server" else "server", TOKEN)
    server, peer = (hs, other) if side == "server" else (other, hs)
    if state is State.CLOSED:
        hs.send(Goodbye("bye"))
        return hs
    if state is State.IDLE:
        return hs
    challenge = server.receive(peer.send(HELLO))
    if state is State.HELLO:
        return hs
    assert challenge is not None
    reply = peer.receive(challenge)
    if state is State.CHALLENGED:
        return hs
    assert reply is not None
    server.receive(reply)
    if state is State.PROVED:
        return hs
    peer.receive(server.send(WELCOME))
    return hs


#: where each side can stand: a peer answers a challenge as it takes it (AuthReply out), so
#: it never waits in CHALLENGED
STANDS = [(side, state) for side in ("server", "peer") for state in State]
STANDS.remove(("peer", State.CHALLENGED))

ILLEGAL = [
    (side, state, name)
    for (side, state), name in itertools.product(STANDS, SAMPLES)
    if TRANSITIONS.get((state, name), ("", None))[0] != ("peer" if side == "server" else "server")
]


@pytest.mark.parametrize(("side", "state", "name"), ILLEGAL)
def test_every_illegal_received_message_is_refused(side: str, state: State, name: str) -> None:
    hs = at(side, state)
    assert hs.state is state
    with pytest.raises(OutOfOrder, match=f"^{EXPECTED[state]}, got {name}$") as e:
        hs.receive(SAMPLES[name])
    if side == "peer":  # the peer tells the server why it closes
        assert e.value.reply == Error("order", f"{EXPECTED[state]}, got {name}")
    assert hs.state is state  # nothing moved


@pytest.mark.parametrize(
    ("side", "state", "name"),
    [
        (side, state, name)
        for (side, state), name in itertools.product(STANDS, SAMPLES)
        if TRANSITIONS.get((state, name), ("", None))[0] != side
    ],
)
def test_every_illegal_sent_message_is_refused(side: str, state: State, name: str) -> None:
    hs = at(side, state)
    with pytest.raises(OutOfOrder, match=f"^this {side} may not send {name} now"):
        hs.send(SAMPLES[name])
    assert hs.state is state


def test_the_table_is_one_conversation() -> None:
    # each state but the ends is left by exactly one side's messages, and DONE is reachable
    senders: dict[State, set[str]] = {}
    for (state, _), (sender, _) in TRANSITIONS.items():
        senders.setdefault(state, set()).add(sender)
    assert all(len(s) == 1 for s in senders.values())
    assert State.DONE not in senders and State.CLOSED not in senders
    assert {nxt for _, nxt in TRANSITIONS.values()} >= {State.DONE}
    with pytest.raises(ValueError, match="side must be"):
        Handshake("client")  # type: ignore[arg-type]
