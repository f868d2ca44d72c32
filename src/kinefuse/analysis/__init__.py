"""Normalization and parameterization of skeleton motion (paper B, METHODS.md section B).

The shared input type is :class:`SkeletonSequence` (``kinefuse.analysis.sequence``). The rest of
the API is documented here as it lands.
"""

from kinefuse.analysis.sequence import SkeletonSequence, kinect_parents

__all__ = ["SkeletonSequence", "kinect_parents"]
