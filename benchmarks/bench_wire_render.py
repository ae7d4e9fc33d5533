"""Rendered glints of the wire-wound mirror against the two-bounce labels, per spp (issue 35,
part 2): the camera -> cornea -> wire -> LED chain is all specular up to a finite emitter, so
plain path tracing renders it; this shows how its glint centroids converge.

The scene's wire group with a larger LED (``--led-mm``, default 2: the glint of a 0.5 mm LED
through a 0.8 mm wire is a line ~0.01 px wide that ~1 % of a pixel's paths hit), strobe light
only, conductor cornea, only the rows that hold glints, through the per-band frozen renderer
(``BandedRenderer.render_rows``, ``llvm_ad_rgb``). Labels: the solver's glints averaged over the
LED's disk (``estimator.geometry.wire.led_disk_glints``); the table also gives their offset from
the LED centre's glints. Centroids: the renderer tests' 9x9 window
(``tests/scet_render/centroids.py``).

Usage::

    python benchmarks/bench_wire_render.py [--scene prototype_ov5647_wire] [--spp 64,256,1024]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from estimator.geometry.wire import eye_wire_glints, led_disk_glints, setup_wire_mirrors  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from estimator.setup import LightGroup, Setup  # noqa: E402
from scet_render.render import BandedRenderer  # noqa: E402
from tests.scet_render.centroids import glint_centroids  # noqa: E402

#: The rendered LED's diameter (m) in :func:`render_convergence`: the glint of the scene's
#: 0.5 mm LED through a 0.8 mm wire is a line ~0.01 px wide, hit by ~1 % of a pixel's paths; at
#: 2 mm (a 5 mm lensed LED's apparent emitter) 1024 spp reach the labels.
RENDER_LED_M = 2e-3
#: The rendered pose (Fick yaw, pitch in rad): 22 turns visible, glints 3-7 px apart.
RENDER_POSE = (-0.10, 0.05)


def render_convergence(setup: Setup, spps=(64, 256, 1024), *, led_m: float = RENDER_LED_M,
                       pose=RENDER_POSE, seed: int = 2) -> dict:
    """Rendered glint centroids against the labels, per spp: the scene with an LED of
    ``led_m``, strobe light only, conductor cornea (exact glints), only the rows of the glints,
    through the per-band frozen renderer (:meth:`BandedRenderer.render_rows`). The labels are
    the solver's glints averaged over the LED's disk (:func:`led_disk_glints`).

    Returns
    -------
    dict
        ``errors_px`` {spp: (k,) float}, ``seconds`` {spp: float}, ``centre_shift_px`` (k,)
        the disk labels' offset from the LED centre's glints, ``rows`` (start, stop).
    """
    ((gi, _, _),) = setup_wire_mirrors(setup)
    groups = list(setup.lights.groups)
    g0 = groups[gi]
    groups[gi] = LightGroup(g0.name, g0.kind, g0.points_local_m, g0.pose, g0.source_radius_m,
                            replace(g0.emitter, led_diameter_m=float(led_m)))
    s = replace(setup, lights=replace(setup.lights, groups=tuple(groups)))
    ((_, _, mirror),) = setup_wire_mirrors(s)
    yaw, pitch = pose
    g = eye_wire_glints(s.eye, s.camera, mirror, yaw, pitch)
    disk, _ = led_disk_glints(s.eye, s.camera, mirror, yaw, pitch)
    vis = g.visible & np.isfinite(disk).all(-1)
    labels = disk[vis]
    rows = (max(int(labels[:, 1].min()) - 6, 0), min(int(labels[:, 1].max()) + 7, s.camera.height_px))
    r = BandedRenderer(s, spp=16, cornea="conductor", ambient=0.0, seed=1)
    errors, seconds = {}, {}
    for spp in spps:
        t0 = time.perf_counter()
        strobe, _ = r.render_rows(yaw, pitch, row_start=rows[0], row_stop=rows[1], seed=seed, spp=int(spp))
        seconds[spp] = time.perf_counter() - t0
        img = np.zeros((s.camera.height_px, s.camera.width_px), np.float32)
        img[rows[0]:rows[1]] = strobe
        c, _ = glint_centroids(img, labels, labels)
        errors[spp] = np.linalg.norm(c - labels, axis=-1)
    return {"errors_px": errors, "seconds": seconds, "rows": rows, "led_m": float(led_m),
            "centre_shift_px": np.linalg.norm(labels - g.glints_px[vis], axis=-1)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="prototype_ov5647_wire")
    ap.add_argument("--spp", default="64,256,1024")
    ap.add_argument("--led-mm", type=float, default=RENDER_LED_M * 1e3)
    args = ap.parse_args(argv)
    spps = [int(x) for x in args.spp.split(",")]
    r = render_convergence(load_scene(args.scene), spps, led_m=args.led_mm * 1e-3)
    shift = r["centre_shift_px"]
    print(f"LED {args.led_mm:g} mm, rows {r['rows'][0]}-{r['rows'][1]}, {shift.size} glints; disk labels "
          f"{np.median(shift):.3f} px median, {shift.max():.3f} px max from the centre's glints")
    print("  spp   median px   max px   found   seconds")
    for spp in spps:
        e = r["errors_px"][spp]
        ok = np.isfinite(e)
        print(f"{spp:5d}   {np.median(e[ok]):9.3f}   {e[ok].max():6.3f}   {ok.sum():5d}   {r['seconds'][spp]:7.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
