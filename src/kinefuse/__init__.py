"""kinefuse: markerless motion capture with several depth sensors.

Conventions (see ``docs/conventions.md``): SI units inside (metres, seconds, radians); world frame
right-handed with z up; sensor frame x right, y down, z forward (OpenCV); arrays batch-first with
coordinates last, e.g. positions ``(T, J, 3)``; missing data is NaN plus a mask.
"""

__version__ = "0.1.0"
