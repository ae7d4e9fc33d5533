"""Glints per second per core on a conic (aspheric) cornea against the sphere's closed form:
40 lights x {1, 100, 10,000} poses.

Runs on one core (BLAS threads pinned to 1 before numpy loads) with the paper_sim scene and
prints, for each batch size, the throughput of :func:`estimator.geometry.project_glints_conic`
(Newton on the optical path, Q = -0.25) and of :func:`estimator.geometry.project_glints` (the
sphere), measured in the same run, and the Newton iterations the conic took. Usage:

    python benchmarks/bench_conic.py [--seconds 2] [--scene paper_sim] [--asphericity -0.25]
"""

from __future__ import annotations

import argparse
import os
import platform

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import numpy as np  # noqa: E402

from bench_projection import rate  # noqa: E402  (this folder is on sys.path when run)
from estimator.eye import gaze_direction  # noqa: E402
from estimator.geometry import project_glints, project_glints_conic  # noqa: E402
from estimator.scene import load_scene  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="time per measurement")
    ap.add_argument("--scene", default="paper_sim")
    ap.add_argument("--asphericity", type=float, default=-0.25, help="conic constant Q")
    args = ap.parse_args()
    setup = load_scene(args.scene)
    eye, lights = setup.eye, setup.lights_world_m
    rng = np.random.default_rng(1)
    print(f"# {platform.processor() or platform.machine()}, numpy {np.__version__}, one core, "
          f"scene {setup.name}, {lights.shape[0]} lights, Q = {args.asphericity:g}, best of "
          f"{args.seconds:g} s per row")
    print(f"{'poses':>7} {'lights':>6} {'conic glints/s':>15} {'sphere glints/s':>16} {'ratio':>6}")
    for poses in (1, 100, 10_000):
        yaw, pitch = rng.uniform(-0.33, 0.33, poses), rng.uniform(-0.28, 0.14, poses)
        axis = gaze_direction(yaw, pitch)
        center, apex = eye.cornea_center(yaw, pitch), eye.apex(yaw, pitch)
        pairs = poses * lights.shape[0]
        conic = rate(lambda: project_glints_conic(
            setup.camera, apex, axis, eye.cornea_radius_m, args.asphericity, lights,
            limbus_depth_m=eye.limbus_depth_m), pairs, args.seconds)
        sphere = rate(lambda: project_glints(
            setup.camera, center, eye.cornea_radius_m, lights, cornea_axis=axis,
            cap_cos_min=eye.cap_cos_min), pairs, args.seconds)
        print(f"{poses:>7} {lights.shape[0]:>6} {conic:>15,.0f} {sphere:>16,.0f} "
              f"{sphere / conic:>6.1f}")


if __name__ == "__main__":
    main()
