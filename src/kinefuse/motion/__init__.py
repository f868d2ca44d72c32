"""Reading real motion (BVH, ASF/AMC) into Kinect v2 joint sequences."""

from kinefuse.motion.types import Motion

__all__ = ["Motion"]
