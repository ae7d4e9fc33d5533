"""Seconds per banded frame against seconds per global-shutter frame, same scene, same spp.

A banded frame renders each of the frame's strobes only over the rows it lights, at the eye
pose of its instant, plus the ambient light over every row's exposure window
(:class:`scet_render.render.rolling_shutter.BandedRenderer`); a global-shutter frame renders every row
once at one pose. Their ratio is the price of banding: the bands overlap by ~3 rows (about
1.06 frames of rows in all), every strobe moves the eye (a BVH rebuild) and launches its own
kernel, and a moving eye adds ambient-only instants. Rendering every strobe as a full frame
would cost about 16.

Three eye motions, each timed on the same renderer, interleaved with global frames:
``still`` (a fixation without fixational noise: every strobe at the same pose), ``drift``
(fixational drift and tremor: a new pose at every strobe) and ``saccade`` (20 deg saccades
back and forth: new poses, and ambient-only instants for motion blur). Wall and process CPU
seconds are both reported (CPU time is the fairer measure on a shared machine). Kernels are
compiled and the frozen functions recorded during a warm-up that is not timed. Usage:

    python benchmarks/bench_render.py [--scene paper_sim] [--spp 16] [--frames 3] [--variant V]
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from estimator.scene import load_scene
from scet_render.motion import FixationalNoise, fixation_sequence
from scet_render.render import BandedRenderer


def timed(fn) -> tuple[float, float]:
    """(wall s, process CPU s) of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="paper_sim")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--frames", type=int, default=3, help="timed frames per motion")
    ap.add_argument("--cornea", default="dielectric", choices=("dielectric", "plain_dielectric", "conductor"))
    ap.add_argument("--variant", default=None)
    args = ap.parse_args()
    setup = load_scene(args.scene)
    renderer = BandedRenderer(setup, variant=args.variant, spp=args.spp, cornea=args.cornea)
    eye, screen = setup.eye, setup.screen
    targets = screen.grid(3, 3)
    motions = {
        "still": (fixation_sequence(eye, targets[[4]], [2.0]), 0),
        "drift": (fixation_sequence(eye, targets[[4]], [2.0], rng=1, noise=FixationalNoise()),
                  0),
        # Back and forth between the top-left and centre targets (20 deg, ~65 ms each way)
        # with 5 ms fixations: every timed frame falls mostly inside a saccade.
        "saccade": (fixation_sequence(eye, targets[[0, 4] * 20], 0.005), 0),
    }
    print(f"# {platform.processor() or platform.machine()}, Mitsuba {renderer.mi.__version__} "
          f"{renderer.variant}, scene {setup.name}, {setup.camera.width_px}x"
          f"{setup.camera.height_px}, {args.spp} spp, {setup.strobe.pulses_per_frame} strobes "
          f"per frame, {args.cornea} cornea")
    for traj, first in motions.values():  # warm-up: compile, record the frozen functions
        for f in range(first, first + 3):
            renderer.render_frame(traj, f)
    renderer.render_global(0.0, 0.0, seed=1)
    print(f"{'motion':>8} {'K':>2} {'slices':>6} {'rows':>5} {'banded s':>9} {'global s':>9} "
          f"{'ratio':>6} {'banded cpu':>10} {'global cpu':>10} {'cpu ratio':>9}")
    for name, (traj, first) in motions.items():
        banded, glob, slices = [], [], []
        for k in range(args.frames):
            f = first + 3 + k
            banded.append(timed(lambda: renderer.render_frame(traj, f)))
            slices.append(renderer.plan(traj, f))
            yaw, pitch = traj.angles_at(f * setup.sensor.frame_period_s)
            glob.append(timed(lambda: renderer.render_global(float(yaw), float(pitch), seed=f)))
        K = max(p.instants_per_period for p in slices)
        n_slices = np.mean([p.times_s.size for p in slices])
        rows = np.mean([(p.rows[:, 1] - p.rows[:, 0]).sum() for p in slices])
        b, g = np.median(banded, axis=0), np.median(glob, axis=0)
        print(f"{name:>8} {K:>2} {n_slices:>6.1f} {rows:>5.0f} "
              f"{b[0]:>9.3f} {g[0]:>9.3f} {b[0] / g[0]:>6.2f} {b[1]:>10.3f} {g[1]:>10.3f} "
              f"{b[1] / g[1]:>9.2f}")


if __name__ == "__main__":
    main()
