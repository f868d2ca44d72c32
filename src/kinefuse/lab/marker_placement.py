"""Synthetic marker trials with a known truth: a marker set placed on a real clip's segments.

A real motion-capture clip (BVH or ASF/AMC, with every segment's rotation) gives joint centres
and segment orientations over time. Each segment gets a *true* anatomical frame: built from the
joint centres in a reference pose as :func:`kinefuse.biomech.anatomical.skeleton_anatomical_frames`
does with ``zero="geometry"`` (pelvis from the hips and SpineMid, thigh hip -> knee with ``Z``
from the pelvis, shank from the thigh, foot ankle -> Foot made horizontal), and carried by the
clip's own rotation of that segment. Markers are fixed in those frames: the pelvis's ASIS and
sacral markers placed so that Harrington's regression (the map's ``[pelvis]``) gives back the
clip's hip centres, epicondyle and malleolus markers on the true joint centres' ``Z`` line (so
their midpoints are the true knee and ankle centres), heel and toe on the true foot's ``X``
line, clusters at fixed offsets. The static trial is the reference pose held with every
marker; the motion lacks the knee and ankle markers (as OpenSim's Gait2354 walks do).

The true anatomical angles are those frames' joint coordinate system angles
(:func:`kinefuse.biomech.anatomical.anatomical_angles`), so ``analyze`` on the two files can be
scored against them: a check of the marker chain (clusters, landmarks carried from the static
trial, Harrington's hip centres, ISB frames, the joint coordinate systems) on motions other than
the shared walk, that knows the true joint centres and angles.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kinefuse.biomech.anatomical import (
    anatomical_angles,
    frame_from_long_axis,
    lab_frame,
    skeleton_anatomical_frames,
)
from kinefuse.biomech.limbs import LIMB_NAMES
from kinefuse.biomech.static_trial import HEADING_S
from kinefuse.core.skeleton import JOINT_INDEX, JOINTS
from kinefuse.errors import InputError

Array = NDArray[np.float64]

__all__ = ["MARKER_SETS", "SyntheticTrial", "gait2354_trial", "marker_trial", "write_trc"]

#: Markers of the Gait2354 static trial that its walks do not have.
STATIC_ONLY = ("R.Knee.Lat", "R.Knee.Med", "L.Knee.Lat", "L.Knee.Med", "R.Ankle.Lat",
               "R.Ankle.Med", "L.Ankle.Lat", "L.Ankle.Med")  # fmt: skip


@dataclass(frozen=True, eq=False)
class SyntheticTrial:
    """A static trial and a motion of a marker set on a real clip, with their truth."""

    names: tuple[str, ...]  # the static trial's markers
    static: Array  # (S, M, 3) metres, z up
    motion_names: tuple[str, ...]  # the motion's (no knee and ankle markers)
    motion: Array  # (T, M', 3)
    t_s: Array  # (T,) the motion's times
    rate_hz: float
    true_angles: dict[str, Array]  # anatomical angles of the motion, degrees
    true_joints: dict[str, Array]  # Kinect joint -> (T, 3) true centre during the motion


def write_trc(
    path: Path, t_s: Array, names: tuple[str, ...], positions: Array, *, up: str = "+y"
) -> Path:
    """A TRC file (millimetres, y up) of ``positions (T, M, 3)`` metres in the z-up world, such
    that :func:`kinefuse.formats.markers.read_markers` with ``up="+y"`` (the map's) gives
    them back: it permutes the file's axes cyclically, world ``(x, y, z)`` = file ``(z, x, y)``.
    ``up="+z"``: the world's axes as they are (a Plug-in Gait file's)."""
    p = np.asarray(positions, dtype=np.float64) * 1000.0
    if up not in ("+y", "+z"):
        raise InputError(f"up must be '+y' or '+z', got {up!r}")
    f = np.stack([p[..., 1], p[..., 2], p[..., 0]], axis=-1) if up == "+y" else p
    rate = 1.0 / float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame"
        "\tOrigNumFrames",
        f"{rate:.6g}\t{rate:.6g}\t{len(t_s)}\t{len(names)}\tmm\t{rate:.6g}\t1\t{len(t_s)}",
        "Frame#\tTime\t" + "\t\t\t".join(names) + "\t\t",
        "\t\t" + "\t".join(f"X{i + 1}\tY{i + 1}\tZ{i + 1}" for i in range(len(names))),
        "",
    ]
    for k in range(len(t_s)):
        vals = "\t".join("NaN" if not np.isfinite(v) else f"{v:.4f}" for v in f[k].reshape(-1))
        lines.append(f"{k + 1}\t{t_s[k]:.6f}\t{vals}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _harrington_asis(hip_mid: Array, frame: Array, sep: Array, pd: float) -> tuple[Array, ...]:
    """ASIS right, left and the sacral marker that make Harrington et al. (2007) give hip
    centres ``sep / 2`` either side of ``hip_mid`` along the pelvis frame's ``Z``."""
    pw = (0.5 * sep - 0.0073) / 0.33
    hx = -0.24 * pd - 0.0099
    hy = -0.30 * pw - 0.0109
    mid = hip_mid - np.einsum("tij,tj->ti", frame, np.stack([hx * np.ones_like(pw), hy,
                                                             np.zeros_like(pw)], -1))  # fmt: skip
    z = frame[..., 2]
    return (mid + 0.5 * pw[:, None] * z, mid - 0.5 * pw[:, None] * z,
            mid - pd * frame[..., 0])  # fmt: skip


