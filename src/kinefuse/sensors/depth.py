"""Depth images of the simulated lab, with Kinect v2 time-of-flight errors.

The scene is the lab room (floor ``z = 0`` and four walls of an axis-aligned box), the actor's
capsule body and, during calibration, the wand (a sphere on a thin stick). Rays are cast through
every pixel of a pinhole depth camera, all at once:

* the room analytically (a camera inside a box leaves it through exactly one face);
* capsules and spheres only on the pixels of their exact bounding rectangle in the image
  (culling), gathered into one flat batch of (pixel, primitive) pairs and z-buffered with
  ``np.minimum.at``; no pixel is tested against a primitive whose rectangle misses it.

:func:`render_depth` returns what the Kinect SDK gives: ``(H, W) uint16`` millimetres of the
z coordinate in the sensor frame (not the ray length), 0 for no reading. Its error model
(:class:`DepthNoiseParams`, every value with its unit, source and whether it is a measurement or
an assumption; see ``docs/error_model_depth.md``):

1. lateral noise: every pixel's ray is jittered by a sub-pixel Gaussian offset before casting;
2. flying pixels: pixels at depth discontinuities take a depth between foreground and background
   (or no reading, as the SDK's edge filter drops some);
3. axial noise along the ray, growing with distance and incidence angle (Fankhauser et al. 2015);
4. a systematic, distance-dependent range offset (a linear trend plus the periodic "wiggling"
   error of continuous-wave time-of-flight cameras);
5. multipath: concave floor-wall corners read too far;
6. no reading out of the 0.5-4.5 m range, at grazing incidence, or where nothing is hit.

:func:`render_depth_m` is the noise-free geometry in metres (NaN for no reading) for tests and
calibration checks, and :func:`render_geometry` adds the incidence angle and a per-pixel surface
label (floor, wall, body, wand sphere, wand stick): the ground truth a detector is checked with.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field, fields
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.camera.intrinsics import Intrinsics
from kinefuse.camera.wand import Wand
from kinefuse.errors import InputError
from kinefuse.geometry.transforms import check_rigid
from kinefuse.skeleton import N_JOINTS, bone_index_array, capsule_radii
from kinefuse.skeleton.kinect_v2 import REFERENCE_HEIGHT_M

Array = NDArray[np.float64]

__all__ = [
    "DEFAULT_DEPTH_NOISE",
    "DepthGeometry",
    "DepthNoiseParams",
    "Scene",
    "SurfaceLabel",
    "axial_sigma_m",
    "render_depth",
    "render_depth_m",
    "render_geometry",
    "systematic_offset_m",
]

_MEAS = "measurement"
_ASSUME = "assumption"
_FANKHAUSER = (
    "Fankhauser, Bloesch, Rodriguez, Kaestner, Hutter, Siegwart: Kinect v2 for mobile robot "
    "navigation: evaluation and modeling, ICAR 2015, axial noise model"
)


def _meta(unit: str, kind: str, source: str) -> dict[str, str]:
    return {"unit": unit, "kind": kind, "source": source}


@dataclass(frozen=True)
class DepthNoiseParams:
    """Every parameter of the Kinect v2 depth error model, with its unit and source.

    Each field's ``metadata`` holds ``unit``, ``kind`` (``"measurement"``: a published figure;
    ``"assumption"``: our choice, with what informed it) and ``source``.
    ``docs/error_model_depth.md`` discusses them one by one. Setting a magnitude to 0 switches
    that error off.
    """

    # axial noise sigma_z(z, theta) = c0 + c1 z + c2 z^2 + ca z^1.5 theta^2 / (pi/2 - theta)^2
    axial_c0_mm: float = field(default=1.5, metadata=_meta("mm", _MEAS, _FANKHAUSER))
    axial_c1_mm_per_m: float = field(default=-0.5, metadata=_meta("mm/m", _MEAS, _FANKHAUSER))
    axial_c2_mm_per_m2: float = field(default=0.3, metadata=_meta("mm/m^2", _MEAS, _FANKHAUSER))
    # incidence-angle term of the same model
    axial_angle_mm_per_m1_5: float = field(
        default=0.1, metadata=_meta("mm/m^1.5", _MEAS, _FANKHAUSER)
    )
    # lateral noise: Gaussian sub-pixel jitter of each pixel's ray (clipped at 3 sigma)
    lateral_sigma_px: float = field(
        default=0.5,
        metadata=_meta(
            "px",
            _ASSUME,
            "Fankhauser et al. 2015 model the Kinect v2 noise in axial and lateral directions; "
            "their lateral figure is not reproduced here. Nguyen, Izadi, Lovell (3DIMPVT 2012) "
            "give 0.8 px for the structured-light Kinect v1; 0.5 px (sub-pixel) is our choice",
        ),
    )
    # systematic range offset: b0 + b1 (r - 1 m) + A sin(2 pi r / P + phi)   (measured - true)
    offset_at_1m_mm: float = field(
        default=2.0,
        metadata=_meta(
            "mm",
            _ASSUME,
            "Lachat et al. 2015 (Remote Sens. 7:13070) and Corti et al. 2016 (Robot. Auton. "
            "Syst.) measure a distance-dependent systematic error of the Kinect v2; its form "
            "(trend plus wiggling) follows them, the magnitudes (mm) are chosen, not read off "
            "their figures",
        ),
    )
    offset_slope_mm_per_m: float = field(
        default=2.5,
        metadata=_meta(
            "mm/m", _ASSUME, "as offset_at_1m_mm: the error grows with distance; slope chosen"
        ),
    )
    wiggle_amplitude_mm: float = field(
        default=2.0,
        metadata=_meta(
            "mm",
            _ASSUME,
            "Corti et al. 2016: the Kinect v2 systematic error follows a harmonic trend "
            "('wiggling'); amplitude of a few mm chosen",
        ),
    )
    wiggle_period_m: float = field(
        default=0.47,
        metadata=_meta(
            "m",
            _ASSUME,
            "a quarter of the 1.87 m unambiguous range of the 80 MHz modulation (4-phase "
            "sampling aliases odd harmonics into an error with 4 periods per ambiguity range)",
        ),
    )
    wiggle_phase_rad: float = field(default=0.0, metadata=_meta("rad", _ASSUME, "arbitrary"))
    # flying pixels at depth discontinuities
    flying_jump_m: float = field(
        default=0.10,
        metadata=_meta(
            "m",
            _ASSUME,
            "a jump between 4-neighbours larger than this is a silhouette (larger than the "
            "step between neighbours on a floor seen up to about 75 deg)",
        ),
    )
    flying_prob: float = field(
        default=0.5,
        metadata=_meta(
            "1",
            _ASSUME,
            "Wasenmueller & Stricker 2016 (ACCV workshops) and Sarbolandi et al. 2015 (CVIU) "
            "show Kinect v2 flying pixels at depth edges; the fraction is chosen",
        ),
    )
    flying_max_fraction: float = field(
        default=0.5,
        metadata=_meta(
            "1",
            _ASSUME,
            "a pixel whose centre lies on one side covers at least half of its own side "
            "(straight edge): it moves a uniform fraction in [0, this] toward the other depth",
        ),
    )
    edge_invalid_prob: float = field(
        default=0.2,
        metadata=_meta(
            "1",
            _ASSUME,
            "fraction of silhouette pixels with no reading (the SDK filters part of the "
            "flying pixels out)",
        ),
    )
    # multipath in concave floor-wall corners: extra range max * (1 - d / extent)
    multipath_max_mm: float = field(
        default=10.0,
        metadata=_meta(
            "mm",
            _ASSUME,
            "Corti et al. 2016: multiple reflections distort concave geometry; Wasenmueller & "
            "Stricker 2016 and Sarbolandi et al. 2015 show multipath interference; a concave "
            "corner reads too far (extra light path); magnitude chosen",
        ),
    )
    multipath_extent_m: float = field(
        default=0.30,
        metadata=_meta("m", _ASSUME, "distance from the corner over which multipath fades"),
    )
    # invalid pixels at grazing incidence: dropout rises linearly from soft to max
    grazing_soft_deg: float = field(
        default=70.0,
        metadata=_meta(
            "deg",
            _ASSUME,
            "a diffuse surface returns power proportional to cos(incidence), so readings thin "
            "out toward grazing incidence; onset chosen",
        ),
    )
    grazing_max_deg: float = field(
        default=82.0,
        metadata=_meta(
            "deg",
            _ASSUME,
            "above this incidence angle no reading (also where the axial model above diverges)",
        ),
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"DepthNoiseParams.{f.name} must be a finite number, got {v!r}")
        nonneg = (
            "lateral_sigma_px",
            "wiggle_amplitude_mm",
            "flying_jump_m",
            "multipath_max_mm",
            "axial_angle_mm_per_m1_5",
        )
        for name in nonneg:
            if getattr(self, name) < 0:
                raise InputError(
                    f"DepthNoiseParams.{name} must be >= 0, got {getattr(self, name)!r}"
                )
        for name in ("flying_prob", "flying_max_fraction", "edge_invalid_prob"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise InputError(f"DepthNoiseParams.{name} is a probability in [0, 1], got {v!r}")
        if self.flying_prob + self.edge_invalid_prob > 1.0:
            raise InputError(
                "DepthNoiseParams: flying_prob + edge_invalid_prob must not exceed 1, got "
                f"{self.flying_prob} + {self.edge_invalid_prob}"
            )
        if self.wiggle_period_m <= 0 or self.multipath_extent_m <= 0:
            raise InputError(
                "DepthNoiseParams: wiggle_period_m and multipath_extent_m must be > 0, got "
                f"{self.wiggle_period_m} and {self.multipath_extent_m}"
            )
        if not 0.0 < self.grazing_soft_deg <= self.grazing_max_deg < 90.0:
            raise InputError(
                "DepthNoiseParams: need 0 < grazing_soft_deg <= grazing_max_deg < 90, got "
                f"{self.grazing_soft_deg} and {self.grazing_max_deg}"
            )
        if self.lateral_sigma_px > 5.0:
            raise InputError(
                f"DepthNoiseParams.lateral_sigma_px must be at most 5 px, got "
                f"{self.lateral_sigma_px}; the lateral noise is a sub-pixel jitter"
            )
        z = np.linspace(0.0, 10.0, 101)
        if np.any(
            self.axial_c0_mm + self.axial_c1_mm_per_m * z + self.axial_c2_mm_per_m2 * z**2 < 0
        ):
            raise InputError(
                "DepthNoiseParams: the axial noise c0 + c1 z + c2 z^2 must be >= 0 for z in "
                f"0..10 m, got c0={self.axial_c0_mm}, c1={self.axial_c1_mm_per_m}, "
                f"c2={self.axial_c2_mm_per_m2}"
            )


#: The default error model (an immutable instance, safe as a default argument).
DEFAULT_DEPTH_NOISE = DepthNoiseParams()


def axial_sigma_m(
    z_m: ArrayLike, theta_rad: ArrayLike, params: DepthNoiseParams = DEFAULT_DEPTH_NOISE
) -> Array:
    """Standard deviation of the axial noise (Fankhauser et al. 2015), metres.

    ``sigma_z = c0 + c1 z + c2 z^2 + ca z^1.5 theta^2 / (pi/2 - theta)^2`` in mm with ``z`` in m.

    Parameters
    ----------
    z_m : (...) float
        Depth, metres.
    theta_rad : (...) float
        Incidence angle between the ray and the surface normal, radians, in ``[0, pi/2)``.
    params : DepthNoiseParams

    Returns
    -------
    sigma_m : (...) float
        Standard deviation, metres (inf at ``theta = pi/2``).
    """
    z = np.asarray(z_m, dtype=np.float64)
    th = np.asarray(theta_rad, dtype=np.float64)
    p = params
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = th / (0.5 * np.pi - th)
    s_mm = p.axial_c0_mm + z * (p.axial_c1_mm_per_m + p.axial_c2_mm_per_m2 * z)
    if p.axial_angle_mm_per_m1_5 != 0.0:
        s_mm = s_mm + p.axial_angle_mm_per_m1_5 * (z * np.sqrt(np.maximum(z, 0.0))) * (
            ratio * ratio
        )
    return np.asarray(s_mm * 1e-3, dtype=np.float64)


def systematic_offset_m(
    range_m: ArrayLike, params: DepthNoiseParams = DEFAULT_DEPTH_NOISE
) -> Array:
    """Systematic range error (measured minus true) at a true range, metres.

    ``b0 + b1 (r - 1 m) + A sin(2 pi r / P + phi)`` with the values of ``params`` (in mm).

    Parameters
    ----------
    range_m : (...) float
        True distance along the ray, metres.

    Returns
    -------
    offset_m : (...) float
    """
    r = np.asarray(range_m, dtype=np.float64)
    p = params
    mm = p.offset_at_1m_mm + p.offset_slope_mm_per_m * (r - 1.0)
    if p.wiggle_amplitude_mm != 0.0:
        # single-precision sine: rounding the argument (< 4e-6 rad at 5 m) moves it < 0.01 um
        arg = (r * (2.0 * np.pi / p.wiggle_period_m) + p.wiggle_phase_rad).astype(np.float32)
        mm = mm + p.wiggle_amplitude_mm * np.sin(arg).astype(np.float64)
    return np.asarray(mm * 1e-3, dtype=np.float64)


class SurfaceLabel(enum.IntEnum):
    """What a pixel's ray hits first."""

    NONE = 0
    FLOOR = 1
    WALL = 2
    BODY = 3
    WAND_SPHERE = 4
    WAND_STICK = 5


