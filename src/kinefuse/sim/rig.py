"""Sensor rigs: where the sensors stand (rig TOML files or the default layout) and where the actor
starts.

Rig file (TOML)::

    [[sensor]]
    id = "front"              # unique
    serial = "000123"         # optional, default derived from the id
    position_m = [3.0, 0.0, 1.1]
    look_at_m = [0.0, 0.0, 1.0]
    roll_deg = 0.0            # optional: rotation about the optical axis

    [actor]                   # optional
    position_m = [0.0, 0.0]   # where the actor's SpineBase starts on the floor (default: the
                              # clip's path is centred on the origin)
    heading_deg = 0.0         # initial facing direction, from the world x axis toward y

    [room]                    # optional: the floor rectangle the walls stand on
    min_xy_m = [-4.0, -4.0]   # default: an 8 m x 8 m room centred on the origin
    max_xy_m = [4.0, 4.0]

Positions are world metres, z up. Every sensor must stand inside the room.
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.geometry.transforms import look_at
from kinefuse.core.skeleton import JOINT_INDEX
from kinefuse.errors import RigError

if TYPE_CHECKING:
    from kinefuse.core.frames.motion import Motion
from kinefuse.core.inputs import MAX_SMALL_TEXT_BYTES, check_text_file
from kinefuse.core.toml import dumps_toml, toml_error

Array = NDArray[np.float64]

DEFAULT_RADIUS_M = 3.0
DEFAULT_HEIGHTS_M = (1.0, 1.2)
DEFAULT_TARGET_HEIGHT_M = 1.0
DEFAULT_ROOM_MIN_XY_M = (-4.0, -4.0)
DEFAULT_ROOM_MAX_XY_M = (4.0, 4.0)
#: Two sensors closer than this stand in the same spot: no two cameras fit there (a Kinect v2 is
#: 25 x 6.6 x 6.7 cm), so it is a copied position in the rig file, not a layout.
MIN_SENSOR_SEPARATION_M = 0.05


@dataclass(frozen=True)
class SensorSpec:
    """One sensor of a rig: its id, serial number and true pose."""

    id: str
    serial: str
    sensor2world: Array

    @property
    def position_m(self) -> Array:
        return self.sensor2world[:3, 3]


@dataclass(frozen=True)
class Rig:
    """A set of sensors and the actor's starting place."""

    sensors: tuple[SensorSpec, ...]
    actor_position_m: tuple[float, float] | None = None
    actor_heading_deg: float = 0.0
    description: str = field(default="")
    room_min_xy_m: tuple[float, float] = DEFAULT_ROOM_MIN_XY_M
    room_max_xy_m: tuple[float, float] = DEFAULT_ROOM_MAX_XY_M

    def __post_init__(self) -> None:
        where = f"{self.description}: " if self.description else ""
        if not self.sensors:
            raise RigError(f"{where}a rig needs at least one sensor")
        ids = [s.id for s in self.sensors]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise RigError(f"{where}sensor ids must be unique; repeated: {', '.join(dup)}")
        lo = np.asarray(self.room_min_xy_m, dtype=np.float64)
        hi = np.asarray(self.room_max_xy_m, dtype=np.float64)
        if lo.shape != (2,) or hi.shape != (2,) or not (np.isfinite(lo).all() and (lo < hi).all()):
            raise RigError(
                f"{where}the room's min_xy_m must be below its max_xy_m in x and y, got "
                f"{self.room_min_xy_m} and {self.room_max_xy_m}"
            )
        for s in self.sensors:
            x, y, z = (float(v) for v in s.position_m)
            if not (lo[0] < x < hi[0] and lo[1] < y < hi[1] and z > 0.0):
                raise RigError(
                    f"{where}sensor {s.id!r} at [{x:.2f}, {y:.2f}, {z:.2f}] m is outside the room "
                    f"(floor from {lo.tolist()} to {hi.tolist()} m, above z = 0); move it inside, "
                    "or make the room larger ([room] in the rig file, or --room)"
                )
        pos = np.array([s.position_m for s in self.sensors], dtype=np.float64)
        for i in range(len(pos)):
            for j in range(i + 1, len(pos)):
                d = float(np.linalg.norm(pos[i] - pos[j]))
                if d < MIN_SENSOR_SEPARATION_M:
                    a, b = self.sensors[i].id, self.sensors[j].id
                    raise RigError(
                        f"{where}sensors {a!r} and {b!r} stand at the same spot "
                        f"([{', '.join(f'{v:.2f}' for v in pos[i])}] m, {100 * d:.1f} cm apart; "
                        f"two cameras need at least {100 * MIN_SENSOR_SEPARATION_M:.0f} cm): give "
                        "each sensor its own position_m"
                    )
        object.__setattr__(self, "room_min_xy_m", (float(lo[0]), float(lo[1])))
        object.__setattr__(self, "room_max_xy_m", (float(hi[0]), float(hi[1])))


