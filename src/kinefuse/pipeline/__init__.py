"""The batch path: a stored session -> the core's inputs -> results (``session.py``: load the
sensors with their clocks and occlusion flags, gather the calibration phase, run a method), frame
sources by spec (``sources.py``: a stored session, a real log, a simulated sensor) and the analysis
chain as the commands run it (``analysis.py``).

May import every room below it (the core, ``io``, ``sim``); read by evaluation, net and
workflows."""
