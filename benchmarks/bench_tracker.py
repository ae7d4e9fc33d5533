"""Tracker throughput on one core: glint detection frames/s and end-to-end samples/s.

Frames: 640x480 10-bit banded frames of paper_sim (Gaussian glints at their closed-form
positions for an eye making saccades, each pulse's glints at the eye's pose then, every pulse's
row weights, an eye-like background, shot and read noise; :func:`bench_glints.moving_sequence`),
or with ``--dataset DIR`` the PNG frames of a rendered dataset. Detection is timed through
:class:`estimator.glints.GlintDetector` (one pass over the frames as a stream, after a warm-up
that loads its compiled kernels); the
end-to-end figure through :meth:`estimator.tracker.Tracker.process` (detect, group by strobe,
match with the previous sample as prior, fit, map), both gaze methods. Usage:

    python benchmarks/bench_tracker.py [--frames 24] [--dataset DIR]
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_glints import moving_sequence  # noqa: E402

from estimator.calibration import Calibration, fit_gaze_mapping
from estimator.folders import iter_folder  # noqa: E402
from estimator.gaze import fit_cornea_centers  # noqa: E402
from estimator.glints import GlintDetector
from estimator.scene import load_scene  # noqa: E402
from estimator.tracker import Tracker  # noqa: E402
from scet_render.simulate import ground_truth_glints  # noqa: E402


def ground_truth_calibration(setup) -> Calibration:
    targets = setup.screen.grid(5, 5, margin=0.0)
    yaw, pitch = setup.eye.angles_toward(targets)
    g, vis, _ = ground_truth_glints(setup, yaw, pitch)
    cal = Calibration.ground_truth(setup)
    c = fit_cornea_centers(setup, cal, np.where(vis[..., None], g, np.nan)).center_m
    return cal.with_mappings(eq1_25=fit_gaze_mapping(c, targets, "eq1", degenerate="min_norm"))


def synthetic_frames(setup, n: int, rng):
    """Frames of an eye making saccades between random screen targets
    (:func:`bench_glints.moving_sequence`: each pulse's glints at the eye's pose then)."""
    return moving_sequence(setup, n, rng)[0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--dataset", type=Path, default=None)
    args = ap.parse_args(argv)
    setup = load_scene("paper_sim")
    rng = np.random.default_rng(0)
    cv2.setNumThreads(1)
    if args.dataset is not None:
        import json

        from estimator.banding import scaled_setup

        width = json.loads((args.dataset / "manifest.json").read_text())["image"]["width_px"]
        setup = scaled_setup(setup, setup.camera.width_px // int(width))
        frames = [(f, img) for f, _, img, err in iter_folder(args.dataset, setup)
                  if err is None][: args.frames]
    else:
        frames = synthetic_frames(setup, args.frames, rng)
    print(f"{platform.processor() or platform.machine()}, {len(frames)} frames "
          f"{setup.camera.width_px}x{setup.camera.height_px}, one core")

    for f, img in frames[:2]:  # load (or compile) the detector's kernels before timing
        GlintDetector(setup)(img, f)
    detector = GlintDetector(setup)
    t = time.perf_counter()
    n_glints = sum(len(detector(img, f)) for f, img in frames)
    dt = time.perf_counter() - t
    print(f"detection (GlintDetector, one pass): {len(frames) / dt:.1f} frames/s "
          f"({1e3 * dt / len(frames):.2f} ms/frame, {n_glints / len(frames):.1f} glints/frame, "
          f"{detector.windowed} of {detector.frames} frames in a window)")

    cal = ground_truth_calibration(setup)
    for method in ("polynomial", "geometric"):
        tr = Tracker(setup, cal, method)
        t = time.perf_counter()
        samples = [s for f, img in frames for s in tr.process(img, f)]
        dt = time.perf_counter() - t
        ok = sum(s.ok for s in samples)
        print(f"tracker {method}: {len(samples) / dt:.1f} samples/s "
              f"({ok / dt:.1f} estimated samples/s, {ok}/{len(samples)} ok, "
              f"{len(frames) / dt:.1f} frames/s)")


if __name__ == "__main__":
    main()
