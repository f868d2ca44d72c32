"""The handshake as one sans-I/O state machine that both ends of the wire drive.

One conversation, one table (:data:`TRANSITIONS`), as h11 keeps one for HTTP: the server and the
peer (a sensor or a control peer) each hold a :class:`Handshake` of their own ``side`` and feed
it every handshake message, the ones they send (:meth:`Handshake.send`) and the ones they
receive (:meth:`Handshake.receive`). It moves through::

    IDLE --hello(peer)--> HELLO --challenge(server)--> CHALLENGED --auth_reply(peer)--> PROVED
                            |                                                            |
                            +------------------------welcome(server)---------------------+--> DONE

(``welcome`` straight from ``HELLO`` only when the server has no token; a peer with a token
refuses it.) A message the table does not allow in the current state, from that sender, is
:class:`~kinefuse.live.protocol.wire_errors.OutOfOrder` (error ``order``) naming what was expected.
The machine also owns what depends on the state: the peer's nonce and the server's proof
(:mod:`kinefuse.live.protocol.auth`), the major-version check of the Hello and the Welcome, and the
version rule after it (:attr:`Handshake.sends_every_body`: 1.3 bodies only to a 1.3 peer).

On the peer's side an ``error`` from the server raises
:class:`~kinefuse.live.protocol.wire_errors.RemoteError` and a ``goodbye`` ends the handshake
(:attr:`State.CLOSED`); a refusal of the server's
(:class:`~kinefuse.live.protocol.wire_errors.AuthError`,
:class:`OutOfOrder`) carries in ``reply`` the message the peer sends before it closes. No I/O,
no clock: the deadlines stay with the drivers (``live/server/server.py``,
``live/client/client.py``, the control peer of ``kinefuse calibrate --live``).
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable
from typing import Literal

from kinefuse.live.protocol import auth
from kinefuse.live.protocol.codec import check_version
from kinefuse.live.protocol.messages import (
    BODIES_VERSION,
    PROTOCOL_VERSION,
    AuthReply,
    Challenge,
    Error,
    Goodbye,
    Hello,
    Message,
    Welcome,
)
from kinefuse.live.protocol.wire_errors import AuthError, OutOfOrder, RemoteError, WireError

Side = Literal["server", "peer"]


class State(enum.Enum):
    """Where the handshake is (the same for both sides: it is one conversation)."""

    IDLE = "idle"  # nothing sent yet
    HELLO = "hello"  # the peer said hello; the server challenges or welcomes
    CHALLENGED = "challenged"  # the server challenged; the peer proves it knows the token
    PROVED = "proved"  # the peer proved it; the server welcomes
    DONE = "done"  # welcomed: data may flow
    CLOSED = "closed"  # one side refused or said goodbye


#: (state, message type) -> (who may send it, the next state)
TRANSITIONS: dict[tuple[State, str], tuple[Side, State]] = {
    (State.IDLE, "hello"): ("peer", State.HELLO),
    (State.HELLO, "challenge"): ("server", State.CHALLENGED),
    (State.HELLO, "welcome"): ("server", State.DONE),
    (State.CHALLENGED, "auth_reply"): ("peer", State.PROVED),
    (State.PROVED, "welcome"): ("server", State.DONE),
}

#: what the receiving side expected in each state (the text of an OutOfOrder)
_EXPECTED: dict[State, str] = {
    State.IDLE: "the first message must be hello",
    State.HELLO: "expected challenge or welcome",
    State.CHALLENGED: "expected auth_reply after the challenge",
    State.PROVED: "expected welcome",
    State.DONE: "the handshake is over",
    State.CLOSED: "the handshake was closed",
}


def refusal(error: WireError, reply: Message | None) -> WireError:
    """``error`` with ``reply``, the message to send before closing, attached."""
    error.reply = reply
    return error


class TokenRequired(AuthError):
    """The server challenged a peer that has no token."""


class Handshake:
    """One side's view of the handshake (see the module docstring).

    Parameters
    ----------
    side : {"server", "peer"}
    token : str or None
        The shared token (None: this side neither asks nor gives a proof).
    new_nonce : callable
        Fresh nonces (:func:`kinefuse.live.protocol.auth.new_nonce`; a test may fix them).

    Attributes
    ----------
    state : State
    hello : Hello or None
        The Hello of this connection (sent by a peer, received by a server).
    welcome : Welcome or None
        The Welcome, once the handshake is done.
    nonce, client_nonce : bytes or None
        The server's challenge nonce and the peer's Hello nonce of this connection.
    """

    def __init__(
        self,
        side: Side,
        token: str | None = None,
        *,
        new_nonce: Callable[[], bytes] = auth.new_nonce,
    ) -> None:
        if side not in ("server", "peer"):
            raise ValueError(f"side must be 'server' or 'peer', got {side!r}")
        self.side: Side = side
        self.token = token
        self._new_nonce = new_nonce
        self.state = State.IDLE
        self.hello: Hello | None = None
        self.welcome: Welcome | None = None
        self.nonce: bytes | None = None
        self.client_nonce: bytes | None = None

    @property
    def other(self) -> Side:
        """The side this one talks to."""
        return "peer" if self.side == "server" else "server"

    @property
    def done(self) -> bool:
        """Whether the Welcome went (or came): data may flow."""
        return self.state is State.DONE

    @property
    def peer_version(self) -> tuple[int, int]:
        """The other side's protocol version (from its Hello or Welcome; ours before it)."""
        if self.side == "server":
            return self.hello.protocol_version if self.hello else PROTOCOL_VERSION
        return self.welcome.protocol_version if self.welcome else PROTOCOL_VERSION

    @property
    def sends_every_body(self) -> bool:
        """Whether a body frame may carry ``others`` (the other side speaks 1.3 or newer): to
        an older server a sensor sends the first body of each frame only."""
        return self.peer_version >= BODIES_VERSION

    def _step(self, msg: Message, sender: Side) -> State:
        """The next state for ``msg`` from ``sender``, or OutOfOrder."""
        rule = TRANSITIONS.get((self.state, msg.TYPE))
        if rule is None or rule[0] != sender:
            if sender == self.side:
                raise OutOfOrder(
                    f"this {self.side} may not send {msg.TYPE} now (handshake state "
                    f"{self.state.value})"
                )
            raise OutOfOrder(f"{_EXPECTED[self.state]}, got {msg.TYPE}")
        return rule[1]

    # -- what this side sends -------------------------------------------------------------------

    def send(self, msg: Message) -> Message:
        """Check that this side may send ``msg`` now and move on; returns the message to write
        (a peer's Hello gets its ``client_nonce`` when the peer has a token). An Error or a
        Goodbye may always be sent: it closes the handshake."""
        if isinstance(msg, Error | Goodbye):
            if self.state is not State.DONE:
                self.state = State.CLOSED
            return msg
        nxt = self._step(msg, self.side)
        if isinstance(msg, Hello):
            if self.token is not None:
                self.client_nonce = self._new_nonce()
            msg = dataclasses.replace(msg, client_nonce=self.client_nonce)
            self.hello = msg
        elif isinstance(msg, Welcome):
            self.welcome = msg
        self.state = nxt
        return msg

    # -- what this side receives ----------------------------------------------------------------

    def receive(self, msg: Message) -> Message | None:
        """Take ``msg`` from the other side; returns what to answer at once (a server's
        Challenge, a peer's AuthReply) or None.

        Raises
        ------
        OutOfOrder
            ``msg`` is not allowed from the other side now.
        VersionError
            A Hello or Welcome of another major version.
        AuthError
            A wrong proof (either way), a challenge to a peer without a token
            (:class:`TokenRequired`), or a Welcome without a challenge to a peer with one.
        RemoteError
            The server sent an Error (on the peer's side).
        """
        if self.side == "peer" and self.state is not State.DONE:
            if isinstance(msg, Error):
                self.state = State.CLOSED
                raise RemoteError(msg.code, msg.reason)
            if isinstance(msg, Goodbye):
                self.state = State.CLOSED
                return None
        try:
            nxt = self._step(msg, self.other)
        except OutOfOrder as e:
            if self.side == "peer":
                raise refusal(e, Error("order", str(e))) from None
            raise
        if isinstance(msg, Hello):
            return self._on_hello(msg, nxt)
        if isinstance(msg, AuthReply):
            hello, nonce, token = self.hello, self.nonce, self.token
            assert hello is not None and nonce is not None and token is not None
            auth.verify_mac(token, nonce, msg.mac, role=hello.role, sensor_id=hello.sensor_id)
            self.state = nxt
            return None
        if isinstance(msg, Challenge):
            return self._on_challenge(msg, nxt)
        assert isinstance(msg, Welcome)
        if self.state is State.HELLO and self.token is not None:
            self.state = State.CLOSED
            who = "this sensor" if self.hello and self.hello.role == "sensor" else "this peer"
            raise refusal(
                auth.no_challenge_error(),
                Error("auth", f"{who} has a token and the server asked for none"),
            )
        check_version(msg.protocol_version)
        self.welcome = msg
        self.state = nxt
        return None

    def _on_hello(self, msg: Hello, nxt: State) -> Message | None:
        check_version(msg.protocol_version)
        self.hello = msg
        self.state = nxt
        if self.token is None:
            return None
        self.nonce = self._new_nonce()
        proof = None  # a peer older than 1.1 (or without a token) asks for no proof
        if msg.client_nonce is not None:
            proof = auth.compute_server_mac(
                self.token, msg.client_nonce, self.nonce, role=msg.role, sensor_id=msg.sensor_id
            )
        challenge = Challenge(nonce=self.nonce, server_mac=proof)
        self.state = self._step(challenge, self.side)
        return challenge

    def _on_challenge(self, msg: Challenge, nxt: State) -> Message:
        assert self.hello is not None
        role, sid = self.hello.role, self.hello.sensor_id
        if self.token is None or self.client_nonce is None:
            self.state = State.CLOSED
            raise refusal(TokenRequired("the server requires a token"), Goodbye("no token"))
        try:
            auth.verify_server_mac(
                self.token, self.client_nonce, msg.nonce, msg.server_mac, role=role, sensor_id=sid
            )
        except AuthError as e:
            self.state = State.CLOSED
            raise refusal(
                e, Error("auth", "the server did not prove that it knows the token")
            ) from None
        self.state = nxt
        reply = AuthReply(auth.compute_mac(self.token, msg.nonce, role=role, sensor_id=sid))
        self.state = self._step(reply, self.side)
        return reply
