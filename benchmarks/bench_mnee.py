"""Strobe light through the cornea (MNEE): what it costs a frame and what it does to the eye.

Renders one pose of a scene with ``strobe_through_cornea`` = ``none`` (the renders before MNEE:
the path tracer carries no strobe light through the cornea) and ``mnee``, alternating the two
``--rounds`` times after a warm-up (kernels compiled), and prints the seconds per frame of
each and their ratio per round (the machine's speed swings: the ratio within a round is the
figure), the same in process CPU time (every thread's: steadier on a shared machine), and the
mean strobe radiance of the iris and pupil relative to the sclera
(:func:`scet_render.render.region_labels`) at the cornea's index and at ``--index-near-one``,
where a barely bending interface must light the iris about as a bare diffuse surface
(albedo ratio iris / sclera = 0.3 / 0.7 = 0.43, less the iris's lower irradiance).

Measured (paper_sim 640x480, 16 spp, 2-core machine shared by 8 agents, 2026-12-04; the iris
and pupil fill 64 % of this frame):

* one masked MNEE kernel on every lane, the solve in float64 (main before): ratio 1.76-1.84 on
  a free machine, 1.66-2.77 shared;
* the two frozen kernels with the iris lanes compacted between them and the float32 start
  (:mod:`scet_render.render.mnee_kernels`): runs of 5, 8 and 6 rounds, wall ratio median
  1.22 / 1.25 / 1.36 (0.59-2.91: the load swings within a round), CPU ratio median
  1.27 / 1.31 / 1.32 (1.11-1.51); none 4.0-4.5 s CPU a frame, MNEE's share 1.2-1.4 s CPU
  (front 0.3, compaction 0.05, back 1.0, of which the shadow ray and shading ~0.25). Region
  means unchanged: iris / sclera 0.438 and pupil / sclera 0.0286 (1.01: 0.503, 0.0320).

Usage::

    python benchmarks/bench_mnee.py [--scene paper_sim] [--spp 16] [--rounds 3]
        [--index-near-one 1.01] [--timing-only]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from estimator.scene import load_scene  # noqa: E402
from scet_render.render import BandedRenderer  # noqa: E402
from scet_render.render.layout import SceneOptions  # noqa: E402
from scet_render.render.regions import REGIONS, region_labels  # noqa: E402

POSE = (0.1, -0.05)


def _renderer(setup, mode, spp):
    return BandedRenderer(setup, spp=spp, ambient=0.0, seed=3,
                          options=SceneOptions(strobe_through_cornea=mode))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="paper_sim")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--index-near-one", type=float, default=1.01)
    ap.add_argument("--timing-only", action="store_true", help="skip the region means")
    args = ap.parse_args(argv)
    if args.spp < 1 or args.rounds < 1 or not args.index_near_one >= 1.0:
        raise SystemExit("error: --spp and --rounds must be >= 1, --index-near-one >= 1")
    setup = load_scene(args.scene)
    cam = setup.camera
    print(f"# MNEE, {args.scene} {cam.width_px}x{cam.height_px}, {args.spp} spp, pose {POSE} "
          "rad, strobe light only\n")
    rend = {m: _renderer(setup, m, args.spp) for m in ("none", "mnee")}
    for r in rend.values():
        r.render_rows(*POSE, seed=999)  # warm: kernels compiled
    wall, cpu = ({m: [] for m in rend} for _ in range(2))
    for k in range(args.rounds):
        for m, r in rend.items():
            t, c = time.perf_counter(), time.process_time()
            r.render_rows(POSE[0] + 0.01 * k, POSE[1], seed=100 + k)
            wall[m].append(time.perf_counter() - t)
            cpu[m].append(time.process_time() - c)
        print(f"  round {k}: none {wall['none'][-1]:.2f} s ({cpu['none'][-1]:.2f} s CPU), "
              f"mnee {wall['mnee'][-1]:.2f} s ({cpu['mnee'][-1]:.2f} s CPU), ratio "
              f"{wall['mnee'][-1] / wall['none'][-1]:.2f} ({cpu['mnee'][-1] / cpu['none'][-1]:.2f}"
              " CPU)", file=sys.stderr, flush=True)
    print("| strobe through the cornea | s / frame (min-max) | ratio to none, per round "
          "(min-median-max) | CPU s / frame | CPU ratio, per round |")
    print("|---|---:|---:|---:|---:|")
    for m in rend:
        cells = []
        for t in (wall, cpu):
            ratio = np.array(t[m]) / np.array(t["none"])
            cells += [f"{min(t[m]):.2f}-{max(t[m]):.2f}", "1" if m == "none" else
                      f"{ratio.min():.2f}-{np.median(ratio):.2f}-{ratio.max():.2f}"]
        print(f"| {m} | " + " | ".join(cells) + " |")
    if args.timing_only:
        return
    print("\n| cornea index | mode | iris / sclera | pupil / sclera | pupil / iris |")
    print("|---:|---|---:|---:|---:|")
    for n in (setup.eye.refractive_index, args.index_near_one):
        s = dataclasses.replace(setup, eye=dataclasses.replace(setup.eye, refractive_index=n))
        for m in ("none", "mnee"):
            r = _renderer(s, m, args.spp)
            labels = region_labels(r, *POSE)
            strobe, _ = r.render_rows(*POSE, seed=5)
            mean = {name: strobe[labels == i].mean() for i, name in enumerate(REGIONS)}
            print(f"| {n:g} | {m} | {mean['iris'] / mean['sclera']:.3f} | "
                  f"{mean['pupil'] / mean['sclera']:.4f} | {mean['pupil'] / mean['iris']:.3f} |")
    print("\nRegion means include the glints that fall on each region (both modes alike).")


if __name__ == "__main__":
    main()
