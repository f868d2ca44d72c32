"""What a sensor delivers: one body-tracker frame (:class:`BodyFrame`) and a stream of them in
batch form (:class:`BodyFrames`), plus the calibration phase's depth images (:class:`DepthFrame`).

This is the one observation type of kinefuse: a frame source yields :class:`BodyFrame` items in
arrival order (the live path); offline work reads a sensor's stream as :class:`BodyFrames`,
arrays with the time axis first and NaN where a joint is missing (the batch path). The two
convert both ways (:meth:`BodyFrames.from_frames`, :meth:`BodyFrames.frame`, iteration).

Times are each clock's own: ``t_device_s`` stamps the capture on the device's clock,
``t_host_s`` the arrival at the sensor's client PC on its clock (the one the clock probes
measure), NaN where unknown. Once a clock estimate maps a stream onto the server's clock, the
batch form also carries the capture times there (``t_server_s``, :meth:`BodyFrames.on_server`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.core.skeleton import N_JOINTS, TrackingState
from kinefuse.errors import InputError

Array = NDArray[np.float64]

__all__ = ["MAX_BODIES", "BodyFrame", "BodyFrames", "DepthFrame", "Frame"]

#: the most bodies kinefuse keeps of one frame (Kinect v2 and the Azure Kinect track up to six);
#: the wire's limit (docs/protocol.md, "Limits")
MAX_BODIES = 8


@dataclass(frozen=True, eq=False)
class BodyFrame:
    """One body-tracker frame of one sensor.

    Attributes
    ----------
    sensor_id : str
    seq : int
        The sensor's frame counter.
    t_device_s : float
        Capture time on the device's clock, seconds.
    t_host_s : float
        Arrival at the sensor's client PC, on its clock (the one clock probes measure); NaN if
        unknown.
    joints_m : (25, 3) float
        Joints in the sensor frame (x right, y down, z forward), metres; NaN where not tracked.
    states : (25,) int8
        :class:`~kinefuse.core.skeleton.TrackingState` per joint.
    occluded : (25,) bool or None
        The client's occlusion flags, if it ran the test.
    n_crossings : int or None
        The client's number of bone crossings, if it ran the test.
    body_id : int
        The sensor's tracking id of this body (0 when the source reports none).
    others : tuple of BodyFrame
        The other bodies the tracker reported at this instant (same ``sensor_id``, ``seq`` and
        times; their own ``body_id``, joints, states and occlusion; their own ``others``
        empty). The frame itself is the body the tracker listed first: the one kinefuse has
        always used.
    """

    sensor_id: str
    seq: int
    t_device_s: float
    t_host_s: float
    joints_m: Array
    states: NDArray[np.int8]
    occluded: NDArray[np.bool_] | None = None
    n_crossings: int | None = None
    body_id: int = 0
    others: tuple[BodyFrame, ...] = ()

    def bodies(self) -> tuple[BodyFrame, ...]:
        """Every body of this instant, the first listed first: ``(self, *others)``."""
        return (self, *self.others)

    def first_body(self) -> BodyFrame:
        """This frame without its other bodies (what a one-body consumer or peer gets)."""
        return replace(self, others=()) if self.others else self


@dataclass(frozen=True, eq=False)
class DepthFrame:
    """One depth image of one sensor (``depth_mm (H, W) uint16``, 0 = no reading)."""

    sensor_id: str
    seq: int
    t_device_s: float
    t_host_s: float
    depth_mm: NDArray[np.uint16]


Frame = BodyFrame | DepthFrame


#: the default of a time column nobody gave: filled with NaN (unknown) for every frame
_UNKNOWN = np.zeros(0)
#: the default of the body-id column nobody gave: filled with 0 for every row
_NO_IDS = np.zeros(0, dtype=np.int64)


def _nan_column(x: ArrayLike | None, n: int, name: str, sensor_id: str) -> Array:
    if x is None or x is _UNKNOWN:
        return np.full(n, np.nan)
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.shape != (n,):
        raise InputError(
            f"sensor {sensor_id!r}: {name} must have one value per frame ({n}), got {a.shape}"
        )
    return a


@dataclass(frozen=True, eq=False)
class BodyFrames:
    """One sensor's stream of body-tracker frames, in batch form (the time axis first).

    Attributes
    ----------
    sensor_id : str
    seq : (T,) int64
        Frame sequence numbers, in stream order (increasing for a stored stream).
    t_device_s : (T,) float
        Capture time on the device's clock, seconds.
    t_host_s : (T,) float
        Arrival at the client PC on its clock, seconds; NaN where unknown.
    joints_m : (T, 25, 3) float
        Joints in the sensor frame (x right, y down, z forward), metres; NaN where missing.
    states : (T, 25) int8
        :class:`~kinefuse.core.skeleton.TrackingState` per joint.
    occluded : (T, 25) bool or None
        The client's occlusion flags, or None when it sent none.
    n_crossings : (T,) int64 or None
        The client's count of bone crossings per frame, or None.
    t_server_s : (T,) float
        Capture time on the server's clock, seconds (NaN until a clock estimate maps the
        stream there: :meth:`on_server`).
    t_receive_server_s : (T,) float
        Arrival on the server's clock, seconds; NaN where unknown.
    body_id : (T,) int64
        The sensor's tracking id of each row's body (default: 0 for every row).

    A stream may be in *all-bodies form*: several rows with the same ``seq``, one per body the
    tracker reported (consecutive, the first listed first, identical times); :attr:`multi` says
    whether it is, :meth:`first_bodies` gives the one-row-per-seq stream every fusion and
    analysis consumer takes.

    ``present`` is the mask of the NaN convention (a joint with finite coordinates that the
    tracker did not mark NOT_TRACKED).
    """

    sensor_id: str
    seq: NDArray[np.int64]
    t_device_s: Array
    t_host_s: Array
    joints_m: Array
    states: NDArray[np.int8]
    occluded: NDArray[np.bool_] | None = None
    n_crossings: NDArray[np.int64] | None = None
    t_server_s: Array = field(default_factory=lambda: _UNKNOWN)
    t_receive_server_s: Array = field(default_factory=lambda: _UNKNOWN)
    body_id: NDArray[np.int64] = field(default_factory=lambda: _NO_IDS)

    def __post_init__(self) -> None:
        sid = self.sensor_id
        seq = np.asarray(self.seq, dtype=np.int64).reshape(-1)
        n = seq.shape[0]
        joints = np.asarray(self.joints_m, dtype=np.float64)
        if joints.size == 0 and n == 0:
            joints = joints.reshape(0, N_JOINTS, 3)
        if joints.shape != (n, N_JOINTS, 3):
            raise InputError(
                f"sensor {sid!r}: joints_m must be ({n}, {N_JOINTS}, 3) for {n} frames, "
                f"got {joints.shape}"
            )
        states = np.asarray(self.states, dtype=np.int8)
        if states.size == 0 and n == 0:
            states = states.reshape(0, N_JOINTS)
        if states.shape != (n, N_JOINTS):
            raise InputError(
                f"sensor {sid!r}: states must be ({n}, {N_JOINTS}), got {states.shape}"
            )
        set_ = object.__setattr__
        set_(self, "seq", seq)
        set_(self, "joints_m", joints)
        set_(self, "states", states)
        for name in ("t_device_s", "t_host_s", "t_server_s", "t_receive_server_s"):
            set_(self, name, _nan_column(getattr(self, name), n, name, sid))
        if self.occluded is not None:
            occ = np.asarray(self.occluded, dtype=bool)
            if occ.shape != (n, N_JOINTS):
                raise InputError(
                    f"sensor {sid!r}: occluded must be ({n}, {N_JOINTS}), got {occ.shape}"
                )
            set_(self, "occluded", occ)
        if self.n_crossings is not None:
            cr = np.asarray(self.n_crossings, dtype=np.int64).reshape(-1)
            if cr.shape != (n,):
                raise InputError(f"sensor {sid!r}: n_crossings must be ({n},), got {cr.shape}")
            set_(self, "n_crossings", cr)
        if self.body_id is _NO_IDS:
            set_(self, "body_id", np.zeros(n, dtype=np.int64))
        else:
            ids = np.asarray(self.body_id, dtype=np.int64).reshape(-1)
            if ids.shape != (n,):
                raise InputError(f"sensor {sid!r}: body_id must be ({n},), got {ids.shape}")
            set_(self, "body_id", ids)

    # -- sizes and masks ------------------------------------------------------------------------

    @property
    def n_frames(self) -> int:
        return int(self.seq.shape[0])

    def __len__(self) -> int:
        return self.n_frames

    @property
    def present(self) -> NDArray[np.bool_]:
        """``(T, 25)`` the mask: finite joints the tracker did not mark NOT_TRACKED."""
        return np.asarray(
            np.isfinite(self.joints_m).all(-1) & (self.states != TrackingState.NOT_TRACKED)
        )

    @property
    def has_body(self) -> NDArray[np.bool_]:
        """``(T,)`` True for frames in which at least one joint is not ``NOT_TRACKED``."""
        return np.asarray((self.states != TrackingState.NOT_TRACKED).any(axis=1))

    # the session store's column names for the two client-side clocks
    @property
    def t_sensor_s(self) -> Array:
        """The store's name of ``t_device_s``."""
        return self.t_device_s

    @property
    def t_receive_host_s(self) -> Array:
        """The store's name of ``t_host_s``."""
        return self.t_host_s

    # -- bodies -----------------------------------------------------------------------------------

    def _first_rows(self) -> NDArray[np.bool_]:
        """``(T,)`` True for each row whose seq differs from the row before (a seq's first)."""
        first = np.ones(self.n_frames, dtype=bool)
        first[1:] = self.seq[1:] != self.seq[:-1]
        return first

    @property
    def multi(self) -> bool:
        """True when the stream is in all-bodies form with a seq of several bodies."""
        return bool(self.n_frames) and not bool(self._first_rows().all())

    def first_bodies(self) -> BodyFrames:
        """One row per seq, the body the tracker listed first (the stream itself when every seq
        has one row: a one-body stream is returned unchanged)."""
        first = self._first_rows()
        return self if first.all() else self.take(first)

    # -- derived streams ------------------------------------------------------------------------

    def take(self, index: ArrayLike) -> BodyFrames:
        """The frames at ``index`` (an int array or a ``(T,)`` bool mask), in that order."""
        k = np.asarray(index)

        def pick(a: NDArray | None) -> NDArray | None:
            return None if a is None else a[k]

        return BodyFrames(
            sensor_id=self.sensor_id,
            seq=self.seq[k],
            t_device_s=self.t_device_s[k],
            t_host_s=self.t_host_s[k],
            joints_m=self.joints_m[k],
            states=self.states[k],
            occluded=pick(self.occluded),
            n_crossings=pick(self.n_crossings),
            t_server_s=self.t_server_s[k],
            t_receive_server_s=self.t_receive_server_s[k],
            body_id=self.body_id[k],
        )

    def on_server(self, t_server_s: ArrayLike) -> BodyFrames:
        """The same stream with its capture times on the server clock ``(T,)`` seconds."""
        return replace(self, t_server_s=np.asarray(t_server_s, dtype=np.float64))

    def with_occlusion(self, occluded: ArrayLike, n_crossings: ArrayLike) -> BodyFrames:
        """The same stream with occlusion flags ``(T, 25)`` and crossing counts ``(T,)``."""
        return replace(
            self,
            occluded=np.asarray(occluded, dtype=bool),
            n_crossings=np.asarray(n_crossings, dtype=np.int64),
        )

    @classmethod
    def on_server_clock(
        cls,
        t_server_s: ArrayLike,
        joints_m: ArrayLike,
        states: ArrayLike | None = None,
        *,
        sensor_id: str = "",
        occluded: ArrayLike | None = None,
    ) -> BodyFrames:
        """A stream known only on the server clock (synthetic data, logs already synchronized):
        ``(T,)`` capture times, ``(T, 25, 3)`` joints, states (default: TRACKED where the joint
        is finite, else NOT_TRACKED), occlusion flags ``(T, 25)`` if any; frames numbered
        0, 1, ...; device and host times unknown."""
        t = np.asarray(t_server_s, dtype=np.float64).reshape(-1)
        j = np.asarray(joints_m, dtype=np.float64)
        if states is None:
            present = np.isfinite(j).all(-1)
            states = np.where(present, TrackingState.TRACKED, TrackingState.NOT_TRACKED)
        n = t.shape[0]
        return cls(
            sensor_id=sensor_id,
            seq=np.arange(n, dtype=np.int64),
            t_device_s=np.full(n, np.nan),
            t_host_s=np.full(n, np.nan),
            joints_m=j,
            states=np.asarray(states, dtype=np.int8),
            occluded=None if occluded is None else np.asarray(occluded, dtype=bool),
            t_server_s=t,
        )

    # -- conversions to and from single frames ---------------------------------------------------

    def frame(self, k: int) -> BodyFrame:
        """Row ``k`` as a :class:`BodyFrame` (views of the arrays, no copies; no others)."""
        return BodyFrame(
            sensor_id=self.sensor_id,
            seq=int(self.seq[k]),
            t_device_s=float(self.t_device_s[k]),
            t_host_s=float(self.t_host_s[k]),
            joints_m=self.joints_m[k],
            states=self.states[k],
            occluded=None if self.occluded is None else self.occluded[k],
            n_crossings=None if self.n_crossings is None else int(self.n_crossings[k]),
            body_id=int(self.body_id[k]),
        )

    def __iter__(self) -> Iterator[BodyFrame]:
        """One :class:`BodyFrame` per seq: its first row, the seq's other rows as ``others``
        (a one-body stream yields every row as it is)."""
        starts = np.flatnonzero(self._first_rows()).tolist()
        for a, b in zip(starts, [*starts[1:], self.n_frames], strict=True):
            f = self.frame(a)
            if b - a > 1:
                f = replace(f, others=tuple(self.frame(k) for k in range(a + 1, b)))
            yield f

    @classmethod
    def from_frames(
        cls,
        frames: Sequence[BodyFrame],
        *,
        sensor_id: str | None = None,
        bodies: Literal["first", "all"] = "first",
    ) -> BodyFrames:
        """Stack frames of one sensor (in the given order) into the batch form.

        ``bodies="first"``: one row per frame, its first body (the frames' ``others`` are left
        out); ``"all"``: the all-bodies form, a row per body of each frame (the first listed
        first). Occlusion flags and crossing counts are kept when every frame has them (frames
        without them in a mixed list count as not occluded, 0 crossings). ``sensor_id`` names
        an empty stream; a list with frames of several sensors is refused.
        """
        ids = {f.sensor_id for f in frames}
        if len(ids) > 1:
            raise InputError(
                f"BodyFrames.from_frames: frames of several sensors ({', '.join(sorted(ids))}); "
                "split them by sensor_id first"
            )
        if bodies not in ("first", "all"):
            raise InputError(
                f"BodyFrames.from_frames: bodies must be 'first' or 'all', not {bodies!r}"
            )
        if bodies == "all":
            frames = [b for f in frames for b in f.bodies()]
        sid = next(iter(ids)) if ids else (sensor_id or "")
        n = len(frames)
        occ = cr = None
        if any(f.occluded is not None for f in frames):
            blank = np.zeros(N_JOINTS, dtype=bool)
            occ = np.array([blank if f.occluded is None else f.occluded for f in frames])
            cr = np.array([f.n_crossings or 0 for f in frames], dtype=np.int64)
        return cls(
            sensor_id=sid,
            seq=np.array([f.seq for f in frames], dtype=np.int64),
            t_device_s=np.array([f.t_device_s for f in frames], dtype=np.float64),
            t_host_s=np.array([f.t_host_s for f in frames], dtype=np.float64),
            joints_m=np.array([f.joints_m for f in frames], dtype=np.float64).reshape(
                n, N_JOINTS, 3
            ),
            states=np.array([f.states for f in frames], dtype=np.int8).reshape(n, N_JOINTS),
            occluded=occ,
            n_crossings=cr,
            body_id=np.array([f.body_id for f in frames], dtype=np.int64),
        )
