"""Glint projections per second per core: 40 lights x {1, 100, 10,000} cornea poses.

Runs on one core (BLAS threads pinned to 1 before numpy loads) with the paper_sim scene and
prints, for each batch size, the throughput of the default Newton solver and of the
companion-matrix quartic solver measured in the same run. Usage:

    python benchmarks/bench_projection.py [--seconds 2] [--scene paper_sim]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

from estimator.eye import gaze_direction  # noqa: E402
from estimator.geometry import project_glints
from estimator.scene import load_scene  # noqa: E402


def rate(fn, pairs: int, seconds: float) -> float:
    """Best-of-runs projections per second: repeat ``fn`` for ``seconds``, keep the fastest
    call (the least disturbed by other load on the machine)."""
    fn()  # warm-up
    best = float("inf")
    end = time.perf_counter() + seconds
    calls = 0
    while time.perf_counter() < end or calls < 3:
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
        calls += 1
    return pairs / best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="time per measurement")
    ap.add_argument("--scene", default="paper_sim")
    args = ap.parse_args()
    setup = load_scene(args.scene)
    lights = setup.lights_world_m
    rng = np.random.default_rng(1)
    print(f"# {platform.processor() or platform.machine()}, numpy {np.__version__}, one core, "
          f"scene {setup.name}, {lights.shape[0]} lights, best of {args.seconds:g} s per row")
    print(f"{'poses':>7} {'lights':>6} {'newton proj/s':>14} {'quartic proj/s':>15} {'ratio':>6}")
    for poses in (1, 100, 10_000):
        yaw, pitch = rng.uniform(-0.33, 0.33, poses), rng.uniform(-0.28, 0.14, poses)
        center = setup.eye.cornea_center(yaw, pitch)
        axis = gaze_direction(yaw, pitch)
        pairs = poses * lights.shape[0]
        rates = {}
        for solver in ("newton", "quartic"):
            rates[solver] = rate(lambda: project_glints(
                setup.camera, center, setup.eye.cornea_radius_m, lights, cornea_axis=axis,
                cap_cos_min=setup.eye.cap_cos_min, solver=solver), pairs, args.seconds)
        print(f"{poses:>7} {lights.shape[0]:>6} {rates['newton']:>14,.0f} {rates['quartic']:>15,.0f} "
              f"{rates['newton'] / rates['quartic']:>6.1f}")


if __name__ == "__main__":
    main()
