"""Live calibration on the server: collect wand sightings, register the sensors, grade, switch.

Pure state (no I/O, times come in as arguments); the server feeds it and acts on the outcome.
It is used on the server's event loop only, except the solve, which runs in a worker thread on
a snapshot: :meth:`LiveCalibration.begin_solve` (on the loop) takes the sightings, floors and
poses as they are and switches to ``SOLVING``; :func:`solve_calibration` (in the thread) is a
pure function of that snapshot; :meth:`LiveCalibration.apply` (on the loop) switches to its
outcome. Meanwhile the loop keeps the floors sensors send and reads the state freely.

Flow
----
1. :meth:`LiveCalibration.start` (a control peer's ``CalibrationStart``, or automatically with
   ``kinefuse serve --auto-calibrate`` as soon as a sensor without a pose joins). The targets are
   the named sensors, else every connected sensor without a pose, else (all have one) all of them.
2. While collecting, every target's :class:`~kinefuse.live.protocol.messages.WandSighting` is kept
   with its capture time mapped onto the server clock (device -> host -> server, as for body
   frames); floor planes the clients report are kept across calibrations.
3. It ends (:meth:`LiveCalibration.should_stop`) on a control ``CalibrationStop``, after the
   ``seconds`` the ``CalibrationStart`` asked for if it did, else when no
   sensor has sent a sighting for ``quiet_s`` (the wand was put away; the simulated sensors'
   depth phase ended) once one has sent ``min_sightings``, or after ``max_s``.
4. :func:`solve_calibration`: with no sensor kept fixed, every target is registered as the
   offline ``kinefuse calibrate`` does
   (:func:`kinefuse.capture.calibration.calibration_run.calibrate`: full 6-DoF with gravity from the
   floors by default, or the paper's level-sensor method; the scale from the wand protocol's known
   move when ``axis_length_m`` is given). Sensors that already have a pose and are not targets stay
   as they are: each target is then registered against them, its sightings matched in time with the
   wand track the fixed sensors see in the world (robust Kabsch, :func:`register_against`). The
   result is graded (:func:`kinefuse.capture.calibration.grade.grade_calibration`); a ``failed`` one
   is not used (the previous poses stay).

A sensor's pose is kept by its id, so a client that reconnects gets it back at once.
"""

from __future__ import annotations

import datetime as _dt
import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.calibration.calib_file import (
    CalibrationFile,
    SensorCalibration,
    calibration_from_registration,
    dumps_calibration,
)
from kinefuse.capture.calibration.calibration_run import CalibrationInput, calibrate
from kinefuse.capture.calibration.floor import FloorPlane
from kinefuse.capture.calibration.grade import (
    Grade,
    HalvesCheck,
    grade_calibration,
    halves_disagreement,
    split_halves,
)
from kinefuse.capture.calibration.methods import METHODS
from kinefuse.capture.calibration.register import Registration, Sightings, register_full
from kinefuse.capture.calibration.register_full import _match_in_time, _robust_kabsch
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.errors import CalibrationError, KinefuseError

Array = NDArray[np.float64]


@dataclass(frozen=True)
class LiveCalibrationOptions:
    """Settings (seconds, metres)."""

    method: str = "full"
    #: the wand protocol's known move between its two holds (m), for the scale; None: no scale fix
    axis_length_m: float | None = None
    #: the calibration ends when no sensor has sent a sighting for this long
    quiet_s: float = 1.5
    #: ... once one sensor has sent at least this many
    min_sightings: int = 30
    #: the longest a calibration collects
    max_s: float = 120.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise CalibrationError(
                f"unknown calibration method {self.method!r}; choose full or paper"
            )
        if not (self.quiet_s > 0 and self.max_s > 0 and self.min_sightings >= 1):
            raise CalibrationError("quiet_s and max_s must be > 0, min_sightings >= 1")


class CalibrationState(enum.StrEnum):
    """Where the live calibration is (the value is the string the server reports)."""

    NONE = "none"
    COLLECTING = "collecting"
    #: the collected sightings are being registered (a worker thread); reported as "collecting"
    SOLVING = "solving"
    CALIBRATED = "calibrated"
    FAILED = "failed"

    @property
    def reported(self) -> str:
        """The state as the status messages carry it: none, collecting, calibrated, failed."""
        return CalibrationState.COLLECTING.value if self is CalibrationState.SOLVING else self.value


