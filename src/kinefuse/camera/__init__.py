"""What the system knows of a depth camera and the calibration object: the pinhole intrinsics
(projection between pixels and rays) and the wand's geometry. The core (calibration, occlusion,
fusion) imports these from here, never from the simulator in ``kinefuse.sim``.

May import: errors, io (base), skeleton, geometry.
"""

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.camera.wand import Wand

__all__ = ["Intrinsics", "Wand"]
