"""Marker trajectories as the analysis takes them, and how their names are matched.

:class:`MarkerData` holds a marker file's trajectories ``(T, M, 3)`` in metres in a **z-up**
world, NaN where a marker is missing (the readers in :mod:`kinefuse.formats.markers` make
one). Marker names are matched by :class:`MarkerResolver`: exactly, else by :func:`marker_key`,
which drops a subject prefix (``Name:``), case and separators, reads the side as a prefix or a
suffix and turns the names labs give one landmark into one (:data:`MARKER_SYNONYMS`).
:func:`up_rotation` turns a file's up axis into world +z.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError

Array = NDArray[np.float64]

#: File axis (signed) -> its index.
UP_AXES: Final = {"+x": 0, "+y": 1, "+z": 2, "-x": 0, "-y": 1, "-z": 2}

#: One landmark's names in the common marker sets (lower case, no side, no separators) ->
#: its key. Sources: Vicon Plug-in Gait and Helen Hayes / Davis (ASI, PSI, SACR, THI, KNE, TIB,
#: ANK, HEE, TOE, SHO, ELB, WRA radial, WRB ulnar, FIN, CLAV on the jugular notch, STRN on the
#: xiphoid); the ISB / Van Sint Jan landmark names (Wu et al. 2002, 2005; Van Sint Jan 2007:
#: IAS, IPS, FLE, FME, FAL, TAM, FCC, FM1, FM2, FM5, SAJ, HLE, HME, RSP, USP, HM2, HM5, CV7, TV8,
#: SJN, SXS) and their short forms (IJ, PX, EL, EM, RS, US); Cappozzo's CAST (1995: LE, ME,
#: LM, MM, CA, FM, SM, VM); OpenSim's example sets (Gait2354 ``Knee.Lat``, Rajagopal 2016
#: ``Knee``/``MKnee``, its running trial's ``LFC``/``MFC``, ``LMAL``/``MMAL``, ``CAL``, ``LEL``/
#: ``MEL``, ``FAradius``/``FAulna``, ``ACR``); Motion Analysis (``R.Thigh``, ``R.Shank``,
#: ``V.Sacral``); BTS (``r thigh``/``r bar 1``, ``r shank``/``r bar 2``, ``r mall``, ``r met``,
#: ``sacrum``).
MARKER_SYNONYMS: Final[dict[str, str]] = {
    name: key
    for key, names in {
        "asis": ("asi", "ias", "asis"),
        "psis": ("psi", "ips", "psis"),
        "sacrum": ("sacr", "sacral", "vsacral", "sacrum"),
        "thi": ("thi", "thigh", "thighwand", "bar1"),
        "tib": ("tib", "shank", "shankwand", "tibia", "bar2"),
        "fle": ("kne", "knee", "kneelat", "fle", "lfc", "lfe", "le", "lek", "knee1"),
        "fme": ("mknee", "kneemed", "fme", "mfc", "mfe", "me", "mek", "knee2"),
        "fal": ("ank", "ankle", "anklelat", "fal", "lmal", "lm", "mall", "lmall"),
        "tam": ("mankle", "anklemed", "tam", "mmal", "mm", "mmall"),
        "fcc": ("hee", "heel", "fcc", "cal", "ca", "calc"),
        "fm1": ("fm1", "mt1", "fm", "fmh"),
        "fm2": ("toe", "fm2", "mt2", "sm", "met"),
        "fm5": ("fm5", "mt5", "vm", "vmh"),
        "ac": ("sho", "acr", "acromion", "acromium", "shoulder", "saj", "sae", "ac"),
        "hle": ("elb", "elbow", "elbowlat", "hle", "lel", "el", "lee"),
        "hme": ("melbow", "elbowmed", "hme", "mel", "em", "mee"),
        "rsp": ("wra", "rsp", "rs", "faradius", "wristlat"),
        "usp": ("wrb", "usp", "us", "faulna", "wristmed"),
        "hm2": ("fin", "hm2", "mh2"),
        "hm5": ("hm5", "mh5"),
        "ij": ("clav", "ij", "sjn", "snj", "ster", "jn"),
        "px": ("strn", "px", "sxs", "xiph", "xp", "xpro"),
        "c7": ("c7", "cv7"),
        "t1": ("t1", "tv1"),
        "t8": ("t8", "tv8"),
        "t10": ("t10", "tv10"),
        "sh1": ("sh1", "sk1", "tb1"),
        "sh2": ("sh2", "sk2", "tb2"),
        "sh3": ("sh3", "sk3", "tb3"),
    }.items()
    for name in names
}
_SEPARATORS = re.compile(r"[\s_.\-]+")
_SIDE_WORDS = {"l": "l", "r": "r", "left": "l", "right": "r"}


def marker_key(name: str) -> str:
    """A marker name as matched loosely: ``"l:asis"`` for ``"Sub01:LASI"``, ``"L_ASIS"``,
    ``"ASIS_L"``, ``"L.ASIS"``, ``"ASISl"``, ``"l asis"`` or ``"LeftIAS"`` (the module
    docstring; no side: ``"c7"``). A glued side prefix is read only on names of three or more
    characters whose second is upper case or a digit (``LKNE``, ``RTH1``, ``RFAradius``; not
    ``Lumbar`` or ``LM``)."""
    base = name.strip().rsplit(":", 1)[-1].strip()
    side = ""
    glued = re.fullmatch(r"([A-Z0-9]{2,})([lr])", base)  # ASISl
    if glued:
        base, side = glued.group(1), glued.group(2)
    word = re.match(r"(Left|Right|LEFT|RIGHT|left|right)(?=[A-Z0-9_.\s\-])", base)
    if word and not side:
        side, base = word.group(1)[0].lower(), base[word.end() :]
    tokens = [t for t in _SEPARATORS.split(base) if t]
    if not side and len(tokens) > 1 and tokens[0].casefold() in _SIDE_WORDS:
        side, tokens = _SIDE_WORDS[tokens[0].casefold()], tokens[1:]
    elif not side and len(tokens) > 1 and tokens[-1].casefold() in _SIDE_WORDS:
        side, tokens = _SIDE_WORDS[tokens[-1].casefold()], tokens[:-1]
    elif not side and tokens and re.fullmatch(r"[LR][A-Z0-9]\w+", tokens[0]):
        side, tokens = tokens[0][0].lower(), [tokens[0][1:], *tokens[1:]]
    key = "".join(tokens).casefold()
    key = MARKER_SYNONYMS.get(key, key)
    return f"{side}:{key}" if side else key


class MarkerResolver:
    """Finds marker names in a file's list: exactly, else by :func:`marker_key` where that is
    unambiguous (one marker of the file has the key). Calling it gives the column or None."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = list(names)
        self.exact = {n: i for i, n in enumerate(self.names)}
        keys: dict[str, list[int]] = {}
        for i, n in enumerate(self.names):
            keys.setdefault(marker_key(n), []).append(i)
        self.keys = {k: v[0] for k, v in keys.items() if len(v) == 1}

    def __call__(self, name: str) -> int | None:
        if name in self.exact:
            return self.exact[name]
        return self.keys.get(marker_key(name))


