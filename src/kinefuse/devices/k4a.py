"""A live Azure Kinect DK (or an Orbbec Femto through Orbbec's K4A wrapper) with pyk4a.

``k4a:[INDEX|SERIAL][?depth_mode=NFOV_UNBINNED&fps=30&color=720P]``: the device at that index
(default 0) or with that serial number, in that depth mode (the k4a names without
``K4A_DEPTH_MODE_``), frame rate (5, 15, 30) and colour resolution (``720P`` ... ``3072P``, or
``OFF``). The calibration is the device's own (its raw calibration JSON, converted for the
mode as libk4a does: :mod:`kinefuse.devices.k4a_calibration`); captures carry the device
timestamps of the depth image and the IMU samples read since the previous capture.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np

from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.k4a_calibration import COLOR_MODES, DEPTH_MODES, calibration_from_k4a_json
from kinefuse.errors import InputError

__all__ = ["K4ACamera", "import_pyk4a", "open_k4a"]

_RATES = (5, 15, 30)


def import_pyk4a() -> Any:
    """pyk4a, or one line saying what to install (and why an installed one does not load)."""
    try:
        import pyk4a
    except ImportError as e:
        if e.name == "pyk4a":  # not installed
            raise InputError(
                "the k4a source needs pyk4a and the Azure Kinect SDK: pip install "
                "'kinefuse[k4a]' (docs/devices.md, Azure Kinect)"
            ) from None
        raise InputError(
            f"pyk4a is installed but does not load ({str(e).splitlines()[0]}); the pyk4a-bundle "
            "wheel is built against numpy 1.x: pip install 'numpy<2' (docs/devices.md, Azure "
            "Kinect)"
        ) from None
    return pyk4a


class K4ACamera:
    """One started Azure Kinect (see the module notes for the options)."""

    live = True

    def __init__(self, arg: str, options: dict[str, str]) -> None:
        known = {"depth_mode", "fps", "color"}
        bad = sorted(set(options) - known)
        if bad:
            raise InputError(f"k4a: unknown option(s) {', '.join(bad)}; it takes {sorted(known)}")
        depth_mode = options.get("depth_mode", "NFOV_UNBINNED").upper()
        color = options.get("color", "720P").upper()
        if depth_mode not in DEPTH_MODES:
            raise InputError(f"k4a: depth_mode must be one of {', '.join(DEPTH_MODES)}")
        if color != "OFF" and color not in COLOR_MODES:
            raise InputError(f"k4a: color must be OFF or one of {', '.join(COLOR_MODES)}")
        try:
            fps = int(options.get("fps", "30"))
        except ValueError:
            fps = -1
        if fps not in _RATES or (fps == 30 and (depth_mode == "WFOV_UNBINNED" or color == "3072P")):
            raise InputError(
                "k4a: fps must be 5, 15 or 30 (WFOV_UNBINNED and 3072P run at 15 at most)"
            )
        pyk4a = import_pyk4a()
        n = int(pyk4a.connected_device_count())
        if n == 0:
            raise InputError(
                "k4a: no Azure Kinect or Femto is connected (check the USB 3 cable and the power "
                "supply; `k4aviewer` should see it)"
            )
        index = self._index(pyk4a, arg, n)
        config = pyk4a.Config(
            color_resolution=getattr(pyk4a.ColorResolution, f"RES_{color}")
            if color != "OFF"
            else pyk4a.ColorResolution.OFF,
            color_format=pyk4a.ImageFormat.COLOR_BGRA32,
            depth_mode=getattr(pyk4a.DepthMode, depth_mode),
            camera_fps=getattr(pyk4a.FPS, f"FPS_{fps}"),
            synchronized_images_only=color != "OFF",
        )
        self._dev = pyk4a.PyK4A(config=config, device_id=index)
        try:
            self._dev.start()
        except pyk4a.K4AException as e:
            raise InputError(f"k4a: device {index} does not start ({e})") from None
        self.serial = str(self._dev.serial)
        self.default_id = f"k4a-{self.serial}"
        self.rate_hz = float(fps)
        self.calibration: CameraCalibration = calibration_from_k4a_json(
            self._dev.calibration_raw,
            depth_mode,
            None if color == "OFF" else color,
            what=f"k4a device {self.serial}",
        )
        self._pyk4a = pyk4a

    @staticmethod
    def _index(pyk4a: Any, arg: str, n: int) -> int:
        if arg == "":
            return 0
        if arg.isdigit() and int(arg) < n and len(arg) < 4:
            return int(arg)
        for i in range(n):  # a serial number: open each device to read its own
            dev = pyk4a.PyK4A(device_id=i)
            try:
                dev.open()
                serial = str(dev.serial)
            finally:
                dev.close()
            if serial == arg:
                return i
        raise InputError(f"k4a: no connected device has index or serial {arg!r} ({n} connected)")

    def _imu(self) -> np.ndarray | None:
        rows = []
        while True:
            try:
                s = self._dev.get_imu_sample(timeout=0)
            except (self._pyk4a.K4ATimeoutException, self._pyk4a.K4AException):
                break
            if not s:
                break
            rows.append((s["acc_timestamp"] * 1e-6, *s["acc_sample"], *s["gyro_sample"]))
        return np.asarray(rows, dtype=np.float64).reshape(-1, 7) if rows else None

    def captures(self) -> Iterator[Capture]:
        """Captures as the device delivers them, stamped on arrival with this PC's clock."""
        seq = 0
        while True:
            try:
                cap = self._dev.get_capture(timeout=2000)
            except self._pyk4a.K4ATimeoutException:
                raise InputError(
                    f"k4a {self.serial}: no capture for 2 s (unplugged, or another program has "
                    "the camera)"
                ) from None
            t_host = time.monotonic()
            depth = cap.depth
            color = cap.color
            yield Capture(
                seq=seq,
                t_device_s=(cap.depth_timestamp_usec if depth is not None else
                            cap.color_timestamp_usec) * 1e-6,
                t_host_s=t_host,
                depth_mm=None if depth is None else np.asarray(depth, dtype=np.uint16),
                color=None if color is None else np.ascontiguousarray(color[..., 2::-1]),
                ir=None if cap.ir is None else np.asarray(cap.ir, dtype=np.uint16),
                imu=self._imu(),
            )  # fmt: skip
            seq += 1

    def close(self) -> None:
        self._dev.stop()


def open_k4a(arg: str, options: dict[str, str]) -> K4ACamera:
    """The ``k4a`` camera kind."""
    return K4ACamera(arg, options)
