"""``kinefuse serve`` and ``kinefuse calibrate --live``: the live server and its control peer.

No argument parsing here (that is :mod:`kinefuse.app.cli`): these run the asyncio parts and turn
their outcome into exit codes and printed lines.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import os
import signal
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from kinefuse.errors import InputError, KinefuseError
from kinefuse.live.protocol.fields import printable

log = logging.getLogger("kinefuse.serve")


def _setup_logging(verbose: bool) -> None:
    root = logging.getLogger("kinefuse")
    if not any(getattr(h, "_kinefuse", False) for h in root.handlers):
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter("kinefuse serve: %(levelname)s: %(message)s"))
        h._kinefuse = True  # type: ignore[attr-defined]
        root.addHandler(h)
    root.setLevel(logging.DEBUG if verbose else logging.INFO)


def token_from(arg: str | None, file: Path | None = None) -> str | None:
    """The shared token: ``--token-file`` (its first line), else ``--token``, else the
    ``KINEFUSE_TOKEN`` environment variable (None: no token). A file or the environment keep
    the token out of ``ps``; ``--token`` on the command line does not."""
    if file is not None and arg is not None:
        raise InputError("give either --token-file or --token, not both")
    if file is not None:
        try:
            lines = Path(file).read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as e:
            raise InputError(f"cannot read the token file {file}: {e}") from None
        tok: str | None = lines[0].strip() if lines else ""
        if not tok:
            raise InputError(f"the token file {file} is empty; put the token on its first line")
        warn_if_shared(Path(file))
        return tok
    tok = arg if arg is not None else os.environ.get("KINEFUSE_TOKEN")
    if tok is not None and not tok:
        raise InputError("the token is empty; give a non-empty --token-file (or KINEFUSE_TOKEN)")
    return tok


def warn_if_shared(file: Path) -> bool:
    """Warn (and return True) when the token file can be read by the group or others: anyone
    who can read it can stream to the server as any sensor."""
    try:
        mode = file.stat().st_mode
    except OSError:
        return False
    if mode & 0o077 and not file.is_fifo():
        logging.getLogger("kinefuse").warning(
            "the token file %s can be read by other users (mode %s): anyone who reads it can "
            "send data as any sensor; make it private: chmod 600 %s",
            file,
            oct(mode & 0o777),
            file,
        )
        return True
    return False


def check_serve_token(token: str | None, *, allow_weak: bool) -> None:
    """Refuse (``InputError``) a token too weak to keep the sensor port closed, unless
    ``allow_weak`` (``kinefuse serve --allow-weak-token``)."""
    from kinefuse.live.protocol.auth import check_token_strength

    if token is not None:
        try:
            check_token_strength(token, allow_weak=allow_weak)
        except ValueError as e:
            raise InputError(str(e)) from None


def write_new_token(path: Path) -> Path:
    """``kinefuse token new FILE``: a new random 256-bit token (64 hex characters) in a new
    file of mode 0600, written through a temporary file and renamed (an existing file is
    never replaced)."""
    from kinefuse.core.outputs import atomic_file, never_replace
    from kinefuse.errors import OutputError
    from kinefuse.live.protocol.auth import new_token

    if Path(path).exists() or Path(path).is_symlink():
        raise OutputError(
            f"{path} exists; a token file is never replaced (the server and the sensors may "
            "hold that token): choose a new path"
        )
    with atomic_file(path, what="token file", recognizer=never_replace) as tmp:
        tmp.chmod(0o600)
        tmp.write_text(new_token() + "\n", encoding="utf-8")
    return Path(path)


def _unwrap(eg: BaseExceptionGroup[BaseException]) -> BaseException:
    """The first leaf of an exception group (what a TaskGroup raised)."""
    e: BaseException = eg
    while isinstance(e, BaseExceptionGroup):
        e = e.exceptions[0]
    return e


def run_serve(
    *,
    host: str,
    port: int,
    token: str | None,
    record: Path | None,
    calibration: Path | None,
    method: str,
    latency_budget_ms: float,
    auto_calibrate: bool,
    calibration_method: str = "full",
    wand_axis_m: float | None = None,
    viewer_port: int | None = None,
    allow_hosts: tuple[str, ...] = (),
    lsl: str | None = None,
    lsl_xml: Path | None = None,
    verbose: bool = False,
    allow_weak_token: bool = False,
    subject: int | None = None,
    people: str = "subject",
) -> int:
    """Run the server until SIGINT/SIGTERM or a control peer's Shutdown; 0 on a clean stop.

    ``subject``: the person the server gives (``--subject``); default the first person seen.
    The viewer's operator can pick another. ``people="all"``: the LSL outlet also publishes one
    stream per person (:func:`kinefuse.live.lsl.lsl_outlet`)."""
    from kinefuse.live.server.live_calibration import LiveCalibrationOptions
    from kinefuse.live.server.server import Server, ServerOptions

    _setup_logging(verbose)
    check_serve_token(token, allow_weak=allow_weak_token)
    if not (math.isfinite(latency_budget_ms) and latency_budget_ms >= 0):
        raise InputError(f"--latency-budget-ms must be >= 0, got {latency_budget_ms}")
    if record is not None:
        from kinefuse.live.server.recorder import check_recording_path

        check_recording_path(record)
    options = ServerOptions(
        host=host,
        port=port,
        token=token,
        record=record,
        method=method,
        latency_budget_s=latency_budget_ms / 1e3,
        auto_calibrate=auto_calibrate,
        calibration=LiveCalibrationOptions(method=calibration_method, axis_length_m=wand_axis_m),
    )
    services: dict[str, Any] = {}
    the_server: list[Server] = []
    if lsl is not None:  # the LSL outlet, on the server's publisher (checked before we listen)
        from kinefuse.live.lsl import (
            MAX_NAME_CHARS,
            check_stream_name,
            check_xml_path,
            lsl_outlet,
            require_pylsl,
        )

        check_stream_name(lsl)
        if people == "all" and len(lsl) > MAX_NAME_CHARS - 5:
            raise InputError(
                f"--lsl {lsl!r} --people all: each person's stream is NAME_pID; use a name of "
                f"at most {MAX_NAME_CHARS - 5} characters"
            )
        require_pylsl()
        if lsl_xml is not None:
            check_xml_path(lsl_xml)
        # (the frames' clock is the server's own, known once it exists: read at start)
        services["lsl"] = lambda pub: lsl_outlet(
            pub, name=lsl, server_clock=lambda: the_server[0].clock(), xml_path=lsl_xml,
            people=people,
        )  # fmt: skip
    elif lsl_xml is not None:
        raise InputError("--lsl-xml writes the LSL stream's description: give --lsl too")
    elif people == "all":
        raise InputError(
            "--people all publishes one LSL stream per person: give --lsl too (the viewer and "
            "the live API give every person already)"
        )
    if viewer_port is not None:  # the live web viewer, on the server's publisher
        from kinefuse.live.viewer import live_viewer
        from kinefuse.live.viewer.port_limits import host_name

        for name in allow_hosts:
            try:
                host_name(name)
            except ValueError as e:
                raise InputError(f"--allow-host: {e}; give a DNS name or an IP address") from None
        services["viewer"] = functools.partial(
            live_viewer,
            host=host,
            port=viewer_port,
            token=token,
            allowed_hosts=allow_hosts,
            on_subject=lambda p: the_server[0].fusion.set_subject(p, "operator", known=True),
        )
    elif allow_hosts:
        raise InputError("--allow-host names the viewer's host: give --viewer-port too")
    # every descriptor the hard limit allows: the viewer's share of them is capped, the rest
    # is the sensors' (kinefuse.live.viewer.port_limits)
    from kinefuse.live.viewer.port_limits import raise_descriptor_limit

    raise_descriptor_limit()
    server = Server(options, services=services)
    the_server.append(server)
    if subject is not None:
        server.fusion.set_subject(subject, "chosen")
    if calibration is not None:
        from kinefuse.capture.calibration.calib_file import read_calibration

        server.load_calibration(read_calibration(calibration))

    def ready(h: str, p: int) -> None:
        print(f"kinefuse serve: listening on {h}:{p}", flush=True)
        if "viewer" in server.services:
            print(f"kinefuse serve: viewer at http://{h}:{server.services['viewer']}/", flush=True)
        if "lsl" in server.services:
            out: Any = server.services["lsl"]
            print(f"kinefuse serve: LSL stream {out.name!r} (type MoCap, 100 channels, 30 Hz), "
                  f"t_lsl = t_server {out.clock.offset_s:+.6f} s", flush=True)  # fmt: skip

    async def main() -> None:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            # (not possible outside the main thread or on some platforms: then Ctrl-C ends it)
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, server.request_stop, f"signal {sig.name}")
        await server.run(ready)

    # the loop thread stamps every arrival: it must get the GIL back quickly from the
    # recorder's thread (and a threaded fusion's), as `kinefuse sensor` does (5 ms by default)
    sys.setswitchinterval(0.001)
    try:
        asyncio.run(main())
    except BaseExceptionGroup as eg:
        raise _unwrap(eg) from None
    frames = server.loop.frames
    print(f"kinefuse serve: stopped ({server._stop_reason}); {frames} fused frames"
          + (f", recording {record}" if record else ""), flush=True)  # fmt: skip
    return 0


# -- kinefuse calibrate --live ---------------------------------------------------------------------


async def _control_calibrate(
    host: str, port: int, token: str | None, method: str, seconds: float | None, timeout_s: float
) -> Any:
    from kinefuse.live.protocol import (
        CalibrationResult,
        CalibrationStart,
        CalibrationStop,
        Decoder,
        Error,
        Goodbye,
        Heartbeat,
        Hello,
        encode,
    )
    from kinefuse.live.protocol.handshake import Handshake, State, TokenRequired
    from kinefuse.live.protocol.wire_errors import AuthError, OutOfOrder, RemoteError

    try:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), 10.0)
    except (OSError, TimeoutError) as e:
        raise KinefuseError(f"cannot reach the server at {host}:{port} ({e}); is `kinefuse "
                            "serve` running there?") from None  # fmt: skip
    dec = Decoder()
    inbox: list[Any] = []

    async def recv(t: float) -> Any:
        while not inbox:
            data = await asyncio.wait_for(reader.read(65536), t)
            if not data:
                raise KinefuseError("the server closed the connection")
            inbox.extend(dec.feed(data))
        return inbox.pop(0)

    def send(m: Any) -> None:
        writer.write(encode(m))

    try:
        # the sans-I/O handshake: with a token, the server proves it knows it over our fresh
        # nonce before we answer
        hs = Handshake("peer", token)
        send(hs.send(Hello(role="control", software="kinefuse calibrate --live")))
        while not hs.done:
            msg = await recv(10.0)
            try:
                answer = hs.receive(msg)
            except RemoteError as e:
                raise KinefuseError(
                    f"the server refused: {printable(e.reason)} ({e.code})"
                ) from None
            except TokenRequired:
                raise KinefuseError(
                    "the server requires a token: pass --token-file FILE (or KINEFUSE_TOKEN)"
                ) from None
            except AuthError as e:
                send(e.reply)
                raise KinefuseError(f"refusing the server at {host}:{port}: {e}") from None
            except OutOfOrder:
                raise KinefuseError(f"expected welcome from the server, got {msg.TYPE}") from None
            if hs.state is State.CLOSED:
                raise KinefuseError(f"expected welcome from the server, got {msg.TYPE}")
            if answer is not None:
                send(answer)
        assert hs.welcome is not None
        beat = hs.welcome.heartbeat_s
        send(CalibrationStart(method=method, seconds=seconds))
        loop = asyncio.get_running_loop()
        t_end = loop.time() + timeout_s
        # the server ends the phase after `seconds`; a Stop a little later in case it did not
        t_stop = loop.time() + seconds + 2.0 if seconds is not None else math.inf
        while True:
            now = loop.time()
            if now > t_end:
                raise KinefuseError(f"no calibration result within {timeout_s:g} s")
            if now >= t_stop:
                send(CalibrationStop())
                t_stop = math.inf
            try:
                msg = await recv(min(beat, max(t_stop - now, 0.01)))
            except TimeoutError:
                send(Heartbeat(t_s=now))
                continue
            if isinstance(msg, CalibrationResult):
                send(Goodbye(reason="calibration done"))
                await writer.drain()
                return msg
            if isinstance(msg, Error):
                raise KinefuseError(f"the server refused: {printable(msg.reason)} ({msg.code})")
            if isinstance(msg, Goodbye):
                raise KinefuseError(
                    f"the server said goodbye before a result: {printable(msg.reason)}"
                )
    finally:
        writer.close()


@dataclass(frozen=True)
class LiveSensorFit:
    """One sensor's part of a live calibration: ``id``, its RMS ``residual_m`` (metres) and
    the wand ``sightings`` the server's registration used."""

    id: str
    residual_m: float
    sightings: int


