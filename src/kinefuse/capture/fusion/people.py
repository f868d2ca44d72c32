"""People in the room: every sensor's bodies matched to persons across sensors and over time.

A depth-sensor tracker reports several bodies, each with a tracking id that is the sensor's own
(it changes when a body is lost and found, and means nothing to another sensor). The fusion needs
persons: the bodies of every sensor that are one human being. :class:`PeopleTracker` finds them
causally, one sensor frame at a time, as a live server must:

- each body is mapped to the world with its sensor's pose and summarised by its *trunk* (the
  mean of the tracked spine base, spine mid and hips: the part of a skeleton a tracker gets right
  even when limbs are occluded or swapped);
- each person track predicts its trunk at the frame's time from its position and velocity (a
  person passing close to another is told apart by where they are heading, not only by where
  they stand);
- the bodies of that frame are assigned to the tracks by an optimal assignment
  (:func:`scipy.optimize.linear_sum_assignment`) on the trunk distances, with a gate that grows
  with the time the person was not seen; a body that keeps the sensor's tracking id of the body
  last assigned to a track (same sensor, same id) costs :attr:`PeopleOptions.id_bonus_m` less,
  so the sensor's own tracking wins over a close call on positions;
- a body left unassigned starts a new person (ids 0, 1, 2, ... in order of appearance, never
  reused); a person not seen for :attr:`PeopleOptions.keep_s` is dropped, so one who leaves and
  comes back within that time keeps their id, even under a new tracking id.

The one-person rule keeps every one-person figure unchanged: as long as no sensor has reported
two bodies at one instant there is one person, id 0, and every body is theirs.

:func:`associate` replays the tracker over recorded streams (all-bodies form, times on the server
clock) in capture order, chooses the subject (:func:`choose_subject`) and returns
:class:`People`; :meth:`People.split` cuts the streams into one stream per person and sensor, the
input of every existing fusion method.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment

from kinefuse.core.frames.observations import BodyFrame, BodyFrames
from kinefuse.core.skeleton import JOINT_INDEX, TrackingState
from kinefuse.errors import InputError

Array = NDArray[np.float64]

__all__ = [
    "PICK_WINDOW_S",
    "SUBJECT_RULES",
    "People",
    "PeopleOptions",
    "PeopleTracker",
    "associate",
    "choose_subject",
    "live_subject",
    "trunk_world",
]

#: the joints whose mean is a body's trunk position
TRUNK_JOINTS = tuple(JOINT_INDEX[j] for j in ("SpineBase", "SpineMid", "HipLeft", "HipRight"))

#: how the subject was chosen, in the order the rule tries them
SUBJECT_RULES = ("one person", "chosen", "live", "calibration phase", "nearest the centre")
#: how far from a live pick's time a recorded body is looked for, seconds
PICK_WINDOW_S = 0.5


@dataclass(frozen=True)
class PeopleOptions:
    """The tracker's settings (SI units).

    Attributes
    ----------
    gate_m : float
        A body farther than this from a person's predicted trunk is not theirs.
    gate_growth_m_s : float
        The gate widens by this per second the person was not seen (up to ``max_gate_m``).
    max_gate_m : float
    id_bonus_m : float
        Cost taken off a body that keeps the tracking id of the body this sensor last gave the
        person (the sensor's tracking id as a strong prior).
    keep_s : float
        A person unseen for longer is dropped (their id is not reused).
    velocity_s : float
        The window over which a person's velocity is measured.
    max_predict_s : float
        Velocity is extrapolated at most this long (a person who left stops where they left).
    """

    gate_m: float = 0.6
    gate_growth_m_s: float = 0.5
    max_gate_m: float = 1.5
    id_bonus_m: float = 0.4
    keep_s: float = 5.0
    velocity_s: float = 0.3
    max_predict_s: float = 0.5


def trunk_world(joints_m: ArrayLike, states: ArrayLike, sensor2world: ArrayLike) -> Array:
    """The trunk of bodies in the world: the mean of their tracked trunk joints.

    Parameters
    ----------
    joints_m : (N, 25, 3) float
        Joints in the sensor frame, metres.
    states : (N, 25) int
        :class:`~kinefuse.core.skeleton.TrackingState` per joint.
    sensor2world : (4, 4) float

    Returns
    -------
    (N, 3) float
        World positions, metres; NaN where no trunk joint is tracked.
    """
    j = np.asarray(joints_m, dtype=np.float64)[:, TRUNK_JOINTS]
    ok = np.isfinite(j).all(-1) & (np.asarray(states)[:, TRUNK_JOINTS] != TrackingState.NOT_TRACKED)
    n = ok.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(ok[..., None], j, 0.0).sum(axis=1) / np.where(n > 0, n, np.nan)[:, None]
    pose = np.asarray(sensor2world, dtype=np.float64)
    return np.asarray(mean @ pose[:3, :3].T + pose[:3, 3])


@dataclass
class _Track:
    id: int
    t_last: float
    position: Array
    velocity: Array = field(default_factory=lambda: np.zeros(3))
    #: per sensor, the tracking id of the body last assigned to this person
    body_ids: dict[str, int] = field(default_factory=dict)
    #: (time, position) after each update, over the velocity window
    history: list[tuple[float, Array]] = field(default_factory=list)

    def predict(self, t: float, options: PeopleOptions) -> Array:
        dt = min(max(t - self.t_last, 0.0), options.max_predict_s)
        return self.position + self.velocity * dt

    def gate(self, t: float, options: PeopleOptions) -> float:
        grow = options.gate_growth_m_s * max(t - self.t_last, 0.0)
        return min(options.gate_m + grow, options.max_gate_m)

    def observe(self, t: float, trunk: Array, options: PeopleOptions) -> None:
        # several sensors see one person at nearly one instant, each with its own small offset:
        # blend, so that the position does not jump between them
        pred = self.predict(t, options)
        self.position = trunk if t - self.t_last > options.velocity_s else 0.5 * (pred + trunk)
        self.t_last = max(self.t_last, t)
        self.history.append((t, self.position))
        while len(self.history) > 2 and self.history[1][0] <= t - options.velocity_s:
            self.history.pop(0)
        t0, p0 = self.history[0]
        if t - t0 >= 0.5 * options.velocity_s:
            self.velocity = (self.position - p0) / (t - t0)


class PeopleTracker:
    """The causal associator of bodies to people (the module's docstring tells how).

    ``update`` is called with each sensor frame (or several sensors' latest frames) as it
    arrives; it returns the person of every body given.
    """

    def __init__(self, options: PeopleOptions | None = None) -> None:
        self.options = options or PeopleOptions()
        self._tracks: list[_Track] = []
        self._next_id = 0
        #: True once a sensor has reported two bodies at one instant
        self.multi = False

    @property
    def people(self) -> tuple[int, ...]:
        """The ids of the persons currently tracked."""
        return tuple(t.id for t in self._tracks)

    def body_ids(self, person_id: int) -> dict[str, int]:
        """Per sensor, the tracking id of the body last given to a tracked person (empty for a
        person not tracked)."""
        for t in self._tracks:
            if t.id == person_id:
                return dict(t.body_ids)
        return {}

    def position(self, person_id: int) -> Array | None:
        """The last trunk position of a tracked person (world, metres), or None."""
        for t in self._tracks:
            if t.id == person_id:
                return t.position.copy()
        return None

    def update(
        self,
        t_server_s: float,
        bodies: Mapping[str, Sequence[BodyFrame]],
        poses: Mapping[str, ArrayLike],
    ) -> dict[tuple[str, int], int]:
        """Assign the bodies seen at ``t_server_s`` (per sensor id) to persons.

        Parameters
        ----------
        t_server_s : float
            The frame's capture time on the server clock, seconds.
        bodies : mapping
            ``sensor id -> the bodies it reported at that instant`` (a frame's ``bodies()``).
        poses : mapping
            ``sensor id -> sensor2world (4, 4)``.

        Returns
        -------
        dict
            ``(sensor id, body id) -> person id`` for every body with a tracked trunk (a body
            with none is not assigned and is left out, as is a body whose tracking id an
            earlier body of the same instant has).
        """
        t = float(t_server_s)
        opts = self.options
        out: dict[tuple[str, int], int] = {}
        for sid, frames in bodies.items():
            if not frames:
                continue
            if sid not in poses:
                raise InputError(f"people: no pose for sensor {sid!r}; calibrate it first")
            if len(frames) > 1:
                self.multi = True
            trunks = trunk_world(
                np.array([f.joints_m for f in frames]),
                np.array([f.states for f in frames]),
                poses[sid],
            )
            ids = [f.body_id for f in frames]
            # a tracking id names one body of an instant: a repeat (a source that numbers
            # nothing) is left out
            seen = np.isfinite(trunks).all(axis=1) & np.array(
                [f.body_id not in ids[:k] for k, f in enumerate(frames)]
            )
            self._expire(t)
            if not self.multi:
                # the one-person rule: every body is person 0's
                k = int(np.flatnonzero(seen)[0]) if seen.any() else -1
                if k >= 0:
                    self._assign(self._track0(t, trunks[k]), sid, ids[k], t, trunks[k])
                    out[(sid, ids[k])] = 0
                continue
            rows = np.flatnonzero(seen)
            if rows.size == 0:
                continue
            n_t = len(self._tracks)
            cost = np.full((rows.size, max(n_t, 1)), np.inf)
            for j, tr in enumerate(self._tracks):
                d = np.linalg.norm(trunks[rows] - tr.predict(t, opts), axis=1)
                ok = d <= tr.gate(t, opts)
                same = np.array([tr.body_ids.get(sid) == ids[r] for r in rows])
                cost[:, j] = np.where(ok, d - opts.id_bonus_m * same, np.inf)
            assigned: dict[int, int] = {}
            if n_t:
                big = 1e6
                r_idx, c_idx = linear_sum_assignment(np.where(np.isfinite(cost), cost, big))
                for r, c in zip(r_idx, c_idx, strict=True):
                    if np.isfinite(cost[r, c]):
                        assigned[int(r)] = int(c)
            for i, r in enumerate(rows):
                tr = self._tracks[assigned[i]] if i in assigned else self._new_track(t, trunks[r])
                self._assign(tr, sid, ids[r], t, trunks[r])
                out[(sid, ids[r])] = tr.id
        return out

    # -- tracks ----------------------------------------------------------------------------------

    def _expire(self, t: float) -> None:
        self._tracks = [tr for tr in self._tracks if t - tr.t_last <= self.options.keep_s]

    def _new_track(self, t: float, trunk: Array) -> _Track:
        tr = _Track(id=self._next_id, t_last=t, position=trunk.copy())
        self._next_id += 1
        self._tracks.append(tr)
        return tr

    def _track0(self, t: float, trunk: Array) -> _Track:
        for tr in self._tracks:
            if tr.id == 0:
                return tr
        self._tracks = []
        self._next_id = 0
        return self._new_track(t, trunk)

    def _assign(self, tr: _Track, sid: str, body_id: int, t: float, trunk: Array) -> None:
        # a tracking id now given to this person is no longer another's on this sensor
        for other in self._tracks:
            if other is not tr and other.body_ids.get(sid) == body_id:
                del other.body_ids[sid]
        tr.body_ids[sid] = body_id
        tr.observe(t, trunk, self.options)


@dataclass(frozen=True)
class People:
    """The persons of a recording (:func:`associate`).

    Attributes
    ----------
    person : dict
        ``sensor id -> (N,) int64``: the person of every row of that sensor's all-bodies stream
        (-1: a body without a tracked trunk, nobody's).
    ids : tuple of int
        Every person id, in order of appearance.
    subject : int
        The person the commands give by default.
    rule : str
        How the subject was chosen (one of :data:`SUBJECT_RULES`).
    """

    person: dict[str, NDArray[np.int64]]
    ids: tuple[int, ...]
    subject: int
    rule: str

    def rows(self, person_id: int) -> dict[str, NDArray[np.int64]]:
        """Per sensor, the row indices (into the all-bodies stream) of one person's bodies."""
        return {sid: np.flatnonzero(p == person_id) for sid, p in self.person.items()}

    def split(self, streams: Mapping[str, BodyFrames]) -> dict[int, dict[str, BodyFrames]]:
        """Per person, per sensor, a one-row-per-seq stream: the person's body where the sensor
        saw them, an empty body (NaN joints, ``NOT_TRACKED``) at the sensor's other instants.
        For a one-person recording person 0's streams are the first bodies, unchanged."""
        out: dict[int, dict[str, BodyFrames]] = {}
        for pid in self.ids:
            per: dict[str, BodyFrames] = {}
            for sid, s in streams.items():
                if sid not in self.person:
                    raise InputError(f"people: no assignment for sensor {sid!r}")
                per[sid] = split_stream(s, self.person[sid] == pid)
            out[pid] = per
        return out


def split_stream(s: BodyFrames, mine: NDArray[np.bool_]) -> BodyFrames:
    """One row per seq of ``s``: the row where ``mine`` holds, else the instant's first row
    emptied of its body."""
    if not s.multi and mine.all():
        return s
    first = np.ones(s.n_frames, dtype=bool)
    first[1:] = np.diff(s.seq) != 0
    group = np.cumsum(first) - 1  # the instant of each row
    pick = np.flatnonzero(first)  # default: the first row of each instant...
    has = np.zeros(pick.size, dtype=bool)
    pick[group[mine]] = np.flatnonzero(mine)  # ...or the person's own body
    has[group[mine]] = True
    out = s.take(pick)
    if has.all():
        return out
    empty = ~has
    joints = out.joints_m.copy()
    joints[empty] = np.nan
    states = out.states.copy()
    states[empty] = TrackingState.NOT_TRACKED
    occ = None if out.occluded is None else np.where(empty[:, None], False, out.occluded)
    cr = None if out.n_crossings is None else np.where(empty, 0, out.n_crossings)
    return BodyFrames(
        sensor_id=out.sensor_id,
        seq=out.seq,
        t_device_s=out.t_device_s,
        t_host_s=out.t_host_s,
        joints_m=joints,
        states=states,
        occluded=occ,
        n_crossings=cr,
        t_server_s=out.t_server_s,
        t_receive_server_s=out.t_receive_server_s,
        body_id=np.where(empty, -1, out.body_id),
    )


def associate(
    streams: Mapping[str, BodyFrames],
    poses: Mapping[str, ArrayLike],
    *,
    subject: int | None = None,
    phases_s: Sequence[tuple[float, float]] = (),
    centre_xy_m: ArrayLike | None = None,
    options: PeopleOptions | None = None,
    picks: Sequence[tuple[float, Mapping[str, int]]] = (),
) -> People:
    """Replay :class:`PeopleTracker` over recorded streams and choose the subject.

    Parameters
    ----------
    streams : mapping
        ``sensor id -> BodyFrames`` in all-bodies form, capture times on the server clock.
    poses : mapping
        ``sensor id -> sensor2world (4, 4)``.
    subject : int, optional
        The subject chosen by hand (``--subject``, the operator); must be a person found.
    phases_s, centre_xy_m, picks
        For the rule (:func:`choose_subject`).
    options : PeopleOptions, optional
    """
    person = {sid: np.full(s.n_frames, -1, dtype=np.int64) for sid, s in streams.items()}
    if not any(s.multi for s in streams.values()):
        # the one-person rule, without replaying anything
        for p in person.values():
            p[:] = 0
        ids: tuple[int, ...] = (0,) if any(s.n_frames for s in streams.values()) else ()
        if subject not in (None, 0):
            raise InputError(
                f"--subject {subject}: this recording has one person, id 0; leave --subject out"
            )
        return People(person, ids, 0, "one person")
    for sid, s in streams.items():
        if not np.isfinite(s.t_server_s).all():
            raise InputError(f"people: sensor {sid!r} has frames without a server time")
    tracker = PeopleTracker(options)
    # every instant of every sensor, in capture order
    events = []
    for sid, s in streams.items():
        first = np.ones(s.n_frames, dtype=bool)
        first[1:] = np.diff(s.seq) != 0
        starts = np.flatnonzero(first)
        ends = np.append(starts[1:], s.n_frames)
        events += [
            (float(s.t_server_s[a]), sid, int(a), int(b)) for a, b in zip(starts, ends, strict=True)
        ]
    events.sort(key=lambda e: (e[0], e[1]))
    trunks = {sid: trunk_world(s.joints_m, s.states, poses[sid]) for sid, s in streams.items()}
    seen: list[int] = []
    for t, sid, a, b in events:
        s = streams[sid]
        got = tracker.update(t, {sid: [s.frame(k) for k in range(a, b)]}, poses)
        for k in range(a, b):
            pid = got.get((sid, int(s.body_id[k])))
            unique = int(s.body_id[k]) not in s.body_id[a:k]
            if pid is not None and unique and np.isfinite(trunks[sid][k]).all():
                person[sid][k] = pid
                if pid not in seen:
                    seen.append(pid)
    ids = tuple(sorted(seen))
    if centre_xy_m is None:
        centre_xy_m = np.mean(
            [np.asarray(p, dtype=np.float64)[:2, 3] for p in poses.values()], axis=0
        )
    pid, rule = choose_subject(
        person, streams, trunks, ids, subject=subject, phases_s=phases_s,
        centre_xy_m=centre_xy_m, picks=picks,
    )  # fmt: skip
    return People(person, ids, pid, rule)


def choose_subject(
    person: Mapping[str, NDArray[np.int64]],
    streams: Mapping[str, BodyFrames],
    trunks: Mapping[str, Array],
    ids: Sequence[int],
    *,
    subject: int | None = None,
    phases_s: Sequence[tuple[float, float]] = (),
    centre_xy_m: ArrayLike = (0.0, 0.0),
    first_s: float = 3.0,
    picks: Sequence[tuple[float, Mapping[str, int]]] = (),
) -> tuple[int, str]:
    """The subject and the rule that chose them.

    In order: the person chosen by hand (``subject``); else the live server's last subject
    (``picks``: each ``(t_server_s, {sensor id: tracking id})``, the tracking ids the sensors
    gave the live subject when it was chosen, :func:`live_subject`); else the person seen in
    the most sensor frames during the calibration walk or range-of-motion phases
    (``phases_s``, server clock); else the person whose trunk stood nearest the volume's
    centre (``centre_xy_m``, the floor point) over the recording's first ``first_s`` seconds
    (the median over every sensor's frames of that time, a frame in which the sensor did not
    see the person counting as infinitely far: someone who walks in later is not the subject).
    """
    if not ids:
        raise InputError("people: no body with a tracked trunk in the recording: nobody to fuse")
    if subject is not None:
        if subject not in ids:
            raise InputError(
                f"--subject {subject}: no such person; the recording's people are "
                f"{', '.join(str(i) for i in ids)}"
            )
        return int(subject), "chosen"
    for t_pick, body_ids in reversed(picks):
        pid = live_subject(person, streams, t_pick, body_ids)
        if pid is not None:
            return pid, "live"
    if phases_s:
        counts = dict.fromkeys(ids, 0)
        for sid, s in streams.items():
            inside = np.zeros(s.n_frames, dtype=bool)
            for a, b in phases_s:
                inside |= (s.t_server_s >= a) & (s.t_server_s <= b)
            for pid in ids:
                counts[pid] += int((inside & (person[sid] == pid)).sum())
        top = max(counts.values())
        if top > 0:
            best = [p for p in ids if counts[p] == top]
            if len(best) == 1:
                return best[0], "calibration phase"
    t0 = min((float(s.t_server_s[0]) for s in streams.values() if s.n_frames), default=0.0)
    centre = np.asarray(centre_xy_m, dtype=np.float64)[:2]
    dist: dict[int, list[Array]] = {p: [] for p in ids}
    for sid, s in streams.items():
        early = s.t_server_s <= t0 + first_s
        _, instant = np.unique(s.seq[early], return_inverse=True)
        n_inst = int(instant.max()) + 1 if instant.size else 0
        for pid in ids:
            # per instant of the sensor: the person's distance, or infinitely far when the
            # sensor did not see them then (someone who walks in later is not the subject)
            d = np.full(n_inst, np.inf)
            k = person[sid][early] == pid
            d[instant[k]] = np.linalg.norm(trunks[sid][early][k, :2] - centre, axis=1)
            dist[pid].append(d)
    med = {
        p: float(np.median(np.concatenate(d))) if sum(x.size for x in d) else np.inf
        for p, d in dist.items()
    }
    return min(ids, key=lambda p: (med[p], p)), "nearest the centre"


def live_subject(
    person: Mapping[str, NDArray[np.int64]],
    streams: Mapping[str, BodyFrames],
    t_pick_s: float,
    body_ids: Mapping[str, int],
) -> int | None:
    """The person of a recording who is the live server's subject picked at ``t_pick_s``: the
    person the association gives the bodies with those sensors' tracking ids ``body_ids``
    nearest that time (within :data:`PICK_WINDOW_S`), by majority over the sensors (the lowest
    id on a tie); None when no such body was recorded. The association offline numbers people
    as the live one does only when it sees the bodies in the same order, so a live pick is
    carried by the sensors' own tracking ids, not by its person id."""
    votes: dict[int, int] = {}
    for sid, bid in body_ids.items():
        s = streams.get(sid)
        if s is None or not s.n_frames:
            continue
        rows = np.flatnonzero((s.body_id == int(bid)) & (person[sid] >= 0))
        if rows.size == 0:
            continue
        k = rows[np.argmin(np.abs(s.t_server_s[rows] - t_pick_s))]
        if abs(float(s.t_server_s[k]) - t_pick_s) <= PICK_WINDOW_S:
            pid = int(person[sid][k])
            votes[pid] = votes.get(pid, 0) + 1
    if not votes:
        return None
    top = max(votes.values())
    return min(p for p, v in votes.items() if v == top)
