"""Capture: from the sensors' observations to one fused skeleton, the numerical core of paper A.

- ``sync/``: clock synchronisation (the offline NTP fit, the online estimator, device -> host
  mapping) and frame assembly;
- ``occlusion/``: the 2D bone-crossing occlusion test, per-joint sensor selection;
- ``calibration/``: wand detection, floor planes, registration, grading, the calibration file;
  ``calibration_run.py`` runs it on given sightings;
- ``fusion/``: trilateration (linear, geometric, nonlinear, paper), the causal ``best-live``
  and the offline ``best``; ``fusion_run.py`` runs a method on given sensors.

Pure: arrays and frozen dataclasses in and out; no store, no sockets, no wall clock (clocks are
injected; files only through :mod:`kinefuse.core`). May import :mod:`kinefuse.core` and
:mod:`kinefuse.errors`.
"""
