"""The cornea materials side by side: glint centroids, cost, bias (issue 14, part A).

Materials: ``plain_dielectric`` (Mitsuba's own), ``dielectric`` (the default: the
:mod:`scet_render.render.cornea_bsdf` plugin, reflection sampled with p = 0.75 from outside),
``conductor`` (a mirror with the dielectric's Fresnel). One run prints three tables:

1. glint centroid error against the closed form (``ground_truth_glints``, i.e.
   ``project_glints``) at the scene's full size, ``--spp`` samples, strobe light only, over
   several eye poses (isolated visible glints; intensity-weighted centroid in a 9x9 window);
2. render cost of a whole frame, new vs plain dielectric, alternated, ``--repeats`` times each;
3. bias: region means (iris, pupil, sclera, skin; pixels classified by casting each pixel
   centre's ray, refracted once at the cornea) and glint energies of the new material at
   ``--spp`` against Mitsuba's dielectric at ``--ref-spp``, each over ``--seeds`` seeds, with the
   standard error of the difference (seed scatter).

Path depth (``max_depth``) and its bias per region: ``benchmarks/bench_depth.py``.

Usage::

    python benchmarks/bench_cornea.py [--scene paper_sim] [--spp 16] [--ref-spp 256]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

# The renderer tests' glint measurement (tests/scet_render/centroids.py).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from estimator.scene import load_scene  # noqa: E402
from scet_render.render import BandedRenderer  # noqa: E402
from scet_render.render.regions import REGIONS, region_labels  # noqa: E402
from scet_render.simulate import ground_truth_glints  # noqa: E402
from tests.scet_render.centroids import glint_centroids  # noqa: E402

POSES = [(0.0, 0.0), (0.2, -0.12), (-0.15, 0.1), (0.1, 0.15)]
HALF_PX = 4
MIN_SPACING_PX = 7.0


def centroids(img, pred_px, all_px):
    """Centroids and energies of the glints predicted at ``pred_px``
    (:func:`tests.scet_render.centroids.glint_centroids`, the renderer tests' measurement)."""
    return glint_centroids(img, pred_px, all_px, HALF_PX)


def isolated(g, vis):
    gg = np.where(vis[:, None], g, np.inf)
    d = np.linalg.norm(gg[:, None] - gg[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return vis & (d.min(axis=1) > MIN_SPACING_PX)


def glint_errors(renderer, setup, seed):
    errs, energies = [], []
    for yaw, pitch in POSES:
        g, vis, _ = ground_truth_glints(setup, yaw, pitch)
        ok = isolated(g, vis)
        strobe, _ = renderer.render_rows(yaw, pitch, seed=seed)
        c, e = centroids(strobe, g[ok], g[vis])
        errs.append(np.linalg.norm(c - g[ok], axis=1))
        energies.append(e)
    return np.concatenate(errs), np.concatenate(energies)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="paper_sim")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    setup = load_scene(args.scene)
    r = {c: BandedRenderer(setup, spp=args.spp, cornea=c, seed=1)
         for c in ("plain_dielectric", "dielectric", "conductor")}
    print(f"# cornea materials, {args.scene} {setup.camera.width_px}x{setup.camera.height_px}, "
          f"{args.spp} spp, variant {r['dielectric'].variant}\n")
    print("| material | glints | median error (px) | max error (px) |")
    print("|---|---:|---:|---:|")
    for name, rend in r.items():
        e, _ = glint_errors(rend, setup, seed=5)
        e = e[np.isfinite(e)]
        print(f"| {name} | {e.size} | {np.median(e):.3f} | {e.max():.3f} |")

    for rend in (r["plain_dielectric"], r["dielectric"]):
        rend.render_rows(0.0, 0.0, seed=0)  # warm: kernels compiled
    times = {"plain_dielectric": [], "dielectric": []}
    for k in range(args.repeats):
        for name in times:
            t = time.perf_counter()
            r[name].render_rows(0.05 * k, 0.0, seed=10 + k)
            times[name].append(time.perf_counter() - t)
    med = {k: float(np.median(v)) for k, v in times.items()}
    print(f"\nwhole frame, median of {args.repeats} alternated: plain dielectric "
          f"{med['plain_dielectric']:.2f} s, new {med['dielectric']:.2f} s, ratio "
          f"{med['dielectric'] / med['plain_dielectric']:.3f}")

    yaw, pitch = POSES[1]
    labels = region_labels(r["dielectric"], yaw, pitch)
    g, vis, _ = ground_truth_glints(setup, yaw, pitch)
    ok = isolated(g, vis)

    def stats(rend, spp):
        means, energies = [], []
        for s in range(args.seeds):
            strobe, amb = rend.render_rows(yaw, pitch, spp=spp, seed=100 + s)
            means.append([[img[labels == k].mean() for k in range(len(REGIONS))]
                          for img in (strobe, amb)])
            energies.append(centroids(strobe, g[ok], g[vis])[1])
        m, e = np.array(means), np.array(energies)
        n = args.seeds
        return m.mean(0), m.std(0, ddof=1) / np.sqrt(n), e.mean(0), e.std(0, ddof=1) / np.sqrt(n)

    t = time.perf_counter()
    new = stats(r["dielectric"], args.spp)
    ref = stats(r["plain_dielectric"], args.ref_spp)
    print(f"\nbias at pose {POSES[1]} rad: new at {args.spp} spp vs Mitsuba's dielectric at "
          f"{args.ref_spp} spp, {args.seeds} seeds each ({time.perf_counter() - t:.0f} s)\n")
    print("| region | channel | pixels | new | reference | difference / sigma |")
    print("|---|---|---:|---:|---:|---:|")
    for k, name in enumerate(REGIONS):
        for c, ch in enumerate(("strobe", "ambient")):
            a, b = new[0][c, k], ref[0][c, k]
            s = np.hypot(new[1][c, k], ref[1][c, k])
            z = (a - b) / s if s > 0 else 0.0
            print(f"| {name} | {ch} | {(labels == k).sum()} | {a:.5g} | {b:.5g} | {z:+.2f} |")
    ea, eb = new[2], ref[2]
    z = (ea - eb) / np.hypot(new[3], ref[3])
    tot = np.nansum(ea) / np.nansum(eb)
    tot_se = tot * np.hypot(np.sqrt(np.nansum(new[3] ** 2)) / np.nansum(ea),
                            np.sqrt(np.nansum(ref[3] ** 2)) / np.nansum(eb))
    print(f"\nglint energies ({ea.size} glints): total new / reference = {tot:.4f} +- "
          f"{tot_se:.4f}, per glint median ratio {np.nanmedian(ea / eb):.4f}, "
          f"|difference| / sigma median "
          f"{np.nanmedian(np.abs(z)):.2f}, max {np.nanmax(np.abs(z)):.2f}")


if __name__ == "__main__":
    main()
