"""Fusion of several sensors' joints: the paper's trilateration chain and its baselines, the
causal ``best-live`` and the offline ``best``.

Part of :mod:`kinefuse.capture`: may import :mod:`kinefuse.core` and the rest of capture.
"""
