"""Paper A's level-sensor registration (METHODS.md A.3 step 5) and the blind still-phase detector
that finds the protocol's wand holds in the data. Re-exported by
:mod:`kinefuse.capture.calibration.register`, whose docstring describes both methods.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinefuse.capture.calibration.register_common import _SENSOR2LEVEL, Registration, Sightings
from kinefuse.core.geometry.rotations import rot_z
from kinefuse.core.geometry.transforms import make_transform
from kinefuse.errors import CalibrationError, InputError

Array = NDArray[np.float64]


# ---------------------------------------------------------------------------------------------
# Paper's level-sensor method


def register_paper(
    origin_sensor_m: Mapping[str, ArrayLike],
    moved_sensor_m: Mapping[str, ArrayLike],
    *,
    min_move_m: float = 0.1,
) -> Registration:
    """The paper's registration of level sensors from two wand positions.

    The world's origin is the wand's centre at its first position, its y axis the horizontal
    direction in which the wand was then moved, z up (every sensor is assumed level: its image
    "down" axis is the world's -z). For each sensor the heading is
    ``theta = atan2`` of the move it saw in its own horizontal plane, and its translation puts its
    first wand position at the origin.

    Parameters
    ----------
    origin_sensor_m : mapping sensor id -> (3,) float
        Wand centre at the origin, in each sensor's frame (metres).
    moved_sensor_m : mapping sensor id -> (3,) float
        Wand centre after the move along the world y axis.
    min_move_m : float
        A sensor that saw a horizontal move shorter than this cannot be registered.

    Returns
    -------
    Registration
        ``residual_m`` is the distance of each sensor's second wand position (in the world) from
        the sensors' median; ``n_sightings`` is 2.

    Raises
    ------
    CalibrationError
        Missing sensors, non-finite positions, or a move too short to give a direction.
    """
    ids = tuple(origin_sensor_m)
    missing = sorted(set(ids) ^ set(moved_sensor_m))
    if missing:
        raise CalibrationError(
            f"register_paper needs both wand positions from every sensor; sensor(s) "
            f"{', '.join(missing)} have only one"
        )
    if not ids:
        raise CalibrationError("register_paper needs at least one sensor")
    poses = np.empty((len(ids), 4, 4))
    moved_world = np.empty((len(ids), 3))
    for i, sid in enumerate(ids):
        p0 = np.asarray(origin_sensor_m[sid], dtype=np.float64).reshape(-1)
        p1 = np.asarray(moved_sensor_m[sid], dtype=np.float64).reshape(-1)
        if (
            p0.shape != (3,)
            or p1.shape != (3,)
            or not (np.isfinite(p0).all() and np.isfinite(p1).all())
        ):
            raise CalibrationError(
                f"sensor {sid}: wand positions must be finite 3-vectors, got {p0} and {p1}"
            )
        delta = _SENSOR2LEVEL @ (p1 - p0)
        horiz = float(np.hypot(delta[0], delta[1]))
        if horiz < min_move_m:
            raise CalibrationError(
                f"sensor {sid} saw the wand move only {horiz * 100:.1f} cm horizontally "
                f"(need {min_move_m * 100:.0f} cm): move the wand further along the y axis"
            )
        # rotate the seen move onto +y: theta = pi/2 - atan2(dy, dx)
        theta = np.pi / 2 - np.arctan2(delta[1], delta[0])
        rot = rot_z(theta) @ _SENSOR2LEVEL
        poses[i] = make_transform(rot, -rot @ p0)
        moved_world[i] = rot @ p1 - rot @ p0
    consensus = np.median(moved_world, axis=0)
    resid = np.linalg.norm(moved_world - consensus, axis=1)
    return Registration(
        method="paper",
        sensor_ids=ids,
        sensor2world=poses,
        residual_m=resid,
        n_sightings=np.full(len(ids), 2, dtype=np.int64),
        rms_m=float(np.sqrt(np.mean(resid**2))),
        world="paper: origin at the wand's first position, y along its move, z up (level sensors)",
    )


def paper_positions_from_sightings(
    sightings: Mapping[str, Sightings],
    *,
    origin_window_s: tuple[float, float] | None = None,
    moved_window_s: tuple[float, float] | None = None,
    still_tol_m: float = 0.03,
    min_still_s: float = 0.3,
    min_move_m: float = 0.2,
    min_sightings: int = 2,
) -> tuple[dict[str, Array], dict[str, Array]]:
    """The two still wand positions of the paper's protocol, in each sensor's frame.

    The operator holds the wand still at the origin, moves it along the y axis and holds it still
    again. Each position is the median of a sensor's sightings in a time window (server clock):
    the protocol's windows when they are known (``origin_window_s``, ``moved_window_s``), else
    windows found in the tracks: in each track, the first still phase (sightings staying within
    ``still_tol_m`` of their mean for at least ``min_still_s``; isolated outliers skipped) and
    the next one at least ``min_move_m`` away; the windows are the median over the sensors that
    saw both, so a sensor that missed one of the positions is named rather than registered on
    the wrong pair.

    Returns
    -------
    origin, moved : dict sensor id -> (3,) float
        Inputs for :func:`register_paper`.

    Raises
    ------
    CalibrationError
        A sensor that did not see both still positions (named in the message), or no sensor
        whose track shows them.
    """
    if (origin_window_s is None) != (moved_window_s is None):
        raise InputError("give both origin_window_s and moved_window_s, or neither")
    blind = origin_window_s is None or moved_window_s is None
    if origin_window_s is None or moved_window_s is None:
        origin_window_s, moved_window_s = find_hold_windows(
            sightings, tol_m=still_tol_m, min_s=min_still_s, min_move_m=min_move_m
        )
    origin: dict[str, Array] = {}
    moved: dict[str, Array] = {}
    for sid, s in sightings.items():
        t, p = s.t_server_s, s.centre_sensor_m
        phases = _still_phases(t, p, still_tol_m, min_still_s) if blind else []
        pair = []
        for (t0, t1), what in ((origin_window_s, "origin"), (moved_window_s, "moved")):
            sel = (t >= t0) & (t <= t1)
            if blind:
                # the sensor's own still phase that overlaps the consensus window (its
                # sightings fall at other instants than the median sensor's); none: it did not
                # see the wand held there, whatever it saw passing through the window
                own = [ph for ph in phases if t[ph[0]] <= t1 and t[ph[-1]] >= t0]
                sel = np.zeros(len(t), dtype=bool)
                if own:
                    sel[max(own, key=len)] = True
            if sel.sum() < min_sightings:
                raise CalibrationError(
                    f"sensor {sid} saw the wand {int(sel.sum())} times while it was held at the "
                    f"{what} position (server time {t0:.2f}-{t1:.2f} s; need {min_sightings}); "
                    "the paper's method needs every sensor to see both positions (is the wand "
                    "hidden by the operator, or out of the sensor's range?)"
                )
            pair.append(np.median(p[sel], axis=0))
        origin[sid], moved[sid] = pair[0], pair[1]
    return origin, moved


def find_hold_windows(
    sightings: Mapping[str, Sightings],
    *,
    tol_m: float = 0.03,
    min_s: float = 0.3,
    min_move_m: float = 0.2,
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Server-time windows of the protocol's two still wand positions, found blind in the
    sightings: in each track the first still phase and the next one at least ``min_move_m``
    away, the windows being the median over the sensors (see
    :func:`paper_positions_from_sightings`). Nothing of the operator's own timing is used."""
    votes = []
    for s in sightings.values():
        t, p = s.t_server_s, s.centre_sensor_m
        phases = _still_phases(t, p, tol_m, min_s)
        if not phases:
            continue
        p0 = np.median(p[phases[0]], axis=0)
        for ph in phases[1:]:
            if np.linalg.norm(np.median(p[ph], axis=0) - p0) >= min_move_m:
                votes.append((t[phases[0][0]], t[phases[0][-1]], t[ph[0]], t[ph[-1]]))
                break
    if not votes:
        raise CalibrationError(
            f"no sensor saw the wand held still ({min_s} s within {tol_m * 100:.0f} cm) at the "
            f"origin and again at least {min_move_m} m away: hold the wand still at the origin, "
            "move it along the y axis and hold it still again (or give the protocol's times)"
        )
    w = np.median(np.array(votes), axis=0)
    # the still phases are made of sightings within tol_m of their mean already: no trimming,
    # which would drop a hold's first and last sightings (at 5 Hz, a 0.6 s hold has three)
    return (w[0], w[1]), (w[2], w[3])


def _still_phases(t: Array, p: Array, tol_m: float, min_s: float) -> list[NDArray[np.intp]]:
    """Runs of sightings that stay within ``tol_m`` of their mean for at least ``min_s``.

    Up to two consecutive outliers inside a run are skipped (left out of it); a gap of more
    than 0.2 s ends a run.
    """
    n = len(t)
    phases: list[NDArray[np.intp]] = []
    i = 0
    while i < n:
        members = [i]
        total = p[i].copy()
        j = i + 1
        misses = 0
        while j < n and t[j] - t[members[-1]] < 0.2 and misses <= 2:
            if np.linalg.norm(p[j] - total / len(members)) < tol_m:
                members.append(j)
                total += p[j]
                misses = 0
            else:
                misses += 1
            j += 1
        if t[members[-1]] - t[i] >= min_s:
            phases.append(np.asarray(members, dtype=np.intp))
            i = members[-1] + 1
        else:
            i += 1
    return phases