@dataclass
class _Track:
    t: list[float] = field(default_factory=list)
    c: list[Array] = field(default_factory=list)
    q: list[float] = field(default_factory=list)

    def sightings(self) -> Sightings:
        return Sightings(np.array(self.t), np.array(self.c).reshape(-1, 3), np.array(self.q))


@dataclass(frozen=True, eq=False)
class CalibrationOutcome:
    """What one calibration gave.

    ``ok``: the poses were switched to; ``calibration``: the whole calibration now in force (the
    fixed sensors and the new ones) or None; ``text``: its TOML; ``grade``; ``message``: one line
    for people; ``targets``: the sensors this run (re)registered.
    """

    calibration_id: int
    ok: bool
    method: str
    grade: Grade
    message: str
    targets: tuple[str, ...]
    calibration: CalibrationFile | None = None
    text: str | None = None
    registration: Registration | None = None
    #: the split-half check the grade used (None: the solve failed before it)
    halves: HalvesCheck | None = None


@dataclass(frozen=True, eq=False)
class SolveInput:
    """What one solve works on, taken on the event loop (:meth:`LiveCalibration.begin_solve`):
    nothing in it is shared with the live state."""

    calibration_id: int
    method: str
    options: LiveCalibrationOptions
    #: every sensor's sightings of this run (those with at least 3)
    tracks: dict[str, Sightings]
    targets: tuple[str, ...]
    #: the poses of the sensors that stay as they are
    fixed: dict[str, Array]
    floors: dict[str, FloorPlane]
    previous: CalibrationFile | None
    t_start: float
    intrinsics: dict[str, Intrinsics]
    serials: dict[str, str]


