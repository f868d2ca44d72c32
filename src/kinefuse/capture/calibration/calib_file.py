"""The calibration file: every sensor's pose in the world, as TOML (format in docs/calibration.md).

Example::

    format = "kinefuse-calibration"
    format_version = 1
    method = "full"
    created = 2026-11-21T22:50:00Z
    world = "wand: origin below the wand's first position, x along its first move; z up ..."
    rms_mm = 1.9
    scale = 1.0022

    [[sensor]]
    id = "k0"
    serial = "003456165147"
    residual_mm = 1.7
    sightings = 571
    sensor2world = [
        [0.70, -0.10, 0.70, -2.10],
        [-0.71, -0.10, 0.70, -2.00],
        [0.00, -0.99, -0.14, 1.20],
        [0.0, 0.0, 0.0, 1.0],
    ]

    [sensor.intrinsics]
    width = 512
    height = 424
    fx = 365.0
    ...

Lengths are metres except the fields named ``_mm``; ``sensor2world`` maps a point in the sensor
frame (x right, y down, z forward) to the world (z up). Reading checks every field and says which
one is wrong in which file.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.register import Registration
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import check_rigid
from kinefuse.core.inputs import MAX_SMALL_TEXT_BYTES, check_text_file
from kinefuse.core.toml import dumps_toml, toml_error
from kinefuse.errors import InputError

Array = NDArray[np.float64]

FORMAT = "kinefuse-calibration"
FORMAT_VERSION = 1


@dataclass(frozen=True, eq=False)
class SensorCalibration:
    """One sensor in a calibration file.

    Attributes
    ----------
    id : str
    serial : str
        Device serial number ("" when unknown).
    sensor2world : (4, 4) float
    intrinsics : Intrinsics
        The intrinsics the wand detection used.
    residual_m : float
        The registration residual of this sensor, metres (NaN when unknown).
    n_sightings : int
        Number of wand sightings the pose rests on.
    """

    id: str
    serial: str
    sensor2world: Array
    intrinsics: Intrinsics
    residual_m: float
    n_sightings: int


@dataclass(frozen=True, eq=False)
class CalibrationFile:
    """A whole calibration: method, date, world definition and the sensors.

    ``scale``: the factor the sensor positions were scaled by to correct the world's scale
    (:attr:`~kinefuse.capture.calibration.register.Registration.scale`; 1.0: not scaled).
    """

    method: str
    created: _dt.datetime
    sensors: tuple[SensorCalibration, ...]
    world: str = ""
    rms_m: float = float("nan")
    scale: float = 1.0

    def sensor(self, sensor_id: str) -> SensorCalibration:
        """The entry of one sensor (KeyError naming the known ids otherwise)."""
        for s in self.sensors:
            if s.id == sensor_id:
                return s
        raise KeyError(
            f"no sensor {sensor_id!r} in the calibration; it has: "
            f"{', '.join(s.id for s in self.sensors)}"
        )

    @property
    def sensor2world(self) -> dict[str, Array]:
        """Poses by sensor id."""
        return {s.id: s.sensor2world for s in self.sensors}


def calibration_from_registration(
    registration: Registration,
    intrinsics: Mapping[str, Intrinsics],
    *,
    serials: Mapping[str, str] | None = None,
    created: _dt.datetime | None = None,
) -> CalibrationFile:
    """Bundle a :class:`Registration` with the sensors' intrinsics and serials for writing.

    ``created`` defaults to now (UTC). Every registered sensor needs its intrinsics.
    """
    missing = [sid for sid in registration.sensor_ids if sid not in intrinsics]
    if missing:
        raise InputError(f"no intrinsics given for sensor(s) {', '.join(missing)}")
    ser = dict(serials or {})
    sensors = tuple(
        SensorCalibration(
            id=sid,
            serial=str(ser.get(sid, "")),
            sensor2world=np.asarray(registration.sensor2world[k], dtype=np.float64),
            intrinsics=intrinsics[sid],
            residual_m=float(registration.residual_m[k]),
            n_sightings=int(registration.n_sightings[k]),
        )
        for k, sid in enumerate(registration.sensor_ids)
    )
    when = created or _dt.datetime.now(_dt.UTC).replace(microsecond=0)
    return CalibrationFile(
        method=registration.method,
        created=when,
        sensors=sensors,
        world=registration.world,
        rms_m=float(registration.rms_m),
        scale=float(registration.scale),
    )


def _mm(x_m: float) -> float:
    return round(float(x_m) * 1e3, 4) if math.isfinite(x_m) else float("nan")


def dumps_calibration(cal: CalibrationFile) -> str:
    """The calibration as TOML text (one matrix row per line, floats written exactly), through
    :func:`kinefuse.core.toml.dumps_toml`."""
    created = cal.created
    if created.tzinfo is None:
        created = created.replace(tzinfo=_dt.UTC)
    return dumps_toml(
        {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "method": cal.method,
            "created": created,
            "world": cal.world,
            "rms_mm": _mm(cal.rms_m),
            "scale": float(cal.scale),
            "sensor": [
                {
                    "id": s.id,
                    "serial": s.serial,
                    "residual_mm": _mm(s.residual_m),
                    "sightings": int(s.n_sightings),
                    "sensor2world": [[float(v) for v in row] for row in s.sensor2world],
                    "intrinsics": {
                        k: v if isinstance(v, int) else float(v)
                        for k, v in s.intrinsics.to_dict().items()
                    },
                }
                for s in cal.sensors
            ],
        }
    )


def is_calibration_file(path: Path) -> bool:
    """True if ``path`` is a calibration file kinefuse wrote (its ``format`` key says so)."""
    try:  # check_text_file: a file too large to be a calibration is not read whole
        check_text_file(path, what="calibration file", max_bytes=MAX_SMALL_TEXT_BYTES)
        return tomllib.loads(Path(path).read_text(encoding="utf-8")).get("format") == FORMAT
    except (OSError, ValueError, RecursionError):
        return False


def write_calibration(path: str | Path, cal: CalibrationFile | str) -> Path:
    """Write the calibration (or its TOML text) to a file, atomically; an existing file is
    replaced only if it is a kinefuse calibration file.

    Raises
    ------
    OutputError
        The file is someone else's, or could not be written.
    """
    from kinefuse.core.outputs import atomic_write_text

    text = cal if isinstance(cal, str) else dumps_calibration(cal)
    return atomic_write_text(path, text, what="calibration file", recognizer=is_calibration_file)


def _need(table: Mapping[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    if key not in table:
        raise InputError(f"{where}: missing field '{key}'")
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, kind):
        names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise InputError(f"{where}: field '{key}' must be {names}, got {v!r}")
    return v


def _check_pose(m: Any, where: str) -> Array:
    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where}: sensor2world must be a 4x4 array of numbers") from None
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise InputError(f"{where}: sensor2world must be a finite 4x4 array, got shape {a.shape}")
    return check_rigid(a, f"{where}: sensor2world")


def loads_calibration(text: str, *, source: str = "<string>") -> CalibrationFile:
    """Parse calibration TOML text; ``source`` names the file in error messages."""
    try:
        doc = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as e:
        raise InputError(f"{source}: not valid TOML ({toml_error(e)})") from None
    fmt = doc.get("format")
    if fmt != FORMAT:
        raise InputError(f"{source}: not a kinefuse calibration file (format = {fmt!r})")
    ver = _need(doc, "format_version", int, source)
    if ver > FORMAT_VERSION:
        raise InputError(
            f"{source}: format_version {ver} is newer than this kinefuse reads "
            f"({FORMAT_VERSION}); update kinefuse"
        )
    method = _need(doc, "method", str, source)
    created = _need(doc, "created", (_dt.datetime, _dt.date), source)
    if not isinstance(created, _dt.datetime):
        created = _dt.datetime(created.year, created.month, created.day, tzinfo=_dt.UTC)
    world = doc.get("world", "")
    rms = float(_need(doc, "rms_mm", (int, float), source)) * 1e-3 if "rms_mm" in doc else math.nan
    if "scale" in doc:
        scale = float(_need(doc, "scale", (int, float), source))
        if not (math.isfinite(scale) and scale > 0):
            raise InputError(f"{source}: field 'scale' must be a finite number > 0, got {scale}")
    else:
        scale = _scale_of_old_file(str(world), source)
    tables = _need(doc, "sensor", list, source)
    if not tables:
        raise InputError(f"{source}: no [[sensor]] tables")
    sensors = []
    seen: set[str] = set()
    for i, t in enumerate(tables):
        where = f"{source}: sensor #{i + 1}"
        if not isinstance(t, dict):
            raise InputError(f"{where}: must be a table")
        sid = _need(t, "id", str, where)
        where = f"{source}: sensor {sid!r}"
        if sid in seen:
            raise InputError(f"{where}: duplicate sensor id")
        seen.add(sid)
        intr_t = _need(t, "intrinsics", dict, where)
        try:
            intr = Intrinsics.from_dict(intr_t)
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{where}: bad intrinsics ({e})") from None
        sensors.append(
            SensorCalibration(
                id=sid,
                serial=str(t.get("serial", "")),
                sensor2world=_check_pose(_need(t, "sensor2world", list, where), where),
                intrinsics=intr,
                residual_m=float(_need(t, "residual_mm", (int, float), where)) * 1e-3,
                n_sightings=int(_need(t, "sightings", int, where)),
            )
        )
    return CalibrationFile(
        method=method,
        created=created,
        sensors=tuple(sensors),
        world=str(world),
        rms_m=rms,
        scale=scale,
    )


#: the sentence :func:`kinefuse.capture.calibration.calibration_run.scale_registration` adds to
#: ``world``
_SCALED_BY = re.compile(r"; scaled by ([0-9]+\.[0-9]+) from the protocol's known axis length")


def _scale_of_old_file(world: str, source: str) -> float:
    """The scale of a file written before the ``scale`` field: the factor in the one sentence
    kinefuse wrote into ``world`` when it scaled (5 decimals: within 5e-6 of the factor), else
    1.0 (the world was not scaled). A sentence that no correction of kinefuse can have written
    (several factors, one off by more than 3 %) is refused rather than guessed."""
    found = {float(m) for m in _SCALED_BY.findall(world)}
    if not found:
        return 1.0
    f = found.pop()
    if found or not 0.97 <= f <= 1.03:
        raise InputError(
            f"{source}: no field 'scale', and the world description's scale sentence is not "
            "one kinefuse wrote; add the line 'scale = <factor>' (1.0 when not scaled)"
        )
    return f


def read_calibration(path: str | Path) -> CalibrationFile:
    """Read a calibration TOML file; clear :class:`~kinefuse.errors.InputError` if malformed."""
    p = Path(path)
    try:
        check_text_file(p, what="calibration file", max_bytes=MAX_SMALL_TEXT_BYTES)
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{p}: calibration file not found") from None
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a text (UTF-8) file") from None
    return loads_calibration(text, source=str(p))