_At = Callable[[Array, Array, tuple[float, float, float]], Array]

#: The marker sets :func:`marker_trial` places (the shipped map of the same name reads them;
#: ``hamner``: Gait2354's names with the Hamner 2010 model's joint-centre markers, read by the
#: ``gait2354`` map).
MARKER_SETS = ("gait2354", "rajagopal", "plug-in-gait", "helen-hayes", "isb", "upper-limb-isb",
               "cast", "rajagopal-run", "hamner")  # fmt: skip

#: The Plug-in Gait map's chord offsets (knee, ankle), metres: where KNE and ANK are placed.
PIG_OFFSETS_M = (0.057, 0.042)

#: Markers of the Rajagopal static trial that its walk does not have.
RAJAGOPAL_STATIC_ONLY = ("R.MKnee", "L.MKnee", "R.MAnkle", "L.MAnkle", "R.MElbow", "L.MElbow")


def gait2354_trial(clip: str | Path, **kw: float | int | None) -> SyntheticTrial:
    """:func:`marker_trial` with the Gait2354 set."""
    return marker_trial(clip, "gait2354", **kw)  # type: ignore[arg-type]


def _rajagopal(
    m: dict[str, Array], fr: dict[str, Array], j: Callable[[str], Array], at: _At
) -> dict[str, Array]:
    """The Rajagopal 2016 set from the Gait2354 placement (same segments, their names)."""
    out: dict[str, Array] = {"R.ASIS": m["R.ASIS"], "L.ASIS": m["L.ASIS"], "S2": m["V.Sacral"]}
    z = fr["pelvis"][..., 2]
    out["R.PSIS"] = m["V.Sacral"] + 0.045 * z  # their midpoint is the sacral point
    out["L.PSIS"] = m["V.Sacral"] - 0.045 * z
    for x, side, s in (("R", "right", 1.0), ("L", "left", -1.0)):
        c = side.capitalize()
        out[f"{x}.TH1"] = m[f"{x}.Thigh.Upper"]
        out[f"{x}.TH2"] = m[f"{x}.Thigh.Front"]
        out[f"{x}.TH3"] = m[f"{x}.Thigh.Rear"]
        out[f"{x}.Knee"], out[f"{x}.MKnee"] = m[f"{x}.Knee.Lat"], m[f"{x}.Knee.Med"]
        out[f"{x}.SH1"] = m[f"{x}.Shank.Upper"]
        out[f"{x}.SH2"] = m[f"{x}.Shank.Front"]
        out[f"{x}.SH3"] = m[f"{x}.Shank.Rear"]
        out[f"{x}.Ankle"], out[f"{x}.MAnkle"] = m[f"{x}.Ankle.Lat"], m[f"{x}.Ankle.Med"]
        out[f"{x}.Heel"], out[f"{x}.Toe"] = m[f"{x}.Heel"], m[f"{x}.Toe.Tip"]
        foot = 0.5 * (m[f"{x}.Toe.Lat"] + m[f"{x}.Toe.Med"])  # the Foot joint
        out[f"{x}.MT5"] = 2.0 * foot - m[f"{x}.Toe.Tip"]  # mean(MT5, Toe) = the Foot joint
        out[f"{x}.Shoulder"] = m[f"{x}.Acromium"]
        out[f"{x}.Clavicle"] = at(j("SpineShoulder"), fr["trunk"], (0.03, 0.0, 0.06 * s))
        out[f"{x}.Biceps"] = m[f"{x}.Bicep"]
        ua = fr[f"upper_arm_{side}"]
        out[f"{x}.Elbow"] = at(j(f"Elbow{c}"), ua, (0.0, 0.0, 0.03 * s))
        out[f"{x}.MElbow"] = at(j(f"Elbow{c}"), ua, (0.0, 0.0, -0.03 * s))
        out[f"{x}.Forearm"] = at(j(f"Wrist{c}"), fr[f"forearm_{side}"], (0.02, 0.12, 0.02 * s))
        out[f"{x}.Wrist"] = j(f"Wrist{c}")
    return out


