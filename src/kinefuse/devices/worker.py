"""Running a tracker on its own thread without falling behind the camera.

A camera delivers captures at its rate whether the tracker keeps up or not. :class:`TrackerWorker`
holds at most ``max_pending`` captures; when a new one arrives and the queue is full, the
*oldest* waiting capture is dropped (the newest is what the live view needs), and counted. The
tracker runs on the worker's thread, one capture at a time, in capture order; its results go
to a bounded output queue (oldest dropped too, counted) or to a callback. :meth:`status` gives
the achieved rate over the last few seconds, the drops, and the last refusal, for the sensor's
status line and the viewer.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.trackers import Tracker, TrackerResult

__all__ = ["TrackerStatus", "TrackerWorker"]


@dataclass(frozen=True)
class TrackerStatus:
    """What the worker has done so far.

    Attributes
    ----------
    submitted, tracked, dropped : int
        Captures handed in, tracked, and dropped unseen because the tracker was behind.
    results_dropped : int
        Results dropped because nobody took them from the output queue.
    errors : int
        Captures on which the tracker raised (the message is in ``last_error``).
    rate_hz : float
        Captures tracked per second over the last ``window_s`` (NaN before two).
    last_refused : str
        The tracker's last refusal ("" if none yet).
    last_error : str
    """

    submitted: int
    tracked: int
    dropped: int
    results_dropped: int
    errors: int
    rate_hz: float
    last_refused: str
    last_error: str

    def line(self) -> str:
        """One line for a status display."""
        rate = "-" if self.rate_hz != self.rate_hz else f"{self.rate_hz:.1f} Hz"
        text = f"tracker {rate}, {self.tracked} tracked, {self.dropped} dropped (behind)"
        if self.last_refused:
            text += f"; refused: {self.last_refused}"
        if self.last_error:
            text += f"; error: {self.last_error}"
        return text


class TrackerWorker:
    """A tracker on its own thread, fed through a bounded queue that drops the oldest capture.

    Parameters
    ----------
    tracker : Tracker
        Called as ``tracker.track(capture, calibration)`` on the worker's thread only.
    calibration : CameraCalibration
    max_pending : int
        Captures waiting at most (>= 1).
    max_results : int
        Results kept for :meth:`get` at most (>= 1); ignored with ``on_result``.
    on_result : callable, optional
        ``on_result(capture, result)`` on the worker's thread instead of the output queue.
    window_s : float
        Span of the achieved-rate estimate, seconds.
    """

    def __init__(
        self,
        tracker: Tracker,
        calibration: CameraCalibration,
        *,
        max_pending: int = 2,
        max_results: int = 64,
        on_result: Callable[[Capture, TrackerResult], None] | None = None,
        window_s: float = 2.0,
    ) -> None:
        if max_pending < 1 or max_results < 1:
            raise ValueError("max_pending and max_results must be at least 1")
        self.tracker, self.calibration = tracker, calibration
        self._pending: deque[Capture] = deque()
        self._max_pending = int(max_pending)
        self._results: deque[tuple[Capture, TrackerResult]] = deque()
        self._max_results = int(max_results)
        self._on_result = on_result
        self._window_s = float(window_s)
        self._done_times: deque[float] = deque()
        self._cond = threading.Condition()
        self._stop = False
        self._busy = False
        self._counts = {"submitted": 0, "tracked": 0, "dropped": 0, "results_dropped": 0,
                        "errors": 0}  # fmt: skip
        self._last_refused = ""
        self._last_error = ""
        self._thread = threading.Thread(target=self._run, name="kinefuse-tracker", daemon=True)

    def start(self) -> TrackerWorker:
        self._thread.start()
        return self

    def __enter__(self) -> TrackerWorker:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def submit(self, capture: Capture) -> bool:
        """Queue a capture; False when the queue was full and the oldest capture was dropped."""
        with self._cond:
            self._counts["submitted"] += 1
            dropped = len(self._pending) >= self._max_pending
            if dropped:
                self._pending.popleft()
                self._counts["dropped"] += 1
            self._pending.append(capture)
            self._cond.notify_all()
            return not dropped

    def get(self, timeout: float | None = None) -> tuple[Capture, TrackerResult] | None:
        """The next result (oldest first), waiting up to ``timeout`` s; None if there is none."""
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._results) or self._stop, timeout):
                return None
            return self._results.popleft() if self._results else None

    def drain(self, timeout: float = 10.0) -> bool:
        """Wait until every queued capture is tracked; False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._pending and not self._busy, timeout)

    def status(self) -> TrackerStatus:
        with self._cond:
            now = time.monotonic()
            self._trim(now)
            t = self._done_times
            rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) >= 2 and t[-1] > t[0] else float("nan")
            return TrackerStatus(rate_hz=rate, last_refused=self._last_refused,
                                 last_error=self._last_error, **self._counts)  # fmt: skip

    def stop(self, timeout: float = 10.0) -> None:
        """Stop after the capture being tracked (queued ones are dropped); join the thread."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def _trim(self, now: float) -> None:
        while self._done_times and now - self._done_times[0] > self._window_s:
            self._done_times.popleft()

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: bool(self._pending) or self._stop)
                if self._stop:
                    return
                capture = self._pending.popleft()
                self._busy = True
            try:
                result: TrackerResult | None = self.tracker.track(capture, self.calibration)
                error = ""
            except Exception as e:  # one bad capture must not end the tracking
                result, error = None, f"{type(e).__name__}: {e}"
            if result is not None and self._on_result is not None:
                try:
                    self._on_result(capture, result)
                except Exception as e:
                    error = f"on_result: {type(e).__name__}: {e}"
            with self._cond:
                self._busy = False
                if result is None:
                    self._counts["errors"] += 1
                else:
                    self._counts["tracked"] += 1
                    now = time.monotonic()
                    self._done_times.append(now)
                    self._trim(now)
                    if result.refused:
                        self._last_refused = result.refused[-1]
                    if self._on_result is None:
                        if len(self._results) >= self._max_results:
                            self._results.popleft()
                            self._counts["results_dropped"] += 1
                        self._results.append((capture, result))
                if error:
                    self._last_error = error
                    if result is not None:
                        self._counts["errors"] += 1
                self._cond.notify_all()
