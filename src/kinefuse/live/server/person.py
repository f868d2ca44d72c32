"""Live calibration from the person: when no wand calibrates the sensors, the body they track does.

The wand path (:mod:`kinefuse.live.server.live_calibration`) needs depth frames and a wand. When the
sensors deliver only skeletons (a real log replayed, a camera with no depth for the wand) or
nobody waves a wand, the server calibrates from the person instead, as ``kinefuse realdata``
does offline (:func:`kinefuse.capture.calibration.body.calibrate_from_body`): the floor under the
reference sensor's standing feet, the other sensors registered onto it from the trunk joints
they see at the same instants.

When it starts
--------------
Some connected sensor has no pose, two or more connected sensors track a person (a trunk frame
captured in the last ``tracking_s``), and no wand sighting came for ``wand_wait_s`` while they
did. A wand calibration that is collecting and has had no sighting by then is given up (the
clients are told to stop looking). A wand sighting at any time stops the person path from
starting; once started it goes on.

What it does
------------
Every ``refine_s`` it solves on what it has kept (each sensor's last ``keep_s`` of trunk frames,
on the server clock), in a worker thread on a snapshot, as the wand's solve: the fusion loop
only takes the new poses between two frames. A ``failed`` result is not used; a ``doubtful`` one
is (the fusion starts) and the solving goes on; it stops at the first ``good`` one. The status
and the log say what the operator has to do (``calibrating from the person: walk through the
volume``, with the reason); a session that has no pose at all says why every ``say_s``.

Pure state and functions of snapshots; :func:`person_step` is the server's housekeeping hook.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.body import calibrate_from_body
from kinefuse.capture.calibration.calib_file import (
    CalibrationFile,
    calibration_from_registration,
    dumps_calibration,
)
from kinefuse.capture.calibration.grade import Grade
from kinefuse.capture.calibration.register import Registration
from kinefuse.capture.sync.envelope import fit_clock_lower_envelope
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.skeleton import JOINT_INDEX, TRUNK_JOINTS
from kinefuse.errors import KinefuseError
from kinefuse.live.server.live_calibration import CalibrationOutcome, LiveCalibration, _merge

if TYPE_CHECKING:
    from kinefuse.live.server.server import Server

log = logging.getLogger("kinefuse.serve")

Array = NDArray[np.float64]

#: the name the calibration is stored under in a recording, and its method
METHOD = "body"
#: what the operator is asked to do while the person path runs
WALK = "calibrating from the person: walk through the volume"

_TRUNK = np.array([JOINT_INDEX[n] for n in TRUNK_JOINTS])
_RANK = {"failed": 0, "doubtful": 1, "good": 2}
#: a followed body unseen this long is lost (another near where it was is taken for it), s
_GAP_S = 0.2


@dataclass(frozen=True)
class PersonOptions:
    """Settings (seconds)."""

    #: no wand sighting for this long while two sensors track a person: calibrate from the person
    wand_wait_s: float = 5.0
    #: solve again after this long while the grade is not good
    refine_s: float = 5.0
    #: trunk frames kept per sensor
    keep_s: float = 240.0
    #: a session with no pose says why this often
    say_s: float = 5.0
    #: a sensor tracks a person if its last trunk frame was captured this recently
    tracking_s: float = 1.0


@dataclass
class _Frames:
    td: deque[float] = field(default_factory=deque)
    tr: deque[float] = field(default_factory=deque)
    p: deque[Array] = field(default_factory=deque)


@dataclass(frozen=True, eq=False)
class PersonJob:
    """What one solve works on, taken on the event loop (nothing shared with the live state)."""

    calibration_id: int
    #: per sensor: device stamps, server receive times, joints (25, 3) per frame (lists, made
    #: arrays in the worker thread; the frames' arrays are never changed once kept)
    tracks: dict[str, tuple[list[float], list[float], list[Array]]]
    fixed: dict[str, Array]
    previous: CalibrationFile | None
    intrinsics: dict[str, Intrinsics]
    serials: dict[str, str]


class PersonCalibration:
    """The person path's state (see the module docstring). Used on the event loop only."""

    def __init__(self, options: PersonOptions = PersonOptions()) -> None:
        self.options = options
        self._frames: dict[str, _Frames] = {}
        #: per sensor, the bodies in view: tracking id -> (first seen, last seen, trunk)
        self._runs: dict[str, dict[int, tuple[float, float, Array]]] = {}
        #: per sensor, the body followed: (tracking id, last seen, trunk in the sensor frame)
        self._followed: dict[str, tuple[int, float, Array]] = {}
        #: the person path has started (it goes on until its grade is good)
        self.active = False
        self.solving = False
        #: the grade of the person calibration in force (None: none yet)
        self.grade: str | None = None
        #: what the status shows the operator (None: nothing to say)
        self.message: str | None = None
        self._since: float | None = None
        self._last_solve = -math.inf
        self._last_said = -math.inf
        self._refining = True

    def add_body(
        self,
        sensor_id: str,
        t_device_s: float,
        t_receive_s: float,
        joints_m: Array,
        body_id: int = 0,
    ) -> None:
        """Keep a body frame whose trunk is seen: its device stamp and the server time it reached
        the sensor's PC (a repeated or out-of-order frame is not kept).

        With several bodies in view only the subject's are kept. The sensors have no poses yet,
        so each sensor follows one body on its own: the one it has tracked longest (the person
        who walks through the volume to calibrate it stays; a passer-by comes and goes), and
        after a loss the body nearest where that one was last seen (a new tracking id for the
        same person), else again the one tracked longest."""
        if not (math.isfinite(t_device_s) and math.isfinite(t_receive_s)):
            return
        if not np.isfinite(joints_m[_TRUNK]).all():
            return
        if not self._follows(sensor_id, body_id, t_receive_s, joints_m):
            return
        f = self._frames.setdefault(sensor_id, _Frames())
        if f.td and t_device_s <= f.td[-1]:
            return
        f.td.append(t_device_s)
        f.tr.append(t_receive_s)
        f.p.append(np.array(joints_m, dtype=np.float64))
        while f.tr[0] < t_receive_s - self.options.keep_s:
            f.td.popleft()
            f.tr.popleft()
            f.p.popleft()

    def _follows(self, sensor_id: str, body_id: int, t: float, joints_m: Array) -> bool:
        """Whether this body is the one the sensor follows (see :meth:`add_body`)."""
        lost = self.options.tracking_s
        runs = self._runs.setdefault(sensor_id, {})
        trunk = np.asarray(joints_m, dtype=np.float64)[_TRUNK].mean(axis=0)
        start = runs[body_id][0] if body_id in runs and t - runs[body_id][1] <= lost else t
        runs[body_id] = (start, t, trunk)
        for b in [b for b, r in runs.items() if t - r[1] > lost]:
            del runs[b]
        followed = self._followed.get(sensor_id)
        if followed is not None and followed[0] in runs and t - runs[followed[0]][1] <= _GAP_S:
            if body_id == followed[0]:
                self._followed[sensor_id] = (body_id, t, trunk)
            return body_id == followed[0]
        if followed is not None:  # lost: a body near where it was last seen is the same person
            _, t_last, where = followed
            gate = 0.5 + 1.0 * (t - t_last)
            near = [
                b
                for b, r in runs.items()
                if t - r[1] <= _GAP_S and np.linalg.norm(r[2] - where) <= gate
            ]
            if near:
                b = min(near, key=lambda b: float(np.linalg.norm(runs[b][2] - where)))
                self._followed[sensor_id] = (b, t, runs[b][2])
                return body_id == b
        here = [b for b, r in runs.items() if t - r[1] <= _GAP_S]
        b = min(here, key=lambda b: (runs[b][0], b))  # tracked longest
        self._followed[sensor_id] = (b, t, runs[b][2])
        return body_id == b

    def tracking(self, now: float, connected: list[str]) -> list[str]:
        """The connected sensors that track a person now."""
        f, o = self._frames, self.options
        return [s for s in connected if s in f and now - f[s].tr[-1] < o.tracking_s]

    def _wand_took_over(self, cal: LiveCalibration) -> None:
        """A wand calibration is in force: the person path stops refining and says nothing (it
        may start again for a sensor that joins without a pose)."""
        if cal.calibration is not None and cal.calibration.method != METHOD and self.active:
            self.active = False
            self.grade = None
            self.message = None

    def due(self, now: float, connected: list[str], cal: LiveCalibration) -> bool:
        """Whether to solve now (and start the path if it should)."""
        o = self.options
        self._wand_took_over(cal)
        if self.solving or cal.solving:
            return False
        unposed = [s for s in connected if s not in cal.poses]
        if not unposed and not (self.active and self.grade != "good"):
            self._since = None
            return False
        tracking = self.tracking(now, connected)
        if len(tracking) < 2 or now - cal.last_sighting_s < o.wand_wait_s:
            self._since = None
            return False
        if self._since is None:
            self._since = now
        if not self.active and now - self._since < o.wand_wait_s:
            return False
        if cal.collecting and sum(cal.n_sightings().values()) > 0:
            return False  # the wand path is under way
        return now - self._last_solve >= o.refine_s

    def begin(self, now: float, cal: LiveCalibration, intrinsics: Mapping[str, Intrinsics],
              serials: Mapping[str, str]) -> PersonJob:  # fmt: skip
        """Start a solve: the snapshot :func:`solve_person` works on (on the event loop)."""
        if not self.active:
            log.info("%s (no wand seen for %g s while two sensors track a person)", WALK,
                     self.options.wand_wait_s)  # fmt: skip
            self.message = WALK
        self.active = True
        self.solving = True
        self._last_solve = now
        prev = cal.calibration
        keep = prev is not None and (prev.method != METHOD or self.grade == "good")
        tracks = {
            s: (list(f.td), list(f.tr), list(f.p))
            for s, f in self._frames.items()
            if len(f.td) >= 10 and s in intrinsics
        }
        cal.calibration_id += 1
        self._refining = not keep  # every sensor solved anew (else new ones onto kept poses)
        return PersonJob(
            calibration_id=cal.calibration_id,
            tracks=tracks,
            fixed={s: np.array(p) for s, p in cal.poses.items()} if keep else {},
            previous=prev if keep else None,
            intrinsics=dict(intrinsics),
            serials=dict(serials),
        )

    def finish(self, out: CalibrationOutcome, cal: LiveCalibration) -> bool:
        """Take a solve's outcome (on the event loop); True if it is to be put in force."""
        self.solving = False
        first = out.grade.reasons[0].split(": ", 1)[-1] if out.grade.reasons else ""
        # a solve of every sensor anew replaces one of the same sensors only if it is no worse
        better = self.grade is None or _RANK[out.grade.grade] >= _RANK[self.grade]
        use = out.ok and (better or not self._refining)
        if use:
            cal.adopt(out)
            self.grade = out.grade.grade
        if self.grade == "good":
            self.message = f"calibrated from the person: {self.grade}"
        else:
            self.message = f"{WALK} ({first})" if first else WALK
        return use

    def say(self, now: float, connected: list[str], cal: LiveCalibration) -> str | None:
        """Why there is no pose (every ``say_s`` while no sensor has one), else None."""
        self._wand_took_over(cal)
        if cal.poses:
            if not self.active:
                self.message = None  # (a wand calibration, or one from a file)
            return None
        o = self.options
        tracking = self.tracking(now, connected)
        if self.active:
            text = self.message or WALK
        elif cal.collecting:
            n = sum(cal.n_sightings().values())
            text = f"no pose yet: a wand calibration is collecting ({n} sightings so far)"
        elif not connected:
            text = "no pose yet: no sensor is connected"
        elif len(connected) == 1:
            text = (f"no pose yet: only sensor {connected[0]} is connected; calibrate it with "
                    "the wand, or connect a second sensor that sees the person")  # fmt: skip
        elif len(tracking) < 2:
            who = ", ".join(tracking) or "none"
            text = (f"no pose yet: no two sensors track a person at once (tracking now: {who}); "
                    "step into the view of two sensors")  # fmt: skip
        else:
            left = o.wand_wait_s - (now - (self._since if self._since is not None else now))
            text = (f"no pose yet: waiting for a wand; calibrating from the person in "
                    f"{max(left, 0.0):.0f} s")  # fmt: skip
        if not self.active:
            self.message = text
        if now - self._last_said < o.say_s:
            return None
        self._last_said = now
        return text


