"""What the system knows of a depth camera and the calibration object: the pinhole intrinsics
(projection between pixels and rays) and the wand's geometry. The capture core imports these
from here, never from the simulator.

Part of :mod:`kinefuse.core`: may import only :mod:`kinefuse.errors` and the rest of the core.
"""

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.camera.wand import Wand

__all__ = ["Intrinsics", "Wand"]
