"""The command line: argparse only, one module per command (``add_parser`` and ``run``),
``args.py`` for the argument types every command shares, ``main.py`` for dispatch and error
reporting. The work is in :mod:`kinefuse.app.workflows`. May import anything below.
"""

from kinefuse.app.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
