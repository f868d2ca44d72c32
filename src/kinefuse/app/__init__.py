"""The application: the commands (``cli/``: argparse only, one module per command) and their
logic (``workflows/``: one module per command, no argument parsing; keyword arguments in,
results or exit codes out).

The top of the layer table: may import every room; only :mod:`kinefuse.api` and
:mod:`kinefuse.__main__` sit beside it.
"""
