"""How well the phase lock inside the capture loop holds the bands over minutes (issue 32):
the strobe firmware in simavr (real time), a camera that renders its strobe edges by the
rolling-shutter equations on a clock ``--ppm`` off the board's
(:class:`scet_hardware.capture.rig.StrobeRigCamera`), :class:`PhaseLockLoop` fed every frame
it has time for. Prints the commands sent, the period it settled on, and the true first-band
onset's deviation from its median over the run after the lock (rows; goal +-1).

    python benchmarks/bench_lock_hold.py --seconds 120 --ppm -2000
"""

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from estimator.capture import CaptureWriter  # noqa: E402
from scet_hardware.capture import stream_capture  # noqa: E402
from scet_hardware.capture.rig import StrobeRigCamera  # noqa: E402
from scet_hardware.firmware import SimulatedBoard, build_firmware  # noqa: E402
from scet_hardware.lock import LockFeed, PhaseLockLoop, split_period  # noqa: E402
from scet_hardware.strobe import StrobeLink  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--ppm", type=float, default=-2000.0)
    ap.add_argument("--settle-s", type=float, default=3.0, help="left out at the start (s)")
    args = ap.parse_args()
    dt, S, M = 16636.35e-6, 524, 16
    pitch = S / M
    work = Path(tempfile.mkdtemp(prefix="lockhold-"))
    try:
        build = build_firmware(work / "fw")
        with SimulatedBoard(build, work / "board", boot_s=1.0, edges=True) as board:
            with StrobeLink(board.port, settings=work / "strobe.json") as link:
                period, trim = split_period(dt / M * 16e6)
                link.apply(period_ticks=period, trim_256th=trim)
                lock = PhaseLockLoop(link, frame_period_s=dt, total_lines=S, periods_per_frame=M)
                link.on_reset = lock.restart
                cam = StrobeRigCamera(board, ppm=args.ppm, total_lines=S, frame_period_s=dt)
                feed = LockFeed(lock, "SGBRG10_CSI2P", 640)
                cam.start()
                t = time.perf_counter()
                try:
                    report = stream_capture(cam, CaptureWriter(work / "cap", cam.header()),
                                            frames=int(args.seconds / dt), skip_frames=0,
                                            timeout_s=5.0,
                                            on_frame=lambda i, rows, md: feed(rows, md) and None)
                finally:
                    cam.stop()
                    feed.close()
                wall = time.perf_counter() - t
        truth = cam.truth
        ks = sorted(truth)
        start = ks[0] + int(args.settle_s / dt)
        late = [k for k in ks if k >= start]
        v = np.array([truth[k] for k in late])
        med = np.median(v)
        dev = (v - med + pitch / 2) % pitch - pitch / 2
        last = lock.commands[-1][1] if lock.commands else None
        print(f"lock hold: {args.seconds:g} s asked, {wall:.1f} s run, board {args.ppm:+g} ppm, "
              f"{report.frames_written} frames written, {report.dropped_camera} dropped, "
              f"{cam.skipped} not rendered in time")
        print(f"commands {len(lock.commands)}; last PERIOD {last.period_ticks if last else '-'} "
              f"TRIM {last.trim_256th if last else '-'}; frames measured {len(lock.history)}, "
              f"skipped by the lock thread {feed.worker.skipped}")
        print(f"true first-band onset after {args.settle_s:g} s ({len(late)} frames over "
              f"{len(late) * dt:.0f} s): deviation from its median p50 {np.percentile(np.abs(dev), 50):.3f}, "
              f"p99 {np.percentile(np.abs(dev), 99):.3f}, max {np.abs(dev).max():.3f} rows")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