def _serial_for(sensor_id: str, index: int) -> str:
    return f"SIM{index:03d}-{sensor_id}"


def default_rig(
    n_sensors: int = 4, radius_m: float = DEFAULT_RADIUS_M, *, room: Room | None = None
) -> Rig:
    """``n_sensors`` sensors evenly spaced on a circle of ``radius_m`` around the capture area.

    Heights step from 1.0 to 1.2 m across the sensors (so that they are not all coplanar), each
    looks at the centre of the area at 1.0 m height. Sensor 0 stands on the +x axis; the actor
    starts at the centre facing it.
    """
    if not 1 <= n_sensors <= 16:
        raise RigError(f"the default layout takes 1 to 16 sensors, got {n_sensors}")
    if not 0.5 <= radius_m <= 10.0:
        raise RigError(f"the default layout's radius must be 0.5 to 10 m, got {radius_m}")
    lo, hi = DEFAULT_HEIGHTS_M
    sensors = []
    for i in range(n_sensors):
        a = 2 * np.pi * i / n_sensors
        h = lo if n_sensors == 1 else lo + (hi - lo) * i / (n_sensors - 1)
        pos = np.array([radius_m * np.cos(a), radius_m * np.sin(a), h])
        pose = look_at(pos, [0.0, 0.0, DEFAULT_TARGET_HEIGHT_M])
        sid = f"k{i}"
        sensors.append(SensorSpec(id=sid, serial=_serial_for(sid, i), sensor2world=pose))
    half = max(DEFAULT_ROOM_MAX_XY_M[0], radius_m + 1.0)
    x0, y0, x1, y1 = (-half, -half, half, half) if room is None else room
    return Rig(
        sensors=tuple(sensors),
        description=f"default: {n_sensors} sensors on a {radius_m:g} m circle",
        room_min_xy_m=(x0, y0),
        room_max_xy_m=(x1, y1),
    )


def _vec(table: dict[str, object], key: str, n: int, where: str) -> Array:
    if key not in table:
        raise RigError(f"{where}: missing '{key}' (a list of {n} numbers, metres)")
    v = table[key]
    if (
        not isinstance(v, list)
        or len(v) != n
        or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
    ):
        raise RigError(f"{where}: '{key}' must be a list of {n} numbers (metres), got {v!r}")
    a = np.array(v, dtype=np.float64)
    if not np.isfinite(a).all():
        raise RigError(f"{where}: '{key}' must be finite, got {v!r}")
    return a


Room = tuple[float, float, float, float]


