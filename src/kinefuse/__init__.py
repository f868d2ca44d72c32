"""kinefuse: markerless motion capture with several depth sensors.

Conventions (see ``docs/conventions.md``): SI units inside (metres, seconds, radians); world frame
right-handed with z up; sensor frame x right, y down, z forward (OpenCV); arrays batch-first with
coordinates last, e.g. positions ``(T, J, 3)``; missing data is NaN plus a mask.
"""

__version__ = "0.1.0"

#: the Python API (:mod:`kinefuse.api`), loaded on first use: ``import kinefuse`` stays cheap
_API = (
    "Analysis",
    "Angles",
    "MarkerData",
    "Session",
    "Skeleton",
    "analyze",
    "fuse",
    "load_clip",
    "load_markers",
    "open_session",
)

__all__ = ["__version__", *_API]


def __getattr__(name: str) -> object:
    if name in _API:
        from kinefuse import api  # the one import of this module: the lazy facade

        return getattr(api, name)
    raise AttributeError(f"module 'kinefuse' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
