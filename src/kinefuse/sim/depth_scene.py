"""What the simulated depth camera sees: the lab room, the actor's capsule body and the wand
(:class:`Scene`), and the surface labels of a rendered pixel. Re-exported by
:mod:`kinefuse.sim.depth`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.camera.wand import Wand
from kinefuse.core.skeleton import N_JOINTS, bone_index_array, capsule_radii
from kinefuse.core.skeleton.kinect_v2 import REFERENCE_HEIGHT_M
from kinefuse.errors import InputError

Array = NDArray[np.float64]


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
            Kinect v2 joints in the world frame, metres (``kinefuse.core.skeleton.JOINTS`` order).
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