def capture_times(t_device_s: Array, t_receive_s: Array) -> Array:
    """Capture times on the server clock from a sensor's device stamps and receive times: the
    lower envelope of the receive times
    (:func:`kinefuse.capture.sync.envelope.fit_clock_lower_envelope`, as ``kinefuse realdata``
    aligns the logs), which a receive-time jitter of hundreds of milliseconds leaves alone; the
    receive times themselves when there are too few frames."""
    try:
        return fit_clock_lower_envelope(t_device_s, t_receive_s).affine.forward(t_device_s)
    except KinefuseError:
        return t_receive_s


def solve_person(job: PersonJob) -> CalibrationOutcome:
    """Register the sensors from the person (a pure function of ``job``, safe in a thread)."""
    cid = job.calibration_id
    targets = tuple(sorted(s for s in job.tracks if s not in job.fixed))
    try:
        bc = calibrate_from_body(
            {
                s: (capture_times(np.array(td), np.array(tr)), np.stack(p))
                for s, (td, tr, p) in job.tracks.items()
            },
            fixed=job.fixed,
        )
    except KinefuseError as e:
        return CalibrationOutcome(
            cid, False, METHOD, Grade("failed", (str(e),)), f"calibration failed: {e}", targets
        )
    ids = tuple(sorted(bc.sensor2world))
    if not set(ids) - set(job.fixed):
        why = "no sensor could be registered from the person (too few frames with a person)"
        return CalibrationOutcome(
            cid, False, METHOD, Grade("failed", (why,)), f"calibration failed: {why}", targets
        )
    res = [bc.fits[s].residual_m if s in bc.fits else 0.0 for s in ids]
    n = [bc.fits[s].n_frames if s in bc.fits else len(job.tracks[s][0]) for s in ids]
    world = (
        f"z up from sensor {bc.reference}'s standing feet, origin on the foot plane below it"
        if bc.floor is not None
        else f"the calibrated sensors' world; registered onto {bc.reference}"
    )
    reg = Registration(
        method=METHOD,
        sensor_ids=ids,
        sensor2world=np.stack([bc.sensor2world[s] for s in ids]),
        residual_m=np.array(res),
        n_sightings=np.array(n, dtype=np.int64),
        rms_m=float(np.sqrt(np.mean(np.square(res)))),
        world=world,
    )
    grade = Grade(bc.grade, bc.reasons)
    new = calibration_from_registration(
        reg, {s: job.intrinsics[s] for s in ids}, serials=job.serials
    )
    merged = _merge(job.previous, new, job.fixed)
    trunk = ", ".join(f"{s} {1e3 * f.residual_m:.0f} mm" for s, f in sorted(bc.fits.items()))
    message = f"from the person: {grade.grade}; trunk onto {bc.reference}: {trunk or 'none'}"
    ok = grade.grade != "failed"
    if not ok:
        message += " (not used)"
    return CalibrationOutcome(
        cid, ok, METHOD, grade, message, targets, merged, dumps_calibration(merged), reg
    )


