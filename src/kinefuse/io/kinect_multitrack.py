"""Reader of KinectMultiTrack CSV logs: two (or more) real Kinect v2 sensors watching one person.

KinectMultiTrack (C.-J. Wu, MIT license) logs, whenever a body frame arrives at its server, one
row per sensor with that sensor's latest skeleton. Columns (names are matched after stripping
spaces, in any order; extra columns are ignored):

``Study_Id, Kinect_Config, Scenario_Id``
    study, sensor layout (0 parallel, 1 at 45 degrees in the shipped files), task (1 stand still,
    2 steps, 3 walk a square and its diagonals).
``Tracker_Time``
    the receiving server's clock, milliseconds (.NET epoch; tens of ms of jitter).
``Person_Id, Skeleton_Id``
    the tracked person, and the skeleton's index among the sensors watching them.
``Skeleton_Time``
    the sensor's own clock (Kinect ``RelativeTime``), 100 ns ticks.
``Skeleton_Init_Angle, Skeleton_Init_Dist``
    the body's yaw relative to the sensor (radians) and its distance (metres) when tracking
    started; KinectMultiTrack uses them to map every sensor into the reference sensor's frame.
``Kinect_Id, Kinect_Tilt_Angle, Kinect_Height``
    the sensor (its PC's IP address), its tilt (degrees) and height (centimetres).
``<Joint>_X, <Joint>_Y, <Joint>_Z``
    the 25 joints (Kinect SDK names), metres, already mapped by KinectMultiTrack into the
    reference sensor's frame, in Kinect camera-space axes (x left, y up, z forward).

The reader converts joints to kinefuse's sensor axes (x right, y down, z forward: ``(-x, -y, z)``,
a rotation by 180 degrees about z) and the joint order to :data:`kinefuse.skeleton.JOINTS`.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError
from kinefuse.skeleton import JOINTS, N_JOINTS

Array = NDArray[np.float64]

_META_COLUMNS = (
    "Kinect_Config",
    "Scenario_Id",
    "Tracker_Time",
    "Skeleton_Time",
    "Kinect_Id",
)
_OPTIONAL_COLUMNS = (
    "Skeleton_Init_Angle",
    "Skeleton_Init_Dist",
    "Kinect_Tilt_Angle",
    "Kinect_Height",
)
#: Kinect camera space (x left, y up, z forward) -> kinefuse sensor axes (x right, y down, z fwd).
_AXES = np.array([-1.0, -1.0, 1.0])


@dataclass(frozen=True, eq=False)
class MultitrackStream:
    """One sensor's rows of a KinectMultiTrack log, in file order.

    Attributes
    ----------
    sensor_id : str
        ``Kinect_Id`` (the sensor PC's IP address).
    t_receive_s : (N,) float
        Server receive time, seconds since the file's first ``Tracker_Time``.
    t_sensor_s : (N,) float
        The sensor's own clock (``Skeleton_Time``), seconds.
    joints_m : (N, 25, 3) float
        Joints in the reference sensor's frame (kinefuse sensor axes), metres, ``JOINTS`` order.
    scenario : (N,) int
        ``Scenario_Id`` of each row.
    init_angle_rad, init_dist_m : float
        Body yaw relative to this sensor and its distance when tracking started (NaN if absent).
    tilt_deg, height_m : float
        The sensor's tilt and height as logged (NaN if absent).
    """

    sensor_id: str
    t_receive_s: Array
    t_sensor_s: Array
    joints_m: Array
    scenario: NDArray[np.int64]
    init_angle_rad: float
    init_dist_m: float
    tilt_deg: float
    height_m: float

    @property
    def n_frames(self) -> int:
        return int(self.t_receive_s.shape[0])


@dataclass(frozen=True, eq=False)
class MultitrackRecording:
    """A whole KinectMultiTrack log.

    Attributes
    ----------
    path : str
    kinect_config : int
        ``Kinect_Config`` (0 = parallel sensors, 1 = side sensor at 45 degrees in the shipped
        files).
    t_receive_epoch_ms : int
        The first ``Tracker_Time``, milliseconds (the origin of every ``t_receive_s``).
    streams : tuple of MultitrackStream
        One per sensor, in order of first appearance.
    """

    path: str
    kinect_config: int
    t_receive_epoch_ms: int
    streams: tuple[MultitrackStream, ...]

    def stream(self, sensor_id: str) -> MultitrackStream:
        for s in self.streams:
            if s.sensor_id == sensor_id:
                return s
        raise KeyError(
            f"no sensor {sensor_id!r} in {self.path}; sensors: "
            + ", ".join(s.sensor_id for s in self.streams)
        )

    @property
    def scenarios(self) -> tuple[int, ...]:
        return tuple(sorted({int(v) for s in self.streams for v in np.unique(s.scenario)}))


def _number(text: str, path: str, line: int, column: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise InputError(
            f"{path}:{line}: column {column} holds {text!r}, not a number; the file is "
            "damaged or not a KinectMultiTrack log"
        ) from None
    if not np.isfinite(v):
        raise InputError(f"{path}:{line}: column {column} is {text!r}; expected a finite number")
    return v


def read_kinect_multitrack(path: str | Path) -> MultitrackRecording:
    """Read a KinectMultiTrack CSV log into per-sensor streams.

    Parameters
    ----------
    path : str or Path
        A ``Study_*_Kinect_*.csv`` file.

    Returns
    -------
    MultitrackRecording
        ``streams``: per sensor, receive times (s), sensor times (s), ``(N, 25, 3)`` joints in
        metres in ``JOINTS`` order (kinefuse sensor axes), scenario per row.

    Raises
    ------
    InputError
        Missing file, empty file, missing columns (listed), a row of the wrong length or with a
        value that is not a number (with its line number), or mixed ``Kinect_Config`` values.
    """
    p = Path(path)
    name = str(p)
    if not p.is_file():
        raise InputError(f"{name}: no such file; give the path of a KinectMultiTrack CSV log")
    with p.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        try:
            header = [c.strip() for c in next(reader)]
        except StopIteration:
            raise InputError(f"{name}: the file is empty; expected a CSV header line") from None
        except csv.Error as e:
            raise InputError(f"{name}:1: not a readable CSV header ({e})") from None
        col = {c: i for i, c in enumerate(header)}
        joint_cols = [f"{j}_{a}" for j in JOINTS for a in "XYZ"]
        missing = [c for c in (*_META_COLUMNS, *joint_cols) if c not in col]
        if missing:
            raise InputError(
                f"{name}:1: not a KinectMultiTrack log; missing columns: {', '.join(missing)}"
            )
        jidx = np.array([col[c] for c in joint_cols])
        rows: list[list[str]] = []
        lines: list[int] = []
        try:
            for row in reader:
                if not row or all(not c.strip() for c in row):
                    continue
                if len(row) != len(header):
                    raise InputError(
                        f"{name}:{reader.line_num}: row has {len(row)} fields, the header has "
                        f"{len(header)}; the file is truncated or damaged"
                    )
                rows.append([c.strip() for c in row])
                lines.append(reader.line_num)
        except csv.Error as e:
            raise InputError(f"{name}:{reader.line_num}: unreadable CSV ({e})") from None
    if not rows:
        raise InputError(f"{name}: the header is there but there are no data rows")

    n = len(rows)
    joints = np.empty((n, N_JOINTS * 3))
    config = np.empty(n, dtype=np.int64)
    scenario = np.empty(n, dtype=np.int64)
    t_recv_ms = np.empty(n, dtype=np.int64)
    t_skel = np.empty(n)
    ids: list[str] = []
    opt = {c: np.full(n, np.nan) for c in _OPTIONAL_COLUMNS}
    for k, (row, line) in enumerate(zip(rows, lines, strict=True)):
        try:
            joints[k] = np.asarray([row[i] for i in jidx], dtype=np.float64)
        except ValueError:
            bad = [c for c, i in zip(joint_cols, jidx, strict=True) if not _is_float(row[i])]
            raise InputError(
                f"{name}:{line}: column {bad[0]} holds {row[col[bad[0]]]!r}, not a number; the "
                "file is damaged or not a KinectMultiTrack log"
            ) from None
        if not np.all(np.isfinite(joints[k])):
            raise InputError(f"{name}:{line}: a joint coordinate is not finite")
        config[k] = int(_number(row[col["Kinect_Config"]], name, line, "Kinect_Config"))
        scenario[k] = int(_number(row[col["Scenario_Id"]], name, line, "Scenario_Id"))
        t_recv_ms[k] = int(_number(row[col["Tracker_Time"]], name, line, "Tracker_Time"))
        t_skel[k] = _number(row[col["Skeleton_Time"]], name, line, "Skeleton_Time") * 1e-7
        sid = row[col["Kinect_Id"]]
        if not sid:
            raise InputError(f"{name}:{line}: empty Kinect_Id; every row must name its sensor")
        ids.append(sid)
        for c in _OPTIONAL_COLUMNS:
            if c in col and row[col[c]]:
                opt[c][k] = _number(row[col[c]], name, line, c)
    configs = np.unique(config)
    if configs.size != 1:
        raise InputError(
            f"{name}: mixed Kinect_Config values {configs.tolist()}; one log holds one layout"
        )
    joints = joints.reshape(n, N_JOINTS, 3) * _AXES
    epoch = int(t_recv_ms.min())
    id_arr = np.array(ids)
    order = list(dict.fromkeys(ids))
    streams = []
    for sid in order:
        m = id_arr == sid
        streams.append(
            MultitrackStream(
                sensor_id=sid,
                t_receive_s=(t_recv_ms[m] - epoch) * 1e-3,
                t_sensor_s=t_skel[m],
                joints_m=joints[m],
                scenario=scenario[m],
                init_angle_rad=_first(opt["Skeleton_Init_Angle"][m]),
                init_dist_m=_first(opt["Skeleton_Init_Dist"][m]),
                tilt_deg=_first(opt["Kinect_Tilt_Angle"][m]),
                height_m=_first(opt["Kinect_Height"][m]) * 0.01,
            )
        )
    return MultitrackRecording(
        path=name, kinect_config=int(configs[0]), t_receive_epoch_ms=epoch, streams=tuple(streams)
    )


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _first(values: Array) -> float:
    finite = values[np.isfinite(values)]
    return float(finite[0]) if finite.size else float("nan")
