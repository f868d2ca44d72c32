"""A static trial: landmarks carried by marker clusters, ISB segment frames, and its checks.

The map's ``[landmarks]`` (virtual markers: joint centres, epicondyle midpoints) are computed
by their rule in the static trial and expressed in the frame of the named ``[clusters]`` entry
(a least-squares rigid fit of all its markers, :func:`kinefuse.biomech.anatomical.rigid_fit`);
during the motion the cluster carries them. A motion file with thigh and shank clusters but no
knee markers so reaches the knee centre (the CAST idea).

The anatomical frames (:mod:`kinefuse.biomech.anatomical`) are built in the static trial from
the map's joint centres (Kinect joints ``HipRight``, ``KneeRight``, ...) and its ``[anatomy]``
axis landmarks, and carried by the segment's cluster; every cluster is fitted to its own markers
plus the joint centres its neighbours carry (:func:`~kinefuse.biomech.anatomical.segment_poses`).
The trunk and the arms are not rigid clusters (the shoulder markers slide with the shoulder
girdle; an arm's clusters hold the acromion, the biceps, the lateral epicondyle and markers on
both forearm bones): the trunk's long axis is built in every frame from the lumbar joint the
pelvis carries to the middle of the shoulders, the arms' long axes from their joint centres,
and the elbow as a hinge with the static trial's carrying angle
(:func:`~kinefuse.biomech.anatomical.hinge_axis`).

Checks (each an :class:`~kinefuse.errors.InputError` naming what came and what to do):

* the static trial has every marker the landmarks, clusters and joints need;
* it is of the same marker set (the motion's cluster markers are all in it) and subject: the
  size of every pelvis, thigh, shank and foot cluster (the RMS distance of its markers from
  their centre, median over frames) differs by at most 10 % between the two trials (the trunk's
  and arms' markers move with the shoulders, so they are not compared);
* the subject stands still: no marker of those clusters moves more than 30 mm from its median
  position over the static window (the largest is named).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech import anatomical as an
from kinefuse.biomech.limbs import limb
from kinefuse.biomech.marker_maps import (
    JointRule,
    MarkerMap,
    apply_marker_map,
    rule_points,
)
from kinefuse.core.frames.marker_data import MarkerData, MarkerResolver
from kinefuse.errors import InputError

Array = NDArray[np.float64]

__all__ = [
    "MAX_LENGTH_CHANGE",
    "MAX_STATIC_MOTION_M",
    "AnatomicalFrames",
    "anatomical_frames",
    "static_window",
    "with_landmarks",
]

#: Largest relative change of an inter-marker distance between the static trial and the motion.
MAX_LENGTH_CHANGE = 0.10
#: Largest distance of a cluster marker from its median position in the static trial, metres.
MAX_STATIC_MOTION_M = 0.030

_LEG = ("thigh", "shank", "foot")
#: clusters the checks compare (rigid enough: the trunk's and arms' markers move with the arms)
_RIGID = ("pelvis", *_LEG)
_ARM = ("upper_arm", "forearm")


def static_window(markers: MarkerData, window: tuple[float, float] | None) -> MarkerData:
    """The frames of ``markers`` inside ``window`` (seconds; all frames when None)."""
    if window is None:
        return markers
    lo, hi = window
    sel = (markers.t_s >= lo) & (markers.t_s <= hi)
    if sel.sum() < 1:
        raise InputError(
            f"{markers.path}: the static window {lo:g}:{hi:g} s holds no frame (the file runs "
            f"{markers.t_s[0]:.2f} to {markers.t_s[-1]:.2f} s); give START:END inside it"
        )
    return replace(markers, positions=markers.positions[sel], t_s=markers.t_s[sel])


def _rule_points(markers: MarkerData, rule: JointRule, mmap: MarkerMap) -> Array | None:
    """(T, 3) of a rule on ``markers``, None when a marker is missing from the file."""
    return rule_points(markers, rule, mmap)


def _cluster_points(markers: MarkerData, names: tuple[str, ...]) -> Array | None:
    f = MarkerResolver(markers.names)
    idx = [f(n) for n in names]
    if any(i is None for i in idx):
        return None
    return markers.positions[:, [int(i) for i in idx if i is not None]]


def _cluster_size(p: Array) -> float:
    """A cluster's size: the median over frames of the RMS distance of its markers from their
    centroid, metres (frames with a missing marker are left out). One number per segment, so a
    short marker pair that soft tissue or a toe joint stretches does not decide alone (the
    shared Gait2354 walk's R.Toe.Tip-R.Toe.Med pair is 9 % shorter than in its static trial,
    the foot cluster's size 0.7 %)."""
    ok = np.isfinite(p).all(axis=(1, 2))
    if not ok.any():
        return float("nan")
    q = p[ok]
    c = q.mean(axis=1, keepdims=True)
    return float(np.median(np.sqrt(((q - c) ** 2).sum(-1).mean(-1))))


def _median(p: Array) -> Array:
    return np.asarray(np.nanmedian(p, axis=0), dtype=np.float64)


def check_static(static: MarkerData, motion: MarkerData, mmap: MarkerMap) -> None:
    """Refuse a static trial of another marker set or subject, or one in which the subject
    moves (rules in the module docstring)."""
    # the map's landmarks as the static trial gives them (the motion has them carried)
    static = with_landmarks(static, mmap, None)[0]
    sf, mf = MarkerResolver(static.names), MarkerResolver(motion.names)
    wanted = {n for names in mmap.clusters.values() for n in names}
    lack = sorted(n for n in wanted if mf(n) is not None and sf(n) is None)
    if lack:
        raise InputError(
            f"{static.path}: not a static trial of this marker set: it lacks the cluster markers "
            f"{', '.join(lack)} that {motion.path} has. Give the static trial recorded with the "
            "same markers"
        )
    worst = (0.0, "")
    for seg, names in mmap.clusters.items():
        if not seg.startswith(_RIGID):
            continue  # markers over the shoulder girdle move with the arms: not a rigid body
        ps = _cluster_points(static, names)
        pm = _cluster_points(motion, names)
        if ps is None or pm is None:
            continue
        med = _median(ps)
        d = np.linalg.norm(ps - med[None], axis=-1)
        if np.isfinite(d).any():
            k = int(np.nanargmax(np.nanmax(d, axis=0)))
            dmax = float(np.nanmax(d[:, k]))
            if dmax > worst[0]:
                worst = (dmax, names[k])
        ls, lm = _cluster_size(ps), _cluster_size(pm)
        if np.isfinite(ls) and np.isfinite(lm) and abs(lm - ls) > MAX_LENGTH_CHANGE * ls:
            raise InputError(
                f"{static.path}: not a static trial of this subject: the {seg} cluster "
                f"({', '.join(names)}) spans {1e3 * ls:.0f} mm (RMS distance of its markers "
                f"from their centre), in {motion.path} {1e3 * lm:.0f} mm (more than "
                f"{100 * MAX_LENGTH_CHANGE:.0f} % apart). Give this subject's static trial"
            )
    if worst[0] > MAX_STATIC_MOTION_M:
        raise InputError(
            f"{static.path}: the subject moves during the static trial: marker {worst[1]} goes "
            f"{1e3 * worst[0]:.0f} mm from its median position (at most "
            f"{1e3 * MAX_STATIC_MOTION_M:.0f} mm allowed). Choose a still part with "
            "--static-window START:END or STATIC.trc:START:END"
        )


def with_landmarks(
    markers: MarkerData, mmap: MarkerMap, static: MarkerData | None = None
) -> tuple[MarkerData, tuple[str, ...]]:
    """``markers`` with the map's ``[landmarks]`` appended as virtual markers.

    A landmark whose rule's markers the file has is computed from them; else, with a static
    trial, it is computed there and carried by its cluster; else it is left out (a joint that
    needs it then fails naming the markers). Returns the markers and notes.
    """
    notes = []
    cur = markers  # grows: a landmark may use (or be carried by a cluster with) earlier ones
    st = static

    def add(m: MarkerData, name: str, pts: Array) -> MarkerData:
        return replace(m, names=(*m.names, name),
                       positions=np.concatenate([m.positions, pts[:, None]], axis=1))  # fmt: skip

    for lm, (rule, cluster) in mmap.landmarks.items():
        if MarkerResolver(cur.names)(lm) is not None:
            continue
        if st is None:
            direct = _rule_points(cur, rule, mmap)
            if direct is not None:
                cur = add(cur, lm, direct)
            continue
        ps = _rule_points(st, rule, mmap)
        if ps is None and _cluster_points(cur, mmap.clusters[cluster]) is None:
            continue  # the motion lacks its segment too (a partial body): the joint is unbuilt
        if ps is None:
            need = [
                n for n in rule.marker_names(mmap.pelvis) if MarkerResolver(st.names)(n) is None
            ]
            raise InputError(
                f"{st.path}: the landmark rule {lm!r} needs the markers {', '.join(need)}, "
                "which the static trial does not have. Give a static trial with them, or fix "
                "the map's [landmarks]"
            )
        if MarkerResolver(st.names)(lm) is None:
            st = add(st, lm, ps)
        tmpl = _cluster_points(st, mmap.clusters[cluster])
        mov = _cluster_points(cur, mmap.clusters[cluster])
        if tmpl is None or mov is None:
            where = st.path if tmpl is None else cur.path
            raise InputError(
                f"{where}: the landmark {lm!r} is carried by cluster {cluster} "
                f"({', '.join(mmap.clusters[cluster])}), whose markers this file lacks"
            )
        r, p = an.rigid_fit(_median(tmpl), mov)
        cur = add(cur, lm, np.einsum("tij,j->ti", r, _median(ps)) + p)
        notes.append(f"{lm} from the static trial, carried by {cluster}")
    return cur, tuple(notes)


@dataclass(frozen=True, eq=False)
class AnatomicalFrames:
    """ISB segment frames over the motion, the lab frame, and what was skipped and why."""

    frames: dict[str, Array]  # segment -> (T, 3, 3)
    lab: Array  # (3, 3)
    status: dict[str, str] = field(default_factory=dict)  # segment -> "ok" or the reason
    #: angles the frames do not define (forearm pronation without two styloid markers)
    undefined: tuple[str, ...] = ()
    #: OpenSim model -> segment -> the model body's frame in the ISB frame
    #: (:func:`kinefuse.biomech.anatomical.model_body_offsets`), for the models whose marker
    #: template the static trial has
    model_offsets: dict[str, dict[str, Array]] = field(default_factory=dict)


def _axis_hint(static: MarkerData, mmap: MarkerMap, key: str, side: str) -> Array | None:
    pair = mmap.anatomy.get(f"{key}_{side}")
    if pair is None:
        return None
    pts = _cluster_points(static, pair)
    if pts is None:
        raise InputError(
            f"{static.path}: [anatomy] {key}_{side} needs the markers {', '.join(pair)}, which "
            "the static trial does not have"
        )
    a, b = _median(pts[:, 0]), _median(pts[:, 1])
    d = b - a  # medial -> lateral (heel -> toe for the foot)
    return d if side == "right" or key == "foot" else -d


#: Segments whose long axis is rebuilt in every frame from their two joint centres (the
#: cluster keeps only the rotation about it): an arm's markers are not one rigid body (the upper
#: arm's cluster holds the acromion marker, which moves with the shoulder girdle; the
#: forearm's holds the lateral epicondyle, on the humerus, and markers on both the radius and
#: the ulna, which pronation turns about each other).
LONG_AXIS_PER_FRAME = ("upper_arm", "forearm")


def _elbow_centres(
    pos: Array,
    idx: dict[str, int],
    motion: MarkerData,
    static: MarkerData,
    mmap: MarkerMap,
    carrying: dict[str, float],
) -> None:
    """Put each elbow centre (in place in ``pos``) on the hinge's axis
    (:func:`kinefuse.biomech.anatomical.hinge_axis`) through the lateral epicondyle marker,
    half the static trial's epicondyle width medial of it, where the elbow is bent enough for
    the axis to be defined (blended with the carried centre below). A centre carried from the
    static trial by the upper arm's markers turns with their error about the arm (the biceps
    marker over a contracting muscle, the acromion marker on the shoulder girdle); the lateral
    marker sits on the axis itself."""
    for side in ("right", "left"):
        cap = side.capitalize()
        pair = mmap.anatomy.get(f"elbow_axis_{side}")
        need = (f"Shoulder{cap}", f"Elbow{cap}", f"Wrist{cap}")
        if pair is None or not set(need) <= set(idx):
            continue
        lat_m, lat_s = _cluster_points(motion, pair[1:]), _cluster_points(static, pair)
        if lat_m is None or lat_s is None or _cluster_points(motion, pair) is not None:
            continue  # no lateral marker, or both epicondyles: the map's centre is measured
        half = 0.5 * float(np.nanmedian(np.linalg.norm(lat_s[:, 1] - lat_s[:, 0], axis=-1)))
        lat = lat_m[:, 0]
        sh, wr = pos[:, idx[need[0]]], pos[:, idx[need[2]]]
        carried = pos[:, idx[need[1]]].copy()
        c = lat.copy()  # on the axis already: the bend is measured about it from the start
        for _ in range(3):  # the axis from the centre, the centre from the axis
            axis, w = an.hinge_axis(sh - c, c - wr, carrying.get(side, 0.0))
            hinge = lat + half * axis * (-1.0 if side == "right" else 1.0)  # medial
            c = an.blend(hinge, carried, w)
        pos[:, idx[need[1]]] = c


def _long_axes_per_frame(
    pos: Array,
    idx: dict[str, int],
    motion: MarkerData,
    static: MarkerData,
    mmap: MarkerMap,
    frames: dict[str, Array],
    carrying: dict[str, float],
) -> None:
    """Rebuild the long axis ``Y`` of the :data:`LONG_AXIS_PER_FRAME` segments in ``frames``
    (in place) from the motion's joint centres ``pos`` of every frame (the elbow's on its hinge
    axis, :func:`_elbow_centres`); ``Z`` stays the carried one made perpendicular (the
    forearm's from its two styloid markers where the map's ``wrist_axis`` has them), and the
    humerus's comes from the forearm where the elbow is bent
    (:func:`kinefuse.biomech.anatomical.humerus_from_forearm`)."""
    pos = pos.copy()
    _elbow_centres(pos, idx, motion, static, mmap, carrying)
    for kind in LONG_AXIS_PER_FRAME:
        for side in ("right", "left"):
            seg = f"{kind}_{side}"
            lb = limb(seg)
            if seg not in frames or lb.proximal not in idx or lb.distal not in idx:
                continue
            y = pos[:, idx[lb.proximal]] - pos[:, idx[lb.distal]]
            z = frames[seg][..., 2]
            pair = mmap.anatomy.get(f"wrist_axis_{side}") if kind == "forearm" else None
            sty = None if pair is None else _cluster_points(motion, pair)
            if sty is not None:  # ulnar to radial styloid, to the right on both sides
                d = sty[:, 1] - sty[:, 0]
                z = np.where(np.isfinite(d), d if side == "right" else -d, z)
            frames[seg] = an.frame_from_long_axis(y, z)
    for side in ("right", "left"):
        arm, fore = f"upper_arm_{side}", f"forearm_{side}"
        if arm in frames and fore in frames:
            frames[arm] = an.humerus_from_forearm(
                frames[arm], frames[fore][..., 1], carrying.get(side, 0.0)
            )


def _trunk_frames(
    pos: Array, idx: dict[str, int], pelvis_pose: tuple[Array, Array], lumbar: Array
) -> Array | None:
    """Trunk frames ``(T, 3, 3)`` built in every frame: ``Y`` from the lumbar joint (``lumbar``,
    found in the static trial, carried by the pelvis) to the middle of the shoulders (joint
    centres ``pos``), ``Z`` along the shoulder line; None when the motion lacks the
    shoulders."""
    if not {"ShoulderLeft", "ShoulderRight"} <= set(idx):
        return None
    r, p = pelvis_pose
    lum = np.einsum("tij,j->ti", r, lumbar) + p
    sl, sr = pos[:, idx["ShoulderLeft"]], pos[:, idx["ShoulderRight"]]
    out: Array = an.frame_from_long_axis(0.5 * (sl + sr) - lum, sr - sl)
    return out


#: Least knee flexion range in the motion (degrees) for its hinge axis to be found from it.
MIN_FUNCTIONAL_RANGE_DEG = 30.0
#: Largest angle (degrees) between the static trial's epicondyle axis and the axis the knee
#: flexes about in the motion that is taken as the same axis (the epicondyles are kept, ISB).
#: Ours, not a literature value: the two are 0.3-10.7 deg apart on the marker sets placed on
#: CMU clips and on the shared walks' other knees, 29 deg on the Rajagopal walk's left knee,
#: whose medial marker sits behind the axis the knee turns about (docs/analysis.md).
MAX_KNEE_AXIS_DISAGREEMENT_DEG = 15.0


def _rotvec(r: Array) -> Array:
    """Rotation vectors (axis times angle, radians) of rotations ``(..., 3, 3)``."""
    c = np.clip((np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    ang = np.arccos(c)
    v = np.stack([r[..., 2, 1] - r[..., 1, 2], r[..., 0, 2] - r[..., 2, 0],
                  r[..., 1, 0] - r[..., 0, 1]], axis=-1)  # fmt: skip
    with np.errstate(invalid="ignore", divide="ignore"):
        out: Array = v * (ang / (2.0 * np.sin(ang)))[..., None]
    return np.where((ang < 1e-9)[..., None], 0.0, out)


def functional_hinge_axis(proximal: Array, distal: Array) -> tuple[Array, float] | None:
    """The axis a hinge turns about in the motion, in the static trial's world coordinates.

    ``proximal``, ``distal``: ``(T, 3, 3)`` rotations of the two segments' clusters from the
    static trial (:func:`kinefuse.biomech.anatomical.rigid_fit`). The distal segment's
    rotation relative to the proximal one, from its least-turned frame to every other, is a
    rotation about the hinge's axis (in the proximal segment's static coordinates); the axis is
    the principal direction of those rotation vectors. Returns ``(unit axis, range in
    degrees)``, None with fewer than 10 frames."""
    rel = np.einsum("tji,tjk->tik", proximal, distal)
    ok = np.isfinite(rel).all(axis=(1, 2))
    if ok.sum() < 10:
        return None
    rel = rel[ok]
    ref = int(np.argmin(np.linalg.norm(_rotvec(rel), axis=-1)))
    v = _rotvec(np.einsum("tij,kj->tik", rel, rel[ref]))
    _, _, vt = np.linalg.svd(v, full_matrices=False)
    axis: Array = vt[0]
    span = float(np.degrees(np.ptp(v @ axis)))
    return axis, span


def _functional_knees(
    poses: dict[str, tuple[Array, Array]],
    static_frames: dict[str, Array],
    jp: dict[str, Array],
    static: MarkerData,
    mmap: MarkerMap,
) -> dict[str, str]:
    """Each knee whose static trial's epicondyle axis is more than
    :data:`MAX_KNEE_AXIS_DISAGREEMENT_DEG` from the axis it flexes about in the motion (at
    least :data:`MIN_FUNCTIONAL_RANGE_DEG` of flexion; :func:`functional_hinge_axis`): a
    medial or lateral knee marker of the static trial is misplaced, and with it the ISB axis
    and the centre between the two. The thigh's ``Z`` then is the hinge axis (pointing right),
    the centre on it through the lateral epicondyle marker, as far medial of it as the map's
    centre is, and the thigh's and shank's long axes are rebuilt to that centre (in place in
    ``static_frames``). Returns ``thigh_<side>`` -> what was done, for its status."""
    notes: dict[str, str] = {}
    for side in ("right", "left"):
        cap = side.capitalize()
        th, sh = f"thigh_{side}", f"shank_{side}"
        pair = mmap.anatomy.get(f"knee_axis_{side}")
        need = (f"Hip{cap}", f"Knee{cap}", f"Ankle{cap}")
        if th not in poses or sh not in poses or pair is None or not set(need) <= set(jp):
            continue
        found = functional_hinge_axis(poses[th][0], poses[sh][0])
        hint = _axis_hint(static, mmap, "knee_axis", side)
        lat = _cluster_points(static, pair[1:])
        if found is None or hint is None or lat is None:
            continue
        axis, span = found
        axis = axis if axis @ hint > 0 else -axis
        off = float(np.degrees(np.arccos(np.clip(axis @ hint / np.linalg.norm(hint), -1, 1))))
        if span < MIN_FUNCTIONAL_RANGE_DEG or off <= MAX_KNEE_AXIS_DISAGREEMENT_DEG:
            continue
        lateral = _median(lat[:, 0])
        depth = float(np.linalg.norm(jp[need[1]] - lateral))
        centre = lateral + depth * (-axis if side == "right" else axis)
        static_frames[th] = an.frame_from_long_axis(jp[need[0]] - centre, axis)
        ankle_hint = _axis_hint(static, mmap, "ankle_axis", side)
        static_frames[sh] = an.frame_from_long_axis(
            centre - jp[need[2]], ankle_hint if ankle_hint is not None else axis
        )
        notes[th] = (
            f"ok: the static trial's knee markers give an axis {off:.0f} deg from the one the "
            f"knee flexes about in the motion ({span:.0f} deg of flexion), so the knee's axis "
            "and centre are that hinge's, through the lateral knee marker"
        )
    return notes


#: A trunk cluster marker within this distance of the thorax's midsagittal plane in the static
#: trial (the plane of its long axis and ``X``), metres, is a midline marker (IJ, PX, C7, T8;
#: not the acromions).
MIDLINE_M = 0.03


def _thorax_frames(
    y: Array,
    top: Array,
    template: Array,
    moving: Array,
    static_frame: Array,
    static_top: Array,
    carried: Array,
) -> Array:
    """The thorax of a capture without a pelvis, built in every frame as ISB's (Wu et al. 2005):
    ``Y`` the long axis (``y``, from the landmarks' midpoints: mid PX/T8 to mid IJ/C7, which
    ``SpineBase`` and ``SpineShoulder`` lie on), ``Z`` normal to the plane of that axis and the
    cluster's midline markers (:data:`MIDLINE_M`; the plane of IJ, C7 and mid PX/T8 when they
    are IJ and PX). The acromion markers of the cluster slide with the shoulder girdle: a
    rigid fit through them turns the thorax with every shrug and arm swing. Frames (or a
    cluster) without midline markers keep the carried ``Z`` (``carried``, ``(T, 3, 3)``), and
    frames without the axis the carried frame.

    ``top``: ``(T, 3)`` the axis's upper point (``SpineShoulder``); ``template``, ``moving``:
    the cluster's markers in the static trial ``(M, 3)`` and the motion ``(T, M, 3)``;
    ``static_frame``, ``static_top``: the thorax frame and ``SpineShoulder`` in the static
    trial."""
    lateral = (template - static_top) @ static_frame[:, 2]
    midline = np.abs(lateral) < MIDLINE_M
    z_hint = carried[..., 2]
    if midline.any():
        with np.errstate(invalid="ignore"):
            forward = np.nanmean(moving[:, midline] - top[:, None], axis=1)
        z_from = np.cross(forward, y)  # forward x up: to the right
        z_hint = np.where(np.isfinite(z_from), z_from, z_hint)
    built: Array = an.frame_from_long_axis(y, z_hint)
    out: Array = np.where(np.isfinite(built), built, carried)
    return out


#: Seconds at the start of the motion whose mean thorax heading is the lab's ``X`` of a
#: capture without a pelvis.
HEADING_S = 1.0


def _initial_heading(trunk: Array, t_s: Array) -> Array:
    """The thorax's mean forward axis over the first :data:`HEADING_S` seconds in which it is
    present (world ``+x`` when it never is), ``(3,)``."""
    ok = np.flatnonzero(np.isfinite(trunk).all(axis=(1, 2)))
    if not ok.size:
        return np.array([1.0, 0.0, 0.0])
    first = ok[t_s[ok] <= t_s[ok[0]] + HEADING_S]
    forward: Array = trunk[first, :, 0].mean(axis=0)
    return forward


def anatomical_frames(motion: MarkerData, static: MarkerData, mmap: MarkerMap) -> AnatomicalFrames:
    """ISB frames of every segment the map and the files allow (module docstring).

    Parameters
    ----------
    motion, static : MarkerData
        The motion (with the map's landmarks appended, :func:`with_landmarks`) and the static
        trial (its still window).
    mmap : MarkerMap

    Returns
    -------
    AnatomicalFrames
    """
    st_aug, _ = with_landmarks(static, mmap, None)
    pos, jn, _ = apply_marker_map(st_aug, mmap, partial=True)  # a partial body: its segments
    jp = {n: _median(pos[:, i]) for i, n in enumerate(jn)}
    status: dict[str, str] = {}
    static_frames: dict[str, Array] = {}
    up = np.array([0.0, 0.0, 1.0])
    pv = mmap.pelvis
    pelvis_pts = None if pv is None else _cluster_points(static, pv.marker_names())
    asis_mid: Array | None = None
    asis_width = 0.0
    depth: float | None = None  # ASIS midpoint to PSIS midpoint (not to a sacral marker)
    if pv is not None and pelvis_pts is not None:
        pts = [_median(pelvis_pts[:, k]) for k in range(pelvis_pts.shape[1])]
        back = pts[2] if pv.sacrum else 0.5 * (pts[2] + pts[3])
        static_frames["pelvis"], asis_mid = an.pelvis_frame(pts[0], pts[1], back)
        asis_width = float(np.linalg.norm(pts[0] - pts[1]))
        depth = None if pv.sacrum else float(np.linalg.norm(asis_mid - back))
    elif {"HipLeft", "HipRight", "SpineMid"} <= set(jp):
        static_frames["pelvis"] = an.pelvis_frame_from_hips(jp["HipRight"], jp["HipLeft"],
                                                            jp["SpineMid"])  # fmt: skip
    else:
        status["pelvis"] = "skipped: no pelvis markers ([pelvis]) and no hip joints in the map"
    shoulders = {"ShoulderLeft", "ShoulderRight"} <= set(jp)
    lumbar: Array | None = None
    if shoulders and asis_mid is not None:
        # the torso's long axis as the gait models define it: from the lumbar joint to the
        # middle of the shoulders (anatomical.lumbar_joint_centre)
        lumbar = an.lumbar_joint_centre(static_frames["pelvis"], asis_mid, asis_width, depth)
        static_frames["trunk"] = an.frame_from_long_axis(
            0.5 * (jp["ShoulderLeft"] + jp["ShoulderRight"]) - lumbar,
            jp["ShoulderRight"] - jp["ShoulderLeft"],
        )
    elif shoulders and {"SpineBase", "SpineShoulder"} <= set(jp):
        static_frames["trunk"] = an.frame_from_long_axis(
            jp["SpineShoulder"] - jp["SpineBase"], jp["ShoulderRight"] - jp["ShoulderLeft"]
        )
    else:
        status["trunk"] = "skipped: the map has no SpineShoulder and shoulders"
    for side in ("right", "left"):
        cap = side.capitalize()
        hip, knee, ankle = (jp.get(f"{j}{cap}") for j in ("Hip", "Knee", "Ankle"))
        sh, el, wr = (jp.get(f"{j}{cap}") for j in ("Shoulder", "Elbow", "Wrist"))
        # each long-bone segment: its long axis, and the hint of its second axis (a landmark
        # axis, else its parent segment's z)
        for segment, proximal, distal, hint, parent in (
            ("thigh", hip, knee, "knee_axis", "pelvis"),
            ("shank", knee, ankle, "ankle_axis", f"thigh_{side}"),
            ("upper_arm", sh, el, "elbow_axis", "trunk"),
            ("forearm", el, wr, "wrist_axis", f"upper_arm_{side}"),
        ):
            if proximal is None or distal is None:
                continue
            h = _axis_hint(st_aug, mmap, hint, side)
            fallback = static_frames.get(parent, np.eye(3))[:, 2]
            static_frames[f"{segment}_{side}"] = an.frame_from_long_axis(
                proximal - distal, h if h is not None else fallback
            )
        foot = _axis_hint(st_aug, mmap, "foot", side) if ankle is not None else None
        if foot is not None:
            x = foot * np.array([1.0, 1.0, 0.0])
            x = x / np.linalg.norm(x)
            static_frames[f"foot_{side}"] = np.stack([x, up, np.cross(x, up)], axis=-1)
    templates: dict[str, Array] = {}
    moving: dict[str, Array] = {}
    for seg in list(static_frames):
        names = mmap.clusters.get(seg)
        if names is None:
            status[seg] = "skipped: the map gives this segment no marker cluster ([clusters])"
            del static_frames[seg]
            continue
        ts, tm = _cluster_points(st_aug, names), _cluster_points(motion, names)
        if ts is None or tm is None:
            where = static.path if ts is None else motion.path
            status[seg] = f"skipped: {where} lacks markers of its cluster ({', '.join(names)})"
            del static_frames[seg]
            continue
        templates[seg], moving[seg] = _median(ts), tm
    joints = []
    for seg in templates:
        if seg in ("pelvis", "trunk"):
            continue
        lb = limb(seg)
        if lb.parent in templates and lb.proximal in jp:
            joints.append((lb.parent, seg, jp[lb.proximal]))
    poses = an.segment_poses(templates, moving, joints)
    knee_notes = _functional_knees(poses, static_frames, jp, st_aug, mmap)
    frames = {seg: an.carry(static_frames[seg], np.eye(3), poses[seg][0]) for seg in templates}
    # the motion's joint centres in every frame: the trunk and the arms are built from them
    mpos, mjn, _ = apply_marker_map(motion, mmap, partial=True)
    midx = {n: i for i, n in enumerate(mjn)}
    if "trunk" in frames and lumbar is not None and "pelvis" in frames:
        # the shoulder markers slide with the shoulder girdle (their spread changes by
        # centimetres with the arm swing), so the trunk is not carried as a rigid cluster: its
        # long axis is built in every frame, from the lumbar joint the pelvis carries to the
        # middle of the shoulders, as in the static trial
        trunk = _trunk_frames(mpos, midx, poses["pelvis"], lumbar)
        if trunk is not None:
            frames["trunk"] = trunk
    elif (
        "trunk" in frames and "pelvis" not in frames and {"SpineBase", "SpineShoulder"} <= set(midx)
    ):
        frames["trunk"] = _thorax_frames(
            mpos[:, midx["SpineShoulder"]] - mpos[:, midx["SpineBase"]],
            mpos[:, midx["SpineShoulder"]],
            templates["trunk"],
            moving["trunk"],
            static_frames["trunk"],
            jp["SpineShoulder"],
            frames["trunk"],
        )
    # each elbow's carrying angle in the static trial (its epicondyle frames): the hinge's
    carrying = {}
    for side in ("right", "left"):
        arm, fore = (static_frames.get(f"{k}_{side}") for k in ("upper_arm", "forearm"))
        if arm is not None and fore is not None:
            carrying[side] = float(an.jcs_zxy(arm, fore)[1])
    _long_axes_per_frame(mpos, midx, motion, st_aug, mmap, frames, carrying)
    for seg in frames:
        status[seg] = knee_notes.get(seg, "ok")
    if "trunk" in frames and "pelvis" not in frames:
        status["trunk"] = (
            "ok: no pelvis, so its angles (thorax_*) are relative to the lab: the vertical and "
            "the thorax's heading at the start of the motion"
        )
    for kind in (*_LEG, *_ARM):
        for side in ("right", "left"):
            seg = f"{kind}_{side}"
            status.setdefault(seg, "skipped: the map or the files do not give its joint centres")
    # the lab: the horizontal world axis of progression (pelvis travel; else its facing)
    if "pelvis" in frames:
        tr = poses["pelvis"][1]
        ok = np.flatnonzero(np.isfinite(tr).all(-1))
        disp = tr[ok[-1]] - tr[ok[0]] if ok.size else np.zeros(3)
        facing = np.nanmean(frames["pelvis"][:, :, 0], axis=0)
        lab = an.lab_frame(an.progression_axis(disp, facing))
    elif "trunk" in frames:
        lab = an.lab_frame(_initial_heading(frames["trunk"], motion.t_s))
    else:
        lab = an.lab_frame(np.array([1.0, 0.0, 0.0]))
    undefined = tuple(
        f"forearm_pronation_{side}"
        for side in ("right", "left")
        if mmap.anatomy.get(f"wrist_axis_{side}") is None
        or _cluster_points(motion, mmap.anatomy[f"wrist_axis_{side}"]) is None
    )
    model_offsets = {}
    for name, model in an.OPENSIM_MODELS.items():
        names = tuple(k for tmpl in model.templates.values() for k in tmpl)
        found = _cluster_points(static, names) if names else None
        if found is not None:
            medians = {k: _median(found[:, i]) for i, k in enumerate(names)}
            offsets = an.model_body_offsets(
                {k: v for k, v in static_frames.items() if k in frames}, medians,
                model.templates, lumbar,
            )  # fmt: skip
            if offsets:
                model_offsets[name] = offsets
    return AnatomicalFrames(
        frames=frames, lab=lab, status=status, undefined=undefined, model_offsets=model_offsets
    )