class LiveCalibration:
    """The server's calibration state (see the module docstring)."""

    def __init__(self, options: LiveCalibrationOptions = LiveCalibrationOptions()) -> None:
        self.options = options
        self.state = CalibrationState.NONE
        self.grade: str | None = None
        self.calibration: CalibrationFile | None = None
        self.floors: dict[str, FloorPlane] = {}
        self.calibration_id = 0
        self.method = options.method
        self._targets: set[str] = set()
        self._tracks: dict[str, _Track] = {}
        self._t_start = 0.0
        self._seconds: float | None = None
        self._state_before = CalibrationState.NONE
        #: server time of the last wand sighting (collecting or not; -inf: none yet)
        self.last_sighting_s = -np.inf

    # -- poses -----------------------------------------------------------------------------------

    @property
    def poses(self) -> dict[str, Array]:
        """``sensor id -> sensor2world (4, 4)`` of the calibration in force."""
        return {} if self.calibration is None else self.calibration.sensor2world

    def load(self, cal: CalibrationFile) -> None:
        """Start from a calibration file (``kinefuse serve --calibration``)."""
        self.calibration = cal
        self.state = CalibrationState.CALIBRATED
        self.grade = None

    @property
    def collecting(self) -> bool:
        return self.state is CalibrationState.COLLECTING

    @property
    def solving(self) -> bool:
        return self.state is CalibrationState.SOLVING

    @property
    def targets(self) -> tuple[str, ...]:
        return tuple(sorted(self._targets))

    # -- collecting ------------------------------------------------------------------------------

    def start(
        self,
        t_server_s: float,
        connected: Sequence[str],
        *,
        sensor_ids: Sequence[str] = (),
        method: str = "",
        calibration_id: int | None = None,
        seconds: float | None = None,
    ) -> int:
        """Begin collecting; returns the calibration id. Restarting discards what was collected."""
        if self.solving:
            raise CalibrationError("a calibration is being solved; start again when it is done")
        if method and method not in METHODS:
            raise CalibrationError(f"unknown calibration method {method!r}; choose full or paper")
        self.method = method or self.options.method
        if sensor_ids:
            targets = set(sensor_ids)
        else:
            unposed = {s for s in connected if s not in self.poses}
            targets = unposed or set(connected)
        self.calibration_id = self.calibration_id + 1 if calibration_id is None else calibration_id
        self._targets = targets
        self._tracks = {}
        self._t_start = float(t_server_s)
        self._seconds = seconds
        if self.state is not CalibrationState.COLLECTING:
            self._state_before = self.state
        self.state = CalibrationState.COLLECTING
        return self.calibration_id

    def add_target(self, sensor_id: str) -> None:
        """A sensor that joined while collecting (and has no pose) is collected too."""
        if self.collecting and sensor_id not in self.poses:
            self._targets.add(sensor_id)

    def abort(self) -> None:
        self._tracks = {}
        self._targets = set()
        self.state = self._state_before

    def add_sighting(
        self, sensor_id: str, t_server_s: float, centre_m: Array, score: float
    ) -> bool:
        """Keep one sighting (True) if collecting (from every sensor: the calibrated ones' give
        the world track a target is registered against)."""
        if not np.isfinite(t_server_s):
            return False
        self.last_sighting_s = max(self.last_sighting_s, float(t_server_s))
        if not self.collecting:
            return False
        tr = self._tracks.setdefault(sensor_id, _Track())
        tr.t.append(float(t_server_s))
        tr.c.append(np.asarray(centre_m, dtype=np.float64).reshape(3))
        tr.q.append(float(max(score, 1e-3)))
        return True

    def add_floor(self, sensor_id: str, floor: FloorPlane) -> None:
        self.floors[sensor_id] = floor

    def n_sightings(self) -> dict[str, int]:
        return {sid: len(tr.t) for sid, tr in self._tracks.items()}

    def should_stop(self, t_server_s: float) -> str | None:
        """Why collecting should end now (None: go on)."""
        if not self.collecting:
            return None
        o = self.options
        if t_server_s - self._t_start >= o.max_s:
            return f"the longest calibration ({o.max_s:g} s) has passed"
        if self._seconds is not None:
            if t_server_s - self._t_start >= self._seconds:
                return f"the {self._seconds:g} s asked for have passed"
            return None
        if not self._tracks:
            return None
        last = max(tr.t[-1] for tr in self._tracks.values())
        enough = any(len(tr.t) >= o.min_sightings for tr in self._tracks.values())
        if enough and t_server_s - last >= o.quiet_s:
            return f"no wand sighting for {o.quiet_s:g} s (the wand was put away)"
        return None

    # -- solving ---------------------------------------------------------------------------------

    def begin_solve(
        self, intrinsics: Mapping[str, Intrinsics], serials: Mapping[str, str]
    ) -> SolveInput:
        """End collecting: switch to ``SOLVING`` and return the snapshot
        :func:`solve_calibration` works on (on the event loop)."""
        if not self.collecting:
            raise CalibrationError(f"no calibration is collecting (the state is {self.state})")
        self.state = CalibrationState.SOLVING
        return SolveInput(
            calibration_id=self.calibration_id,
            method=self.method,
            options=self.options,
            tracks={sid: tr.sightings() for sid, tr in self._tracks.items() if len(tr.t) >= 3},
            targets=tuple(sorted(self._targets)),
            fixed={
                sid: np.array(p, dtype=np.float64)
                for sid, p in self.poses.items()
                if sid not in self._targets
            },
            floors=dict(self.floors),
            previous=self.calibration,
            t_start=self._t_start,
            intrinsics=dict(intrinsics),
            serials=dict(serials),
        )

    def apply(self, outcome: CalibrationOutcome) -> None:
        """Switch to a solve's outcome (on the event loop): its calibration unless it failed."""
        if not self.solving or outcome.calibration_id != self.calibration_id:
            return  # not the solve under way (cannot happen through the server)
        self._targets = set()
        if outcome.ok and outcome.calibration is not None:
            self.calibration = outcome.calibration
            self.state = CalibrationState.CALIBRATED
            self.grade = outcome.grade.grade
        else:
            self.state = (
                CalibrationState.FAILED if self.calibration is None else CalibrationState.CALIBRATED
            )

    def adopt(self, outcome: CalibrationOutcome) -> None:
        """Put a calibration from elsewhere in force (the person path,
        :mod:`kinefuse.live.server.person`; on the event loop)."""
        if not (outcome.ok and outcome.calibration is not None) or self.solving:
            return
        self.calibration = outcome.calibration
        self.calibration_id = max(self.calibration_id, outcome.calibration_id)
        self.state = CalibrationState.CALIBRATED
        self.grade = outcome.grade.grade

    def solve(
        self, intrinsics: Mapping[str, Intrinsics], serials: Mapping[str, str]
    ) -> CalibrationOutcome:
        """:meth:`begin_solve`, :func:`solve_calibration` and :meth:`apply` in one call (for a
        caller without threads)."""
        out = solve_calibration(self.begin_solve(intrinsics, serials))
        self.apply(out)
        return out


