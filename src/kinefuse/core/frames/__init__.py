"""The joint-series types: one body-tracker frame (``BodyFrame``), a stream of them in batch form
(``BodyFrames``, NaN + mask), the calibration phase's depth images (``DepthFrame``), a motion
in the world (``motion.py``), a motion file's own joints (``source_motion.py``) and marker
trajectories (``marker_data.py``).

Part of :mod:`kinefuse.core`: may import only :mod:`kinefuse.errors` and the rest of the core.
"""
