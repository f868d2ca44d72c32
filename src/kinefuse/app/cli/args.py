"""The argument types and option groups every command shares (one of each).

Numbers must be finite everywhere (``inf`` and ``nan`` are refused with the same message in every
command); an address is ``HOST:PORT`` with IPv6 in brackets (:mod:`kinefuse.live.address`).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from kinefuse.errors import InputError
from kinefuse.live.address import parse_hostport


def finite_float(text: str) -> float:
    """A finite number."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def positive_float(text: str) -> float:
    """A finite number > 0."""
    v = finite_float(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def nonneg_float(text: str) -> float:
    """A finite number >= 0."""
    v = finite_float(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def count(text: str) -> int:
    """An integer >= 1."""
    if not text.strip().isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return int(text)


def host_port(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (IPv6 as ``[::1]:7400``)."""
    try:
        return parse_hostport(text, default_port=None)
    except InputError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def listen_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, or ``HOST`` alone for a free port."""
    try:
        return parse_hostport(text, default_port=0)
    except InputError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def room(text: str) -> tuple[float, float, float, float]:
    """``XMIN,YMIN,XMAX,YMAX`` in metres, a non-empty rectangle."""
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 4 or not (v[0] < v[2] and v[1] < v[3]):
        raise argparse.ArgumentTypeError(
            f"expected XMIN,YMIN,XMAX,YMAX in metres with XMIN < XMAX and YMIN < YMAX, got {text!r}"
        )
    return (v[0], v[1], v[2], v[3])


def phase(text: str) -> tuple[float, float]:
    """``START_S:END_S`` in seconds, the end after the start."""
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected START_S:END_S in seconds (e.g. 0:20), got {text!r}"
        ) from None
    if not b > a:
        raise argparse.ArgumentTypeError(f"the end must be after the start, got {text!r}")
    return a, b


def methods(text: str) -> tuple[str, ...]:
    """Comma-separated fusion methods, each one of ``kinefuse.capture.fusion.methods.METHODS``."""
    from kinefuse.capture.fusion.methods import METHODS

    names = tuple(m.strip() for m in text.split(",") if m.strip())
    bad = [m for m in names if m not in METHODS]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown method(s) {', '.join(bad) or '(none)'}; choose from {', '.join(METHODS)}"
        )
    return names


def error_parts(text: str) -> tuple[str, ...]:
    """Comma-separated parts of the tracker's error model, each one of
    ``kinefuse.sim.tracker_params.ERROR_PARTS``."""
    from kinefuse.sim.tracker_params import ERROR_PARTS, TrackerParams, without_parts

    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise argparse.ArgumentTypeError(f"no part given; choose from {', '.join(ERROR_PARTS)}")
    try:
        without_parts(TrackerParams(), names)
    except InputError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return names


def add_allow_host_arg(p: argparse.ArgumentParser) -> None:
    """``--allow-host NAME`` of the commands that serve the viewer (``serve``, ``view``)."""
    p.add_argument(
        "--allow-host",
        action="append",
        default=[],
        metavar="NAME",
        help="a name the viewer answers to besides --host and the loopback names (repeatable; "
        "a request naming any other host is refused: docs/security.md)",
    )


def add_calibration_args(p: argparse.ArgumentParser) -> None:
    g = p.add_mutually_exclusive_group()
    g.add_argument("--calibration", type=Path, help="calibration file (TOML) with sensor poses")
    g.add_argument(
        "--true-calibration",
        action="store_true",
        help="use the simulator's true sensor poses (evaluation only)",
    )


def add_span_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--start",
        type=float,
        metavar="S",
        help="first frame time, seconds from the session's start",
    )
    p.add_argument(
        "--end", type=float, metavar="S", help="last frame time, seconds from the session's start"
    )


def add_partial_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--partial",
        action="store_true",
        help="use an incomplete session (an interrupted simulation or recording) as it is",
    )


def person_id(text: str) -> int:
    """A person id: an integer >= 0."""
    if not text.strip().isdigit():
        raise argparse.ArgumentTypeError(f"expected a person id (0, 1, 2, ...), got {text!r}")
    return int(text)


def add_people_args(p: argparse.ArgumentParser, *, every: bool = True) -> None:
    """``--subject ID`` and (``every``) ``--people {subject,all}``."""
    p.add_argument(
        "--subject",
        type=person_id,
        metavar="ID",
        help="the person to give (a recording's default: the one seen in the calibration walk "
        "or the range-of-motion phase, else the one nearest the volume's centre at the start; "
        "live: the first person seen, or the one the viewer's operator picks)",
    )
    if every:
        p.add_argument(
            "--people",
            choices=["subject", "all"],
            default="subject",
            help="the subject only (default) or every person, one file each named by id "
            "(out.c3d -> out_p0.c3d, out_p1.c3d, ...)",
        )