def _plug_in_gait(
    m: dict[str, Array], fr: dict[str, Array], j: Callable[[str], Array], at: _At
) -> dict[str, Array]:
    """The Plug-in Gait set from the Gait2354 placement: KNE and ANK lateral of the true knee
    and ankle centres by the map's chord offsets, the THI and TIB wands in the plane of the
    segment's long axis and its knee/ankle axis (as the chord function takes them), the toe
    marker on the Foot joint and the heel on the true foot's ``X`` line through it."""
    out: dict[str, Array] = {"RASI": m["R.ASIS"], "LASI": m["L.ASIS"]}
    z = fr["pelvis"][..., 2]
    out["RPSI"] = m["V.Sacral"] + 0.045 * z  # their midpoint is the sacral point
    out["LPSI"] = m["V.Sacral"] - 0.045 * z
    tr = fr["trunk"]
    sh = j("SpineShoulder")
    out["C7"] = at(sh, tr, (-0.08, 0.02, 0.0))
    out["T10"] = at(sh, tr, (-0.10, -0.25, 0.0))
    out["CLAV"] = at(sh, tr, (0.05, 0.0, 0.0))
    out["STRN"] = at(sh, tr, (0.08, -0.18, 0.0))
    out["RBAK"] = at(sh, tr, (-0.10, -0.12, 0.08))
    kn, an = PIG_OFFSETS_M
    for x, side, s in (("R", "right", 1.0), ("L", "left", -1.0)):
        c = side.capitalize()
        th, shk, ft = fr[f"thigh_{side}"], fr[f"shank_{side}"], fr[f"foot_{side}"]
        knee, ankle = j(f"Knee{c}"), j(f"Ankle{c}")
        out[f"{x}THI"] = at(knee, th, (0.0, 0.15, 0.07 * s))
        out[f"{x}KNE"] = at(knee, th, (0.0, 0.0, kn * s))
        out[f"{x}TIB"] = at(ankle, shk, (0.0, 0.15, 0.06 * s))
        out[f"{x}ANK"] = at(ankle, shk, (0.0, 0.0, an * s))
        toe = j(f"Foot{c}")
        out[f"{x}TOE"] = toe
        out[f"{x}HEE"] = toe - 0.20 * ft[..., 0]
        out[f"{x}SHO"] = j(f"Shoulder{c}")
        out[f"{x}ELB"] = j(f"Elbow{c}")
        out[f"{x}WRA"] = at(j(f"Wrist{c}"), fr[f"forearm_{side}"], (0.0, 0.0, 0.025 * s))
        out[f"{x}WRB"] = at(j(f"Wrist{c}"), fr[f"forearm_{side}"], (0.0, 0.0, -0.025 * s))
        out[f"{x}FIN"] = j(f"Hand{c}")
        out[f"{x}UPA"] = at(j(f"Elbow{c}"), fr[f"upper_arm_{side}"], (0.0, 0.14, 0.04 * s))
        out[f"{x}FRM"] = at(j(f"Wrist{c}"), fr[f"forearm_{side}"], (0.0, 0.10, 0.04 * s))
        out[f"{x}FHD"] = at(j("Head"), tr, (0.07, 0.02, 0.06 * s))
        out[f"{x}BHD"] = at(j("Head"), tr, (-0.07, 0.02, 0.06 * s))
    return out


