"""``kinefuse simulate``: a session of a real clip seen by simulated sensors (the bundled demo clip
included)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from kinefuse.errors import InputError, OutputError
from kinefuse.formats.store.session_store import SessionStore, is_simulated_session

if TYPE_CHECKING:
    from kinefuse.sim.tracker_params import TrackerParams

Array = NDArray[np.float64]


#: The demo's bundled clip: CMU subject 01, trial 01 (forward jumps, turn around), the original
#: Acclaim ASF/AMC from the fairmotion repository (BSD); see ``kinefuse/data/LICENSE_clips.md``.
DEMO_CLIP = "01_01.amc.gz"


def demo_clip_path() -> Path:
    """Path of the bundled demo clip inside the installed package."""
    return Path(str(resources.files("kinefuse") / "data" / DEMO_CLIP))


def check_session_out(out: Path, force: bool) -> None:
    """Refuse an ``--out`` for a new session: a foreign extension, or an existing file that is
    not a simulated session (or is one, without ``--force``)."""
    from kinefuse.core.outputs import (
        FOREIGN_SESSION_SUFFIXES,
        check_output_folder,
        is_kinefuse_session,
    )

    if out.suffix.lower() in FOREIGN_SESSION_SUFFIXES:
        raise OutputError(
            f"--out {out}: a session is a SQLite file, but {out.suffix!r} is the extension of "
            "another format; name it .sqlite"
        )
    check_output_folder(out, "session")
    if out.is_dir():
        raise OutputError(f"--out {out} is a folder; give the path of a .sqlite file")
    if not out.exists():
        return
    if not force:
        raise OutputError(
            f"{out} already exists; choose another --out, or pass --force to replace it (only a "
            "simulated kinefuse session is ever replaced)"
        )
    if not is_kinefuse_session(out):
        raise OutputError(
            f"refusing to replace {out}: it is not a kinefuse session (checked by its content, "
            "not its name); --force only replaces simulated sessions"
        )
    if any(out.with_name(out.name + s).exists() for s in ("-wal", "-journal")):
        raise OutputError(
            f"refusing to replace {out}: it is open by another process or was not closed cleanly "
            f"(a {out.name}-wal or -journal file lies beside it); close that process, or run "
            f"`kinefuse inspect {out}` once to recover it, then try again"
        )
    if not is_simulated_session(out):
        raise OutputError(
            f"refusing to replace {out}: it is a recording without ground truth (a live session); "
            "choose another --out"
        )


@dataclass(frozen=True)
class SimulateResult:
    """What ``kinefuse simulate`` wrote.

    Attributes
    ----------
    out : Path
        The session written.
    coverage : dict
        How well the sensors saw the subject
        (:func:`kinefuse.lab.coverage.tracking_coverage`).
    warnings : tuple of str
        What the user should know (a subject outside the common volume, ...).
    rom_position_m : tuple of float or None
        With a standing or range-of-motion phase: where it was performed, ``(x, y)`` metres.
    rom_position_from : str or None
        Which rule placed it (the rig's ``[actor]`` position, else the common volume's centre).
    """

    out: Path
    coverage: dict[str, Any]
    warnings: tuple[str, ...]
    rom_position_m: tuple[float, float] | None = None
    rom_position_from: str | None = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-able (with ``default=str`` for the path); the phase's place only with one."""
        d: dict[str, Any] = {
            "out": self.out,
            "coverage": self.coverage,
            "warnings": list(self.warnings),
        }
        if self.rom_position_m is not None:
            d["rom_position_m"] = list(self.rom_position_m)
            d["rom_position_from"] = self.rom_position_from
        return d