def parse_rig(text: str, *, source: str = "<rig>", room: Room | None = None) -> Rig:
    """Parse a rig file's TOML text. Errors name the file and the sensor.

    ``room`` ``(xmin, ymin, xmax, ymax)`` metres, if given, overrides the file's ``[room]``.
    """
    try:
        data = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise RigError(f"{source}: not valid TOML ({toml_error(exc)})") from None
    tables = data.get("sensor")
    if not isinstance(tables, list) or not tables:
        raise RigError(
            f"{source}: no [[sensor]] tables; a rig lists each sensor as\n"
            '[[sensor]]\nid = "front"\nposition_m = [3.0, 0.0, 1.1]\nlook_at_m = [0.0, 0.0, 1.0]'
        )
    unknown_top = set(data) - {"sensor", "actor", "room"}
    if unknown_top:
        raise RigError(
            f"{source}: unknown top-level keys {sorted(unknown_top)}; "
            "expected [[sensor]], [actor] and [room]"
        )
    sensors = []
    for i, t in enumerate(tables):
        if not isinstance(t, dict):
            raise RigError(f"{source}: [[sensor]] #{i + 1} is not a table")
        where = f"{source}: [[sensor]] #{i + 1}"
        sid = t.get("id")
        if not isinstance(sid, str) or not sid:
            raise RigError(f"{where}: missing 'id' (a non-empty string)")
        where += f" (id {sid!r})"
        unknown = set(t) - {"id", "serial", "position_m", "look_at_m", "roll_deg"}
        if unknown:
            raise RigError(f"{where}: unknown keys {sorted(unknown)}")
        pos = _vec(t, "position_m", 3, where)
        tgt = _vec(t, "look_at_m", 3, where)
        roll = t.get("roll_deg", 0.0)
        if not isinstance(roll, int | float) or isinstance(roll, bool):
            raise RigError(f"{where}: 'roll_deg' must be a number (degrees), got {roll!r}")
        serial = t.get("serial", _serial_for(sid, i))
        if not isinstance(serial, str):
            raise RigError(f"{where}: 'serial' must be a string, got {serial!r}")
        try:
            pose = look_at(pos, tgt, np.radians(float(roll)))
        except ValueError as exc:
            raise RigError(f"{where}: {exc}") from None
        sensors.append(SensorSpec(id=sid, serial=serial, sensor2world=pose))
    actor = data.get("actor", {})
    if not isinstance(actor, dict):
        raise RigError(f"{source}: [actor] must be a table")
    unknown = set(actor) - {"position_m", "heading_deg"}
    if unknown:
        raise RigError(f"{source}: [actor]: unknown keys {sorted(unknown)}")
    pos2 = _vec(actor, "position_m", 2, f"{source}: [actor]") if "position_m" in actor else None
    heading = actor.get("heading_deg", 0.0)
    if not isinstance(heading, int | float) or isinstance(heading, bool):
        raise RigError(f"{source}: [actor]: 'heading_deg' must be a number, got {heading!r}")
    room_t = data.get("room", {})
    if not isinstance(room_t, dict):
        raise RigError(f"{source}: [room] must be a table")
    unknown = set(room_t) - {"min_xy_m", "max_xy_m"}
    if unknown:
        raise RigError(f"{source}: [room]: unknown keys {sorted(unknown)}")
    lo = _vec(room_t, "min_xy_m", 2, f"{source}: [room]") if "min_xy_m" in room_t else None
    hi = _vec(room_t, "max_xy_m", 2, f"{source}: [room]") if "max_xy_m" in room_t else None
    if room is not None:
        lo, hi = np.array(room[:2]), np.array(room[2:])
    return Rig(
        sensors=tuple(sensors),
        actor_position_m=None if pos2 is None else (float(pos2[0]), float(pos2[1])),
        actor_heading_deg=float(heading),
        description=source,
        room_min_xy_m=DEFAULT_ROOM_MIN_XY_M if lo is None else (float(lo[0]), float(lo[1])),
        room_max_xy_m=DEFAULT_ROOM_MAX_XY_M if hi is None else (float(hi[0]), float(hi[1])),
    )


def load_rig(path: str | Path, *, room: Room | None = None) -> Rig:
    """Read a rig file (TOML, see the module docstring); ``room`` overrides its ``[room]``."""
    p = Path(path)
    try:
        check_text_file(p, what="rig file", max_bytes=MAX_SMALL_TEXT_BYTES,
                        fail=lambda message, _line: RigError(f"{p}: {message}"))  # fmt: skip
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise RigError(f"rig file not found: {p}") from None
    except UnicodeDecodeError:
        raise RigError(f"{p}: not a text file; a rig file is TOML") from None
    return parse_rig(text, source=str(p), room=room)


def _um(x: float) -> float:
    """A rig coordinate or angle as written: to 6 decimals (micrometres), no negative zero."""
    return round(float(x), 6) + 0.0


def rig_to_toml(rig: Rig) -> str:
    """TOML text of a rig (positions and look-at points of its sensors' poses, to 6 decimals),
    through :func:`kinefuse.core.toml.dumps_toml`."""
    sensors = []
    for s in rig.sensors:
        pos = s.sensor2world[:3, 3]
        tgt = pos + s.sensor2world[:3, 2]
        # roll: angle of the image x axis below the horizontal plane
        x = s.sensor2world[:3, 0]
        ref = look_at(pos, tgt)[:3, 0]
        roll = float(
            np.degrees(np.arctan2(np.dot(np.cross(ref, x), s.sensor2world[:3, 2]), np.dot(ref, x)))
        )
        sensors.append(
            {
                "id": s.id,
                "serial": s.serial,
                "position_m": [_um(v) for v in pos],
                "look_at_m": [_um(v) for v in tgt],
                "roll_deg": _um(roll),
            }
        )
    actor: dict[str, Any] = {}
    if rig.actor_position_m is not None:
        actor["position_m"] = [_um(v) for v in rig.actor_position_m]
    actor["heading_deg"] = _um(rig.actor_heading_deg)
    room = {
        "min_xy_m": [_um(v) for v in rig.room_min_xy_m],
        "max_xy_m": [_um(v) for v in rig.room_max_xy_m],
    }
    return dumps_toml({"sensor": sensors, "actor": actor, "room": room})


