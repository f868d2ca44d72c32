"""The ``pose`` tracker with its real 2D model (MediaPipe Pose, full model, inside the wheel):
offline, on real photographs, and on the shared Azure Kinect recording whose mug "is a person"
to the 2D model and is refused by the gates."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from kinefuse.devices.pose.landmarks import LM
from kinefuse.devices.trackers import available_trackers, load_tracker

pytest.importorskip("mediapipe", reason="the pose tracker's model: pip install 'kinefuse[tracker]'")
skimage_data = pytest.importorskip("skimage.data", reason="scikit-image's sample photos")

sys.path.insert(0, str(Path(__file__).resolve().parent))
from k4a_mkv import k4a_calibration, k4a_first_capture  # noqa: E402


@pytest.fixture(scope="module")
def tracker():  # type: ignore[no-untyped-def]
    t = load_tracker("pose", {"mode": "image"})
    yield t
    t.close()


def test_registered_as_an_entry_point() -> None:
    assert available_trackers()["pose"] == "kinefuse.devices.pose:make"


def test_astronaut_gives_shoulders_elbows_and_hips_where_a_person_sees_them(tracker) -> None:  # type: ignore[no-untyped-def]
    lm = tracker.model.detect(skimage_data.astronaut())  # 512 x 512, facing the camera
    assert lm is not None and lm.image_size == (512, 512)
    uv = lm.uv_px
    # pixel regions read off the photo: her right side is on the image's left
    regions = {
        "right_shoulder": (80, 160, 200, 290),  # u0, u1, v0, v1
        "left_shoulder": (260, 360, 200, 300),
        "right_elbow": (30, 120, 350, 470),
        "left_elbow": (270, 380, 320, 440),
        # the photo ends at the waist: the hips are at or just below its bottom edge
        "right_hip": (80, 220, 470, 600),
        "left_hip": (190, 330, 470, 600),
    }
    for name, (u0, u1, v0, v1) in regions.items():
        u, v = uv[LM[name]]
        assert u0 <= u <= u1 and v0 <= v <= v1, (name, u, v)
    assert lm.visibility[LM["left_shoulder"]] > 0.9 and lm.visibility[LM["right_shoulder"]] > 0.9
    nose = uv[LM["nose"]]
    assert 190 <= nose[0] <= 250 and 100 <= nose[1] <= 160  # her face


def test_a_photo_without_a_person_gives_none(tracker) -> None:  # type: ignore[no-untyped-def]
    assert tracker.model.detect(skimage_data.coffee()) is None


def test_the_mugs_cartoon_is_refused_by_the_gates_with_the_reason(
    tracker,  # type: ignore[no-untyped-def]
    shared_data: Path,
) -> None:
    pytest.importorskip("av", reason="PyAV reads the Azure Kinect MKV")
    depth = shared_data / "depth"
    cal = k4a_calibration(depth / "pyk4a_calibration.json")
    cap = k4a_first_capture(depth / "pyk4a_recording.mkv")
    # the 2D model alone does see a "person": the cartoon on the mug
    lm = tracker.model.detect(cap.color)
    assert lm is not None and float(np.min(lm.visibility[[11, 12, 23, 24]])) > 0.5
    result = tracker.track(cap, cal)
    assert result.bodies == ()
    assert len(result.refused) == 1
    reason = result.refused[0]
    assert "not a person" in reason and re.match(r"bones of \d+ cm", reason), reason
    bones_cm = int(re.match(r"bones of (\d+) cm", reason).group(1))  # type: ignore[union-attr]
    assert bones_cm < 9  # a cartoon's bones, lifted with the real depth
    assert set(result.timings_s) == {"model", "lift", "map", "gates"}


_OFFLINE = """
import json, sys
import numpy as np
from skimage import data
from kinefuse.devices.trackers import load_tracker
t = load_tracker("pose", {"mode": "image"})
lm = t.model.detect(data.astronaut())
print(json.dumps({"found": lm is not None,
                  "shoulders": None if lm is None else lm.uv_px[[11, 12]].tolist()}))
"""


def test_the_model_runs_with_the_network_off(tmp_path: Path) -> None:
    """In a network namespace with no interface up, under strace: the model loads and finds
    the astronaut, and the process makes no connect or send to any address at all."""
    for tool in ("unshare", "strace"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (util-linux, strace)")
    probe = subprocess.run(["unshare", "-rn", "true"], capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"unshare -rn is not permitted here: {probe.stderr.strip()}")
    trace = tmp_path / "strace.log"
    cmd = ["unshare", "-rn", "strace", "-f", "-qq", "-e", "trace=connect,sendto,sendmsg",
           "-o", str(trace), sys.executable, "-c", _OFFLINE]  # fmt: skip
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    assert out["found"] and len(out["shoulders"]) == 2
    calls = [ln for ln in trace.read_text().splitlines() if re.search(r"AF_INET6?\b", ln)]
    assert calls == [], calls[:5]


def test_ir_serves_where_there_is_no_colour_and_no_depth_is_refused(  # type: ignore[no-untyped-def]
    tracker, shared_data: Path
) -> None:
    pytest.importorskip("av", reason="PyAV reads the Azure Kinect MKV")
    from dataclasses import replace

    depth = shared_data / "depth"
    cal = k4a_calibration(depth / "pyk4a_calibration.json")
    cap = k4a_first_capture(depth / "pyk4a_recording.mkv")
    ir_only = tracker.track(replace(cap, color=None), replace(cal, color=None))
    assert "model" in ir_only.timings_s  # the 2D model ran, on the IR image
    assert ir_only.bodies == ()  # no person in the mug scene's IR either
    no_depth = tracker.track(replace(cap, depth_mm=None), cal)
    assert no_depth.bodies == () and "no depth" in no_depth.refused[0]


def test_options_are_checked_and_the_detector_can_run_every_k_frames() -> None:
    from kinefuse.errors import InputError

    with pytest.raises(InputError, match="unknown pose tracker option"):
        load_tracker("pose", {"colour": "yes"})
    with pytest.raises(InputError, match="detect_every"):
        load_tracker("pose", {"detect_every": "-1"})
    with pytest.raises(InputError, match="input_width is whole pixels"):
        load_tracker("pose", {"input_width": "wide"})
    t = load_tracker("pose", {"detect_every": "2"})
    try:
        found = [t.model.detect(skimage_data.astronaut()) is not None for _ in range(5)]
    finally:
        t.close()
    assert all(found)  # tracked, re-detected every other frame, tracked again


def test_images_that_do_not_fit_the_calibration_are_one_line_errors(  # type: ignore[no-untyped-def]
    tracker, shared_data: Path
) -> None:
    from dataclasses import replace

    from kinefuse.errors import InputError

    depth = shared_data / "depth"
    cal = k4a_calibration(depth / "pyk4a_calibration.json")
    cap = k4a_first_capture(depth / "pyk4a_recording.mkv")
    with pytest.raises(InputError, match=r"depth image is uint16 \(288, 320\)"):
        tracker.track(replace(cap, depth_mm=cap.depth_mm[::2, ::2]), cal)  # a binned mode
    with pytest.raises(InputError, match="colour image is 640x360"):
        tracker.track(replace(cap, color=cap.color[::2, ::2]), cal)
    with pytest.raises(InputError, match="uint8 RGB"):
        tracker.track(replace(cap, color=cap.color[:, :, 0]), cal)
