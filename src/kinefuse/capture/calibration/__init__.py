"""Self-calibration: wand detection in depth frames and registration of the sensors.

Pure functions (arrays in, arrays and frozen dataclasses out). Client side: the wand
detectors and the floor plane; server side: the registrations, grading and the TOML
calibration file. See ``docs/calibration.md``.

Part of :mod:`kinefuse.capture`: may import :mod:`kinefuse.core` and the rest of capture.
"""
