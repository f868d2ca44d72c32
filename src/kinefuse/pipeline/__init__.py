"""The batch path: a stored session -> the capture core's inputs -> results.

``store_inputs.py`` loads the sensors with their clocks and occlusion flags, gathers the
calibration phase and runs a method; ``frame_sources.py`` opens frame sources by spec (a stored
session, a real log, a simulated sensor); ``analysis_chain.py`` is the analysis chain as the
commands run it; ``screen.py`` screens the sensors of a session.

May import every room below it (core, capture, biomech, formats, sim, devices); read by lab,
live and app.
"""
