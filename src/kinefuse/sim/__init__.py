"""The simulated lab: virtual depth sensors watching real motion capture (the ground truth).

Rigs, device and host clocks, depth rendering with ToF noise, the body-tracker error model, the
calibration choreography, and the session simulator that writes a store.

May import the rooms below it (:mod:`kinefuse.core`, :mod:`kinefuse.capture`,
:mod:`kinefuse.biomech`, :mod:`kinefuse.formats`); nothing above (devices, pipeline, lab, live,
app).
"""