def _helen_hayes(
    m: dict[str, Array], fr: dict[str, Array], j: Callable[[str], Array], at: _At
) -> dict[str, Array]:
    """Helen Hayes / Davis: Plug-in Gait's lower-body markers, one sacral marker for the PSIS."""
    pig = _plug_in_gait(m, fr, j, at)
    out = {"RASI": pig["RASI"], "LASI": pig["LASI"], "SACR": m["V.Sacral"]}
    for x in "RL":
        for k in ("THI", "KNE", "TIB", "ANK", "HEE", "TOE"):
            out[f"{x}{k}"] = pig[f"{x}{k}"]
    return out


def _isb(
    m: dict[str, Array], fr: dict[str, Array], j: Callable[[str], Array], at: _At
) -> dict[str, Array]:
    """ISB / Van Sint Jan landmarks: epicondyles, malleoli and styloids either side of the true
    joint centres, FM1 and FM5 either side of the Foot joint and FM2 on it, the thorax's
    landmarks either side of SpineShoulder and SpineMid."""
    tr = fr["trunk"]
    out: dict[str, Array] = {"RIAS": m["R.ASIS"], "LIAS": m["L.ASIS"]}
    z = fr["pelvis"][..., 2]
    out["RIPS"], out["LIPS"] = m["V.Sacral"] + 0.045 * z, m["V.Sacral"] - 0.045 * z
    out["SJN"] = at(j("SpineShoulder"), tr, (0.07, 0.0, 0.0))
    out["CV7"] = at(j("SpineShoulder"), tr, (-0.07, 0.0, 0.0))
    out["SXS"] = at(j("SpineMid"), tr, (0.11, 0.0, 0.0))
    out["TV8"] = at(j("SpineMid"), tr, (-0.11, 0.0, 0.0))
    for x, side, s in (("R", "right", 1.0), ("L", "left", -1.0)):
        c = side.capitalize()
        out[f"{x}FLE"], out[f"{x}FME"] = m[f"{x}.Knee.Lat"], m[f"{x}.Knee.Med"]
        out[f"{x}FAL"], out[f"{x}TAM"] = m[f"{x}.Ankle.Lat"], m[f"{x}.Ankle.Med"]
        out[f"{x}FCC"] = m[f"{x}.Heel"]
        out[f"{x}FM1"], out[f"{x}FM5"] = m[f"{x}.Toe.Med"], m[f"{x}.Toe.Lat"]
        out[f"{x}FM2"] = j(f"Foot{c}")
        out[f"{x}SAJ"] = j(f"Shoulder{c}")
        ua, fa = fr[f"upper_arm_{side}"], fr[f"forearm_{side}"]
        out[f"{x}HLE"] = at(j(f"Elbow{c}"), ua, (0.0, 0.0, 0.03 * s))
        out[f"{x}HME"] = at(j(f"Elbow{c}"), ua, (0.0, 0.0, -0.03 * s))
        out[f"{x}RSP"] = m[f"{x}.Wrist.Lat"]
        out[f"{x}USP"] = m[f"{x}.Wrist.Med"]
        out[f"{x}HM2"] = j(f"Hand{c}")
        out[f"{x}HM5"] = at(j(f"Hand{c}"), fa, (0.0, 0.0, -0.04 * s))
    return out


