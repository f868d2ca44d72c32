"""Parts of the tracker's error model switched off (``simulate --errors-off``): each part's
fields and nothing else go to 0, every other draw stays as it was (so the same seed simulates
the same session without the part), and bad names are refused with the choices."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from kinefuse.app.cli import main
from kinefuse.core.camera.intrinsics import Intrinsics
from kinefuse.core.geometry.transforms import look_at
from kinefuse.core.skeleton import JOINT_INDEX, TrackingState, capsule_radii, standing_pose
from kinefuse.errors import InputError
from kinefuse.formats.store.session_store import SessionStore
from kinefuse.sim.tracker import draw_subject_bias, simulate_tracker
from kinefuse.sim.tracker_params import ERROR_PARTS, TrackerParams, without_parts

SHARED = ("subject", "view", "inferred", "swap")


def _walk_in_place(n: int = 900) -> np.ndarray:
    """The standing pose swaying sideways, up to 0.3 m/s (gross failures start only while
    moving)."""
    x = 0.3 * np.sin(np.arange(n) / 30.0)
    shift = np.stack([0 * x, x, 0 * x], axis=1)
    return np.repeat(standing_pose(1.71)[None], n, axis=0) + shift[:, None, :]


def _track(truth: np.ndarray, sensor_at: list[float], params: TrackerParams):  # type: ignore[no-untyped-def]
    subject = draw_subject_bias(np.random.default_rng(9), params)
    s2w = look_at(sensor_at, [0.0, 0.0, 1.0])
    return simulate_tracker(truth, s2w, Intrinsics(), capsule_radii(1.71),
                            np.random.default_rng(4), params, subject=subject)  # fmt: skip


def test_each_part_zeroes_its_fields_and_nothing_else() -> None:
    base = TrackerParams()
    for part, names in ERROR_PARTS.items():
        off = without_parts(base, [part])
        changed = {f.name for f in dataclasses.fields(base)
                   if getattr(off, f.name) != getattr(base, f.name)}  # fmt: skip
        assert changed == set(names), part
        for n in names:
            assert not np.any(np.asarray(getattr(off, n), dtype=float)), (part, n)
    independent = {f for p, names in ERROR_PARTS.items()
                   if p not in (*SHARED, "independent") for f in names}  # fmt: skip
    assert set(ERROR_PARTS["independent"]) == independent
    assert without_parts(base, []) == base
    with pytest.raises(InputError, match=r"'bogus'.*choose from subject, view"):
        without_parts(base, ["gross", "bogus"])


def test_a_part_off_leaves_every_other_draw_as_it_was() -> None:
    """Seen from the front, the inferred-joint and swap processes have nothing to act on and the
    far-limb error next to nothing: switching one off must give the same numbers (had it
    changed how many random numbers are drawn, every later draw would differ, by centimetres).
    Seen from the side, each of them (and each other part) changes what is reported: it really
    is off."""
    truth = _walk_in_place()
    front, side = [2.4, 0.0, 1.0], [0.0, 2.4, 1.0]
    base_front = _track(truth, front, TrackerParams())
    base_side = _track(truth, side, TrackerParams())
    trunk = [JOINT_INDEX[n] for n in TrackerParams().never_inferred]
    assert not base_front.swapped.any()
    assert 0.1 < (base_side.states[:, trunk] == TrackingState.INFERRED).mean() < 0.9
    for part in ERROR_PARTS:
        params = without_parts(TrackerParams(), [part])
        f, s = _track(truth, front, params), _track(truth, side, params)
        # what is drawn before any error is scaled: the same dropouts and visibility; and
        # after every error: the trunk's INFERRED runs seen from the side (a per-sensor random
        # process drawn last, 29 % of the trunk's frames here)
        np.testing.assert_array_equal(f.dropout, base_front.dropout)
        np.testing.assert_array_equal(s.visible, base_side.visible)
        np.testing.assert_array_equal(s.states[:, trunk], base_side.states[:, trunk])
        if part in ("inferred", "swap"):
            np.testing.assert_array_equal(f.joints_sensor, base_front.joints_sensor)
        if part == "far":  # a limb a little on the far side: micrometres
            np.testing.assert_allclose(f.joints_sensor, base_front.joints_sensor, atol=1e-4)
        gap = np.nanmax(np.linalg.norm(s.joints_sensor - base_side.joints_sensor, axis=-1))
        assert gap > 0.005 or part == "swap", part
    # the jitter alone off: the rest of the error (the subject's and the sensor's slow
    # offsets) is what it was, so the difference is the jitter's size, not a redraw of all
    j = _track(truth, front, without_parts(TrackerParams(), ["jitter"]))
    d = np.linalg.norm(j.joints_sensor - base_front.joints_sensor, axis=-1)
    err = np.linalg.norm(base_front.joints_sensor - _track(truth, front, without_parts(
        TrackerParams(), list(ERROR_PARTS))).joints_sensor, axis=-1)  # fmt: skip
    assert np.nanmedian(d) < 0.5 * np.nanmedian(err)


def test_simulate_errors_off_end_to_end(tmp_path, shared_data, capsys) -> None:
    clip = str(shared_data / "motion" / "cmu" / "02_walk_b.amc")
    errors = []
    for name, extra in (("all", []), ("shared", ["--errors-off", "independent"]),
                        ("none", ["--errors-off", ",".join(ERROR_PARTS)])):  # fmt: skip
        out = tmp_path / f"{name}.sqlite"
        assert main(["simulate", "--clip", clip, "--seconds", "2", "--calibration-seconds", "0",
                     "--seed", "7", "--out", str(out), *extra]) == 0  # fmt: skip
        capsys.readouterr()
        assert main(["inspect", str(out), "--json"]) == 0
        errors.append(json.loads(capsys.readouterr().out)["observation_error_m"]["median"])
        with SessionStore.open(out) as st:
            tracker = st.truth().info("error_model")["tracker"]
        if name == "shared":  # stored with the truth: the model the session was made with
            assert not any(tracker["jitter_sigma_m"]) and tracker["gross_limb_rate_hz"] == 0
            assert any(tracker["view_bias_sigma_m"])
    assert errors[0] > errors[1] > errors[2]
    with pytest.raises(SystemExit) as stop:  # argparse's usage error
        main(["simulate", "--clip", clip, "--errors-off", "gross,bogus",
              "--out", str(tmp_path / "x.sqlite")])  # fmt: skip
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "bogus" in err and "independent" in err
    assert not (tmp_path / "x.sqlite").exists()
