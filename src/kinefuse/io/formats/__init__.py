"""Readers and writers of file formats: exports of fused skeletons (C3D, TRC, CSV, behind a
registry by extension), marker files (TRC, C3D) and marker maps, angle files (CSV, OpenSim .mot),
real Kinect logs (KinectMultiTrack), files -> skeleton sequences.

May import every room below it (the core, ``io``, ``io.store``, ``sim``)."""