def solve_calibration(job: SolveInput) -> CalibrationOutcome:
    """Register the targets (see the module docstring): a pure function of ``job``, safe in a
    worker thread. The outcome is not in force until :meth:`LiveCalibration.apply`."""
    cid, method, targets, fixed = job.calibration_id, job.method, job.targets, job.fixed
    try:
        missing = [s for s in targets if s not in job.tracks]
        use = {s: job.tracks[s] for s in targets if s in job.tracks}
        if not use:
            raise CalibrationError(
                "no sensor sent wand sightings during the calibration; wave the wand in the "
                "sensors' view while the calibration runs"
            )
        reg = _against_fixed(job, use) if fixed else _register_all(job, use)
        # (the paper's method rests on the protocol's two holds, which halves would split)
        halves = check_halves(job, use) if method == "full" else None
        grade = grade_calibration(reg, job.floors, halves)
        if missing:
            grade = Grade(
                "doubtful" if grade.grade == "good" else grade.grade,
                (
                    *grade.reasons,
                    f"doubtful: sensor(s) {', '.join(missing)} sent no sightings "
                    "and were not calibrated",
                ),
            )
    except KinefuseError as e:
        return CalibrationOutcome(
            cid, False, method, Grade("failed", (str(e),)), f"calibration failed: {e}", targets
        )
    new = calibration_from_registration(
        reg, {s: job.intrinsics[s] for s in reg.sensor_ids}, serials=job.serials
    )
    merged = _merge(job.previous, new, fixed)
    text = dumps_calibration(merged)
    ok = grade.grade != "failed"
    rms = f"{1e3 * reg.rms_m:.2f} mm RMS" if np.isfinite(reg.rms_m) else "no RMS"
    message = f"{method}: {grade.grade}, {rms} over {', '.join(reg.sensor_ids)}"
    if not ok:
        message += " (not used)"
    return CalibrationOutcome(cid, ok, method, grade, message, targets, merged, text, reg, halves)


def check_halves(job: SolveInput, use: dict[str, Sightings]) -> HalvesCheck:
    """The split-half check (:mod:`kinefuse.capture.calibration.grade`): the same solve on two
    halves of every sensor's sightings (the fixed sensors' too), each target's pose compared."""
    regs = []
    for half in (0, 1):
        tracks = {s: split_halves(t, job.t_start)[half] for s, t in job.tracks.items()}
        sub = {s: split_halves(t, job.t_start)[half] for s, t in use.items()}
        try:
            if job.fixed:
                regs.append(_against_fixed(replace(job, tracks=tracks), sub))
            else:  # the scale fix needs the protocol's holds, which one half may lack
                regs.append(_register_all(replace(job, tracks=tracks), sub, fix_scale=False))
        except KinefuseError as e:
            return HalvesCheck({}, unchecked=f"half {half + 1}: {e}"[:300])
    return HalvesCheck(halves_disagreement(regs[0], regs[1], align_worlds=not job.fixed))


def _register_all(
    job: SolveInput, use: dict[str, Sightings], *, fix_scale: bool = True
) -> Registration:
    floors = {s: f for s, f in job.floors.items() if s in use}
    periods = [float(np.median(np.diff(s.t_server_s))) for s in use.values() if len(s) > 1]
    period = float(np.median(periods)) if periods else 1 / 30
    protocol: dict[str, object] = {}
    axis = job.options.axis_length_m
    if axis is not None:
        protocol["axis_length_m"] = float(axis)
    cal = CalibrationInput(
        sightings=use,
        tracks={},
        floors=floors,
        protocol=protocol,
        phase_server_s=(job.t_start, job.t_start),
        frame_period_s=period,
    )
    if job.method == "full" and not floors:
        return register_full(
            use,
            origin="sensor",
            max_gap_s=1.6 * period,
            max_speed_m_s=min(1.5, 0.05 / period),
        )
    return calibrate(cal, job.method, fix_scale=fix_scale and axis is not None)