def person_step(srv: Server, now: float) -> None:
    """The server's housekeeping hook: start a solve when due, say why there is no pose."""
    p, cal = srv.person, srv.calibration
    connected = [s for s, c in srv.clients.items() if c.connected]
    text = p.say(now, connected, cal)
    if text is not None:
        log.warning("%s", text)
        srv._status_dirty = True
    if not p.due(now, connected, cal):
        return
    if cal.collecting:
        srv._finish_calibration(abort=True, why=f"no wand sighting for {p.options.wand_wait_s:g} s")
    job = p.begin(
        now,
        cal,
        {s: c.intrinsics for s, c in srv.clients.items()},
        {s: c.serial for s, c in srv.clients.items()},
    )
    assert srv._tg is not None
    srv._tg.create_task(_solve(srv, job))
    srv._status_dirty = True


async def _solve(srv: Server, job: PersonJob) -> None:
    try:
        out = await asyncio.to_thread(solve_person, job)
    except Exception as e:  # a defect of ours must not stop the server: the poses in force stay
        why = f"internal error, please report: {type(e).__name__}: {e}"
        log.error("calibration %d from the person: %s", job.calibration_id, why)
        targets = tuple(sorted(s for s in job.tracks if s not in job.fixed))
        out = CalibrationOutcome(
            job.calibration_id, False, METHOD, Grade("failed", (why,)), why, targets
        )
    if srv.person.finish(out, srv.calibration):
        srv.announce_calibration(out)
    else:
        log.info("calibration %d: %s (the poses in force stay)", out.calibration_id, out.message)
        for r in out.grade.reasons:
            log.info("  %s", r)
    srv._status_dirty = True
