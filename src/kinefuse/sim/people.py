"""Bystanders in the simulated lab: where they stand, who hides whom, and the tracking ids a
Kinect gives the bodies it tracks.

**Placement** (:func:`place_bystander`): bystander ``i`` (0, 1, ...) performs its own clip during
the motion phase only (nobody but the subject is in the room during the wand calibration). Its
clip is shifted in time so that the clip's middle falls at the middle of the motion phase (it
stands in its first pose before and in its last pose after), turned so that its travel (first
to last SpineBase, horizontally) crosses the line from the subject to sensor ``i mod S`` at right
angles, and moved so that, at the middle of the motion phase, its SpineBase stands on that line
``BYSTANDER_GAP_M`` from the subject's (toward the sensor): it passes within a metre of the
subject, between the subject and that sensor. Two people do not walk through each other: when
the two SpineBases would come closer than ``MIN_APPROACH_M`` at some instant of the motion
phase, the gap grows in steps of 5 cm (up to half the distance to the sensor) until they do not.

**Occlusion between people** is the tracker model's (:func:`kinefuse.sim.tracker.simulate_tracker`
``others``): a joint whose line of sight from the sensor passes through another person's capsule
body is not visible (INFERRED, with the error the model gives hidden joints), and a body with
more than ``MOSTLY_HIDDEN_FRACTION`` of its joints hidden by others is lost for that frame.

**Tracking ids** (:func:`tracking_ids`): each sensor numbers the bodies it acquires from a base of
its own (ids are never shared between sensors); a body lost and found again gets a new id; a
sensor lists its bodies in the order of the slots they took when acquired (the lowest free one;
people acquired at the same frame take them in a random order), not in person order.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from kinefuse.core.frames.motion import Motion
from kinefuse.core.skeleton import JOINT_INDEX
from kinefuse.errors import InputError
from kinefuse.sim.rig import Rig

Array = NDArray[np.float64]

#: horizontal distance from the subject's SpineBase to a bystander's at mid-motion, metres
BYSTANDER_GAP_M = 0.8
#: the closest the two SpineBases may come (horizontally), metres: about a shoulder width
MIN_APPROACH_M = 0.5
#: a body with more than this share of its joints hidden by other people is lost
MOSTLY_HIDDEN_FRACTION = 0.6
#: the first tracking id of a sensor's bodies (a Kinect v2's ids are large 64-bit numbers);
#: sensor k starts at ``ID_BASE + (k + 1) * ID_STRIDE``
ID_BASE = 72057594037927936
ID_STRIDE = 2**32

_ROOT = JOINT_INDEX["SpineBase"]


def place_bystander(
    bystander: Motion, subject: Motion, rig: Rig, index: int, motion_s: float
) -> Motion:
    """Place bystander ``index`` (already on the floor, :func:`kinefuse.sim.rig.place_actor`)
    by the module's rule, against the ``subject`` (placed) over a motion phase of ``motion_s``.
    """
    if index < 0:
        raise InputError(f"bystander index must be >= 0, got {index}")
    t_mid = 0.5 * float(motion_s)
    centre = subject.at(np.array([t_mid]))[0, _ROOT, :2]
    sensor = rig.sensors[index % len(rig.sensors)].sensor2world[:2, 3]
    u = sensor - centre
    dist = float(np.linalg.norm(u))
    if dist < 1e-6:
        raise InputError(f"sensor {rig.sensors[index % len(rig.sensors)].id} stands on the subject")
    u /= dist
    # the clip's middle at the motion phase's middle
    shift = round((t_mid - 0.5 * bystander.duration_s) * bystander.rate_hz)
    p = bystander.positions
    if shift > 0:
        p = np.concatenate([np.repeat(p[:1], shift, axis=0), p])
    elif shift < 0:
        p = p[min(-shift, len(p) - 1) :]
    travel = p[-1, _ROOT, :2] - p[0, _ROOT, :2]
    # turn the clip so its travel runs across the line of sight (perpendicular to u)
    want = np.arctan2(u[0], -u[1])  # the direction (u rotated by -90 degrees)
    have = np.arctan2(travel[1], travel[0]) if np.linalg.norm(travel) > 0.05 else want
    a = want - have
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    q = p.copy()
    q[..., :2] = p[..., :2] @ rot.T
    turned = replace(bystander, positions=q)
    at_mid = turned.at(np.array([t_mid]))[0, _ROOT, :2]
    t = np.arange(0.0, float(motion_s) + 1e-9, 1.0 / 30.0)
    path = turned.at(t)[:, _ROOT, :2] - at_mid
    own = subject.at(t)[:, _ROOT, :2]
    for gap in np.arange(min(BYSTANDER_GAP_M, 0.5 * dist), 0.5 * dist + 1e-9, 0.05):
        if np.linalg.norm(path + centre + gap * u - own, axis=1).min() >= MIN_APPROACH_M:
            break
    q[..., :2] += centre + gap * u - at_mid
    return replace(bystander, positions=q)


def tracking_ids(
    tracked: NDArray[np.bool_], sensor_index: int, rng: np.random.Generator
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """A sensor's tracking ids and listing order of ``P`` people over ``T`` frames.

    Parameters
    ----------
    tracked : (T, P) bool
        Whether the sensor tracks person ``p`` at frame ``t``.
    sensor_index : int
        The sensor's place in the rig (sets its id base).
    rng : numpy.random.Generator
        Breaks ties between people acquired at the same frame.

    Returns
    -------
    body_id : (T, P) int64
        The id person ``p`` has on this sensor at frame ``t`` (0 where not tracked).
    slot : (T, P) int64
        Its slot (the listing order: lower first); -1 where not tracked.
    """
    n_t, n_p = tracked.shape
    ids = np.zeros((n_t, n_p), dtype=np.int64)
    slot = np.full((n_t, n_p), -1, dtype=np.int64)
    next_id = ID_BASE + (sensor_index + 1) * ID_STRIDE
    cur_id = np.zeros(n_p, dtype=np.int64)
    cur_slot = np.full(n_p, -1, dtype=np.int64)
    for t in range(n_t):
        cur_slot[~tracked[t]] = -1
        cur_id[~tracked[t]] = 0
        new = np.flatnonzero(tracked[t] & (cur_slot < 0))
        for p in rng.permutation(new):
            used = set(cur_slot[cur_slot >= 0].tolist())
            cur_slot[p] = min(set(range(n_p + 1)) - used)
            next_id += 1
            cur_id[p] = next_id
        ids[t], slot[t] = cur_id, cur_slot
    return ids, slot
