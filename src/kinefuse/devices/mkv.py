"""An Azure Kinect recording (k4arecorder's Matroska file) read with PyAV, without libk4a.

k4arecorder writes one track per stream, named by its title and a ``K4A_*_TRACK`` tag: ``COLOR``
(MJPG, NV12, YUY2 or BGRA), ``DEPTH`` and ``IR`` (16-bit big-endian images), ``IMU`` (a block of
40 bytes per sample: accelerometer time (ns, device clock), 3 float32 m/s², gyroscope time,
3 float32 rad/s), and the device's factory calibration as the ``calibration.json`` attachment.
A block's timestamp is the device timestamp minus ``K4A_START_OFFSET_NS`` (a container tag);
the device time of an image is therefore its timestamp plus that offset, on the same clock as
the IMU samples' own stamps. The file format is Microsoft's (docs "Azure Kinect Matroska
format").
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.k4a_calibration import DEPTH_MODES, calibration_from_k4a_json
from kinefuse.errors import InputError

__all__ = ["MkvRecording", "open_mkv", "read_imu_block"]

_IMU = struct.Struct("<Q3fQ3f")

#: the Matroska element ids this module reads to check a file is whole
_EBML_ID = b"\x1a\x45\xdf\xa3"
_SEGMENT_ID = b"\x18\x53\x80\x67"


def read_imu_block(data: bytes) -> NDArray[np.float64]:
    """The IMU samples of one ``IMU`` block: ``(N, 7)`` rows ``t_device_s, ax, ay, az, gx, gy,
    gz`` (the accelerometer's time; the gyroscope is sampled at the same instant)."""
    n = len(data) // _IMU.size
    rows = [_IMU.unpack_from(data, k * _IMU.size) for k in range(n)]
    out = np.array([(r[0] * 1e-9, *r[1:4], *r[5:8]) for r in rows], dtype=np.float64)
    return out.reshape(n, 7)


def _vint(buf: bytes, i: int) -> tuple[int, int]:
    """An EBML variable-size integer at ``buf[i]``: (value, length); value -1 = unknown."""
    first = buf[i]
    length = 1
    while length <= 8 and not first & (0x80 >> (length - 1)):
        length += 1
    if length > 8 or i + length > len(buf):
        raise ValueError("bad EBML size")
    value = first & (0xFF >> length)
    for b in buf[i + 1 : i + length]:
        value = (value << 8) | b
    if value == (1 << (7 * length)) - 1:
        return -1, length
    return value, length


def _check_whole(path: Path) -> None:
    """Refuse a Matroska file shorter than its Segment says (a copy or a recording cut off)."""
    size = path.stat().st_size
    with path.open("rb") as f:
        head = f.read(64)
    if head[:4] != _EBML_ID:
        raise InputError(
            f"{path}: not a Matroska file (an Azure Kinect recording is the .mkv k4arecorder "
            "writes)"
        )
    try:
        n, ln = _vint(head, 4)
        i = 4 + ln + n
        if head[i : i + 4] != _SEGMENT_ID:
            return
        seg, ln = _vint(head, i + 4)
    except (ValueError, IndexError):
        return
    end = i + 4 + ln + seg
    if seg >= 0 and end > size:
        raise InputError(
            f"{path}: truncated: the file has {size} bytes, its Matroska segment says {end}; "
            "copy the recording again (or, if the recorder was stopped abruptly, record again)"
        )


def _wall_seconds(iso: str) -> float:
    """The container's ``creation_time`` (UTC, whole seconds in k4arecorder's files) as Unix
    seconds; NaN if absent."""
    import datetime as dt

    try:
        return dt.datetime.fromisoformat(iso.replace("Z", "+00:00")).timestamp()
    except ValueError:
        return math.nan


class MkvRecording:
    """An Azure Kinect recording, captures in file order (a *camera* of :mod:`.sources`).

    Parameters
    ----------
    path : str or Path
        The ``.mkv`` k4arecorder (or pyk4a, or the Orbbec K4A wrapper's recorder) wrote.

    Attributes
    ----------
    calibration : CameraCalibration
        From the ``calibration.json`` attachment, for the recorded depth mode and colour
        resolution.
    depth_mode, color_mode : str
        The recorded modes (``NFOV_UNBINNED``; ``MJPG_720P``), "" where the stream is off.
    serial : str
        The device's serial number.
    start_offset_s : float
        ``K4A_START_OFFSET_NS`` in seconds: a block's timestamp + this = device time.
    rate_hz : float
        The capture rate (the image blocks' duration).
    sync_mode : str
        ``K4A_WIRED_SYNC_MODE``: ``STANDALONE``, ``MASTER`` or ``SUBORDINATE`` (devices on a sync
        cable share one device clock).
    start_wall_s : float
        When the recording started on the recording PC's wall clock (the container's
        ``creation_time``, to the second), Unix seconds; NaN if absent.
    live : bool
        False: a recording is played on its own timestamps.
    repeat : int
        How many times :meth:`captures` plays the recording (1; the ``repeat`` option: a
        short recording played on for a demonstration or a soak test of a live server).
    """

    live = False

    def __init__(self, path: str | Path, repeat: int = 1) -> None:
        import av

        p = Path(path)
        if not p.is_file():
            raise InputError(f"{p}: no such file (an Azure Kinect recording, .mkv)")
        _check_whole(p)
        try:
            container = av.open(str(p), "r")
        except (av.error.FFmpegError, OSError) as e:
            raise InputError(f"{p}: cannot read it as Matroska ({e})") from None
        try:
            self._read_header(p, container)
        finally:
            container.close()
        self.path = p
        self.repeat = int(repeat)
        #: the sensor id a client gives it unless told (the file's name)
        self.default_id = p.stem

    def _read_header(self, p: Path, container: Any) -> None:
        meta = dict(container.metadata)
        tracks: dict[str, int] = {}
        modes: dict[str, str] = {}
        calib: bytes | None = None
        for s in container.streams:
            m = dict(s.metadata)
            if s.type == "attachment":
                if m.get("filename") == "calibration.json" or "K4A_CALIBRATION_FILE" in m:
                    calib = bytes(s.data or b"")
                continue
            for name in ("COLOR", "DEPTH", "IR", "IMU"):
                if f"K4A_{name}_TRACK" in m:
                    tracks[name] = s.index
                    modes[name] = str(m.get(f"K4A_{name}_MODE", ""))
        if "DEPTH" not in tracks and "COLOR" not in tracks:
            raise InputError(
                f"{p}: not an Azure Kinect recording (no K4A_DEPTH_TRACK or K4A_COLOR_TRACK "
                "track); record with k4arecorder, or open other cameras' files with their source"
            )
        if not calib:
            raise InputError(
                f"{p}: the recording has no calibration.json attachment; it cannot be used "
                "without the device's calibration"
            )
        self.depth_mode = modes.get("DEPTH", "")
        self.color_mode = modes.get("COLOR", "")
        if self.depth_mode and self.depth_mode not in DEPTH_MODES:
            raise InputError(f"{p}: unknown depth mode {self.depth_mode!r}")
        color_res = self.color_mode.rpartition("_")[2] or None
        self.calibration: CameraCalibration = calibration_from_k4a_json(
            calib,
            self.depth_mode or "NFOV_UNBINNED",
            color_res,
            what=f"{p} (calibration.json attachment)",
        )
        try:
            self.start_offset_s = int(meta.get("K4A_START_OFFSET_NS", "0")) * 1e-9
        except ValueError:
            raise InputError(f"{p}: K4A_START_OFFSET_NS is not an integer") from None
        self.serial = str(meta.get("K4A_DEVICE_SERIAL_NUMBER", ""))
        self.sync_mode = str(meta.get("K4A_WIRED_SYNC_MODE", "STANDALONE"))
        self.start_wall_s = _wall_seconds(str(meta.get("creation_time", "")))
        self._tracks = tracks
        self._time_base = {i: float(container.streams[i].time_base) for i in tracks.values()}
        self.rate_hz = 30.0  # k4arecorder's default, unless an image block says otherwise
        video = [container.streams[tracks[n]] for n in ("DEPTH", "COLOR", "IR") if n in tracks]
        for packet in container.demux(video):
            if packet.duration and packet.pts is not None:
                self.rate_hz = 1.0 / (packet.duration * float(packet.stream.time_base))
                break

    @property
    def streams(self) -> tuple[str, ...]:
        """The recorded streams among ``COLOR``, ``DEPTH``, ``IR``, ``IMU``."""
        return tuple(n for n in ("COLOR", "DEPTH", "IR", "IMU") if n in self._tracks)

    def captures(self) -> Iterator[Capture]:
        """The captures in file order: images with the same timestamp (within half a frame)
        form one capture; IMU samples go with the next capture. With :attr:`repeat` above 1
        the recording is played that many times over, its device times (and the IMU's) going
        on by the recording's length plus one frame each pass, its counter going on too."""
        seq = 0
        shift = 0.0
        for _ in range(self.repeat):
            first = last = math.nan
            for cap in self._one_pass():
                first = cap.t_device_s if math.isnan(first) else first
                last = cap.t_device_s
                imu = cap.imu
                if imu is not None and shift:
                    imu = imu.copy()
                    imu[:, 0] += shift
                yield replace(cap, seq=seq, t_device_s=cap.t_device_s + shift, imu=imu)
                seq += 1
            if math.isnan(first):
                return
            shift += last - first + 1.0 / self.rate_hz

    def _one_pass(self) -> Iterator[Capture]:
        import av

        by_index = {i: n for n, i in self._tracks.items()}
        container = av.open(str(self.path), "r")
        try:
            current: dict[str, Any] = {}
            t_cur = math.nan
            imu: list[NDArray[np.float64]] = []
            seq = 0
            half = 0.5 / self.rate_hz
            for packet in container.demux():
                name = by_index.get(packet.stream.index)
                if name is None or packet.pts is None or packet.size == 0:
                    continue
                if name == "IMU":
                    imu.append(read_imu_block(bytes(packet)))
                    continue
                t = packet.pts * self._time_base[packet.stream.index] + self.start_offset_s
                if current and (name in current or abs(t - t_cur) > half):
                    yield self._capture(seq, t_cur, current, imu)
                    seq, current, imu = seq + 1, {}, []
                if not current:
                    t_cur = t
                current[name] = self._decode(packet, name)
            if current:
                yield self._capture(seq, t_cur, current, imu)
        except av.error.FFmpegError as e:
            raise InputError(f"{self.path}: cannot decode it ({e}); the file is damaged") from None
        finally:
            container.close()

    def _decode(self, packet: Any, name: str) -> NDArray[Any]:
        frames = packet.decode()
        if not frames:
            raise InputError(f"{self.path}: a {name} image at {packet.pts} us does not decode")
        if name == "COLOR":
            return np.asarray(frames[0].to_ndarray(format="rgb24"), dtype=np.uint8)
        img = np.asarray(frames[0].to_ndarray(), dtype=np.uint16)
        d = self.calibration.depth
        if img.shape != (d.height, d.width):
            raise InputError(
                f"{self.path}: a {name} image is {img.shape[1]}x{img.shape[0]}, the depth mode "
                f"{self.depth_mode} gives {d.width}x{d.height}"
            )
        return img

    @staticmethod
    def _capture(
        seq: int, t: float, images: dict[str, Any], imu: list[NDArray[np.float64]]
    ) -> Capture:
        return Capture(
            seq=seq,
            t_device_s=t,
            depth_mm=images.get("DEPTH"),
            color=images.get("COLOR"),
            ir=images.get("IR"),
            imu=np.concatenate(imu) if imu else None,
        )

    def close(self) -> None:
        """Nothing held between passes (each :meth:`captures` opens the file)."""


def open_mkv(arg: str, options: dict[str, str]) -> MkvRecording:
    """The ``mkv`` camera kind: ``mkv:FILE.mkv[?repeat=N]`` (``repeat``: play it N times)."""
    extra = sorted(set(options) - {"repeat"})
    if extra:
        raise InputError(f"mkv:{arg}: takes only ?repeat=N (got {', '.join(extra)})")
    text = options.get("repeat", "1")
    if not text.isdigit() or int(text) < 1:
        raise InputError(f"mkv:{arg}: repeat must be a whole number of passes >= 1, got {text!r}")
    if not arg:
        raise InputError("mkv: name the recording, mkv:FILE.mkv")
    try:
        import av  # noqa: F401
    except ImportError:
        raise InputError(
            "reading an Azure Kinect recording needs PyAV: pip install 'kinefuse[mkv]'"
        ) from None
    return MkvRecording(arg, int(text))
