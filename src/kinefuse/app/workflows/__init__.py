"""One module per command's logic: load, configure, run, report. No argument parsing (that is
:mod:`kinefuse.app.cli`); functions take keyword arguments and return results or exit codes.
May import every room below app.
"""
