"""TrackerWorker: a tracker slower than the camera never builds a queue; the oldest capture is
dropped, the newest tracked, the achieved rate reported."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.trackers import TrackerResult
from kinefuse.devices.worker import TrackerWorker

CAL = CameraCalibration(depth=Intrinsics())


class SlowTracker:
    """A deliberately slow tracker: ``delay_s`` per capture, remembering what it saw and the
    most captures ever waiting in the worker's queue."""

    name = "slow"

    def __init__(self, delay_s: float, fail_on: int = -1) -> None:
        self.delay_s, self.fail_on = delay_s, fail_on
        self.seen: list[int] = []
        self.gate = threading.Event()
        self.gate.set()

    def track(self, capture: Capture, calibration: CameraCalibration) -> TrackerResult:
        self.gate.wait()
        time.sleep(self.delay_s)
        self.seen.append(capture.seq)
        if capture.seq == self.fail_on:
            raise RuntimeError("bad frame")
        return TrackerResult(refused=(f"frame {capture.seq} refused",))

    def close(self) -> None:
        pass


def _cap(i: int) -> Capture:
    return Capture(seq=i, t_device_s=i / 30.0, depth_mm=np.zeros((4, 4), np.uint16))


def test_a_slow_tracker_gets_the_newest_frames_and_the_queue_stays_bounded() -> None:
    tracker = SlowTracker(0.0)
    tracker.gate.clear()  # the tracker is stuck on its first capture
    with TrackerWorker(tracker, CAL, max_pending=2) as worker:
        accepted = [worker.submit(_cap(i)) for i in range(40)]
        status = worker.status()
        assert status.submitted == 40
        # one capture in the tracker, two waiting: every other one was dropped, oldest first
        assert status.dropped >= 40 - 3
        assert accepted[:2] == [True, True] and not any(accepted[3:])
        tracker.gate.set()
        assert worker.drain(timeout=10.0)
        status = worker.status()
    assert tracker.seen[-2:] == [38, 39]  # the two newest were kept
    assert len(tracker.seen) <= 3
    assert status.tracked == len(tracker.seen)
    assert status.dropped + status.tracked == 40


def test_the_achieved_rate_and_the_last_refusal_are_reported() -> None:
    tracker = SlowTracker(0.02)  # at most 50 Hz
    with TrackerWorker(tracker, CAL, max_pending=1) as worker:
        for i in range(30):  # a 100 Hz camera
            worker.submit(_cap(i))
            time.sleep(0.01)
        assert worker.drain(timeout=10.0)
        status = worker.status()
        got = [worker.get(timeout=1.0) for _ in range(status.tracked)]
    assert status.dropped > 0
    assert 0 < status.rate_hz < 60  # measured, and no faster than the tracker can go
    assert status.last_refused == f"frame {tracker.seen[-1]} refused"
    assert [c.seq for c, _ in got if c is not None] == tracker.seen
    assert "Hz" in status.line() and "dropped" in status.line()


def test_a_tracker_error_is_counted_and_tracking_goes_on() -> None:
    tracker = SlowTracker(0.0, fail_on=1)
    seen = []
    with TrackerWorker(tracker, CAL, max_pending=8, on_result=lambda c, r: seen.append(c.seq)) as w:
        for i in range(4):
            w.submit(_cap(i))
        assert w.drain(timeout=10.0)
        status = w.status()
    assert status.errors == 1 and "bad frame" in status.last_error
    assert seen == [0, 2, 3] and status.tracked == 3


def test_bounds_must_be_positive() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        TrackerWorker(SlowTracker(0.0), CAL, max_pending=0)
