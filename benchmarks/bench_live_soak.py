"""Soak of the live path (issue 32): a rendered dataset replayed as the camera at its frame
rate (60 fps, picamera2's behaviour: a frame not taken in time is recycled), streamed to a
capture folder through the bounded writer queue, and optionally tracked live as ``scet run``
does. Prints frames lost (camera drops and writer-queue losses; goal 0), the memory
high-water mark (peak RSS, and RSS at the start and the end: a bounded loop stays flat), the
writer queue's high-water mark, and the arrival latency (frame's SensorTimestamp to the loop
taking it) and, with --track, the tracking latency (frame in -> samples out) p50/p99.

    python benchmarks/bench_live_soak.py --seconds 600            # the issue's 10 minutes
    python benchmarks/bench_live_soak.py --seconds 120 --track     # with the tracker

The frames are banded frames of the prototype scene drawn analytically (the tests' drawing,
tests/estimator/test_tracker.draw_frame), repeated; the capture is written under --out
(default a temporary folder, removed at the end: 60 fps packed VGA is 23 MB/s).
"""

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from estimator.capture import CaptureFolder, CaptureWriter  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from scet_hardware.capture import ReplayCamera, Worker, stream_capture  # noqa: E402


def rss_mb() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def make_dataset(folder: Path, frames: int) -> None:
    from tests.estimator.test_tracker import draw_frame

    setup = load_scene("prototype_ov5647")
    (folder / "frames").mkdir(parents=True)
    rng = np.random.default_rng(3)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    for f in range(frames):
        img = draw_frame(setup, f, float(yaw[0]) + 0.002 * f, float(pitch[0]), rng)
        cv2.imwrite(str(folder / "frames" / f"{f:06d}.png"), img)
    manifest = {"format": "scet-dataset", "version": 1, "frames": frames,
                "scene": {"name": setup.name, "toml": Path(setup.source).read_text()},
                "image": {"width_px": 640, "height_px": 480, "png_bit_depth": 16}}
    (folder / "manifest.json").write_text(json.dumps(manifest))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--track", action="store_true", help="also track live (scet run's tracker)")
    ap.add_argument("--out", type=Path, help="where to write the capture (default: a temp folder)")
    ap.add_argument("--queue-frames", type=int, default=16)
    args = ap.parse_args()

    work = Path(tempfile.mkdtemp(prefix="soak-"))
    out = args.out or work / "cap"
    try:
        make_dataset(work / "data", 8)
        cam = ReplayCamera(work / "data", realtime=True, loop=True)
        frames = int(round(args.seconds / cam.frame_period_s))
        tracker_worker, track_lat = None, []
        if args.track:
            from estimator.capture import decode_raw, parse_raw_format, to_tracker_frame
            from estimator.folders import track_frame
            from estimator.tracker import Tracker
            from tests.estimator.simulated import ground_truth_calibration

            setup = load_scene("prototype_ov5647")
            tracker = Tracker(setup, ground_truth_calibration(setup), "polynomial")
            fmt = parse_raw_format(cam.fmt.name)

            def track(item):
                f, rows, md, arrived = item
                black = np.asarray(md["SensorBlackLevels"], float) / 64.0
                img = to_tracker_frame(decode_raw(rows, fmt, 640), fmt.bayer_order, black,
                                       cam.gains, setup.sensor.black_level_dn, fmt.bit_depth)
                track_frame(tracker, f, f * cam.frame_period_s, img, None)
                track_lat.append(time.perf_counter() - arrived)

            tracker_worker = Worker(track, "tracker", slots=2)

        def on_frame(index, rows, md):
            if tracker_worker is not None:
                tracker_worker.offer((index, rows, md, time.perf_counter()))

        rss0 = rss_mb()
        cam.start()
        t = time.perf_counter()
        report = stream_capture(cam, CaptureWriter(out, cam.header()), frames=frames,
                                skip_frames=0, timeout_s=2.0, queue_frames=args.queue_frames,
                                on_frame=on_frame)
        wall = time.perf_counter() - t
        cam.stop()
        if tracker_worker is not None:
            tracker_worker.close()
        rss1 = rss_mb()
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        cap = CaptureFolder(out)
        lat = np.asarray(report.arrival_latency_s) * 1e3
        print(f"soak: {args.seconds:g} s asked, {wall:.1f} s run, {frames} frames at "
              f"{1 / cam.frame_period_s:.2f} fps, state {report.state}")
        print(f"frames written {report.frames_written}, dropped by the camera {report.dropped_camera}, "
              f"lost to the writer queue {report.lost_queue} (lost in all: "
              f"{report.dropped_camera + report.lost_queue}, {100 * (report.dropped_camera + report.lost_queue) / max(frames, 1):.3f} %)")
        print(f"reader: {len(cap.index)} frames indexed, {len(cap.dropped)} dropped slots")
        print(f"memory: RSS {rss0:.0f} MB before, {rss1:.0f} MB after, peak {peak:.0f} MB; writer "
              f"queue high-water {report.queue_high_water} of {args.queue_frames} frames")
        print(f"arrival latency (SensorTimestamp -> loop): p50 {np.percentile(lat, 50):.2f} ms, "
              f"p99 {np.percentile(lat, 99):.2f} ms, max {lat.max():.2f} ms")
        if args.track:
            tl = np.asarray(track_lat) * 1e3
            print(f"tracker: {len(tl)} frames tracked, {tracker_worker.skipped} skipped while busy; "
                  f"latency frame in -> samples out p50 {np.percentile(tl, 50):.1f} ms, "
                  f"p99 {np.percentile(tl, 99):.1f} ms")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