def _as_points(x: ArrayLike, name: str, shape: tuple[int, ...] | None = None) -> Array:
    try:
        a = np.array(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be numeric, got {type(x).__name__}") from None
    if shape is not None and a.shape != shape:
        raise InputError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise InputError(f"{name} must be finite (no NaN/inf); fill or drop missing values first")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Scene:
    """The simulated lab as the depth cameras see it. World frame, metres, z up.

    Attributes
    ----------
    a, b : (C, 3) float
        End points of the body's capsules (``C`` may be 0: an empty room).
    radius : (C,) float
        Capsule radii, > 0.
    wand : Wand or None
        Wand geometry; ``None``: no wand in the scene.
    wand_centre : (3,) float or None
        Centre of the wand's sphere (required with a wand).
    wand_handle_dir : (3,) float or None
        Direction from the sphere's centre along the stick to the hand (normalized here;
        default straight down, the sphere held up).
    room_min_xy_m, room_max_xy_m : (float, float)
        Corners of the room's floor rectangle; the walls stand on its edges.
    wall_height_m : float
        Height of the walls (there is no ceiling).
    walls : bool
        False: no walls (an open floor that extends to infinity).
    floor : bool
        False: no floor either (objects in empty space).
    """

    a: Array = field(default_factory=lambda: np.zeros((0, 3)))
    b: Array = field(default_factory=lambda: np.zeros((0, 3)))
    radius: Array = field(default_factory=lambda: np.zeros(0))
    wand: Wand | None = None
    wand_centre: Array | None = None
    wand_handle_dir: Array | None = None
    room_min_xy_m: tuple[float, float] = (-4.0, -4.0)
    room_max_xy_m: tuple[float, float] = (4.0, 4.0)
    wall_height_m: float = 3.0
    walls: bool = True
    floor: bool = True

    def __post_init__(self) -> None:
        a = _as_points(self.a, "Scene.a")
        if a.ndim != 2 or a.shape[1] != 3:
            raise InputError(f"Scene.a must have shape (C, 3), got {a.shape}")
        b = _as_points(self.b, "Scene.b", a.shape)
        r = _as_points(self.radius, "Scene.radius", (a.shape[0],))
        if np.any(r <= 0):
            raise InputError(f"Scene.radius must be > 0 m, got minimum {r.min()} m")
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "radius", r)
        if self.wand is not None and not isinstance(self.wand, Wand):
            raise InputError(f"Scene.wand must be a Wand or None, got {type(self.wand).__name__}")
        if self.wand is None:
            if self.wand_centre is not None or self.wand_handle_dir is not None:
                raise InputError(
                    "Scene: wand_centre/wand_handle_dir given without a wand; pass wand=Wand()"
                )
        else:
            if self.wand_centre is None:
                raise InputError("Scene: a wand needs wand_centre (3,) in world metres")
            c = _as_points(self.wand_centre, "Scene.wand_centre", (3,))
            d = _as_points(
                (0.0, 0.0, -1.0) if self.wand_handle_dir is None else self.wand_handle_dir,
                "Scene.wand_handle_dir",
                (3,),
            )
            n = float(np.linalg.norm(d))
            if n < 1e-9:
                raise InputError("Scene.wand_handle_dir must be a non-zero direction")
            d = d / n
            d.setflags(write=False)
            object.__setattr__(self, "wand_centre", c)
            object.__setattr__(self, "wand_handle_dir", d)
        lo = tuple(float(v) for v in self.room_min_xy_m)
        hi = tuple(float(v) for v in self.room_max_xy_m)
        if len(lo) != 2 or len(hi) != 2 or not (lo[0] < hi[0] and lo[1] < hi[1]):
            raise InputError(
                "Scene: room_min_xy_m must be below room_max_xy_m in x and y, got "
                f"{self.room_min_xy_m} and {self.room_max_xy_m}"
            )
        if not self.wall_height_m > 0:
            raise InputError(f"Scene.wall_height_m must be > 0, got {self.wall_height_m}")
        object.__setattr__(self, "room_min_xy_m", lo)
        object.__setattr__(self, "room_max_xy_m", hi)

    @classmethod
    def from_pose(
        cls,
        joints_world: ArrayLike,
        height_m: float = REFERENCE_HEIGHT_M,
        *,
        wand: Wand | None = None,
        wand_centre: ArrayLike | None = None,
        wand_handle_dir: ArrayLike | None = None,
        room_min_xy_m: tuple[float, float] = (-4.0, -4.0),
        room_max_xy_m: tuple[float, float] = (4.0, 4.0),
        wall_height_m: float = 3.0,
        walls: bool = True,
        floor: bool = True,
    ) -> Scene:
        """The capsule body of one pose (24 bones), optionally with the wand, in the room.

        Parameters
        ----------
        joints_world : (25, 3) float
            Kinect v2 joints in the world frame, metres (``kinefuse.skeleton.JOINTS`` order).
        height_m : float
            The subject's height; scales the capsule radii.
        wand : Wand, optional
            Wand geometry; defaults to ``Wand()`` when ``wand_centre`` is given.
        wand_centre : (3,) float, optional
            Sphere centre, world metres.
        wand_handle_dir : (3,) float, optional
            Direction from the sphere's centre to the hand (default straight down).

        Returns
        -------
        Scene
        """
        j = _as_points(joints_world, "joints_world")
        if j.shape != (N_JOINTS, 3):
            raise InputError(
                f"joints_world must be one pose of shape ({N_JOINTS}, 3) in metres, got "
                f"{j.shape}; for a sequence pass positions[k]"
            )
        try:
            radii = capsule_radii(height_m)
        except ValueError as e:
            raise InputError(str(e)) from None
        bones = bone_index_array()
        if wand is None and wand_centre is not None:
            wand = Wand()
        return cls(
            a=j[bones[:, 0]],
            b=j[bones[:, 1]],
            radius=radii,
            wand=wand,
            wand_centre=None if wand_centre is None else np.asarray(wand_centre, dtype=float),
            wand_handle_dir=(
                None if wand_handle_dir is None else np.asarray(wand_handle_dir, dtype=float)
            ),
            room_min_xy_m=room_min_xy_m,
            room_max_xy_m=room_max_xy_m,
            wall_height_m=wall_height_m,
            walls=walls,
            floor=floor,
        )

    def primitives(self) -> tuple[Array, Array, Array, NDArray[np.int8]]:
        """All round primitives as capsules (a sphere is a capsule with ``a == b``).

        Returns
        -------
        a, b : (P, 3) float
        radius : (P,) float
        label : (P,) int8
            :class:`SurfaceLabel` of each primitive.
        """
        a, b, r = [self.a], [self.b], [self.radius]
        lab = [np.full(len(self.radius), SurfaceLabel.BODY, dtype=np.int8)]
        if self.wand is not None:
            assert self.wand_centre is not None and self.wand_handle_dir is not None  # post_init
            c = self.wand_centre
            a.append(c[None])
            b.append(c[None])
            r.append(np.array([self.wand.radius_m]))
            lab.append(np.array([SurfaceLabel.WAND_SPHERE], dtype=np.int8))
            if self.wand.stick_length_m > 0 and self.wand.stick_radius_m > 0:
                s0, s1 = self.wand.stick_segment(c, self.wand_handle_dir)
                a.append(s0[None])
                b.append(s1[None])
                r.append(np.array([self.wand.stick_radius_m]))
                lab.append(np.array([SurfaceLabel.WAND_STICK], dtype=np.int8))
        return np.concatenate(a), np.concatenate(b), np.concatenate(r), np.concatenate(lab)