def _upper_limb_isb(
    m: dict[str, Array], fr: dict[str, Array], j: Callable[[str], Array], at: _At
) -> dict[str, Array]:
    """ISB upper-limb landmarks only (no pelvis, no legs): thorax IJ, PX, C7, T8, clavicle SC,
    scapula AA, TS, AI, the ISB set's epicondyles, styloids and second metacarpal head."""
    isb = _isb(m, fr, j, at)
    tr = fr["trunk"]
    out = {"IJ": isb["SJN"], "C7": isb["CV7"], "PX": isb["SXS"], "T8": isb["TV8"]}
    for x, s in (("R", 1.0), ("L", -1.0)):
        sh = j("SpineShoulder")
        out[f"{x}SC"] = at(sh, tr, (0.07, 0.0, 0.03 * s))
        out[f"{x}AC"] = isb[f"{x}SAJ"]
        out[f"{x}AA"] = at(sh, tr, (-0.08, 0.0, 0.16 * s))
        out[f"{x}TS"] = at(sh, tr, (-0.10, -0.05, 0.08 * s))
        out[f"{x}AI"] = at(sh, tr, (-0.10, -0.17, 0.10 * s))
        out[f"{x}EL"], out[f"{x}EM"] = isb[f"{x}HLE"], isb[f"{x}HME"]
        out[f"{x}RS"], out[f"{x}US"] = isb[f"{x}RSP"], isb[f"{x}USP"]
        out[f"{x}HM2"] = isb[f"{x}HM2"]
    return out


def _true_thorax_in_lab(trunk: Array, shoulder: Array, mid: Array, t_s: Array) -> dict[str, Array]:
    """The clip's ``thorax_*`` angles (a capture without a pelvis): ISB's thorax of the clip's
    landmarks (:func:`_upper_limb_isb` puts IJ and C7 either side of ``SpineShoulder``, PX and
    T8 either side of ``SpineMid``, along the clip's trunk bone's ``X``): ``Y`` from ``SpineMid``
    to ``SpineShoulder``, ``Z`` normal to the plane of ``Y`` and that ``X``; relative to the lab
    whose ``X`` is its heading over the motion's first second (as
    :func:`kinefuse.biomech.static_trial.anatomical_frames` defines it)."""
    y = shoulder - mid
    thorax = frame_from_long_axis(y, np.cross(trunk[..., 0], y))
    first = t_s <= t_s[0] + HEADING_S
    lab = lab_frame(thorax[first, :, 0].mean(axis=0))
    out = anatomical_angles({"trunk": thorax}, lab)
    return {k: v for k, v in out.items() if k.startswith("thorax_")}


def _cast(
    m: dict[str, Array], fr: dict[str, Array], j: Callable[[str], Array], at: _At
) -> dict[str, Array]:
    """CAST lower body: the Gait2354 thigh and shank clusters under CAST's names, epicondyles
    and malleoli (static trial only), GT, HF, TT, and the foot's CA, FM, SM, VM."""
    out: dict[str, Array] = {"RASI": m["R.ASIS"], "LASI": m["L.ASIS"]}
    z = fr["pelvis"][..., 2]
    out["RPSI"], out["LPSI"] = m["V.Sacral"] + 0.045 * z, m["V.Sacral"] - 0.045 * z
    for x, side, s in (("R", "right", 1.0), ("L", "left", -1.0)):
        c = side.capitalize()
        th, sh = fr[f"thigh_{side}"], fr[f"shank_{side}"]
        for k, part in enumerate(("Upper", "Front", "Rear")):
            out[f"{x}TH{k + 1}"] = m[f"{x}.Thigh.{part}"]
            out[f"{x}SK{k + 1}"] = m[f"{x}.Shank.{part}"]
        out[f"{x}GT"] = at(j(f"Knee{c}"), th, (0.0, 0.40, 0.08 * s))
        out[f"{x}LE"], out[f"{x}ME"] = m[f"{x}.Knee.Lat"], m[f"{x}.Knee.Med"]
        out[f"{x}HF"] = at(j(f"Ankle{c}"), sh, (0.0, 0.36, 0.045 * s))
        out[f"{x}TT"] = at(j(f"Ankle{c}"), sh, (0.04, 0.34, 0.0))
        out[f"{x}LM"], out[f"{x}MM"] = m[f"{x}.Ankle.Lat"], m[f"{x}.Ankle.Med"]
        out[f"{x}CA"] = m[f"{x}.Heel"]
        out[f"{x}FM"], out[f"{x}VM"] = m[f"{x}.Toe.Med"], m[f"{x}.Toe.Lat"]
        out[f"{x}SM"] = j(f"Foot{c}")
    return out


