"""The occlusion rules by name (imported by :mod:`kinefuse.capture.occlusion.segments`, which
implements them, and by the command line; this module imports nothing but typing)."""

from typing import Literal

OcclusionRule = Literal["crossing", "coverage"]
#: The paper's 2D bone crossing, and capsule coverage.
OCCLUSION_RULES: tuple[OcclusionRule, ...] = ("crossing", "coverage")