def _against_fixed(job: SolveInput, use: dict[str, Sightings]) -> Registration:
    """Each target against the fixed sensors' wand track (fixed sightings are this run's)."""
    fixed = job.fixed
    fixed_tracks = {s: t for s, t in job.tracks.items() if s in fixed}
    if not fixed_tracks:
        raise CalibrationError(
            f"sensor(s) {', '.join(use)} are to be registered against the calibrated "
            f"sensor(s) {', '.join(fixed)}, but none of those saw the wand in this run; "
            "wave the wand where their views overlap"
        )
    prev = job.previous
    world = prev.world if prev is not None else "the calibrated sensors' world"
    # the world's scale was corrected from the wand protocol (sensor positions scaled by f
    # about the origin, the sensors' own measurements not): register in the unscaled world
    # the sightings live in, then scale the new sensor's position the same way
    f = prev.scale if prev is not None else 1.0
    unscaled = {}
    for k in fixed_tracks:
        u = np.array(fixed[k], dtype=np.float64)
        u[:3, 3] /= f
        unscaled[k] = u
    ids, poses, resid, n_used = [], [], [], []
    for sid, s in use.items():
        pose, r, n = register_against(fixed_tracks, unscaled, s, name=sid)
        pose[:3, 3] *= f
        ids.append(sid)
        poses.append(pose)
        resid.append(r)
        n_used.append(n)
    return Registration(
        method=job.method,
        sensor_ids=tuple(ids),
        sensor2world=np.stack(poses),
        residual_m=np.array(resid),
        n_sightings=np.array(n_used, dtype=np.int64),
        rms_m=float(np.sqrt(np.mean(np.square(resid)))),
        world=f"{world}; {', '.join(ids)} registered against {', '.join(sorted(fixed))}",
        scale=f,
    )


def register_against(
    fixed: Mapping[str, Sightings],
    fixed_poses: Mapping[str, Array],
    new: Sightings,
    *,
    name: str = "the new sensor",
    max_gap_s: float | None = None,
    max_speed_m_s: float = 1.5,
    min_matches: int = 10,
    min_spread_m: float = 0.05,
) -> tuple[Array, float, int]:
    """Pose of a new sensor from its sightings matched in time with the wand track the already
    calibrated sensors see in the world.

    Parameters
    ----------
    fixed : mapping sensor id -> Sightings
        The calibrated sensors' sightings of the same wand phase (server clock).
    fixed_poses : mapping sensor id -> (4, 4) float
        Their ``sensor2world``.
    new : Sightings
        The new sensor's sightings.

    Returns
    -------
    sensor2world : (4, 4) float
    residual_m : float
        RMS distance of its matched sightings (inliers) to the world track, metres.
    n_matched : int
    """
    ids = list(fixed)
    tracks = [fixed[s] for s in ids] + [new]
    periods = [float(np.median(np.diff(t.t_server_s))) for t in tracks if len(t) > 1]
    period = float(np.median(periods)) if periods else 1 / 30
    gap = 1.6 * period if max_gap_s is None else max_gap_s
    m = _match_in_time(tracks, 30.0, gap, min(max_speed_m_s, 0.05 / period))
    k = len(ids)
    pw = np.full(m.p[:, :k].shape, np.nan)
    for i, s in enumerate(ids):
        pose = np.asarray(fixed_poses[s], dtype=np.float64)
        pw[:, i] = m.p[:, i] @ pose[:3, :3].T + pose[:3, 3]
    wq = np.where(m.ok[:, :k], m.q[:, :k], 0.0)
    both = m.ok[:, k] & (wq.sum(1) > 0)
    if both.sum() < min_matches:
        raise CalibrationError(
            f"sensor {name} saw the wand at the same time as the calibrated sensors only "
            f"{int(both.sum())} times (need {min_matches}); wave the wand where its view "
            "overlaps theirs"
        )
    target = (np.nan_to_num(pw) * wq[..., None]).sum(1)[both] / wq.sum(1)[both][:, None]
    src = m.p[both, k]
    t = _robust_kabsch(src, target, m.q[both, k], f"sensor {name}", min_spread_m)
    r = np.linalg.norm(src @ t[:3, :3].T + t[:3, 3] - target, axis=1)
    inl = r < max(4.0 * 1.4826 * float(np.median(r)), 0.02)
    return t, float(np.sqrt(np.mean(r[inl] ** 2))), int(inl.sum())


def _merge(
    prev: CalibrationFile | None, new: CalibrationFile, fixed: Mapping[str, Array]
) -> CalibrationFile:
    """The fixed sensors' entries of ``prev`` plus every sensor of ``new``."""
    keep: list[SensorCalibration] = []
    if prev is not None:
        keep = [
            s for s in prev.sensors if s.id in fixed and s.id not in {x.id for x in new.sensors}
        ]
    if not keep:
        return new
    sensors = tuple(keep) + new.sensors
    res = np.array([s.residual_m for s in sensors])
    rms = float(np.sqrt(np.nanmean(res**2))) if np.isfinite(res).any() else float("nan")
    return CalibrationFile(
        method=new.method,
        created=_dt.datetime.now(_dt.UTC).replace(microsecond=0),
        sensors=sensors,
        world=new.world,
        rms_m=rms,
        scale=new.scale,
    )
