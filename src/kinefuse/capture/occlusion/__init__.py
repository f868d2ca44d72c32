"""Occlusion detection (client side, 2D bone intersection) and sensor selection (server side).

Part of :mod:`kinefuse.capture`: may import :mod:`kinefuse.core` and the rest of capture.
"""
