"""The ``kinefuse`` command line."""

import sys


def main(argv: list[str] | None = None) -> int:
    del argv
    print("kinefuse: under construction", file=sys.stderr)
    return 1
