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
    the tracked person, and the skeleton's index among the sensors watching them. The reader
    keeps every person: ``Person_Id`` is each row's body id (0 where the column is absent), and
    :func:`unique_frames` makes a sensor's bodies of one capture one frame (the shipped logs
    hold one person, id 0).
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
a rotation by 180 degrees about z) and the joint order to :data:`kinefuse.core.skeleton.JOINTS`.

What the rows mean, beyond their values: a row repeats a sensor's latest skeleton whenever another
sensor triggered the log line, and rows are logged out of capture order (:func:`unique_frames`
keeps each frame's first receipt, in capture order); which sensor's frame the joints were mapped
into (:func:`reference_sensor`); and KinectMultiTrack's mapping itself (:func:`kmt_rotation`),
from which each sensor's pose is reconstructed (:func:`sensor_poses`).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.geometry.transforms import make_transform
from kinefuse.core.inputs import check_text_file
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS, N_JOINTS, TrackingState
from kinefuse.errors import InputError

Array = NDArray[np.float64]

#: ``Kinect_Config`` codes of the shipped files: the sensor layout.
LAYOUT_NAMES = {0: "parallel", 1: "45 deg"}
#: Nominal angle between the two optical axes of each KinectMultiTrack layout, degrees.
LAYOUT_NOMINAL_DEG = {0: 0.0, 1: 45.0}
#: ``Scenario_Id`` codes: the task.
SCENARIO_NAMES = {1: "stand", 2: "steps", 3: "walk"}

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
class MultitrackSensor:
    """One sensor of a KinectMultiTrack log: its frames, and what the log says of the sensor.

    Attributes
    ----------
    frames : BodyFrames
        Its rows (file order from the reader; distinct frames in capture order after
        :func:`unique_frames`): ``t_device_s`` the sensor's own clock (``Skeleton_Time``),
        ``t_receive_server_s`` the receiving server's clock (``Tracker_Time``, seconds since the
        file's first row), joints in the reference sensor's frame (kinefuse sensor axes),
        metres, every joint TRACKED (the log has no tracking states); ``t_host_s`` unknown.
    scenario : (N,) int
        ``Scenario_Id`` of each frame.
    init_angle_rad, init_dist_m : float
        Body yaw relative to this sensor and its distance when tracking started (NaN if absent).
    tilt_deg, height_m : float
        The sensor's tilt and height as logged (NaN if absent).
    n_rows, n_duplicates, n_out_of_order : int
        Rows in the file, rows that repeated an already-logged frame, and frames logged after a
        frame captured later (0 until :func:`unique_frames` counts them).
    bodies : BodyFrames or None
        After :func:`unique_frames`, the all-bodies form when the sensor logged several persons
        at one capture (``frames`` is then its first bodies); None when it is ``frames`` itself.
    """

    frames: BodyFrames
    scenario: NDArray[np.int64]
    init_angle_rad: float
    init_dist_m: float
    tilt_deg: float
    height_m: float
    n_rows: int
    n_duplicates: int = 0
    n_out_of_order: int = 0
    bodies: BodyFrames | None = None

    @property
    def every_body(self) -> BodyFrames:
        """Every body of each frame (the all-bodies form; ``frames`` for a one-person log)."""
        return self.frames if self.bodies is None else self.bodies

    @property
    def sensor_id(self) -> str:
        return self.frames.sensor_id

    @property
    def n_frames(self) -> int:
        return self.frames.n_frames

    @property
    def t_sensor_s(self) -> Array:
        """``(N,)`` the sensor's clock, seconds (``frames.t_device_s``)."""
        return self.frames.t_device_s

    @property
    def t_receive_s(self) -> Array:
        """``(N,)`` the server's receive time, seconds since the file's first row."""
        return self.frames.t_receive_server_s

    @property
    def joints_m(self) -> Array:
        """``(N, 25, 3)`` joints as logged (``frames.joints_m``), metres."""
        return self.frames.joints_m


def multitrack_sensor(
    sensor_id: str,
    t_receive_s: Array,
    t_sensor_s: Array,
    joints_m: Array,
    scenario: NDArray[np.int64],
    *,
    init_angle_rad: float = float("nan"),
    init_dist_m: float = float("nan"),
    tilt_deg: float = float("nan"),
    height_m: float = float("nan"),
    person: NDArray[np.int64] | None = None,
) -> MultitrackSensor:
    """A sensor's logged rows ``(N,)`` times, ``(N, 25, 3)`` joints as a :class:`MultitrackSensor`
    (sequence numbers are the row order; present joints TRACKED, NaN ones NOT_TRACKED;
    ``person`` ``(N,)`` each row's ``Person_Id``, its body id, default 0)."""
    j = np.asarray(joints_m, dtype=np.float64)
    present = np.isfinite(j).all(-1)
    n = j.shape[0]
    frames = BodyFrames(
        sensor_id=sensor_id,
        seq=np.arange(n, dtype=np.int64),
        t_device_s=t_sensor_s,
        t_host_s=np.full(n, np.nan),  # unknown
        joints_m=j,
        states=np.where(present, TrackingState.TRACKED, TrackingState.NOT_TRACKED),
        t_receive_server_s=t_receive_s,
        body_id=np.zeros(n, dtype=np.int64) if person is None else person,
    )
    return MultitrackSensor(
        frames=frames,
        scenario=np.asarray(scenario, dtype=np.int64),
        init_angle_rad=init_angle_rad,
        init_dist_m=init_dist_m,
        tilt_deg=tilt_deg,
        height_m=height_m,
        n_rows=n,
    )


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
    streams : tuple of MultitrackSensor
        One per sensor, in order of first appearance.
    """

    path: str
    kinect_config: int
    t_receive_epoch_ms: int
    streams: tuple[MultitrackSensor, ...]

    def stream(self, sensor_id: str) -> MultitrackSensor:
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
    check_text_file(p, what="KinectMultiTrack CSV log")
    with p.open(newline="", encoding="utf-8-sig", errors="replace") as fh:
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
    person = np.zeros(n, dtype=np.int64)
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
        if "Person_Id" in col and row[col["Person_Id"]]:
            pid = _number(row[col["Person_Id"]], name, line, "Person_Id")
            if pid < 0 or pid != int(pid):
                raise InputError(
                    f"{name}:{line}: Person_Id {pid:g} is not a person index (0, 1, ...)"
                )
            person[k] = int(pid)
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
            multitrack_sensor(
                sid,
                (t_recv_ms[m] - epoch) * 1e-3,
                t_skel[m],
                joints[m],
                scenario[m],
                init_angle_rad=_first(opt["Skeleton_Init_Angle"][m]),
                init_dist_m=_first(opt["Skeleton_Init_Dist"][m]),
                tilt_deg=_first(opt["Kinect_Tilt_Angle"][m]),
                height_m=_first(opt["Kinect_Height"][m]) * 0.01,
                person=person[m],
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


# --------------------------------------------------------------------------------------------
# what a log's rows mean: distinct frames, the reference sensor, KinectMultiTrack's mapping
# --------------------------------------------------------------------------------------------


def unique_frames(stream: MultitrackSensor) -> MultitrackSensor:
    """Reduce a logged stream to its distinct frames (first receipt of each), in capture order,
    counting the rows that repeated a frame and the frames logged out of order.

    A frame is a capture (``Skeleton_Time``); its bodies are its persons (``Person_Id``), the
    first received first, all under the seq of the frame's first receipt. ``frames`` is the
    first body of each (a one-person log: every frame, as always); when some capture has several
    persons, ``bodies`` holds them all (the all-bodies form).
    """
    ticks = np.round(stream.t_sensor_s * 1e7).astype(np.int64)
    person = stream.frames.body_id
    order = np.lexsort((stream.t_receive_s, person, ticks))
    first = np.ones(order.size, dtype=bool)
    first[1:] = (np.diff(ticks[order]) != 0) | (np.diff(person[order]) != 0)
    kept = order[first]  # the first receipt of each (capture, person)
    frame_first = np.ones(kept.size, dtype=bool)
    frame_first[1:] = np.diff(ticks[kept]) != 0
    # a capture's bodies in order of receipt, the first received first
    group = np.cumsum(frame_first) - 1
    kept = kept[np.lexsort((kept, group))]
    keep = kept[frame_first]  # the first body of each capture
    if keep.size == kept.size:
        bodies = None
    else:
        start = np.flatnonzero(frame_first)
        lead = np.repeat(kept[start], np.diff(np.append(start, kept.size)))
        every = stream.frames.take(kept)
        bodies = replace(
            every,
            seq=stream.frames.seq[lead],
            t_device_s=stream.frames.t_device_s[lead],
            t_receive_server_s=stream.frames.t_receive_server_s[lead],
        )
    # out of order: a first appearance logged after the first appearance of a later frame
    row_first = np.sort(keep)
    later = np.maximum.accumulate(ticks[row_first])
    ooo = int((ticks[row_first][1:] < later[:-1]).sum())
    return replace(
        stream,
        frames=stream.frames.take(keep),
        scenario=stream.scenario[keep],
        n_rows=stream.n_rows,
        n_duplicates=int(stream.n_frames - kept.size),
        n_out_of_order=ooo,
        bodies=bodies,
    )


def _facing_yaw_kinect(p_sensor: Array) -> Array:
    """KinectMultiTrack's body yaw ``(N,)`` from the shoulders, in Kinect camera axes, radians.

    ``atan2(SR.Z - SL.Z, SR.X - SL.X)`` with Kinect ``X = -x`` of kinefuse axes.
    """
    d = p_sensor[:, JOINT_INDEX["ShoulderRight"]] - p_sensor[:, JOINT_INDEX["ShoulderLeft"]]
    return np.arctan2(d[:, 2], -d[:, 0])


def kmt_rotation(delta_rad: float) -> Array:
    """KinectMultiTrack's sensor-to-reference rotation for a yaw difference, kinefuse axes.

    KinectMultiTrack maps a sensor's point ``p_i`` into the reference's frame as
    ``c_ref + M (p_i - c_i)`` with ``M`` a rotation about the vertical camera axis by the
    difference of the body's initial yaws ``delta = a_i - a_ref`` (``X' = X cos + Z sin``,
    ``Z' = Z cos - X sin`` in Kinect axes). In kinefuse axes (``x = -X``)::

        M = [[cos d, 0, -sin d], [0, 1, 0], [sin d, 0, cos d]]

    Returns
    -------
    (3, 3) float
    """
    c, s = math.cos(delta_rad), math.sin(delta_rad)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def sensor_poses(
    *,
    c_ref: Array,
    delta_rad: float,
    other_init_dist_m: float,
    ref2world: Array,
    correction: Array,
    other_offaxis_deg: float = 0.0,
    height_difference_m: float = 0.0,
) -> tuple[Array, Array]:
    """The other sensor's pose: ``other2ref`` (4, 4) and its mapping offset ``o_kmt`` (3,).

    KinectMultiTrack's mapping is ``p_ref = c_ref + M (p_i - c_i)`` (:func:`kmt_rotation`), so
    the other sensor's optical centre (``p_i = 0``) sits at ``o = c_ref - M c_i`` in the mapped
    frame, and ``other2ref = correction @ [M | o]``. ``c_i``, the body's initial centre in the
    other sensor's own frame, is only partly logged: its depth is ``Skeleton_Init_Dist``; its
    lateral coordinate is ``depth * tan(other_offaxis_deg)`` (an assumption: the sensor was aimed
    at the person, default 0); its vertical coordinate is solved so that the sensor's height
    above the floor equals the reference's plus ``height_difference_m`` (the logged heights).

    Parameters
    ----------
    c_ref : (3,) float
        The body's initial centre in the reference's frame, metres.
    delta_rad : float
        ``a_other - a_ref``, the difference of the logged initial yaws, radians.
    other_init_dist_m : float
    ref2world : (4, 4) float
    correction : (4, 4) float
        The rigid re-registration (identity: KinectMultiTrack's mapping as logged).

    Returns
    -------
    other2ref : (4, 4) float
    o_kmt : (3,) float
        The other sensor's centre in KinectMultiTrack's mapped frame (before ``correction``).
    """
    m = kmt_rotation(delta_rad)
    z_i = other_init_dist_m
    x_i = z_i * math.tan(math.radians(other_offaxis_deg))

    def centre_world(y_i: float) -> Array:
        o = c_ref - m @ np.array([x_i, y_i, z_i])
        o_ref = correction[:3, :3] @ o + correction[:3, 3]
        return np.asarray(ref2world[:3, :3] @ o_ref + ref2world[:3, 3])

    target = float(ref2world[2, 3]) + height_difference_m
    h0, h1 = centre_world(0.0)[2], centre_world(1.0)[2]
    # the sensor's vertical axis is never horizontal in practice; if it were, keep c_ref's height
    y_i = (target - h0) / (h1 - h0) if abs(h1 - h0) > 1e-6 else float(c_ref[1])
    o_kmt = c_ref - m @ np.array([x_i, y_i, z_i])
    return correction @ make_transform(m, o_kmt), o_kmt


def _skeleton_ids(path: Path) -> dict[str, set[int]]:
    """``Kinect_Id -> {Skeleton_Id}`` from the log (empty if the column is absent)."""
    out: dict[str, set[int]] = {}
    with path.open(newline="", encoding="utf-8-sig", errors="replace") as fh:
        reader = csv.reader(fh)
        header = [c.strip() for c in next(reader)]
        if "Skeleton_Id" not in header or "Kinect_Id" not in header:
            return out
        ik, isk = header.index("Kinect_Id"), header.index("Skeleton_Id")
        for row in reader:
            if len(row) > max(ik, isk):
                try:
                    out.setdefault(row[ik].strip(), set()).add(int(float(row[isk])))
                except ValueError:
                    continue
    return out


def reference_sensor(path: str | Path, rec: MultitrackRecording) -> tuple[str, str]:
    """The sensor whose frame KinectMultiTrack mapped everything into, and how it was found.

    KinectMultiTrack's logger maps every skeleton into the frame of the person's *local*
    skeleton (a sensor at ``127.0.0.1``) or else of the first one (``Skeleton_Id`` 0). Without a
    usable ``Skeleton_Id`` column, the reference is the sensor whose logged initial yaw matches
    the yaw of the logged (mapped) bodies at the start of the file, which is the reference's.

    Returns
    -------
    sensor_id : str
    how : str
        ``"local"``, ``"skeleton_id"`` or ``"yaw"``.
    """
    ids = [s.sensor_id for s in rec.streams]
    if "127.0.0.1" in ids:
        return "127.0.0.1", "local"
    sk = _skeleton_ids(Path(path))
    zero = [k for k in ids if sk.get(k) == {0}]
    if len(zero) == 1:
        return zero[0], "skeleton_id"
    first = rec.streams[0]
    yaw = float(np.median(_facing_yaw_kinect(first.joints_m[: min(30, first.n_frames)])))
    errs = [abs(math.remainder(yaw - s.init_angle_rad, 2 * math.pi)) for s in rec.streams]
    if not all(math.isfinite(e) for e in errs):
        raise InputError(
            f"{path}: cannot tell the reference sensor: no usable Skeleton_Id column and no "
            "Skeleton_Init_Angle; the log lacks the columns KinectMultiTrack writes"
        )
    return ids[int(np.argmin(errs))], "yaw"
