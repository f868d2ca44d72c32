"""Files -> :class:`~kinefuse.biomech.sequence.SkeletonSequence`, the input of the analysis.

* :func:`sequence_from_motion_file`: a BVH or ASF/AMC clip, retargeted onto the Kinect joints
  (:func:`kinefuse.biomech.retarget`, metres, z up) **with the source's own limb rotations**: a
  limb's orientation is the global rotation of the source joint the name map puts at the limb's
  proximal Kinect joint (``upper_arm_left`` <- the joint at ``ShoulderLeft``: cgspeed
  ``LeftArm``, ASF ``lhumerus``), turned into the world's axes by the retargeting's axis change.
  Limbs whose proximal joint the map builds from several source joints (a mean, a blend) or from
  an End Site, or that the map leaves to synthesis, get no orientation (they fall back to the
  position-based frame of the normalization). The clip is not placed in a lab (the analysis
  does not depend on where the subject stands).
* :func:`sequence_from_markers`: a TRC or C3D marker file through a marker map
  (:mod:`kinefuse.biomech.marker_maps`): the map's joints only, with the orientations of the
  limbs the map gives a rigid marker cluster.

Fused sessions are built by :func:`kinefuse.app.workflows.analyze.sequence_from_session` (it runs
the fusion workflow).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.limbs import LIMBS
from kinefuse.biomech.marker_maps import (
    MarkerMap,
    apply_marker_map,
    cluster_orientations,
    load_marker_map,
    select_marker_map,
)
from kinefuse.biomech.sequence import SkeletonSequence
from kinefuse.core.frames.source_motion import END_SITE_SUFFIX, SourceMotion, motion_suffix
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError
from kinefuse.formats.markers import MarkerData, read_markers

Array = NDArray[np.float64]

__all__ = ["SOURCE_AXES", "sequence_from_markers", "sequence_from_motion_file", "source_motion"]

#: ``world <- source`` axes of retargeting (y-up sources to the z-up lab; as
#: :func:`kinefuse.biomech.retarget`): world x = x, world y = -z, world z = y.
SOURCE_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def source_motion(path: str | Path, *, skeleton: str | Path | None = None) -> SourceMotion:
    """Read a ``.bvh`` or ``.amc`` clip (its ``.asf`` beside it or given) as a SourceMotion."""
    from kinefuse.formats.motion import find_asf_for, read_amc, read_bvh

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such motion file")
    ext = motion_suffix(p)
    if ext == ".bvh":
        return read_bvh(p)
    if ext == ".amc":
        asf = Path(skeleton) if skeleton is not None else find_asf_for(p)
        if not asf.is_file():
            raise InputError(f"{asf}: no such ASF skeleton file")
        return read_amc(p, asf)
    raise InputError(f"{p}: unknown motion format {ext or '(none)'!r}; expected .bvh or .amc")


def sequence_from_motion_file(
    path: str | Path,
    *,
    skeleton: str | Path | None = None,
    name_map: str | Path | None = None,
    units: str | None = None,
) -> SkeletonSequence:
    """A BVH or ASF/AMC clip as a skeleton sequence with the source's limb rotations.

    Parameters
    ----------
    path : str or Path
        ``.bvh`` or ``.amc`` (``.gz`` allowed).
    skeleton : str or Path, optional
        The ASF of an AMC clip (default: found beside it).
    name_map : str or Path, optional
        A shipped name map's name or a TOML map (:func:`kinefuse.formats.motion.load_name_map`).
    units : str, optional
        The clip's length unit (default: chosen from the stature).

    Returns
    -------
    SkeletonSequence
        25 joints, metres, z up; ``orientations (T, L, 3, 3)`` for the limbs whose proximal
        joint is one source joint (see the module docstring).
    """
    from kinefuse.formats.motion import (
        BUILTIN_MAPS,
        load_name_map,
        resolve_map,
        retarget,
        select_map,
    )

    src = source_motion(path, skeleton=skeleton)
    if name_map is None:
        nm, resolved = select_map(src.names)
    else:
        text = str(name_map)
        nm = BUILTIN_MAPS[text] if text in BUILTIN_MAPS else load_name_map(Path(name_map))
        resolved = resolve_map(src.names, nm)
    motion = retarget(src, name_map=nm, units=units)
    limbs: list[str] = []
    rots: list[Array] = []
    if src.rotations is not None:
        for lb in LIMBS:
            term = resolved.get(lb.proximal)
            if term is None or len(term) != 1 or src.names[term[0][0]].endswith(END_SITE_SUFFIX):
                continue
            limbs.append(lb.name)
            rots.append(np.einsum("ij,tjk->tik", SOURCE_AXES, src.rotations[:, term[0][0]]))
    synth = [JOINTS[i] for i in np.flatnonzero(motion.synthesized)]
    return SkeletonSequence.from_kinect(
        motion.positions,
        rate_hz=motion.rate_hz,
        orientations=np.stack(rots, axis=1) if rots else None,
        orientation_limbs=tuple(limbs),
        source=motion.source
        + f"; source rotations for {len(limbs)} limbs"
        + ("; synthesized joints kept: " + ", ".join(synth) if synth else ""),
    )


def resolve_marker_input(
    path: str | Path,
    *,
    marker_map: MarkerMap | str | Path | None = None,
    static: str | Path | None = None,
    static_window: tuple[float, float] | None = None,
) -> tuple[MarkerData, MarkerMap, tuple[str, ...], MarkerData | None]:
    """Read a marker file, choose its map and append the map's landmarks (carried from the
    ``static`` trial, its frames inside ``static_window``, where the file lacks their markers).

    Returns (markers, map, notes, the static trial's window or None), both in the map's axes."""
    from kinefuse.biomech.marker_maps import shipped_marker_maps
    from kinefuse.biomech.static_trial import static_window as window_of
    from kinefuse.biomech.static_trial import with_landmarks

    markers = read_markers(path)
    st = None if static is None else window_of(read_markers(static), static_window)
    if marker_map is None:
        mmap = select_marker_map(markers, st)
    elif isinstance(marker_map, MarkerMap):
        mmap = marker_map
    else:
        shipped = shipped_marker_maps()
        text = str(marker_map)
        mmap = shipped[text] if text in shipped else load_marker_map(Path(marker_map))
    if mmap.up is not None:
        markers = read_markers(path, up=mmap.up)
        if static is not None:
            st = window_of(read_markers(static, up=mmap.up), static_window)
    markers, notes = with_landmarks(markers, mmap, st)
    return markers, mmap, notes, st


def sequence_from_markers(
    path: str | Path,
    *,
    marker_map: MarkerMap | str | Path | None = None,
    static: str | Path | None = None,
    static_window: tuple[float, float] | None = None,
) -> SkeletonSequence:
    """A TRC or C3D marker file as a skeleton sequence through a marker map.

    Parameters
    ----------
    path : str or Path
        ``.trc`` or ``.c3d``.
    marker_map : MarkerMap, str or Path, optional
        A map, a shipped map's name or a TOML file; default: the shipped map whose joints the
        file's markers all build (:func:`~kinefuse.biomech.marker_maps.select_marker_map`).
    static : str or Path, optional
        The static trial (``.trc``/``.c3d``), for the map's ``[landmarks]``.
    static_window : (float, float), optional
        Its still part, seconds (default: all of it).

    Returns
    -------
    SkeletonSequence
        The map's joints, metres, z up; NaN + mask where markers are missing.

    Raises
    ------
    InputError
        The map names markers the file lacks (they are listed), or no shipped map fits.
    MotionFormatError
        The file is malformed (with the line).
    """
    markers, mmap, lm_notes, _ = resolve_marker_input(
        path, marker_map=marker_map, static=static, static_window=static_window
    )
    return sequence_from_marker_data(markers, mmap, lm_notes)


def sequence_from_marker_data(
    markers: MarkerData, mmap: MarkerMap, notes0: tuple[str, ...] = ()
) -> SkeletonSequence:
    """:func:`sequence_from_markers` on markers already read (and given their landmarks)."""
    pos, names, notes = apply_marker_map(markers, mmap, partial=True)
    notes = (*notes0, *notes)
    partial = len(names) < len(mmap.joints)
    if partial:
        notes = (*notes, f"partial body: no {', '.join(j for j in mmap.joints if j not in names)}")
    limbs, ori = cluster_orientations(markers, mmap, partial=partial)
    if limbs:
        notes = (*notes, f"cluster orientations for {', '.join(limbs)}")
    return SkeletonSequence.from_kinect(
        pos,
        t_s=markers.t_s,
        rate_hz=markers.rate_hz,
        joint_names=names,
        orientations=ori,
        orientation_limbs=limbs,
        source="; ".join(
            [
                f"{markers.path} [{markers.fmt}]",
                f"marker map {mmap.name} ({mmap.origin})",
                *markers.notes,
                *notes,
            ]
        ),
    )
