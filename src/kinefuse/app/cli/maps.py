"""``kinefuse maps``: the marker sets that ship, a map written for a file, a map checked on one
(docs/maps.md)."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``kinefuse maps list|suggest|check``."""
    p = sub.add_parser(
        "maps", help="marker maps: list the shipped sets, write one for a file, check one"
    )
    verbs = p.add_subparsers(
        dest="verb", required=True, metavar="VERB", help="list, suggest or check"
    )
    ls = verbs.add_parser("list", help="the marker sets that ship")
    ls.set_defaults(func=run_list)
    sg = verbs.add_parser(
        "suggest", help="write a map for a marker file: every rule it can infer, TODO for the rest"
    )
    sg.add_argument("file", type=Path, help="markers (.trc/.c3d)")
    sg.add_argument(
        "--out", type=Path, required=True, help="the map to write (.toml; never replaced)"
    )
    sg.set_defaults(func=run_suggest)
    ck = verbs.add_parser(
        "check", help="per joint, the rule and markers a map uses on a file, and on how much of it"
    )
    ck.add_argument("file", type=Path, help="markers (.trc/.c3d)")
    ck.add_argument("--map", required=True, help="a map (.toml) or a shipped set's name")
    ck.add_argument("--static", type=Path, help="the static trial, for the map's [landmarks]")
    ck.set_defaults(func=run_check)


def run_list(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.maps import list_maps

    print("\n".join(list_maps()))
    return 0


def run_suggest(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.maps import TODO, suggest_map
    from kinefuse.errors import InputError

    if args.out.suffix != ".toml":
        raise InputError(f"--out {args.out}: a marker map is a .toml file; e.g. --out my_map.toml")
    out, inferred, todo = suggest_map(args.file, args.out)
    print(f"wrote {out}: {len(inferred)} joints inferred ({', '.join(inferred)})")
    check = f"kinefuse maps check {shlex.quote(str(args.file))} --map {shlex.quote(str(out))}"
    if todo:
        print(f'{len(todo)} joints are "{TODO}" (fill them in, or delete them):')
        for t in todo:
            print(f"  {t}")
        print(f"then: {check}")
    else:
        print(f"next: {check}")
    return 0


def run_check(args: argparse.Namespace) -> int:
    from kinefuse.app.workflows.maps import check_map, format_check

    check = check_map(args.file, args.map, args.static)
    print("\n".join(format_check(check, args.file, str(args.map), args.static)))
    return 0