def _rajagopal_run(
    m: dict[str, Array], fr: dict[str, Array], j: Callable[[str], Array], at: _At
) -> dict[str, Array]:
    """The Rajagopal set under its running trial's names (opensim-models'
    ``Pipelines/Rajagopal/IK/ik_setup_run.xml``), CLAV and C7 either side of SpineShoulder,
    a three-marker upper-arm cluster, the forearm's radial and ulnar styloid markers."""
    r = _rajagopal(m, fr, j, at)
    tr = fr["trunk"]
    out: dict[str, Array] = {
        "CLAV": at(j("SpineShoulder"), tr, (0.06, 0.0, 0.0)),
        "C7": at(j("SpineShoulder"), tr, (-0.06, 0.0, 0.0)),
    }
    names = {"ASIS": "ASI", "PSIS": "PSI", "TH1": "TH1", "TH2": "TH2", "TH3": "TH3",
             "SH1": "TB1", "SH2": "TB2", "SH3": "TB3", "Knee": "LFC", "MKnee": "MFC",
             "Ankle": "LMAL", "MAnkle": "MMAL", "Heel": "CAL", "Toe": "TOE", "MT5": "MT5",
             "Shoulder": "ACR", "Elbow": "LEL", "MElbow": "MEL",
             "Forearm": "FAsuperior"}  # fmt: skip
    for x, side, s in (("R", "right", 1.0), ("L", "left", -1.0)):
        c = side.capitalize()
        for old, new in names.items():
            out[f"{x}{new}"] = r[f"{x}.{old}"]
        ua, fa = fr[f"upper_arm_{side}"], fr[f"forearm_{side}"]
        out[f"{x}UA1"] = r[f"{x}.Biceps"]
        out[f"{x}UA2"] = at(j(f"Elbow{c}"), ua, (-0.02, 0.20, 0.04 * s))
        out[f"{x}UA3"] = at(j(f"Elbow{c}"), ua, (0.0, 0.10, 0.05 * s))
        out[f"{x}FAradius"] = at(j(f"Wrist{c}"), fa, (0.0, 0.0, 0.025 * s))
        out[f"{x}FAulna"] = at(j(f"Wrist{c}"), fa, (0.0, 0.0, -0.025 * s))
    return out


def _hamner(
    m: dict[str, Array], fr: dict[str, Array], j: Callable[[str], Array], at: _At
) -> dict[str, Array]:
    """Gait2354's markers with the Hamner 2010 model's knee and ankle joint-centre markers
    (``LKJC``, ``LAJC``: opensim-models' ``FullBodyModel_Hamner2010_v2_0.osim``)."""
    out = dict(m)
    for x, c in (("R", "Right"), ("L", "Left")):
        out[f"{x}KJC"], out[f"{x}AJC"] = j(f"Knee{c}"), j(f"Ankle{c}")
    return out


#: Each set's placement from the Gait2354 one, and the static trial's markers its motion lacks.
_SETS: dict[str, tuple[Callable[..., dict[str, Array]], tuple[str, ...]]] = {
    "rajagopal": (_rajagopal, RAJAGOPAL_STATIC_ONLY),
    "plug-in-gait": (_plug_in_gait, ()),
    "helen-hayes": (_helen_hayes, ()),
    "isb": (_isb, ()),
    "upper-limb-isb": (_upper_limb_isb, ()),
    "cast": (_cast, ("RLE", "RME", "LLE", "LME", "RLM", "RMM", "LLM", "LMM")),
    "rajagopal-run": (_rajagopal_run, ("RMFC", "LMFC", "RMMAL", "LMMAL", "RMEL", "LMEL")),
    "hamner": (_hamner, STATIC_ONLY),
}


