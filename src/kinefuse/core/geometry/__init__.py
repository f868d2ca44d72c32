"""Pure numpy geometry: rigid transforms (``A2B`` naming), Kabsch, plane fits, ray casting, and
the one home of rotations.

Part of :mod:`kinefuse.core`: may import only :mod:`kinefuse.errors` and the rest of the core.
"""
