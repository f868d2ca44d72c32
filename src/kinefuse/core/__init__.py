"""The core: the types and helpers every other room uses.

- ``skeleton/``: the Kinect v2 topology as data (25 joints, 24 bones, capsule radii, the L/R
  mirror map);
- ``geometry/``: pure numpy rigid transforms (``A2B`` naming), Kabsch, plane fits, ray casting
  and ``rotations.py``, the one home of rotations;
- ``camera/``: the pinhole intrinsics of a depth camera and the wand's geometry;
- ``frames/``: the joint-series types: what a sensor delivers (``BodyFrame``, ``BodyFrames``,
  ``DepthFrame``), a motion in the world (``motion.py``), a motion file's own joints
  (``source_motion.py``), marker trajectories and their name matching (``marker_data.py``);
- ``affine_clock.py``: ``AffineClock`` and ``OffsetDriftClock``, the one clock map;
- ``outputs.py`` (the safe-write rules: never replace a file kinefuse did not make; a temporary
  file and an atomic rename), ``inputs.py`` (checked reads), ``toml.py`` (TOML read/write).

May import only :mod:`kinefuse.errors` (and itself): every room can build on it.
"""