@dataclass(frozen=True, eq=False)
class DepthGeometry:
    """Noise-free result of casting one camera's rays into a scene.

    Attributes
    ----------
    z_m : (H, W) float
        Depth (z in the sensor frame) of the first hit, metres; ``inf`` where nothing is hit.
    cos_incidence : (H, W) float
        Cosine of the angle between the ray and the surface normal (1 = head-on); 0 for no hit.
    label : (H, W) int8
        :class:`SurfaceLabel` of the first hit.
    corner_dist_m : (H, W) float
        For floor pixels the distance of the hit to the nearest wall, for wall pixels its height
        above the floor (the distance to the concave floor-wall corner); ``inf`` elsewhere.
    """

    z_m: Array
    cos_incidence: Array
    label: NDArray[np.int8]
    corner_dist_m: Array

    @property
    def incidence_rad(self) -> Array:
        """Incidence angle ``(H, W)`` in radians (pi/2 where nothing is hit)."""
        return np.asarray(np.arccos(np.clip(self.cos_incidence, 0.0, 1.0)), dtype=np.float64)


@dataclass(frozen=True, eq=False)
class _Rays:
    """Pixel rays scaled to z = 1, ``q = (x, y, 1)``: the ray parameter of a hit is its depth."""

    x: Array  # (W,) (u - cx) / fx
    y: Array  # (H,) (v - cy) / fy
    qnorm: Array  # (H, W) |q|: range = z * |q|


