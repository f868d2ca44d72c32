"""kinefuse's Python API: open a session, a clip or a marker file; fuse; analyze; export.

Everything here is also importable from ``kinefuse`` itself (``import kinefuse as kf;
kf.fuse(...)``), loaded on first use. Conventions as everywhere in kinefuse: metres, seconds,
degrees for joint angles; a z-up world; arrays time first, ``(T, J, 3)`` for joints; NaN where
something is missing. The command line is built on the same functions: ``kinefuse fuse`` is
``fuse`` then ``Skeleton.export``, ``kinefuse analyze`` is ``analyze``.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kinefuse import _API
from kinefuse.core.skeleton import JOINTS
from kinefuse.errors import InputError
from kinefuse.formats.markers import MarkerData

__all__ = [*_API]  # the names the package re-exports, listed once there

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Joint centres over time: a fused session or a clip on the 25 Kinect v2 joints.

    Attributes
    ----------
    t_s : (T,) float
        Time of each frame, seconds (a session: the server clock from the session's start).
    positions_m : (T, J, 3) float
        Joint centres, metres, z-up world; NaN where a joint is missing.
    joint_names : tuple of str
        The ``J`` joints (``kinefuse.core.skeleton.JOINTS`` order).
    status : (T, J) int8 or None
        The fusion's per-joint status (``kinefuse.capture.fusion.status.FusionStatus``) for a fused
        session; None for a clip.
    source : str
        Where it came from (the file, the method, the calibration).
    """

    t_s: Array
    positions_m: Array
    joint_names: tuple[str, ...] = JOINTS
    status: NDArray[np.int8] | None = None
    source: str = ""

    def __len__(self) -> int:
        return int(self.t_s.size)

    def joint(self, name: str) -> Array:
        """``(T, 3)``: one joint's trajectory."""
        try:
            return self.positions_m[:, self.joint_names.index(name)]
        except ValueError:
            raise InputError(f"no joint {name!r}; joints: {', '.join(self.joint_names)}") from None

    def export(self, path: str | Path, *, trc_axes: str = "y-up") -> Path:
        """Write the skeleton as ``.c3d``, ``.trc``, ``.csv`` or ``.bvh`` (by the extension),
        through a temporary file and an atomic rename; a file kinefuse did not write is never
        replaced. TRC files are Y up for OpenSim unless ``trc_axes="z-up"``."""
        from kinefuse.formats.export import check_export_path, export_skeleton

        out = check_export_path(path)
        export_skeleton(out, self.t_s, self.positions_m, trc_axes=trc_axes)
        return out


