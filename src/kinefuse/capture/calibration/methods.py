"""The calibration methods and wand detectors by name (imported by the modules that implement
them and by the command line; this module imports nothing)."""

#: Registrations: the paper's, and the full 6-DoF one with gravity
#: (:func:`kinefuse.capture.calibration.calibration_run.calibrate`).
METHODS: tuple[str, ...] = ("paper", "full")
#: The wand detectors: the paper's nearest-object binarization and our sphere fit.
DETECTORS: tuple[str, ...] = ("paper", "robust")
