"""The pose tracker's cost per stage and its sustained rate, on 640x576 depth with 720p colour.

Run: ``python benchmarks/bench_tracker.py [--smoke]`` (``--smoke``: 3 frames per measurement
and a 2 s sustained run, to check that it runs; too few to quote). Needs the tracker extra
(``pip install 'kinefuse[tracker]'``) and PyAV; scikit-image's astronaut, when installed, is
the person the 2D model tracks (else the shared MKV's mug cartoon, which it also "tracks").

Stages, each the median ms per frame:

* **decode**: the shared Azure Kinect MKV's capture (MJPG 720p colour, 640x576 depth) with PyAV;
* **2D model**: MediaPipe Pose (full model) on a 1280x720 colour image, for each option: the
  input width (the image scaled down first), the mode (``video``: the detector only when the
  person is lost, the region of interest tracked from frame to frame; ``image``: the detector
  every frame) and, in video mode, the detector every K frames as well;
* **lift, map, gates**: on a body rendered by the simulator (a real CMU walk, capsule body) in
  640x576 depth with the recording's own intrinsics, landmarks projected into its 720p colour
  camera through its ``color_from_depth``, with a detector's pixel noise.

Then the **sustained rate**: the whole tracker behind a :class:`TrackerWorker` fed at 30 Hz for
a while (drops counted), each option's rate against the default's in the same run.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from kinefuse.core.geometry.transforms import apply_transform, invert_transform, look_at
from kinefuse.devices.capture import CameraCalibration, Capture
from kinefuse.devices.k4a_calibration import calibration_from_k4a_json
from kinefuse.devices.pose.model import BlazePoseModel
from kinefuse.devices.pose.tracker import PoseTracker, body_from_landmarks
from kinefuse.devices.undistort import DepthUndistorter
from kinefuse.devices.worker import TrackerWorker
from kinefuse.formats.motion.load import load_motion
from kinefuse.lab.pose_lift import DetectorNoise, true_landmarks
from kinefuse.sim.depth import Scene, render_depth

ROOT = Path(__file__).resolve().parents[1]
DEPTH_DIR = ROOT.parent / "shared" / "data" / "depth"
WALK = ROOT.parent / "shared" / "data" / "motion" / "cmu" / "131_01_scaled_metres.bvh"


def recording_calibration() -> CameraCalibration:
    """The recording's Azure Kinect as kinefuse reads it (NFOV-unbinned depth, 720p colour)."""
    text = (DEPTH_DIR / "pyk4a_calibration.json").read_text()
    return calibration_from_k4a_json(text, "NFOV_UNBINNED", "720P", what="pyk4a_calibration.json")


def recording_packets() -> dict[str, object]:
    """The recording's first colour and depth packets, demuxed once (PyAV)."""
    import av

    container = av.open(str(DEPTH_DIR / "pyk4a_recording.mkv"))
    packets: dict[str, object] = {}
    for packet in container.demux(video=list(range(len(container.streams.video)))):
        title = packet.stream.metadata.get("title")
        if title in ("COLOR", "DEPTH") and title not in packets and packet.size:
            packets[title] = packet
    return packets


def decode_capture(packets: dict[str, object]) -> tuple[np.ndarray, np.ndarray]:
    """Decode one capture's colour (MJPG -> RGB) and depth (16-bit) packets."""
    color = packets["COLOR"].stream.codec_context.decode(packets["COLOR"])[0]  # type: ignore[attr-defined]
    depth = packets["DEPTH"].stream.codec_context.decode(packets["DEPTH"])[0]  # type: ignore[attr-defined]
    return color.to_ndarray(format="rgb24"), depth.to_ndarray()


def person_image(mug: np.ndarray) -> tuple[np.ndarray, str]:
    """A 1280x720 image with a person in it: the astronaut on grey, or the mug's cartoon."""
    try:
        from skimage import data
    except ImportError:
        return mug, "the mug's cartoon (scikit-image not installed)"
    canvas = np.full((720, 1280, 3), 128, np.uint8)
    canvas[104:616, 384:896] = data.astronaut()
    return canvas, "scikit-image's astronaut on a 1280x720 canvas"


#: (input width px, mode, detector every K frames): the default first
OPTIONS = ((640, "video", 0), (640, "video", 10), (1280, "video", 0), (320, "video", 0),
           (640, "image", 0))  # fmt: skip


def label(width: int, mode: str, every: int) -> str:
    extra = f", detector every {every}" if every else ""
    return f"input {width} px, {mode}{extra}"


