"""What the server reports: its status snapshot, a calibration's outcome, the run's figures.

Functions of the :class:`~kinefuse.live.server.server.Server`'s state (no I/O), split from the
server module so that it keeps to the connections, the tasks and their flow.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from kinefuse.live.protocol import CalibrationResult, SensorInfo, Status
from kinefuse.live.server.live_calibration import CalibrationOutcome

if TYPE_CHECKING:
    from kinefuse.live.server.server import Server


def server_status(srv: Server) -> Status:
    """The server's status snapshot (what the publisher sends about once a second)."""
    now = srv.clock()
    poses = srv.calibration.poses
    sensors = []
    for sid, c in srv.clients.items():
        off, sd = c.clock_ms(now)
        p = poses.get(sid)
        sensors.append(
            SensorInfo(
                sensor_id=sid,
                connected=c.connected,
                rtt_ms=c.rtt_s * 1e3,
                clock_offset_ms=off,
                clock_offset_sd_ms=sd,
                fps=c.fps(now),
                latency_ms=c.latency_s * 1e3,
                tracked_fraction=c.tracked_fraction(),
                sensor2world=None if p is None else np.asarray(p, dtype=float).reshape(4, 4),
                floor_error=c.floor_error,
                stale_frames=c.stale,
                tracker=c.tracker,
            )
        )
    return Status(
        t_server_s=now,
        frames_fused=srv.loop.frames,
        sensors=tuple(sensors),
        calibration_state=srv.calibration.state.reported,
        calibration_grade=srv.calibration.grade,
        fused_fps=srv.loop.fps(),
        method=srv.options.method,
        recording=str(srv.options.record) if srv.options.record else None,
        calibration_message=srv.person.message,
        subject=srv.fusion.subject if srv.fusion.subject_known else None,
        subject_rule=srv.fusion.subject_rule if srv.fusion.subject_known else None,
    )


def status_message(srv: Server, request_id: int) -> Status:
    """The status as a control peer gets it: the published snapshot, answering ``request_id``."""
    return replace(server_status(srv), request_id=request_id)


def run_stats(srv: Server) -> dict[str, object]:
    """Figures of the run so far (also stored as the meta ``live_run`` at a clean stop)."""
    lp = srv.loop
    return {
        "frames_fused": lp.frames,
        "frames_skipped": lp.skipped,
        "fusion_ms_per_frame": 1e3 * lp.fuse_seconds / lp.frames if lp.frames else None,
        "stop_reason": srv._stop_reason,
        "refused": [{"code": c, "reason": r} for c, r in srv.refused],
        "refused_total": srv.refusals.total,
        "refused_by_code": dict(srv.refusals.counts),
        "sensors": {
            sid: {
                "connections": c.connections,
                "queue_dropped": c.dropped,
                "stale_frames": c.stale,
                "late_dropped": c.late_dropped,
            }
            for sid, c in srv.clients.items()
        },
    }


def outcome_meta(out: CalibrationOutcome) -> dict[str, object]:
    reg = out.registration
    d: dict[str, object] = {
        "calibration_id": out.calibration_id,
        "ok": out.ok,
        "method": out.method,
        "grade": out.grade.grade,
        "reasons": list(out.grade.reasons),
        "message": out.message,
        "targets": list(out.targets),
    }
    if out.halves is not None:
        d["halves"] = out.halves.to_dict()
    if reg is not None:
        d["rms_m"] = float(reg.rms_m)
        d["sensors"] = [
            {
                "id": sid,
                "residual_m": float(reg.residual_m[k]),
                "sightings": int(reg.n_sightings[k]),
            }
            for k, sid in enumerate(reg.sensor_ids)
        ]
    return d


def result_message(out: CalibrationOutcome) -> CalibrationResult:
    cal = out.calibration
    sensors = cal.sensors if cal is not None else ()
    text = out.message + "".join(f"; {r}" for r in out.grade.reasons)
    return CalibrationResult(
        calibration_id=out.calibration_id,
        ok=out.ok,
        grade=out.grade.grade,
        method=out.method,
        sensor_ids=tuple(s.id for s in sensors),
        sensor2world=np.array([s.sensor2world for s in sensors]).reshape(-1, 4, 4),
        residual_m=np.array(
            [s.residual_m if np.isfinite(s.residual_m) else np.nan for s in sensors]
        ).reshape(-1),
        n_sightings=np.array([s.n_sightings for s in sensors], dtype=np.int64).reshape(-1),
        message=text[:1024],
    )
