"""Dataset rendering on 1 and 2 Ray workers on this machine, in one run: seconds per frame
(from the frames' completion times, Ray's start and the actors' warm-up left out) and their
ratio, plus the whole run's wall time; and that both datasets are byte-identical.

    python benchmarks/bench_cluster.py [--frames 10] [--spp 16] [--size 320x240]
"""

from __future__ import annotations

import argparse
import hashlib
import platform
import tempfile
import time
from pathlib import Path

from estimator.banding import scaled_setup
from estimator.scene import load_scene
from scet_render.dataset.distributed import render_dataset_ray


def digest(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")):
        if p.is_file():
            h.update(str(p.relative_to(root)).encode() + p.read_bytes())
    return h.hexdigest()


def run(setup, out: Path, workers: int, frames: int, spp: int) -> dict:
    stamps = []
    t0 = time.perf_counter()
    render_dataset_ray(setup, out, workers=workers, frames=frames, spp=spp,
                       trajectory="saccades", seed=1,
                       progress=lambda done, total: stamps.append(time.perf_counter()))
    wall = time.perf_counter() - t0
    # stamps[0]: before any frame; stamps[1]: the first frame done (actors warm from then on).
    steady = (stamps[-1] - stamps[1]) / max(1, frames - 1)
    return {"wall_s": wall, "s_per_frame": steady, "digest": digest(out)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--scale", type=int, default=2, help="1/scale of paper_sim's 640x480")
    args = ap.parse_args()
    setup = scaled_setup(load_scene("paper_sim"), args.scale)
    print(f"# {platform.machine()}, paper_sim at {setup.camera.width_px}x{setup.camera.height_px}, "
          f"{args.spp} spp, {args.frames} frames, dielectric cornea, saccades")
    with tempfile.TemporaryDirectory() as tmp:
        res = {w: run(setup, Path(tmp) / f"w{w}", w, args.frames, args.spp) for w in (1, 2)}
    for w, r in res.items():
        print(f"  {w} worker(s): {r['s_per_frame']:.3f} s/frame steady, {r['wall_s']:.1f} s wall "
              f"(Ray start and actor warm-up included)")
    print(f"  2 workers / 1 worker: {res[1]['s_per_frame'] / res[2]['s_per_frame']:.2f}x frames/s; "
          f"datasets byte-identical: {res[1]['digest'] == res[2]['digest']}")


if __name__ == "__main__":
    main()
