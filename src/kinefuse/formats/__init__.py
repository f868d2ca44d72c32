"""Formats: every reader and writer of files, and the session store.

Exports of fused skeletons (C3D, TRC, CSV, BVH), marker files (TRC, C3D), angle files (CSV,
OpenSim .mot), real Kinect logs, files -> skeleton sequences (``sequences.py``), motion files
(``motion/``: BVH, ASF/AMC, read and retargeted onto the 25 joints) and ``store/`` (the SQLite
session store: one file per capture session, simulated or recorded live; its truth tables are
read only by :mod:`kinefuse.lab`).

May import :mod:`kinefuse.core`, :mod:`kinefuse.capture`, :mod:`kinefuse.biomech` and
:mod:`kinefuse.errors`: a format serialises the types of the rooms below it.
"""
