"""The Lab Streaming Layer outlet: fused frames as one LSL stream (``kinefuse serve --lsl``).

A service on the server's publisher (:mod:`kinefuse.live.bus`), handed to the server by
``app/workflows/serve.py`` like the viewer; the server does not import it. One stream of type
``MoCap``: 25 joints x (x, y, z) in metres, then one status channel per joint (the
:class:`~kinefuse.capture.fusion.status.FusionStatus` code), ``float32``, nominal rate 30 Hz, with
the XDF channel metadata (``docs/lsl.md``). The stream is the subject's (the person the server gives
by default); with ``people="all"`` (``serve --lsl --people all``) every person also has a stream
of their own, ``NAME_pID`` (``kinefuse_p0``, ``kinefuse_p1``, ...; the same channels), created
when the person first appears in a fused frame.

Time stamps: each frame's time on the server clock is mapped onto the LSL clock
(``pylsl.local_clock()``) as ``t_lsl = t_server + offset``. Both clocks count the same
monotonic clock of this host (Linux ``CLOCK_MONOTONIC``: Python's ``time.monotonic`` and
liblsl's ``steady_clock``), so the map has no drift term; the offset is measured once at start
between two ``local_clock()`` readings around one server-clock reading (the narrowest bracket
of :data:`_OFFSET_TRIES`); its uncertainty (half the bracket, typically under 10 µs) is in the
stream's metadata and in :attr:`LslOutlet.offset_uncertainty_s`.

``pylsl`` is the optional extra ``kinefuse[lsl]``; without it :func:`require_pylsl` says so.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import logging
import math
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from kinefuse.capture.fusion.status import FusionStatus
from kinefuse.core.outputs import (
    atomic_write_text,
    check_output_folder,
    never_replace,
    refuse_unless_ours,
)
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError
from kinefuse.live.bus import FusedFrame, Publisher

log = logging.getLogger("kinefuse.lsl")

__all__ = [
    "CHANNELS",
    "DEFAULT_NAME",
    "MAX_NAME_CHARS",
    "NOMINAL_RATE_HZ",
    "STREAM_TYPE",
    "ClockMap",
    "LslOutlet",
    "channel_labels",
    "check_stream_name",
    "lsl_outlet",
    "person_stream_name",
    "person_xml_path",
    "require_pylsl",
    "sample_of",
]

STREAM_TYPE = "MoCap"
DEFAULT_NAME = "kinefuse"
NOMINAL_RATE_HZ = 30.0
MAX_NAME_CHARS = 64
#: 25 joints x (x, y, z), then 25 status channels
CHANNELS = 4 * len(JOINTS)
#: what the reference frame is, in the stream's metadata
REFERENCE_FRAME = (
    "kinefuse world frame: right-handed, z up, z = 0 on the floor, origin on the floor below the "
    "wand's first position, y along the wand's first move (docs/calibration.md); metres"
)
#: items the outlet's subscription keeps queued (lossy): far more than it ever falls behind
QUEUE = 256
_OFFSET_TRIES = 50
_EXTRA = "pip install 'kinefuse[lsl]'"


def require_pylsl() -> ModuleType:
    """The ``pylsl`` module, or an :class:`InputError` naming the extra that brings it."""
    try:
        return importlib.import_module("pylsl")
    except ImportError as e:
        raise InputError(
            f"--lsl needs pylsl (the optional extra kinefuse[lsl]): {_EXTRA} ({e})"
        ) from None
    except RuntimeError as e:  # pylsl found no liblsl
        raise InputError(
            f"--lsl: pylsl cannot load liblsl ({e}); reinstall with {_EXTRA}"
        ) from None


def check_stream_name(name: str) -> str:
    """``name`` if it makes a good LSL stream name, else an :class:`InputError` saying why.

    A name is 1-64 printable characters without ``< > & " '`` (it is put into XML and shown by
    LabRecorder) and without leading or trailing blanks.
    """
    if not name:
        raise InputError("--lsl: the stream name is empty; give a name (default: kinefuse)")
    if len(name) > MAX_NAME_CHARS:
        raise InputError(
            f"--lsl: the stream name is {len(name)} characters long; use at most {MAX_NAME_CHARS}"
        )
    bad = sorted({c for c in name if not c.isprintable() or c in "<>&\"'"})
    if bad:
        shown = ", ".join(repr(c) for c in bad)
        raise InputError(
            f"--lsl: the stream name {name!r} has characters LSL tools cannot show ({shown}); "
            "use letters, digits, spaces and - _ . : ( )"
        )
    if name != name.strip():
        raise InputError(f"--lsl: the stream name {name!r} starts or ends with a blank")
    return name


def check_xml_path(path: Path) -> None:
    """Refuse ``--lsl-xml FILE`` before the server listens: a new file in a writable folder."""
    check_output_folder(path, "LSL stream description")
    refuse_unless_ours(path, never_replace, "LSL stream description")


def channel_labels() -> list[str]:
    """``SpineBase_X, SpineBase_Y, SpineBase_Z, ...`` (75), then ``SpineBase_Status, ...`` (25)."""
    pos = [f"{j}_{a}" for j in JOINTS for a in "XYZ"]
    return pos + [f"{j}_Status" for j in JOINTS]


def sample_of(frame: FusedFrame, person: int | None = None) -> list[float]:
    """One LSL sample of ``frame``: the positions (NaN where not solved), then the codes; of
    the subject, or of ``person`` (:attr:`FusedFrame.people_m`)."""
    status: Any = frame.status
    pos = frame.positions_m
    if person is not None and person != frame.subject:
        pos = frame.people_m[person]
        status = frame.people_status.get(person)
        if status is None:  # (a frame without the codes: only solved or not)
            nan = np.isnan(np.asarray(pos, float)).any(axis=1)
            status = np.where(nan, FusionStatus.NO_DATA, FusionStatus.OK)
    return [float(v) for v in np.asarray(pos, float).ravel()] + [
        float(s) for s in np.asarray(status).ravel()
    ]


def person_stream_name(name: str, person: int) -> str:
    """The stream of one person under ``--people all``: ``NAME_pID``."""
    return f"{name}_p{person}"


def person_xml_path(path: Path, person: int) -> Path:
    """Where ``--lsl-xml FILE`` puts one person's description: ``FILE_pID`` before the
    suffix (``stream.xml`` -> ``stream_p1.xml``)."""
    return path.with_name(f"{path.stem}_p{person}{path.suffix}")


@dataclass(frozen=True)
class ClockMap:
    """``t_lsl = t_server + offset_s`` (the same monotonic clock: no rate term)."""

    offset_s: float
    uncertainty_s: float

    def to_lsl(self, t_server_s: float) -> float:
        return t_server_s + self.offset_s

    def to_server(self, t_lsl_s: float) -> float:
        return t_lsl_s - self.offset_s

    @classmethod
    def measure(cls, server_clock: Callable[[], float], lsl_clock: Callable[[], float]) -> ClockMap:
        """The narrowest of :data:`_OFFSET_TRIES` brackets ``lsl, server, lsl``."""
        best = (math.inf, 0.0)
        for _ in range(_OFFSET_TRIES):
            a = lsl_clock()
            s = server_clock()
            b = lsl_clock()
            if b - a < best[0]:
                best = (b - a, 0.5 * (a + b) - s)
        return cls(offset_s=best[1], uncertainty_s=0.5 * best[0])


def stream_info(pylsl: Any, name: str, source_id: str, clock: ClockMap) -> Any:
    """The ``StreamInfo`` with the XDF channel metadata."""
    info = pylsl.StreamInfo(
        name, STREAM_TYPE, CHANNELS, NOMINAL_RATE_HZ, pylsl.cf_float32, source_id
    )
    desc = info.desc()
    chans = desc.append_child("channels")
    for label in channel_labels():
        joint, kind = label.rsplit("_", 1)
        ch = chans.append_child("channel")
        ch.append_child_value("label", label)
        if kind == "Status":
            ch.append_child_value("type", "Status")
            ch.append_child_value("unit", "code")
        else:
            ch.append_child_value("type", "Position")
            ch.append_child_value("unit", "meters")
            ch.append_child_value("axis", kind)
        ch.append_child_value("joint", joint)
    desc.append_child_value("reference_frame", REFERENCE_FRAME)
    desc.append_child_value(
        "status_codes", "kinefuse FusionStatus: 0 OK ... 9 PREDICTED, 10 NO_DATA (NaN position)"
    )
    acq = desc.append_child("acquisition")
    acq.append_child_value("manufacturer", "kinefuse")
    acq.append_child_value("model", "fused Kinect v2 skeleton")
    clk = desc.append_child("kinefuse_clock")
    clk.append_child_value("mapping", "t_lsl = t_server + offset_s")
    clk.append_child_value("offset_s", repr(clock.offset_s))
    clk.append_child_value("uncertainty_s", repr(clock.uncertainty_s))
    return info


class LslOutlet:
    """The running outlet (what the service yields): its name, clock map and counters."""

    def __init__(self, pylsl: Any, name: str, clock: ClockMap, source_id: str) -> None:
        self.name = name
        self.clock = clock
        self.info = stream_info(pylsl, name, source_id, clock)
        self.outlet = pylsl.StreamOutlet(self.info, chunk_size=1, max_buffered=60)
        #: frames pushed, and frames the subscription dropped (the outlet fell behind)
        self.pushed = 0
        self.dropped = 0
        #: ``--people all``: each person's own outlet, by person id
        self.people: dict[int, LslOutlet] = {}

    @property
    def offset_uncertainty_s(self) -> float:
        return self.clock.uncertainty_s

    def push(self, frame: FusedFrame, person: int | None = None) -> None:
        sample = sample_of(frame, person)
        self.outlet.push_sample(sample, self.clock.to_lsl(frame.t_server_s), True)
        self.pushed += 1

    def xml(self) -> str:
        """The outlet's full stream description (``as_xml``), as an inlet would resolve it."""
        return str(self.outlet.get_info().as_xml())


