"""``kinefuse inspect``: what a session store holds."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse inspect``."""
    p = sub.add_parser("inspect", help="summarize a session store")
    p.add_argument("session", type=Path, help="session store (.sqlite)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kinefuse.formats.store.session_store import SessionStore
    from kinefuse.lab.inspect import format_inspect, inspect_session

    with SessionStore.open(args.session) as st:
        info = inspect_session(st)
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        print(format_inspect(info))
    return 0