def run_simulate(
    *,
    clip: Path,
    out: Path,
    skeleton: Path | None = None,
    units: str | None = None,
    name_map: Path | None = None,
    rig: Path | None = None,
    sensors: int = 4,
    seconds: float | None = None,
    seed: int = 0,
    calibration_s: float = 20.0,
    depth_rate_hz: float = 10.0,
    room: tuple[float, float, float, float] | None = None,
    force: bool = False,
    progress: Callable[[str], None] | None = None,
    rom_s: float | None = None,
    subject_seed: int | None = None,
    tracker: str = "default",
    static_s: float | None = None,
    errors_off: Sequence[str] = (),
    bystanders: Sequence[Path] = (),
) -> SimulateResult:
    """Load a clip and a rig, place the actor, and simulate a session into ``out``.

    Everything that can be checked is checked before anything is written; the session is built
    in a temporary file beside ``out``, marked complete, and renamed into place only when it is
    whole, so an interrupted or failed run leaves any old ``out`` byte-identical. ``force``
    replaces an existing simulated session, never another file or a live recording. ``rom_s``:
    a range-of-motion calibration phase of that many seconds before the motion
    (:func:`kinefuse.biomech.rom.add_rom_phase`), performed at the rig's ``[actor]``
    position, else at the centre of the sensors' common volume
    (:func:`kinefuse.sim.rig.common_volume_centre`), whatever the clip's path; the clip then
    starts from there (a clip that leaves the volume is warned about by the coverage check).
    ``static_s``: a standing phase (a static trial, for the anatomical angles) of that many
    seconds before the ROM phase (or before the clip), performed at the same place.
    ``errors_off``: parts of the tracker's error model switched off
    (:data:`kinefuse.sim.tracker_params.ERROR_PARTS`). ``bystanders``: clips of other people
    in the room during the motion, persons 1, 2, ..., placed by
    :func:`kinefuse.sim.people.place_bystander`'s rule.

    Returns
    -------
    SimulateResult
        The session, its coverage and warnings, and where a standing or ROM phase was placed.
    """
    from kinefuse.core.outputs import atomic_file
    from kinefuse.formats.motion import load_motion
    from kinefuse.lab.coverage import coverage_warnings, tracking_coverage
    from kinefuse.sim.lab import ErrorModel, LabConfig, simulate_session
    from kinefuse.sim.rig import common_volume_centre, default_rig, load_rig, place_actor

    say = progress or (lambda _m: None)
    model = tracker_model(tracker, errors_off)  # an unknown part is refused before anything
    check_session_out(out, force)
    the_rig = load_rig(rig, room=room) if rig is not None else default_rig(sensors, room=room)
    say(f"loading {clip}")
    motion = load_motion(clip, skeleton=skeleton, units=units, name_map=name_map)
    if seconds is not None and seconds > motion.duration_s + 1e-9:
        raise InputError(
            f"--seconds {seconds:g} is longer than the clip ({motion.duration_s:.2f} s); "
            "give at most the clip's length or leave --seconds out"
        )
    rom_place = None
    if rom_s is not None or static_s is not None:
        # the calibration phase happens where the sensors see it: at the rig's [actor] position,
        # else at the centre of the sensors' common volume, whatever the clip's path (a walk's
        # centred path put the phase at its start, at the edge of a walkway: issue 24); the
        # clip then starts there
        at = the_rig.actor_position_m
        rom_place = "the rig's [actor] position"
        if at is None:
            at = common_volume_centre(the_rig)
            the_rig = replace(the_rig, actor_position_m=at)
            rom_place = "the centre of the sensors' common volume"
        where = f"({at[0]:.2f}, {at[1]:.2f}) m"
        what = " and ".join(
            w for w, v in (("standing", static_s), ("range-of-motion", rom_s)) if v is not None
        )
        say(f"{what} phase at {rom_place}, {where}; the clip starts there")
    motion = place_actor(motion, the_rig, seconds)
    rom = None
    if rom_s is not None or static_s is not None:
        from kinefuse.biomech.rom import add_rom_phase

        rom = add_rom_phase(motion, rom_s, seed=seed, static_s=static_s)
        if seconds is not None:
            seconds = min(
                seconds + rom.motion.duration_s - motion.duration_s, rom.motion.duration_s
            )
        motion = rom.motion
    others = []
    for i, path in enumerate(bystanders):
        from kinefuse.sim.people import place_bystander

        say(f"loading bystander {i + 1}: {path}")
        other = place_actor(load_motion(path), the_rig)
        span = motion.duration_s if seconds is None else seconds
        others.append(place_bystander(other, motion, the_rig, i, span))
    config = LabConfig(
        seed=seed,
        calibration_s=calibration_s,
        depth_rate_hz=depth_rate_hz,
        motion_s=seconds,
        subject_seed=subject_seed,
        errors=ErrorModel(tracker=model),
    )
    with atomic_file(
        out, what="session", recognizer=is_simulated_session, suffix=".partial.sqlite"
    ) as tmp:
        tmp.unlink()  # the store creates its own file
        simulate_session(motion, the_rig, tmp, config, progress=say, bystanders=others)
        if rom is not None:
            from kinefuse.app.workflows.analyze import record_rom_phase

            record_rom_phase(tmp, rom, calibration_s)
        with SessionStore.open(tmp, writable=True) as store:
            coverage = tracking_coverage(store)
            store.mark_complete()
    placed = rom is not None and the_rig.actor_position_m is not None
    return SimulateResult(
        out=out,
        coverage=coverage,
        warnings=tuple(coverage_warnings(coverage)),
        rom_position_m=the_rig.actor_position_m if placed else None,
        rom_position_from=rom_place if placed else None,
    )


#: The body-tracker models a simulation can use (``--tracker``).
TRACKER_MODELS = ("default", "light")


def tracker_model(name: str, errors_off: Sequence[str] = ()) -> TrackerParams:
    """``"default"``: the model with the gross failures and the person level fitted on the
    KinectMultiTrack population (issue 21), every published figure stands on it; ``"light"``:
    without them (the lighter-tailed model of before issue 21, for comparison). ``errors_off``:
    parts of it switched off (:func:`kinefuse.sim.tracker_params.without_parts`)."""
    from kinefuse.sim.tracker_params import TrackerParams, light_tracker, without_parts

    if name not in TRACKER_MODELS:
        raise InputError(f"unknown tracker model {name!r}; choose {', '.join(TRACKER_MODELS)}")
    return without_parts(light_tracker() if name == "light" else TrackerParams(), errors_off)