@contextlib.asynccontextmanager
async def lsl_outlet(
    publisher: Publisher,
    *,
    name: str = DEFAULT_NAME,
    server_clock: Callable[[], float],
    source_id: str | None = None,
    xml_path: Path | None = None,
    people: str = "subject",
) -> AsyncIterator[LslOutlet]:
    """Publish every fused frame of ``publisher`` on an LSL outlet while the context is open.

    ``server_clock`` is the server's clock (the frames' ``t_server_s``); ``source_id``
    (default ``kinefuse-NAME``) lets LSL recorders reconnect to the same stream after a
    restart. ``xml_path``: write the outlet's full description there (``--lsl-xml``), from
    which an inlet can be built without discovery (``docs/lsl.md``). ``people="all"``: every
    person also on an outlet of their own (:func:`person_stream_name`), created when they first
    appear, in the yielded outlet's ``people`` (person id -> :class:`LslOutlet`); their
    descriptions go to :func:`person_xml_path` of ``xml_path``.
    """
    pylsl = require_pylsl()
    check_stream_name(name)
    if people not in ("subject", "all"):
        raise InputError(f"--people {people!r}: choose subject or all")
    clock = ClockMap.measure(server_clock, pylsl.local_clock)
    source = source_id or f"kinefuse-{name}"
    out = LslOutlet(pylsl, name, clock, source)
    if xml_path is not None:
        atomic_write_text(
            xml_path, out.xml(), what="LSL stream description", recognizer=never_replace
        )
    sub = publisher.subscribe(maxsize=QUEUE)
    log.info("LSL outlet %r (type %s, %d channels, %.0f Hz); t_lsl = t_server %+.6f s (+- %.1f us)",
             name, STREAM_TYPE, CHANNELS, NOMINAL_RATE_HZ, clock.offset_s,
             clock.uncertainty_s * 1e6)  # fmt: skip

    def person_outlet(pid: int) -> LslOutlet:
        one = LslOutlet(pylsl, person_stream_name(name, pid), clock, f"{source}-p{pid}")
        out.people[pid] = one
        log.info("LSL outlet %r for person %d", one.name, pid)
        if xml_path is not None:
            try:
                where = person_xml_path(xml_path, pid)
                what = "LSL stream description"
                atomic_write_text(where, one.xml(), what=what, recognizer=never_replace)
            except InputError as e:  # the stream runs; only its description is not written
                log.warning("LSL outlet %r: %s", one.name, e)
        return one

    async def pump() -> None:
        async for item in sub:
            if isinstance(item, FusedFrame):
                out.push(item)
                if people == "all":
                    for pid in sorted(item.people_m):
                        (out.people.get(pid) or person_outlet(pid)).push(item, pid)
            out.dropped = sub.dropped

    task = asyncio.create_task(pump())
    try:
        yield out
    finally:
        sub.close()
        with contextlib.suppress(asyncio.CancelledError, TimeoutError):
            await asyncio.wait_for(task, 2.0)
        out.dropped = sub.dropped
        log.info("LSL outlet %r: %d frames pushed, %d dropped", name, out.pushed, out.dropped)
        del out.outlet
        for one in out.people.values():
            del one.outlet