#: Heights at which a floor position must be in a sensor's view (and depth range) for the sensor
#: to see a standing body there: feet, hips, head (metres).
BODY_HEIGHTS_M = (0.15, 1.0, 1.7)
#: Grid step of the search for the common capture volume, metres.
VOLUME_STEP_M = 0.1


def sensors_seeing(
    rig: Rig, xy_m: ArrayLike, heights_m: Sequence[float] = BODY_HEIGHTS_M
) -> NDArray[np.int64]:
    """How many of the rig's sensors see a standing body at floor positions ``xy_m (n, 2)``:
    every height of ``heights_m`` above the position inside the sensor's image and depth range
    (default Kinect v2 depth intrinsics). Returns ``(n,)`` int."""
    from kinefuse.core.camera.intrinsics import Intrinsics

    intr = Intrinsics()
    xy = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    count = np.zeros(xy.shape[0], dtype=np.int64)
    for s in rig.sensors:
        seen = np.ones(xy.shape[0], dtype=bool)
        w2s = np.linalg.inv(s.sensor2world)
        for h in heights_m:
            p = np.column_stack([xy, np.full(xy.shape[0], float(h))]) @ w2s[:3, :3].T + w2s[:3, 3]
            z = p[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                u = intr.fx * p[:, 0] / z + intr.cx
                v = intr.fy * p[:, 1] / z + intr.cy
            seen &= (z >= intr.min_range_m) & (z <= intr.max_range_m)
            seen &= (u >= 0) & (u < intr.width) & (v >= 0) & (v < intr.height)
        count += seen
    return count


def common_volume_centre(rig: Rig) -> tuple[float, float]:
    """The floor position (x, y) at the centre of the sensors' common capture volume: of the
    floor cells (:data:`VOLUME_STEP_M`) where the most sensors see a standing body
    (:func:`sensors_seeing`), the one nearest to their centroid (so it lies inside that area
    even when the area is not convex)."""
    (x0, y0), (x1, y1) = rig.room_min_xy_m, rig.room_max_xy_m
    gx = np.arange(x0 + VOLUME_STEP_M / 2, x1, VOLUME_STEP_M)
    gy = np.arange(y0 + VOLUME_STEP_M / 2, y1, VOLUME_STEP_M)
    xy = np.stack(np.meshgrid(gx, gy, indexing="ij"), -1).reshape(-1, 2)
    n = sensors_seeing(rig, xy)
    if n.max() == 0:
        c = np.mean([s.position_m[:2] for s in rig.sensors], axis=0)
        return float(c[0]), float(c[1])
    best = xy[n == n.max()]
    k = int(np.argmin(np.linalg.norm(best - best.mean(axis=0), axis=1)))
    return float(best[k, 0]), float(best[k, 1])


def place_actor(motion: Motion, rig: Rig, seconds: float | None = None) -> Motion:
    """Put the actor where the rig says: its SpineBase at the rig's actor position at the first
    frame, or, when the rig names none, the path of the part that is simulated (the first
    ``seconds``, default all) centred on the origin; facing the rig's heading at the first
    frame; feet on the floor."""
    from kinefuse.formats.motion import place

    if rig.actor_position_m is not None:
        return place(motion, offset_m=rig.actor_position_m, heading_deg=rig.actor_heading_deg)
    placed = place(motion, offset_m=(0.0, 0.0), heading_deg=rig.actor_heading_deg)
    n = placed.n_frames if seconds is None else int(seconds * placed.rate_hz) + 1
    root = placed.positions[:n, JOINT_INDEX["SpineBase"], :2]
    centre = (root.min(axis=0) + root.max(axis=0)) / 2
    return place(
        motion,
        offset_m=(float(-centre[0]), float(-centre[1])),
        heading_deg=rig.actor_heading_deg,
    )