@dataclass(frozen=True)
class LiveCalibrateResult:
    """What ``kinefuse calibrate --live`` got from the server (``--json`` prints
    :meth:`as_dict`).

    Attributes
    ----------
    method : str
        The registration method.
    detector : str
        ``client``: the sensors found the wand themselves.
    world : str
        Always empty (the server does not say).
    rms_m : float
        RMS residual over the sensors, metres (NaN with none).
    grade : str
        The server's grade of the calibration.
    reasons : tuple of str
        Why the grade is worse than good.
    accepted, used_by_server : bool
        Whether the server took the calibration (the two are the same).
    message : str
        The server's words (escaped for the terminal).
    sensors : tuple of LiveSensorFit
        Per sensor.
    out : None
        No file is written.
    """

    method: str
    detector: str
    world: str
    rms_m: float
    grade: str
    reasons: tuple[str, ...]
    accepted: bool
    used_by_server: bool
    message: str
    sensors: tuple[LiveSensorFit, ...]
    out: None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-able, as ``--json`` prints it."""
        d = asdict(self)
        d["reasons"] = list(self.reasons)
        d["sensors"] = [asdict(s) for s in self.sensors]
        return d


def run_calibrate_live(
    *,
    address: tuple[str, int],
    method: str,
    seconds: float | None,
    token: str | None,
    timeout_s: float = 300.0,
) -> LiveCalibrateResult:
    """Ask a running server to calibrate; the result, like
    :func:`kinefuse.app.workflows.calibrate.run_calibrate`'s. ``address``: the server's
    ``(host, port)`` (:func:`kinefuse.live.address.parse_hostport` reads ``HOST:PORT``)."""
    host, port = address
    res = asyncio.run(_control_calibrate(host, port, token, method, seconds, timeout_s))
    text = printable(res.message, 1024)  # the server's words reach the terminal escaped
    return LiveCalibrateResult(
        method=res.method,
        detector="client",
        world="",
        rms_m=float(np.sqrt(np.nanmean(res.residual_m**2))) if len(res.residual_m) else math.nan,
        grade=res.grade,
        reasons=tuple(r.strip() for r in text.split(";")[1:]),
        accepted=bool(res.ok),
        used_by_server=bool(res.ok),
        message=text.split(";")[0],
        sensors=tuple(
            LiveSensorFit(
                id=sid, residual_m=float(res.residual_m[k]), sightings=int(res.n_sightings[k])
            )
            for k, sid in enumerate(res.sensor_ids)
        ),
    )


def format_calibrate_live(r: LiveCalibrateResult) -> str:
    """A live calibration's result as text for the terminal."""
    lines = [f"live calibration ({r.method}): {r.message}", f"grade: {r.grade}"]
    lines += [f"  {why}" for why in r.reasons]
    lines.append("")
    lines.append(f"{'sensor':<8} {'sightings':>9} {'residual mm':>12}")
    for s in r.sensors:
        lines.append(f"{s.id:<8} {s.sightings:>9} {1e3 * s.residual_m:12.2f}")
    if not r.accepted:
        lines.append("the server keeps its previous poses (this calibration failed)")
    return "\n".join(lines)


# -- command line ----------------------------------------------------------------------------------
