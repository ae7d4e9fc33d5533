"""Path depth: how far the region means of a render are from converged, and what depth costs.

The path tracer stops a path after ``max_depth`` vertices (``SceneOptions.max_depth``). Light
that reaches the iris and pupil through the refracting cornea takes more vertices than light
on the skin and sclera: it enters the cornea, is scattered by the iris, leaves the cornea
(or is reflected back inside it, totally past 46.6 deg), and only then meets the ambient or a
strobe light. A depth too small drops those paths, and the iris renders darker than it is.

For each depth of ``--depths`` and each cornea of ``--corneas`` this renders one pose of the
scene ``--seeds`` times and prints the mean radiance of each region (iris, pupil, sclera,
skin: :func:`scet_render.render.region_labels`) under the strobe lights and under the
ambient, relative to the deepest depth with the standard error of the difference (seed
scatter), and the whole-frame render time (median of the seeds, after a warm-up render, so
kernel compilation is left out) relative to ``--base-depth``.

Usage::

    python benchmarks/bench_depth.py [--scene paper_sim] [--spp 16] [--seeds 4]
        [--depths 4,6,8,12,16,64] [--corneas dielectric,conductor] [--base-depth 6]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.bench_cornea import POSES  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from scet_render.render import BandedRenderer  # noqa: E402
from scet_render.render.layout import SceneOptions  # noqa: E402
from scet_render.render.regions import REGIONS, region_labels  # noqa: E402


def _ints(text: str, name: str) -> list[int]:
    try:
        out = [int(v) for v in text.split(",")]
    except ValueError:
        raise SystemExit(f"error: --{name} must be comma-separated integers, got {text!r}")
    if not out or min(out) < 2:
        raise SystemExit(f"error: --{name} needs depths >= 2, got {text!r}")
    return out


def region_stats(renderer, labels, yaw, pitch, seeds):
    """Per seed: (2, regions) means (strobe, ambient) and the render time (s)."""
    means, times = [], []
    renderer.render_rows(yaw, pitch, seed=999)  # warm: kernels compiled
    for s in range(seeds):
        t = time.perf_counter()
        strobe, amb = renderer.render_rows(yaw, pitch, seed=100 + s)
        times.append(time.perf_counter() - t)
        means.append([[img[labels == k].mean() for k in range(len(REGIONS))]
                      for img in (strobe, amb)])
    return np.array(means), np.array(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="paper_sim")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--depths", default="4,6,8,12,16,64")
    ap.add_argument("--base-depth", type=int, default=6)
    ap.add_argument("--corneas", default="dielectric,conductor")
    args = ap.parse_args(argv)
    depths = _ints(args.depths, "depths")
    if args.base_depth not in depths:
        raise SystemExit(f"error: --base-depth {args.base_depth} is not among --depths")
    if args.seeds < 2 or args.spp < 1:
        raise SystemExit("error: --seeds must be >= 2 and --spp >= 1")
    corneas = args.corneas.split(",")
    setup = load_scene(args.scene)
    yaw, pitch = POSES[1]
    ref_depth = max(depths)
    cam = setup.camera
    print(f"# path depth, {args.scene} {cam.width_px}x{cam.height_px}, {args.spp} spp, "
          f"{args.seeds} seeds, pose {POSES[1]} rad; reference: max_depth {ref_depth}\n")
    for cornea in corneas:
        rend = {d: BandedRenderer(setup, spp=args.spp, cornea=cornea, seed=1,
                                  options=replace(SceneOptions(), cornea=cornea, max_depth=d))
                for d in depths}
        labels = region_labels(rend[depths[0]], yaw, pitch)
        stats = {}
        for d in depths:
            stats[d] = region_stats(rend[d], labels, yaw, pitch, args.seeds)
            print(f"  {cornea} max_depth {d}: {np.median(stats[d][1]):.2f} s a frame",
                  file=sys.stderr, flush=True)
        ref = stats[ref_depth][0]
        base_t = np.median(stats[args.base_depth][1])
        print(f"## {cornea} cornea\n")
        head = " | ".join(f"{name} {ch}" for name in REGIONS for ch in ("strobe", "ambient"))
        print(f"| max_depth | s / frame | cost vs {args.base_depth} | {head} |")
        print("|---:|---:|---:|" + "---:|" * (2 * len(REGIONS)))
        for d in depths:
            m, t = stats[d]
            cells = []
            for k in range(len(REGIONS)):
                for c in range(2):
                    a, b = m[:, c, k], ref[:, c, k]
                    if d == ref_depth:
                        cells.append(f"{a.mean():.4g}")
                        continue
                    se = np.hypot(a.std(ddof=1), b.std(ddof=1)) / np.sqrt(args.seeds)
                    rel = a.mean() / b.mean() - 1.0
                    cells.append(f"{100 * rel:+.1f} % ({(a.mean() - b.mean()) / se:+.1f} sd)"
                                 if se > 0 else f"{100 * rel:+.1f} %")
            tm = np.median(t)
            print(f"| {d} | {tm:.2f} | {tm / base_t:.2f}x | " + " | ".join(cells) + " |")
        print(f"\nThe row of max_depth {ref_depth} gives the mean radiance; the others its "
              "difference in percent and in standard errors of the difference.\n")


if __name__ == "__main__":
    main()
