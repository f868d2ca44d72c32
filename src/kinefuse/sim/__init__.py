"""Sensor models (intrinsics, poses, error models) and the simulated capture lab.

The simulated lab: rigs, device and host clocks, depth rendering with ToF noise, the body-
tracker error model, the calibration choreography, and the session simulator that writes a
store.  May import the core and ``io.store`` (it writes sessions); nothing above (formats,
pipeline, evaluation, net, workflows).
"""