def median_ms(fn, n: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def rendered_body(cal: CameraCalibration, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` depth frames of a walking body 2.5 m in front of the camera, with its true joints
    in the depth camera's frame."""
    motion = load_motion(WALK)
    s2w = look_at([2.5, 0.0, 1.0], [0.0, 0.0, 1.0])
    rng = np.random.default_rng(0)
    frames = []
    for k in np.linspace(0, motion.n_frames - 1, n).astype(int):
        pose = motion.positions[k].copy()
        pose[:, :2] -= pose[0, :2]  # the walker's pelvis at the origin, 2.5 m from the camera
        pose[:, 2] -= pose[:, 2].min()  # feet on the floor
        scene = Scene.from_pose(pose, walls=False)
        depth = render_depth(scene, s2w, cal.depth, rng)
        frames.append((depth, apply_transform(invert_transform(s2w), pose)))
    return frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--smoke", action="store_true", help="3 frames, 2 s sustained (seconds)")
    ap.add_argument("--seconds", type=float, default=10.0, help="sustained run per option (s)")
    args = ap.parse_args()
    n = 3 if args.smoke else 30
    seconds = 2.0 if args.smoke else args.seconds
    device = recording_calibration()
    cal = replace(device, distortion_depth=())  # what a tracker is handed: the pinhole depth

    print("pose tracker, per stage (median ms per frame)")
    packets = recording_packets()
    ms = median_ms(lambda: decode_capture(packets), n)
    mug, raw_depth = decode_capture(packets)
    print(f"  decode  MKV capture (MJPG 1280x720 colour + 640x576 depth)  {ms:7.1f}")
    pinhole = DepthUndistorter(device)
    ms = median_ms(lambda: pinhole(raw_depth), n)
    print(f"  undistort  640x576 depth to the pinhole (IR costs the same)  {ms:7.1f}")

    image, what = person_image(mug)
    print(f"  2D model on {what}:")
    for width, mode, every in OPTIONS:
        model = BlazePoseModel(input_width=width, video=mode == "video", detect_every=every)
        found = model.detect(image) is not None  # the first frame: the detector runs
        ms = median_ms(lambda m=model: m.detect(image), n)
        model.close()
        print(f"    {label(width, mode, every):<40} {ms:7.1f}   (person found: {found})")

    frames = rendered_body(cal, n)
    rng = np.random.default_rng(1)
    stage: dict[str, list[float]] = {"lift": [], "map": [], "gates": []}
    refused = 0
    for depth, truth in frames:
        truth_color = apply_transform(cal.color_from_depth, truth)  # type: ignore[arg-type]
        lm = true_landmarks(truth_color, cal.color, rng, DetectorNoise())  # type: ignore[arg-type]
        st = body_from_landmarks(lm, depth, cal.depth, cal.color,  # type: ignore[arg-type]
                                 cal.color_from_depth)  # fmt: skip
        refused += st.gate.refused is not None
        for k in stage:
            stage[k].append(st.timings_s[k])
    for k, v in stage.items():
        print(f"  {k:5s}   rendered 640x576 body depth, 720p landmarks   "
              f"{1e3 * float(np.median(v)):7.1f}")  # fmt: skip
    print(f"          ({len(frames) - refused} of {len(frames)} frames a person)")

    rounds = 1 if args.smoke else max(1, round(seconds / 2.0))
    print(f"sustained: the whole tracker behind a TrackerWorker fed at 30 Hz, {rounds} x 2 s "
          "per option, the options taking turns (the machine's load drifts)")  # fmt: skip
    trackers = {
        o: PoseTracker(BlazePoseModel(input_width=o[0], video=o[1] == "video", detect_every=o[2]))
        for o in OPTIONS
    }
    done = dict.fromkeys(OPTIONS, 0)
    dropped = dict.fromkeys(OPTIONS, 0)
    spent = dict.fromkeys(OPTIONS, 0.0)
    for _ in range(rounds):
        for option, tracker in trackers.items():
            with TrackerWorker(tracker, cal, max_pending=1) as worker:
                t0 = time.monotonic()
                k = 0
                while time.monotonic() - t0 < 2.0:
                    worker.submit(Capture(seq=k, t_device_s=k / 30, depth_mm=frames[0][0],
                                          color=image))  # fmt: skip
                    k += 1
                    time.sleep(max(0.0, t0 + k / 30.0 - time.monotonic()))  # a 30 Hz camera
                worker.drain(timeout=30.0)
                spent[option] += time.monotonic() - t0
                status = worker.status()
            done[option] += status.tracked
            dropped[option] += status.dropped
    rates = {}
    for option, tracker in trackers.items():
        tracker.close()
        rates[option] = done[option] / spent[option]
        print(f"  {label(*option):<40} {rates[option]:5.1f} Hz achieved, {done[option]} "
              f"tracked, {dropped[option]} dropped")  # fmt: skip
    base = rates[OPTIONS[0]]
    for key, r in rates.items():
        print(f"  rate vs the default: {label(*key):<40} {r / base:5.2f}x")
    print(f"  30 Hz target with the default options: {'met' if base >= 29.0 else 'NOT met'}")


if __name__ == "__main__":
    main()
