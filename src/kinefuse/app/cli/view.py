"""``kinefuse view``: the replay viewer of a session."""

from __future__ import annotations

import argparse
from pathlib import Path

from kinefuse.app.cli import args as shared


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse view``."""
    p = sub.add_parser("view", help="replay a session in the web viewer (docs/viewer.md)")
    p.add_argument("session", type=Path, help="session store (.sqlite) to replay")
    p.add_argument("--host", default="127.0.0.1", help="interface to serve on (127.0.0.1)")
    p.add_argument("--port", type=int, default=0, help="TCP port (0: a free one)")
    shared.add_allow_host_arg(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.view import run_view

    return run_view(
        args.session, host=args.host, port=args.port, allow_hosts=tuple(args.allow_host)
    )
