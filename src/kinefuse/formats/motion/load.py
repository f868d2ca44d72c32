"""One entry point for real motion: :func:`load_motion` reads a BVH or ASF/AMC file and returns
the 25 Kinect v2 joints in the lab frame (metres, z up)."""

from __future__ import annotations

from pathlib import Path

from kinefuse.biomech.name_maps import BUILTIN_MAPS, NameMap, load_name_map
from kinefuse.biomech.retarget import retarget
from kinefuse.core.frames.motion import Motion
from kinefuse.core.frames.source_motion import motion_suffix
from kinefuse.errors import InputError
from kinefuse.formats.motion.asf_amc import read_amc
from kinefuse.formats.motion.bvh import read_bvh


def find_asf_for(amc_path: str | Path) -> Path:
    """The ASF skeleton of an AMC clip, found beside it.

    The clip's subject prefix names it (``11_01.amc`` -> ``11.asf``, ``02_walk_a.amc`` ->
    ``02.asf``, case-insensitive); else the only ``.asf`` in the folder.

    Raises
    ------
    InputError
        No such file and not exactly one ``.asf`` in the folder.
    """
    amc = Path(amc_path)
    folder = amc.parent
    asfs = (
        sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() == ".asf")
        if folder.is_dir()
        else []
    )
    subject = amc.name.split("_", 1)[0].split(".", 1)[0].casefold()
    for p in asfs:
        if p.stem.casefold() == subject:
            return p
    if len(asfs) == 1:
        return asfs[0]
    found = ", ".join(p.name for p in asfs) if asfs else "none"
    raise InputError(
        f"{amc}: cannot find its ASF skeleton: expected {amc.stem.split('_', 1)[0]}.asf beside "
        f"it or a single .asf in {folder} (found: {found}); pass the skeleton explicitly "
        "(load_motion(path, skeleton='SUBJECT.asf'), or --skeleton on the command line)"
    )


def _name_map(name_map: NameMap | str | Path | None) -> NameMap | None:
    if name_map is None or isinstance(name_map, NameMap):
        return name_map
    text = str(name_map)
    if text in BUILTIN_MAPS:
        return BUILTIN_MAPS[text]
    p = Path(name_map)
    if p.suffix.lower() == ".toml" or p.exists():
        return load_name_map(p)
    raise InputError(
        f"name_map {text!r} is neither a shipped map ({', '.join(BUILTIN_MAPS)}) nor a TOML file"
    )


def load_motion(
    path: str | Path,
    *,
    skeleton: str | Path | None = None,
    name_map: NameMap | str | Path | None = None,
    units: str | None = None,
    amc_rate_hz: float = 120.0,
) -> Motion:
    """Read a motion file and retarget it onto the 25 Kinect v2 joints.

    Parameters
    ----------
    path : str or Path
        A ``.bvh`` file, or an ``.amc`` clip (its ASF from ``skeleton`` or
        :func:`find_asf_for`).
    skeleton : str or Path, optional
        The ASF of an AMC clip.
    name_map : NameMap, str or Path, optional
        A map object, the name of a shipped map (``"cgspeed"``, ``"cmu-bvh11"``, ``"acclaim"``,
        ``"mixamo"``, ``"biovision"``) or a TOML file (:func:`load_name_map`); default: the
        shipped map that covers the skeleton best.
    units : {"m", "cm", "mm", "in", "asf"}, optional
        The file's length unit; default: chosen so the subject's stature is 1.2-2.1 m.
    amc_rate_hz : float
        Frame rate of AMC clips, which do not carry one (CMU: 120 Hz).

    Returns
    -------
    Motion
        Positions ``(T, 25, 3)`` in metres, z up, at the file's rate; ``source`` says the file,
        the map, the unit and the frames dropped.

    Raises
    ------
    MotionFormatError
        The file is malformed (with the line).
    RetargetError
        The skeleton cannot be mapped.
    InputError
        Unknown extension, missing ASF, undecidable unit.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such motion file")
    ext = motion_suffix(p)
    nm = _name_map(name_map)
    if ext == ".bvh":
        if skeleton is not None:
            raise InputError(f"{p}: skeleton= is for .amc clips; a BVH carries its own skeleton")
        src = read_bvh(p)
    elif ext == ".amc":
        asf = Path(skeleton) if skeleton is not None else find_asf_for(p)
        if not asf.is_file():
            raise InputError(f"{asf}: no such ASF skeleton file")
        src = read_amc(p, asf, rate_hz=amc_rate_hz)
    else:
        raise InputError(
            f"{p}: unknown motion format {p.suffix or '(no extension)'!r}; kinefuse reads .bvh "
            "and .amc (with its .asf)"
        )
    return retarget(src, name_map=nm, units=units)
