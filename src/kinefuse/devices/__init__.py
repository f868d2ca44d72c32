"""Real cameras and body trackers: the device sources and the tracker plug-in point.

A *source* reads an RGB-D camera (live or a recording) and yields :class:`~.capture.Capture`
items with the camera's own :class:`~.capture.CameraCalibration`; a *tracker* turns a capture
into the bodies it sees (:class:`~.trackers.TrackedBody`, the 25 Kinect v2 joints in the depth
camera's frame). Both are registered as entry points, so a package of a user's can add one.

May import :mod:`kinefuse.core`, :mod:`kinefuse.capture`, :mod:`kinefuse.biomech`,
:mod:`kinefuse.formats` and :mod:`kinefuse.sim`; nothing above.
"""