class Session:
    """A recorded or simulated session, opened read-only (nothing here writes to it).

    Use it as a context manager, or call :meth:`close`.
    """

    def __init__(self, path: str | Path) -> None:
        from kinefuse.formats.store.session_store import SessionStore

        self.path = Path(path)
        self._store = SessionStore.open(self.path)

    @property
    def sensor_ids(self) -> tuple[str, ...]:
        """The session's sensors."""
        return tuple(s.id for s in self._store.sensors())

    @property
    def complete(self) -> bool:
        """Whether the recording was closed cleanly (an interrupted one is incomplete)."""
        return self._store.complete

    @property
    def meta(self) -> dict[str, object]:
        """The session's metadata (what wrote it, the clip, the phases)."""
        return self._store.meta()

    @property
    def stored_fusions(self) -> tuple[str, ...]:
        """The fusion methods whose result is stored in the session (``fuse --store``)."""
        return tuple(self._store.fused_methods())

    def fuse(
        self,
        method: str = "best",
        *,
        calibration: str | Path | None = None,
        start_s: float | None = None,
        end_s: float | None = None,
        allow_incomplete: bool = False,
    ) -> Skeleton:
        """One skeleton from all sensors (``kinefuse fuse``), as ``fuse``."""
        from kinefuse.capture.fusion.methods import METHODS
        from kinefuse.lab.poses import resolve_poses
        from kinefuse.pipeline.store_inputs import (
            clip_grid,
            frame_grid,
            load_usable_sensors,
            run_method,
        )

        if method not in METHODS:
            raise InputError(f"unknown fusion method {method!r}; one of {', '.join(METHODS)}")
        self._store.require_complete(
            allow_incomplete=allow_incomplete, flag="allow_incomplete=True"
        )
        cal = None if calibration is None else Path(calibration)
        poses, source = resolve_poses(self._store, cal, False)
        sensors, _screen = load_usable_sensors(self._store, poses)
        grid = clip_grid(frame_grid(sensors), start_s, end_s)
        res = run_method(sensors, grid, method)
        return Skeleton(
            res.t_server_s,
            res.positions,
            JOINTS,
            res.status,
            f"{self.path} fused with {method} ({source})",
        )

    def close(self) -> None:
        self._store.close()

    def __enter__(self) -> Session:
        return self

    def __exit__(
        self, _t: type[BaseException] | None, _e: BaseException | None, _tb: TracebackType | None
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Session({str(self.path)!r}, sensors={list(self.sensor_ids)})"


def open_session(path: str | Path) -> Session:
    """Open a session (``.sqlite``, recorded by ``kinefuse serve`` or made by ``kinefuse
    simulate``) read-only."""
    return Session(path)


def fuse(
    session: str | Path | Session,
    method: str = "best",
    *,
    calibration: str | Path | None = None,
    start_s: float | None = None,
    end_s: float | None = None,
) -> Skeleton:
    """Fuse a session's sensors into one skeleton.

    ``calibration``: a calibration file (``kinefuse calibrate --out``); default: the one the
    session stored (a live server's, or ``calibrate --store``). ``method``: ``best`` (default),
    ``best-live``, or one of the paper's (``paper``, ``linear``, ``geometric``, ``nonlinear``).
    """
    if isinstance(session, Session):
        return session.fuse(method, calibration=calibration, start_s=start_s, end_s=end_s)
    with Session(session) as s:
        return s.fuse(method, calibration=calibration, start_s=start_s, end_s=end_s)


def load_clip(path: str | Path, *, skeleton: str | Path | None = None) -> Skeleton:
    """A motion clip (``.bvh``, or ``.amc`` with its ``.asf``) retargeted onto the 25 joints."""
    from kinefuse.formats.motion.load import load_motion

    motion = load_motion(path, skeleton=skeleton)
    t_s = np.arange(motion.positions.shape[0]) / motion.rate_hz
    return Skeleton(t_s, motion.positions, JOINTS, None, motion.source)


def load_markers(path: str | Path) -> MarkerData:
    """Marker trajectories from a ``.trc`` or ``.c3d`` file, in metres in a z-up world."""
    from kinefuse.formats.markers import read_markers

    return read_markers(path)


@dataclass(frozen=True, eq=False)
class Angles:
    """Joint angles over time, one column per angle and method.

    Attributes
    ----------
    t_s : (T,) float
    columns : tuple of (angle, joint, method)
        ``method`` is ``functional`` (paper B's learned axes) or ``anatomical`` (ISB, from a
        static trial).
    degrees : (T, A) float
        NaN where the angle is not defined at that frame.
    """

    t_s: Array
    columns: tuple[tuple[str, str, str], ...]
    degrees: Array

    def __getitem__(self, angle: str) -> Array:
        """``(T,)``: the angle by name, ``"knee_flexion_left"`` (its anatomical column when
        there is one) or ``"knee_flexion_left/functional"``."""
        name, _, method = angle.partition("/")
        hits = [i for i, (a, _j, m) in enumerate(self.columns) if a == name]
        if method:
            hits = [i for i in hits if self.columns[i][2] == method]
        elif len(hits) > 1:
            hits = [i for i in hits if self.columns[i][2] == "anatomical"] or hits[:1]
        if not hits:
            names = sorted({a for a, _j, _m in self.columns})
            raise InputError(f"no angle {angle!r}; angles: {', '.join(names)}")
        return self.degrees[:, hits[0]]

    @property
    def names(self) -> tuple[str, ...]:
        """The angles' names, each once."""
        return tuple(dict.fromkeys(a for a, _j, _m in self.columns))

    @classmethod
    def read_csv(cls, path: str | Path) -> Angles:
        """An ``angles.csv`` that ``kinefuse analyze`` wrote."""
        times: dict[float, int] = {}
        cells: dict[tuple[str, str, str], dict[int, float]] = {}
        with Path(path).open(newline="", encoding="utf-8") as f:
            for row in csv.DictReader(f):
                k = times.setdefault(float(row["time_s"]), len(times))
                value = float(row["degrees"]) if row["degrees"] not in ("", "nan") else np.nan
                cells.setdefault((row["angle"], row["joint"], row["method"]), {})[k] = value
        degrees = np.full((len(times), len(cells)), np.nan)
        for j, column in enumerate(cells.values()):
            for k, v in column.items():
                degrees[k, j] = v
        return cls(np.fromiter(times, dtype=float), tuple(cells), degrees)


@dataclass(frozen=True, eq=False)
class Analysis:
    """What :func:`analyze` made of one input: its angles, its report, its output folder."""

    angles: Angles
    report: dict[str, Any]
    out: Path

    @property
    def status(self) -> dict[str, str]:
        """Each limb's status (``ok``, or why not)."""
        return dict(self.report.get("limb_status", {}))


def analyze(
    path: str | Path,
    out: str | Path,
    *,
    static: str | Path | None = None,
    names: str = "kinefuse",
    marker_map: str | Path | None = None,
    calibration_phase: tuple[float, float] | None = None,
    method: str = "best",
    plots: bool = False,
) -> Analysis:
    """Paper B's limb frames and joint angles of a session, clip or marker file
    (``kinefuse analyze``), written into the fresh folder ``out`` and returned.

    ``static``: a static trial (marker files) for the anatomical (ISB) angles; ``names``:
    ``"opensim"`` for OpenSim's coordinate names and signs in ``angles.mot``.
    """
    from kinefuse.app.workflows.analyze import run_analyze

    inputs: Sequence[Path] = [Path(path)]
    result = run_analyze(
        inputs,
        out=Path(out),
        calibration_phase=calibration_phase,
        marker_map=None if marker_map is None else Path(marker_map),
        method=method,
        plots=plots,
        static=None if static is None else Path(static),
        names=names,
    )
    return Analysis(Angles.read_csv(Path(out) / "angles.csv"), result.report, result.out)