def marker_trial(
    clip: str | Path,
    marker_set: str = "gait2354",
    *,
    static_s: float = 1.0,
    ref_frame: int | None = None,
    pd_m: float = 0.16,
) -> SyntheticTrial:
    """A marker set (:data:`MARKER_SETS`, the shipped map of that name) on ``clip``: static
    trial and motion.

    Parameters
    ----------
    clip : str or Path
        A BVH or ASF/AMC clip (``kinefuse.formats.sequences.sequence_from_motion_file``).
    static_s : float
        Length of the static trial (the reference pose held), seconds.
    marker_set : str
        ``"gait2354"`` (OpenSim's Gait2354 example set), ``"rajagopal"`` (Rajagopal 2016),
        ``"plug-in-gait"`` (Vicon's, with the map's assumed knee and ankle widths), or another
        of :data:`MARKER_SETS` (Vicon-style names: side letter, then the landmark).
    ref_frame : int, optional
        The reference (standing) pose's frame; default the clip's default-pose frame.
    pd_m : float
        ASIS midpoint to sacral marker distance, metres.
    """
    from kinefuse.biomech import find_default_pose
    from kinefuse.formats.sequences import sequence_from_motion_file

    if marker_set not in MARKER_SETS:
        raise InputError(f"unknown marker set {marker_set!r}; choose {', '.join(MARKER_SETS)}")
    seq = sequence_from_motion_file(Path(clip))
    if any(seq.orientation(n) is None for n in LIMB_NAMES):
        raise InputError(f"{clip}: the clip must give every segment's rotation")
    ref = find_default_pose(seq) if ref_frame is None else int(ref_frame)
    p = np.asarray(seq.kinect_positions(), dtype=np.float64)
    ns = max(round(static_s * seq.rate_hz), 2)
    pos = np.concatenate([np.repeat(p[ref : ref + 1], ns, 0), p])
    orient = {n: np.asarray(seq.orientation(n), dtype=np.float64) for n in LIMB_NAMES}
    lf = {n: np.concatenate([np.repeat(o[ref : ref + 1], ns, 0), o]) for n, o in orient.items()}
    t = np.arange(pos.shape[0]) / seq.rate_hz
    sa = skeleton_anatomical_frames(pos, JOINTS, t, lf, (0.0, (ns - 1) / seq.rate_hz),
                                    zero="geometry")  # fmt: skip
    fr = sa.frames

    def j(name: str) -> Array:
        return pos[:, JOINT_INDEX[name]]

    def at(anchor: Array, frame: Array, local: tuple[float, float, float]) -> Array:
        return anchor + np.einsum("tij,j->ti", frame, np.asarray(local))

    m: dict[str, Array] = {}
    hip_mid = 0.5 * (j("HipLeft") + j("HipRight"))
    sep = np.linalg.norm(j("HipRight") - j("HipLeft"), axis=-1)
    m["R.ASIS"], m["L.ASIS"], m["V.Sacral"] = _harrington_asis(hip_mid, fr["pelvis"], sep, pd_m)
    for side, s in (("right", 1.0), ("left", -1.0)):
        c, x = side.capitalize(), "R" if side == "right" else "L"
        th, sh, ft = fr[f"thigh_{side}"], fr[f"shank_{side}"], fr[f"foot_{side}"]
        knee, ankle = j(f"Knee{c}"), j(f"Ankle{c}")
        m[f"{x}.Thigh.Upper"] = at(knee, th, (0.00, 0.28, 0.08 * s))
        m[f"{x}.Thigh.Front"] = at(knee, th, (0.07, 0.18, 0.05 * s))
        m[f"{x}.Thigh.Rear"] = at(knee, th, (-0.05, 0.12, 0.07 * s))
        m[f"{x}.Knee.Lat"] = at(knee, th, (0.0, 0.0, 0.05 * s))
        m[f"{x}.Knee.Med"] = at(knee, th, (0.0, 0.0, -0.05 * s))
        m[f"{x}.Shank.Upper"] = at(ankle, sh, (0.00, 0.30, 0.06 * s))
        m[f"{x}.Shank.Front"] = at(ankle, sh, (0.05, 0.20, 0.02 * s))
        m[f"{x}.Shank.Rear"] = at(ankle, sh, (-0.05, 0.15, 0.05 * s))
        m[f"{x}.Ankle.Lat"] = at(ankle, sh, (0.0, 0.0, 0.035 * s))
        m[f"{x}.Ankle.Med"] = at(ankle, sh, (0.0, 0.0, -0.035 * s))
        f0 = fr[f"foot_{side}"][ns - 1].T @ (pos[ns - 1, JOINT_INDEX[f"Foot{c}"]] - ankle[ns - 1])
        m[f"{x}.Heel"] = at(ankle, ft, (-0.06, -0.05, 0.0))
        m[f"{x}.Toe.Tip"] = at(ankle, ft, (float(f0[0]) + 0.04, -0.05, 0.0))
        m[f"{x}.Midfoot.Sup"] = at(ankle, ft, (0.06, -0.01, 0.0))
        m[f"{x}.Midfoot.Lat"] = at(ankle, ft, (0.07, -0.05, 0.04 * s))
        m[f"{x}.Toe.Lat"] = at(ankle, ft, (float(f0[0]), float(f0[1]), float(f0[2]) + 0.03 * s))
        m[f"{x}.Toe.Med"] = at(ankle, ft, (float(f0[0]), float(f0[1]), float(f0[2]) - 0.03 * s))
        ua, fa = fr[f"upper_arm_{side}"], fr[f"forearm_{side}"]
        m[f"{x}.Acromium"] = j(f"Shoulder{c}")
        m[f"{x}.Bicep"] = at(j(f"Elbow{c}"), ua, (0.03, 0.12, 0.0))
        m[f"{x}.Elbow"] = j(f"Elbow{c}")
        m[f"{x}.Wrist.Med"] = at(j(f"Wrist{c}"), fa, (0.0, 0.0, -0.025 * s))
        m[f"{x}.Wrist.Lat"] = at(j(f"Wrist{c}"), fa, (0.0, 0.0, 0.025 * s))
        m[f"{x}.Temple"] = at(j("Head"), fr["trunk"], (0.05, 0.0, 0.07 * s))
    m["Sternum"] = at(j("SpineShoulder"), fr["trunk"], (0.08, -0.15, 0.0))
    m["Top.Head"] = at(j("Head"), fr["trunk"], (0.0, 0.10, 0.0))
    static_only: tuple[str, ...] = STATIC_ONLY
    if marker_set in _SETS:
        place, static_only = _SETS[marker_set]
        m = place(m, fr, j, at)
    names = tuple(m)
    allp = np.stack([m[n] for n in names], axis=1)
    static = allp[:ns]
    motion = allp[ns:].copy()
    keep = [i for i, n in enumerate(names) if n not in static_only]
    motion_names = tuple(names[i] for i in keep)
    true = anatomical_angles({k: v[ns:] for k, v in fr.items()}, sa.lab)
    if marker_set == "upper-limb-isb":
        true.update(_true_thorax_in_lab(fr["trunk"][ns:], j("SpineShoulder")[ns:],
                                        j("SpineMid")[ns:], t[ns:]))  # fmt: skip
    return SyntheticTrial(
        names=names,
        static=static,
        motion_names=motion_names,
        motion=motion[:, keep],
        t_s=np.asarray(seq.t_s, dtype=np.float64) - float(seq.t_s[0]),
        rate_hz=float(seq.rate_hz),
        true_angles=true,
        true_joints={n: p[:, JOINT_INDEX[n]] for n in JOINTS},
    )
