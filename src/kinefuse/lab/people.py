"""Evaluation of a session with several people against the simulator's truth: each person's
fused skeleton scored against their own true motion, and the identity (whether every person's
fused skeleton is made only of bodies that truly are theirs).

An *assignment* says which person the system gave each row of each sensor's all-bodies stream
(:meth:`kinefuse.formats.store.session_store.SessionStore.observations` with ``bodies="all"``):
``{sensor id: (N,) int64}``, -1 for a row given to nobody. The one-body fusion's is
:func:`first_body_assignment` (every sensor's first-listed body is the subject's).

This module reads the truth; nothing in the capture path may import it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.capture.fusion.people import associate, split_stream
from kinefuse.capture.occlusion.segments import detect_occlusion
from kinefuse.core.frames.observations import BodyFrames
from kinefuse.core.geometry.transforms import apply_transform
from kinefuse.core.skeleton import N_JOINTS
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.lab.metrics import position_errors
from kinefuse.pipeline.store_inputs import CalibratedSensor, run_method

Array = NDArray[np.float64]
Assignment = Mapping[str, NDArray[np.int64]]


def several_people(store: SessionStore) -> bool:
    """True when the simulated session has bystanders (its truth holds more than the subject)."""
    return len(store.truth().people()) > 1


def all_bodies(store: SessionStore, sensors: Sequence[CalibratedSensor]) -> dict[str, BodyFrames]:
    """Every sensor's all-bodies stream on the server clock (each sensor's own clock estimate),
    with its occlusion flags (the clients' test, run on each body)."""
    out = {}
    for s in sensors:
        f = store.observations(s.id, bodies="all")
        f = f.take(np.isin(f.seq, s.observations.seq))  # the frames the sensor's load kept
        occ = detect_occlusion(f.joints_m, s.intrinsics)
        out[s.id] = f.with_occlusion(occ.occluded, occ.n_intersections).on_server(
            s.timebase.affine.forward(f.t_device_s)
        )
    return out


def first_body_assignment(streams: Mapping[str, BodyFrames]) -> dict[str, NDArray[np.int64]]:
    """The one-body fusion's assignment: each instant's first-listed body is the subject's (0),
    every other body nobody's (-1)."""
    out = {}
    for sid, f in streams.items():
        first = np.ones(f.n_frames, dtype=bool)
        first[1:] = f.seq[1:] != f.seq[:-1]
        out[sid] = np.where(first, 0, -1).astype(np.int64)
    return out


def true_assignment(store: SessionStore, streams: Mapping[str, BodyFrames]) -> dict[str, Any]:
    """The person each row truly is (the truth's, -1: no person), per sensor."""
    truth = store.truth()
    return {sid: truth.person_of(sid, f.seq, f.body_id) for sid, f in streams.items()}


def match_people(
    assigned: Assignment, true: Assignment, subject: int | None = None
) -> dict[int, int]:
    """Which true person each of the system's persons is: its ``subject`` (the one it gives as
    the subject, when given) is the true subject (0), every other the one most of its bodies
    truly are (the system numbers people its own way; -1 when none of its bodies is anybody's)."""
    pairs: dict[tuple[int, int], int] = {}
    for sid, a in assigned.items():
        for x, y in zip(np.asarray(a).tolist(), np.asarray(true[sid]).tolist(), strict=True):
            if x >= 0:
                pairs[(x, y)] = pairs.get((x, y), 0) + 1
    best: dict[int, tuple[int, int]] = {}
    for (x, y), n in pairs.items():
        if y >= 0 and n > best.get(x, (-1, 0))[1]:
            best[x] = (y, n)
    out = {x: best[x][0] if x in best else -1 for x, _ in pairs}
    if subject is not None:
        out[subject] = 0
    return out


def in_true_ids(
    assigned: Assignment, true: Assignment, subject: int | None = None
) -> dict[str, NDArray[np.int64]]:
    """``assigned`` with the system's person ids replaced by the true persons they are
    (:func:`match_people`)."""
    match = match_people(assigned, true, subject)
    return {
        sid: np.array([match.get(x, -1) if x >= 0 else -1 for x in np.asarray(a).tolist()],
                      dtype=np.int64)
        for sid, a in assigned.items()
    }  # fmt: skip


def system_assignment(
    streams: Mapping[str, BodyFrames], sensors: Sequence[CalibratedSensor]
) -> tuple[dict[str, NDArray[np.int64]], str, int]:
    """The bodies the system gives each person (the association across sensors,
    :func:`kinefuse.capture.fusion.people.associate`), how, and the person it gives as the
    subject."""
    found = associate(streams, {s.id: s.sensor2world for s in sensors})
    how = f"the association (subject: person {found.subject}, {found.rule})"
    return dict(found.person), how, int(found.subject)


def person_stream(frames: BodyFrames, assigned: NDArray[np.int64], person: int) -> BodyFrames:
    """One person's one-row-per-seq stream of a sensor (the fusion's input: their body at each
    instant, an empty one where the sensor did not give them one)."""
    return split_stream(frames, assigned == person)


def identity_share(
    streams: Mapping[str, BodyFrames],
    assigned: Assignment,
    true: Assignment,
    grid: Array,
    subject: int | None = None,
) -> float:
    """Share of the fused frames ``grid`` (server times) at which every person's skeleton comes
    only from bodies that truly are theirs: for each sensor, every row with a body at the two
    instants around the frame (those the fusion reads) that is given to a person truly is that
    person (the system's person ids matched to the true ones first, :func:`match_people`;
    ``subject``: the one the system gives as the subject)."""
    return _identity(streams, in_true_ids(assigned, true, subject), true, grid)


def _identity(
    streams: Mapping[str, BodyFrames], assigned: Assignment, true: Assignment, grid: Array
) -> float:
    """:func:`identity_share` of an assignment already in the true person ids."""
    wrong = np.zeros(grid.shape, dtype=bool)
    for sid, f in streams.items():
        a, t = np.asarray(assigned[sid]), np.asarray(true[sid])
        bad = (a >= 0) & (a != t) & f.has_body
        first = np.ones(f.n_frames, dtype=bool)
        first[1:] = f.seq[1:] != f.seq[:-1]
        inst = np.cumsum(first) - 1
        bad_inst = np.zeros(int(first.sum()), dtype=bool)
        np.logical_or.at(bad_inst, inst, bad)
        t_inst = f.t_server_s[first]
        after = np.searchsorted(t_inst, grid, side="left")
        for k in (after - 1, after):  # the instant before and the one at or after each frame
            ok = (k >= 0) & (k < t_inst.size)
            wrong[ok] |= bad_inst[k[ok]]
    return float(1.0 - wrong.mean()) if grid.size else float("nan")


def person_truth_at(
    store: SessionStore, person: int, grid: Array, truth2world: Array | None = None
) -> Array:
    """A person's true joints ``(T, 25, 3)`` at server times ``grid`` (NaN outside)."""
    t, joints = store.truth().person_motion(person)
    flat = joints.reshape(len(t), -1)
    cols = [np.interp(grid, t, flat[:, k], left=np.nan, right=np.nan) for k in range(flat.shape[1])]
    out = np.stack(cols, axis=-1).reshape(grid.size, N_JOINTS, 3)
    return out if truth2world is None else apply_transform(truth2world, out)


def evaluate_people(
    store: SessionStore,
    sensors: Sequence[CalibratedSensor],
    methods: Sequence[str],
    grid: Array,
    assigned: Assignment | None = None,
    *,
    rule: str = "given",
    subject: int | None = None,
    truth2world: Array | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Each person's MAE per method (their fused skeleton from the rows ``assigned`` to them,
    default :func:`system_assignment`, against their own truth) and the identity share. The
    system's person ids are matched to the true ones first (:func:`match_people`; ``subject``:
    the person it gives as the subject, scored as the true subject).

    Returns
    -------
    dict
        ``persons``: ``{person: {"role", "rows", method: {"mae_m", "coverage"}}}``;
        ``identity``: :func:`identity_share`; ``assignment``: ``rule``.
    """
    say = progress or (lambda _m: None)
    streams = all_bodies(store, sensors)
    if assigned is None:
        assigned, rule, subject = system_assignment(streams, sensors)
    true = true_assignment(store, streams)
    a = in_true_ids(assigned, true, subject)
    persons: dict[str, Any] = {}
    for p in store.truth().people():
        rows = int(sum(int(((a[s.id] == p) & streams[s.id].has_body).sum()) for s in sensors))
        entry: dict[str, Any] = {"role": "subject" if p == 0 else "bystander", "rows": rows}
        truth = person_truth_at(store, p, grid, truth2world)
        own = [replace(s, observations=person_stream(streams[s.id], a[s.id], p)) for s in sensors]
        for m in methods:
            if not rows:
                entry[m] = {"mae_m": float("nan"), "coverage": 0.0}
                continue
            say(f"person {p}: fusing with {m}")
            e = position_errors(run_method(own, grid, m).positions, truth)
            entry[m] = {"mae_m": e["mae_m"], "coverage": 1.0 - e["missing_fraction"]}
        persons[str(p)] = entry
    return {
        "persons": persons,
        "identity": _identity(streams, a, true, grid),
        "assignment": rule,
    }
