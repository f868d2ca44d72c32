"""One module per command's logic (simulate, calibrate, fuse, evaluate, analyze, realism, realdata,
serve, sensor, proxy, demo, view): load, configure, run, report. No argument parsing (that is
:mod:`kinefuse.cli`); functions take keyword arguments and return results or exit codes.

May import every room below it; only ``cli`` imports it."""
