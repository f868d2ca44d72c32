"""The command line: argparse only (room ``cli``, the top of the layer table).

One module per command (``add_parser`` and ``run``), :mod:`kinefuse.cli.args` for the argument
types every command shares, :mod:`kinefuse.cli.main` for dispatch and error reporting. A command
module parses and prints; the work is in :mod:`kinefuse.workflows`. May import anything below.
"""

from kinefuse.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