@lru_cache(maxsize=16)
def _base_rays(intr: Intrinsics) -> _Rays:
    xr = (np.arange(intr.width, dtype=np.float64) - intr.cx) / intr.fx
    yc = (np.arange(intr.height, dtype=np.float64) - intr.cy) / intr.fy
    qn = np.sqrt(xr[None, :] ** 2 + yc[:, None] ** 2 + 1.0)
    for a in (xr, yc, qn):
        a.setflags(write=False)
    return _Rays(xr, yc, qn)


def _check_inputs(
    scene: Any, sensor2world: Any, intrinsics: Any, params: Any
) -> tuple[Array, Array]:
    if not isinstance(scene, Scene):
        raise InputError(f"scene must be a Scene, got {type(scene).__name__}")
    if not isinstance(intrinsics, Intrinsics):
        raise InputError(f"intrinsics must be an Intrinsics, got {type(intrinsics).__name__}")
    if not isinstance(params, DepthNoiseParams):
        raise InputError(f"params must be a DepthNoiseParams, got {type(params).__name__}")
    try:
        t = np.asarray(sensor2world, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("sensor2world must be a (4, 4) numeric array") from None
    if t.shape != (4, 4):
        raise InputError(f"sensor2world must be one (4, 4) transform, got shape {t.shape}")
    t = check_rigid(t, "sensor2world")
    rot = np.ascontiguousarray(t[:3, :3])
    o = np.ascontiguousarray(t[:3, 3])
    if scene.walls:
        lo, hi = scene.room_min_xy_m, scene.room_max_xy_m
        if not (lo[0] < o[0] < hi[0] and lo[1] < o[1] < hi[1] and 0.0 < o[2] < scene.wall_height_m):
            raise InputError(
                f"the sensor at {np.round(o, 3).tolist()} m is outside the room "
                f"x {lo[0]}..{hi[0]}, y {lo[1]}..{hi[1]}, z 0..{scene.wall_height_m} m; move it "
                "inside or build the Scene with walls=False"
            )
    elif scene.floor and not o[2] > 0.0:
        raise InputError(f"the sensor must be above the floor (z > 0), got z = {o[2]:.3f} m")
    return rot, o


@dataclass(frozen=True, eq=False)
class _Room:
    """The room seen through the exact pixel centres, cached per sensor pose and intrinsics."""

    z: Array  # (H, W) depth, inf where nothing is hit
    cos: Array  # (H, W) cosine of incidence, 0 where nothing is hit
    label: NDArray[np.int8]  # (H, W) SurfaceLabel
    corner: Array  # (H, W) distance to the floor-wall corner, inf for no multipath
    gu: Array  # (H, W) d(1/z)/du of the pixel's plane, 1/(m px): 1/z is affine in u, v
    gv: Array  # (H, W) d(1/z)/dv


def _room(scene: Scene, intr: Intrinsics, rot: Array, o: Array) -> _Room:
    key = (
        scene.room_min_xy_m,
        scene.room_max_xy_m,
        float(scene.wall_height_m),
        bool(scene.walls),
        bool(scene.floor),
    )
    return _room_cached(key, intr, rot.tobytes(), o.tobytes())


@lru_cache(maxsize=8)
def _room_cached(
    key: tuple[tuple[float, float], tuple[float, float], float, bool, bool],
    intr: Intrinsics,
    rot_bytes: bytes,
    o_bytes: bytes,
) -> _Room:
    lo, hi, height, walls, floor = key
    rot = np.frombuffer(rot_bytes, dtype=np.float64).reshape(3, 3)
    o = np.frombuffer(o_bytes, dtype=np.float64)
    rays = _base_rays(intr)
    h, w = intr.height, intr.width
    x = rays.x[None, :]
    y = rays.y[:, None]
    # world ray components (in-place arithmetic below: this runs once per pose, on full frames)
    d = [(rot[i, 0] * x + rot[i, 2]) + rot[i, 1] * y for i in range(3)]
    # faces: 0 floor (z = 0), 1 x = lo, 2 x = hi, 3 y = lo, 4 y = hi; 5 = nothing
    normals = np.array([[0, 0, 1], [1, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0]], dtype=float)
    offsets = np.array([0.0, lo[0], hi[0], lo[1], hi[1]])
    face = np.zeros((h, w), dtype=np.int8)
    with np.errstate(divide="ignore", invalid="ignore"):
        if floor:
            z = np.negative(d[2])
            np.maximum(z, 0.0, out=z)
            np.divide(o[2], z, out=z)  # inf where the ray does not go down
        else:
            z = np.full((h, w), np.inf)
        if walls:
            # the camera is inside the box: it leaves through x = hi when moving toward +x
            tx = np.where(d[0] >= 0.0, hi[0] - o[0], o[0] - lo[0])
            tx /= np.abs(d[0])
            ty = np.where(d[1] >= 0.0, hi[1] - o[1], o[1] - lo[1])
            ty /= np.abs(d[1])
            xwall = tx <= ty
            t_wall = np.minimum(tx, ty, out=tx)
            z_hit = np.multiply(t_wall, d[2], out=ty)
            z_hit += o[2]
            t_wall[z_hit > height] = np.inf  # above the wall
            wall_face = np.where(xwall, d[0] >= 0.0, d[1] >= 0.0).astype(np.int8)
            wall_face += 1
            wall_face[~xwall] += 2
            nearer = t_wall < z
            np.copyto(z, t_wall, where=nearer)
            np.copyto(face, wall_face, where=nearer)
    face[~np.isfinite(z)] = 5
    # 1/z = (n_s . q) / d_s on each face, n_s = R^T n_w and d_s = d_w - n_w . o in the sensor frame
    n_s = normals @ rot
    d_s = offsets - normals @ o
    label = np.array([SurfaceLabel.FLOOR] + [SurfaceLabel.WALL] * 4 + [SurfaceLabel.NONE])
    label = label.astype(np.int8)[face]
    cos = np.append(np.abs(d_s), 0.0)[face]  # |n_s . q| / |q| = |d_s| / (z |q|)
    with np.errstate(invalid="ignore"):
        cos /= np.multiply(z, rays.qnorm)
    corner = np.full((h, w), np.inf)
    if walls:
        with np.errstate(invalid="ignore"):
            px = np.multiply(z, d[0], out=d[0])
            px += o[0]
            dwall = px - lo[0]
            np.minimum(dwall, np.subtract(hi[0], px, out=px), out=dwall)
            py = np.multiply(z, d[1], out=d[1])
            py += o[1]
            dy = py - lo[1]
            np.minimum(dy, np.subtract(hi[1], py, out=py), out=dy)
            np.minimum(dwall, dy, out=dwall)  # floor point: distance to the nearest wall
            np.copyto(corner, dwall, where=face == 0)
            pz = np.multiply(z, d[2], out=d[2])
            pz += o[2]  # wall point: height above the floor
            np.copyto(corner, pz, where=(face > 0) & (face < 5))
    gu_face = np.append(n_s[:, 0] / (intr.fx * d_s), 0.0)
    gv_face = np.append(n_s[:, 1] / (intr.fy * d_s), 0.0)
    room = _Room(z=z, cos=cos, label=label, corner=corner, gu=gu_face[face], gv=gv_face[face])
    for arr in (room.z, room.cos, room.label, room.corner, room.gu, room.gv):
        arr.setflags(write=False)
    return room


def _axis_pixel_bounds(
    c_lat: Array, c_z: Array, r: Array, f: float, c0: float
) -> tuple[Array, Array]:
    """Exact range of the image coordinate (u or v, continuous) of rays that meet each sphere.

    Pixel column u lies in the plane ``x = z (u - c0) / f`` through the sensor's y axis; it meets
    the sphere iff the circle (the sphere projected on the x-z plane) meets that line: a 2-D
    test. Spheres must lie in front of the camera (``c_z > r``).
    """
    rho = np.hypot(c_lat, c_z)
    phi = np.arctan2(c_lat, c_z)
    half = np.arcsin(np.minimum(r / rho, 1.0))
    lim = 0.5 * np.pi - 1e-9
    lo_ang = np.maximum(phi - half, -lim)
    hi_ang = np.minimum(phi + half, lim)
    return c0 + f * np.tan(lo_ang), c0 + f * np.tan(hi_ang)


@dataclass(frozen=True, eq=False)
class _Pairs:
    """The (pixel, primitive) pairs to test: every pixel of each primitive's image rectangle."""

    a_s: Array  # (P, 3) capsule ends in the sensor frame
    b_s: Array  # (P, 3)
    r: Array  # (P,)
    label: NDArray[np.int8]  # (P,)
    counts: NDArray[np.intp]  # (P,) pairs per primitive, in pair order
    k: NDArray[np.intp]  # (N,) primitive of each pair
    row: NDArray[np.intp]  # (N,) pixel row
    col: NDArray[np.intp]  # (N,) pixel column
    pix: NDArray[np.intp]  # (N,) flat pixel index


def _pairs(scene: Scene, rot: Array, o: Array, intr: Intrinsics, margin_px: float) -> _Pairs | None:
    """Cull: each primitive is tested only on the pixels of its exact bounding rectangle."""
    h, w = intr.height, intr.width
    pa, pb, pr, plab = scene.primitives()
    if not len(pr):
        return None
    a_s = (pa - o) @ rot  # world -> sensor: R^T (p - o), row-vector form
    b_s = (pb - o) @ rot
    near = 1e-3
    zmin = np.minimum(a_s[:, 2], b_s[:, 2]) - pr
    zmax = np.maximum(a_s[:, 2], b_s[:, 2]) + pr
    keep = zmax > near  # not wholly behind the camera
    ul = np.full(len(pr), -np.inf)
    uh = np.full(len(pr), np.inf)
    vl = np.full(len(pr), -np.inf)
    vh = np.full(len(pr), np.inf)
    m = keep & (zmin > near)  # both end spheres wholly in front: an exact rectangle
    if m.any():
        ula, uha = _axis_pixel_bounds(a_s[m, 0], a_s[m, 2], pr[m], intr.fx, intr.cx)
        ulb, uhb = _axis_pixel_bounds(b_s[m, 0], b_s[m, 2], pr[m], intr.fx, intr.cx)
        vla, vha = _axis_pixel_bounds(a_s[m, 1], a_s[m, 2], pr[m], intr.fy, intr.cy)
        vlb, vhb = _axis_pixel_bounds(b_s[m, 1], b_s[m, 2], pr[m], intr.fy, intr.cy)
        # a capsule is the convex hull of its end spheres: the hull of the two intervals
        ul[m], uh[m] = np.minimum(ula, ulb), np.maximum(uha, uhb)
        vl[m], vh[m] = np.minimum(vla, vlb), np.maximum(vha, vhb)
    mg = margin_px + 1.0  # jittered rays reach margin_px further; 1 px for rounding
    keep &= (uh + mg >= 0) & (ul - mg <= w - 1) & (vh + mg >= 0) & (vl - mg <= h - 1)
    u0 = np.ceil(np.clip(ul - mg, 0, w - 1)).astype(np.intp)
    u1 = np.floor(np.clip(uh + mg, 0, w - 1)).astype(np.intp)
    v0 = np.ceil(np.clip(vl - mg, 0, h - 1)).astype(np.intp)
    v1 = np.floor(np.clip(vh + mg, 0, h - 1)).astype(np.intp)
    nw = np.where(keep, u1 - u0 + 1, 0)
    npx = nw * np.where(keep, v1 - v0 + 1, 0)
    total = int(npx.sum())
    if not total:
        return None
    k = np.repeat(np.arange(len(pr)), npx)
    local = np.arange(total) - np.repeat(np.cumsum(npx) - npx, npx)
    wk = nw[k]
    row = v0[k] + local // wk
    col = u0[k] + local % wk
    return _Pairs(a_s, b_s, pr, plab, npx, k, row, col, row * w + col)


#: a pixel whose noise-free depth is this far outside the range cannot be read (noise is smaller)
_RANGE_MARGIN_M = 0.5


def _cast(
    scene: Scene,
    rot: Array,
    o: Array,
    intr: Intrinsics,
    jitter: tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.intp]] | None = None,
    pairs: _Pairs | None = None,
) -> DepthGeometry:
    """Cast every pixel's ray.

    ``jitter = (du, dv, idx)``: flat per-pixel ray offsets in pixels, nonzero only at ``idx``;
    then ``pairs`` must have been culled with a margin covering the offsets.
    """
    h, w = intr.height, intr.width
    rays = _base_rays(intr)
    room = _room(scene, intr, rot, o)
    z = room.z.copy()
    if jitter is None:
        pairs = _pairs(scene, rot, o, intr, 0.0)
    else:
        # planes: 1/z is affine in (u, v), so the jittered ray's depth is exact on the same face
        du, dv, idx = jitter
        inv = 1.0 / room.z.reshape(-1)[idx]
        inv += room.gu.reshape(-1)[idx] * du[idx]
        inv += room.gv.reshape(-1)[idx] * dv[idx]
        with np.errstate(divide="ignore"):
            z.reshape(-1)[idx] = np.where(inv > 0.0, 1.0 / inv, np.inf)
    label = room.label.copy()
    cos_inc = room.cos.copy()
    corner = room.corner.copy()
    if pairs is None:
        return DepthGeometry(z_m=z, cos_incidence=cos_inc, label=label, corner_dist_m=corner)

    xf = rays.x[pairs.col]
    yf = rays.y[pairs.row]
    if jitter is not None:
        xf = xf + jitter[0][pairs.pix] * (1.0 / intr.fx)
        yf = yf + jitter[1][pairs.pix] * (1.0 / intr.fy)
    t = _ray_capsule_z(xf, yf, pairs.a_s, pairs.b_s, pairs.r, pairs.counts)
    zflat = z.reshape(-1)
    np.minimum.at(zflat, pairs.pix, t)
    win = np.isfinite(t) & (t == zflat[pairs.pix])
    prim = np.full(h * w, -1, dtype=np.intp)
    prim[pairs.pix[win]] = pairs.k[win]
    sel = np.flatnonzero(prim >= 0)
    if sel.size:
        kk = prim[sel]
        xs = rays.x[sel % w]
        ys = rays.y[sel // w]
        if jitter is not None:
            xs = xs + jitter[0][sel] * (1.0 / intr.fx)
            ys = ys + jitter[1][sel] * (1.0 / intr.fy)
        label.reshape(-1)[sel] = pairs.label[kk]
        corner.reshape(-1)[sel] = np.inf
        cos_inc.reshape(-1)[sel] = _capsule_cos(xs, ys, zflat[sel], pairs.a_s[kk], pairs.b_s[kk])
    return DepthGeometry(z_m=z, cos_incidence=cos_inc, label=label, corner_dist_m=corner)


def _ray_capsule_z(
    x: Array, y: Array, a_s: Array, b_s: Array, r: Array, counts: NDArray[np.intp]
) -> Array:
    """Depth of the nearest hit of rays ``(x, y, 1)`` from the origin with capsules, per pair.

    Capsule ``k`` (sensor frame) is repeated ``counts[k]`` times in the pair order. ``inf`` for
    a miss or a camera inside the primitive. Roots in the stable form ``c / (b + sqrt(b^2 - ac))``.
    """
    ba = b_s - a_s
    length = np.linalg.norm(ba, axis=1)
    e = np.where(length[:, None] > 1e-12, ba / np.maximum(length, 1e-300)[:, None], (0.0, 0.0, 1.0))
    aa = np.einsum("ij,ij->i", a_s, a_s)
    ae = np.einsum("ij,ij->i", a_s, e)
    r2 = r * r

    def rep(v: Array) -> Array:
        return np.repeat(v, counts)

    qq = x * x + y * y + 1.0
    qa = x * rep(a_s[:, 0]) + y * rep(a_s[:, 1]) + rep(a_s[:, 2])
    qe = x * rep(e[:, 0]) + y * rep(e[:, 1]) + rep(e[:, 2])
    ca = rep(aa - r2)  # > 0: camera outside the sphere at a
    cb = rep(np.einsum("ij,ij->i", b_s, b_s) - r2)
    cc = rep(aa - ae * ae - r2)  # > 0: camera outside the infinite cylinder
    ae_p = rep(ae)
    len_p = rep(length)
    qb = qa + len_p * qe
    with np.errstate(invalid="ignore", divide="ignore"):
        ha = qa * qa - qq * ca
        t = np.where((ha >= 0) & (qa > 0) & (ca > 0), ca / (qa + np.sqrt(ha)), np.inf)
        hb = qb * qb - qq * cb
        t = np.minimum(
            t, np.where((hb >= 0) & (qb > 0) & (cb > 0), cb / (qb + np.sqrt(hb)), np.inf)
        )
        ac = qq - qe * qe
        bc = qa - qe * ae_p
        hc = bc * bc - ac * cc
        tc = cc / (bc + np.sqrt(hc))
        s = tc * qe - ae_p  # axial coordinate of the hit
        ok = (hc >= 0) & (ac > 1e-12) & (bc > 0) & (cc > 0) & (s >= 0) & (s <= len_p)
        t = np.minimum(t, np.where(ok, tc, np.inf))
    return np.asarray(t, dtype=np.float64)


def _capsule_cos(x: Array, y: Array, z: Array, a_s: Array, b_s: Array) -> Array:
    """Cosine of incidence at hits ``z * (x, y, 1)`` on capsules ``a_s``-``b_s``, per pixel."""
    p = np.stack([x * z, y * z, z], axis=-1)
    ba = b_s - a_s
    baba = np.einsum("ij,ij->i", ba, ba)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(baba > 1e-24, np.einsum("ij,ij->i", p - a_s, ba) / baba, 0.0)
    n = p - a_s - np.clip(s, 0.0, 1.0)[:, None] * ba  # from the axis to the hit
    qn = np.abs(x * n[:, 0] + y * n[:, 1] + n[:, 2])
    with np.errstate(invalid="ignore", divide="ignore"):
        c = qn / (np.sqrt(x * x + y * y + 1.0) * np.linalg.norm(n, axis=1))
    return np.asarray(np.clip(np.nan_to_num(c, nan=1.0), 0.0, 1.0), dtype=np.float64)


def render_geometry(scene: Scene, sensor2world: ArrayLike, intrinsics: Intrinsics) -> DepthGeometry:
    """Noise-free ray casting: depth, incidence and surface label of every pixel.

    Parameters
    ----------
    scene : Scene
    sensor2world : (4, 4) float
        The camera's pose (sensor frame x right, y down, z forward); it must be in the room.
    intrinsics : Intrinsics

    Returns
    -------
    DepthGeometry
        ``z_m`` is not range-limited here (``inf`` only where nothing is hit).
    """
    rot, o = _check_inputs(scene, sensor2world, intrinsics, DEFAULT_DEPTH_NOISE)
    return _cast(scene, rot, o, intrinsics)


def _deterministic_valid(
    geo: DepthGeometry, z: Array, intr: Intrinsics, params: DepthNoiseParams
) -> NDArray[np.bool_]:
    cos_max = math.cos(math.radians(params.grazing_max_deg))
    return (z >= intr.min_range_m) & (z <= intr.max_range_m) & (geo.cos_incidence >= cos_max)


def render_depth_m(
    scene: Scene,
    sensor2world: ArrayLike,
    intrinsics: Intrinsics,
    params: DepthNoiseParams = DEFAULT_DEPTH_NOISE,
) -> Array:
    """Noise-free depth image in metres, NaN where the camera gives no reading.

    No reading: nothing hit, depth outside ``intrinsics``' range, or incidence above
    ``params.grazing_max_deg`` (the only parameter used here).

    Parameters
    ----------
    scene : Scene
    sensor2world : (4, 4) float
    intrinsics : Intrinsics
    params : DepthNoiseParams

    Returns
    -------
    depth_m : (H, W) float
        z coordinate in the sensor frame, metres.
    """
    rot, o = _check_inputs(scene, sensor2world, intrinsics, params)
    geo = _cast(scene, rot, o, intrinsics)
    return np.where(_deterministic_valid(geo, geo.z_m, intrinsics, params), geo.z_m, np.nan)


def _flying_pixels(
    z: Array, params: DepthNoiseParams, rng: np.random.Generator
) -> tuple[Array, NDArray[np.bool_]]:
    """Mix depths across silhouettes. Returns the new depth and the pixels dropped at edges."""
    h, w = z.shape
    drop = np.zeros((h, w), dtype=bool)
    if params.flying_prob == 0.0 and params.edge_invalid_prob == 0.0:
        return z, drop
    with np.errstate(invalid="ignore"):
        eh = np.abs(z[:, 1:] - z[:, :-1]) > params.flying_jump_m  # False where inf - inf
        ev = np.abs(z[1:, :] - z[:-1, :]) > params.flying_jump_m
    fin = np.isfinite(z)
    eh &= fin[:, 1:] & fin[:, :-1]  # a hit next to nothing is no mixture
    ev &= fin[1:, :] & fin[:-1, :]
    edge = np.zeros((h, w), dtype=bool)
    edge[:, 1:] |= eh
    edge[:, :-1] |= eh
    edge[1:, :] |= ev
    edge[:-1, :] |= ev
    idx = np.flatnonzero(edge)
    if idx.size == 0:
        return z, drop
    zf = z.reshape(-1)
    zi = zf[idx]
    row, col = np.divmod(idx, w)
    # the 4-neighbour whose depth differs most: the other side of the silhouette
    best = np.zeros(idx.size)
    other = zi.copy()
    for ok, nb in (
        (col > 0, idx - 1),
        (col < w - 1, idx + 1),
        (row > 0, idx - w),
        (row < h - 1, idx + w),
    ):
        zn = zf[np.where(ok, nb, idx)]  # the pixel itself where there is no neighbour
        with np.errstate(invalid="ignore"):
            d = np.abs(zn - zi)
        better = np.isfinite(d) & (d > best)
        best = np.where(better, d, best)
        other = np.where(better, zn, other)
    u = rng.random(idx.size)
    frac = rng.random(idx.size) * params.flying_max_fraction
    fly = u < params.flying_prob
    dropped = ~fly & (u < params.flying_prob + params.edge_invalid_prob)
    out = z.copy()
    out.reshape(-1)[idx[fly]] = zi[fly] + frac[fly] * (other[fly] - zi[fly])
    drop.reshape(-1)[idx[dropped]] = True
    return out, drop


def render_depth(
    scene: Scene,
    sensor2world: ArrayLike,
    intrinsics: Intrinsics,
    rng: np.random.Generator,
    params: DepthNoiseParams = DEFAULT_DEPTH_NOISE,
    *,
    noise: bool = True,
) -> NDArray[np.uint16]:
    """A depth frame as the Kinect v2 SDK gives it: millimetres of sensor-frame z, 0 = no reading.

    Parameters
    ----------
    scene : Scene
        The room, the body and the wand, world metres.
    sensor2world : (4, 4) float
        The depth camera's pose; it must be inside the room.
    intrinsics : Intrinsics
        Image size, focal lengths, principal point and valid range (0.5-4.5 m for a Kinect v2).
    rng : numpy.random.Generator
        The only source of randomness: the same seed gives the same image.
    params : DepthNoiseParams
        The error model.
    noise : bool
        False: the noise-free depth rounded to mm (the deterministic no-reading rules still
        apply; ``rng`` is not used).

    Returns
    -------
    depth_mm : (H, W) uint16
    """
    if not isinstance(rng, np.random.Generator):
        raise InputError(
            "rng must be a numpy.random.Generator (np.random.default_rng(seed)), got "
            f"{type(rng).__name__}"
        )
    rot, o = _check_inputs(scene, sensor2world, intrinsics, params)
    if not noise:
        geo = _cast(scene, rot, o, intrinsics)
        return _to_mm(geo.z_m, _deterministic_valid(geo, geo.z_m, intrinsics, params))

    p = params
    h, w = intrinsics.height, intrinsics.width
    lo_z = intrinsics.min_range_m - _RANGE_MARGIN_M
    hi_z = intrinsics.max_range_m + _RANGE_MARGIN_M
    sig = p.lateral_sigma_px
    if sig > 0:
        # jitter only the rays that can give a reading: the room in range and the primitives
        pairs = _pairs(scene, rot, o, intrinsics, 3.0 * sig)
        room_z = _room(scene, intrinsics, rot, o).z.reshape(-1)
        cand = (room_z >= lo_z) & (room_z <= hi_z)
        if pairs is not None:
            cand[pairs.pix] = True
        jidx = np.flatnonzero(cand)
        jit = rng.standard_normal((2, jidx.size), dtype=np.float32)
        np.clip(jit, -3.0, 3.0, out=jit)
        jit *= np.float32(sig)
        du = np.zeros(h * w, dtype=np.float32)
        dv = np.zeros(h * w, dtype=np.float32)
        du[jidx] = jit[0]
        dv[jidx] = jit[1]
        geo = _cast(scene, rot, o, intrinsics, (du, dv, jidx), pairs)
    else:
        geo = _cast(scene, rot, o, intrinsics)

    z, dropped = _flying_pixels(geo.z_m, p, rng)
    idx = np.flatnonzero((z >= lo_z) & (z <= hi_z))  # the others cannot come into range
    zf = z.reshape(-1)[idx]
    # |q| of the unjittered ray: the sub-pixel jitter changes it by < 0.2 %, i.e. < 0.01 mm of
    # the noise terms converted below
    qn = _base_rays(intrinsics).qnorm.reshape(-1)[idx]
    theta = np.arccos(np.clip(geo.cos_incidence.reshape(-1)[idx], 0.0, 1.0))
    sigma = axial_sigma_m(zf, np.minimum(theta, math.radians(p.grazing_max_deg)), p)
    range_m = zf * qn
    err = systematic_offset_m(range_m, p)
    err += sigma * rng.standard_normal(idx.size, dtype=np.float32)
    if p.multipath_max_mm > 0:
        cd = geo.corner_dist_m.reshape(-1)[idx]
        err += 1e-3 * p.multipath_max_mm * np.clip(1.0 - cd / p.multipath_extent_m, 0.0, 1.0)
    zm_flat = np.full(h * w, np.inf)
    zm_flat[idx] = zf + err / qn  # the error is along the ray; z is its projection
    z_meas = zm_flat.reshape(h, w)

    # no reading: out of range, grazing (a dropout ramp, then a hard limit), the edge filter
    lo, hi = math.radians(p.grazing_soft_deg), math.radians(p.grazing_max_deg)
    valid = (
        (z_meas >= intrinsics.min_range_m)
        & (z_meas <= intrinsics.max_range_m)
        & (geo.cos_incidence >= math.cos(hi))
        & ~dropped
    )
    ri = np.flatnonzero(valid & (geo.cos_incidence < math.cos(lo)))
    if ri.size:
        th = np.arccos(np.clip(geo.cos_incidence.reshape(-1)[ri], 0.0, 1.0))
        p_drop = (th - lo) / max(hi - lo, 1e-12)
        valid.reshape(-1)[ri[rng.random(ri.size) < p_drop]] = False
    return _to_mm(z_meas, valid)


def _to_mm(z_m: Array, valid: NDArray[np.bool_]) -> NDArray[np.uint16]:
    """Round valid depths to whole millimetres (uint16), 0 elsewhere."""
    out = np.zeros(z_m.shape, dtype=np.uint16)
    out[valid] = (z_m[valid] * 1000.0 + 0.5).astype(np.uint16)
    return out
