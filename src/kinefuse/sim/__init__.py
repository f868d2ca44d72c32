"""Sensor models (intrinsics, poses, error models) and the simulated capture lab."""