@dataclass(frozen=True, eq=False)
class MarkerData:
    """Marker trajectories read from a file, in metres in a z-up world.

    Attributes
    ----------
    names : tuple of str, length M
        Marker labels as written in the file.
    positions : (T, M, 3) float
        Marker positions, metres, z up; NaN where missing.
    t_s : (T,) float
        Time of each frame, seconds, strictly increasing.
    rate_hz : float
        Frame rate.
    path : str
        The file.
    fmt : str
        ``"trc"`` or ``"c3d"``.
    notes : tuple of str
        How units and axes were decided, what was treated as a gap.
    """

    names: tuple[str, ...]
    positions: Array
    t_s: Array
    rate_hz: float
    path: str
    fmt: str
    notes: tuple[str, ...] = ()

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    def index(self) -> dict[str, int]:
        """Marker label -> column."""
        return {n: i for i, n in enumerate(self.names)}


def up_rotation(up: str) -> Array:
    """The rotation ``world <- file`` that turns file axis ``up`` into world +z.

    Parameters
    ----------
    up : {"+x", "+y", "+z", "-x", "-y", "-z"}

    Returns
    -------
    r : (3, 3) float
        A proper rotation (det +1): ``p_world = r @ p_file``.
    """
    key = up.strip().lower()
    if key in ("x", "y", "z"):
        key = "+" + key
    if key not in UP_AXES:
        raise InputError(f"up must be one of {', '.join(UP_AXES)}, got {up!r}")
    a = UP_AXES[key]
    # cyclic permutation putting file axis a at world z: world axis k <- file axis (a + 1 + k) % 3
    r = np.zeros((3, 3))
    for k in range(3):
        r[k, (a + 1 + k) % 3] = 1.0
    if key[0] == "-":
        r = np.diag([1.0, -1.0, -1.0]) @ r
    return r
