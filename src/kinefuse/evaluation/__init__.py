"""Evaluation: the only readers of the simulator's truth (``io/store/truth.py``), and the figures
that measure a run where there is no truth (consistency between sensors, coverage, inspect).

Results are plain dicts and dataclasses that :mod:`kinefuse.report` renders and the workflows
print. May import every room below it (the core, ``io``, ``sim``, ``pipeline``); nothing in the
capture path (``net``, ``fusion``, ``calibration``) may import it."""
