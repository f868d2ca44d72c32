"""The ``kinefuse`` command line: every command registered one way, errors reported one way.

Each command is a module of this folder with ``add_parser(sub)`` (argparse only) and
``run(args) -> int`` (which calls its workflow in :mod:`kinefuse.app.workflows`). Heavy modules load
when a command runs, not when the parser is built.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from kinefuse import __version__
from kinefuse.app.cli import (
    analyze,
    calibrate,
    demo,
    evaluate,
    fuse,
    inspect,
    maps,
    proxy,
    realdata,
    sensor,
    serve,
    simulate,
    token,
    track,
    view,
)
from kinefuse.errors import KinefuseError

#: The commands in the order ``kinefuse --help`` lists them.
COMMANDS = (
    demo,
    simulate,
    calibrate,
    serve,
    sensor,
    token,
    proxy,
    fuse,
    evaluate,
    realdata,
    track,
    analyze,
    maps,
    view,
    inspect,
)


def build_parser() -> argparse.ArgumentParser:
    """The parser of every command."""
    parser = argparse.ArgumentParser(
        prog="kinefuse",
        description="Markerless motion capture with several depth sensors (simulated lab).",
    )
    parser.add_argument("--version", action="version", version=f"kinefuse {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def _exit_cleanly_on_sigterm() -> None:
    """Turn SIGTERM into SystemExit, so that temporary files are removed on the way out (a
    plain SIGTERM would end the process without running any cleanup)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return

    def stop(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, stop)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; its exit code (2 for a user error, with one line saying what to do)."""
    args = build_parser().parse_args(list(sys.argv[1:] if argv is None else argv))
    _exit_cleanly_on_sigterm()
    try:
        return int(args.func(args))
    except KinefuseError as exc:
        print(f"kinefuse: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # the reader of our output went away (e.g. `| head`): not an error of ours; point stdout
        # at /dev/null so that the interpreter's final flush does not fail again
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as exc:
        # a file the user named that cannot be read or written: say which and why, no traceback
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"kinefuse: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("kinefuse: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
