"""``kinefuse token new FILE``: a strong shared token for the server and its sensors."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse token``."""
    p = sub.add_parser("token", help="make the shared token of the server and its sensors")
    actions = p.add_subparsers(
        dest="token_action", required=True, metavar="ACTION", help="new: write a new token"
    )
    new = actions.add_parser(
        "new",
        help="write a new random 256-bit token (64 hex characters) to a NEW file of mode 0600",
    )
    new.add_argument(
        "file", type=Path, metavar="FILE", help="the new token file (never replaced if it exists)"
    )
    new.set_defaults(func=run_new)


def run_new(args: argparse.Namespace) -> int:
    """``kinefuse token new FILE``."""
    from kinefuse.app.workflows.serve import write_new_token

    path = write_new_token(args.file)
    print(
        f"wrote a new token to {path} (mode 0600); copy it to each sensor PC (keep it private) "
        f"and start the server and the sensors with --token-file {path}"
    )
    return 0
