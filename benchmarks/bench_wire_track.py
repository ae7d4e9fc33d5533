"""Rendered wire-mirror glints for the tracker-accuracy table of ``scet study wire`` (issue 35,
part 3: the tracker on renders with (a) point sources, (b) the calibrated lighting pose, (c) the
virtual-source option).

Renders ``prototype_ov5647_wire`` (the bench's 2 mm LED, ``bench_wire_render.RENDER_LED_M``:
the scene's 0.5 mm LED gives glints a hundredth of a pixel wide that plain path tracing needs
thousands of spp to fill), strobe light only, conductor cornea, only the rows that hold glints
(``BandedRenderer.render_rows``), for the 5 x 5 calibration pattern and a handful of test
poses, and measures each visible turn's glint centroid in the renderer tests' window
(``tests/scet_render/centroids.py``, seeded at the solver's disk-averaged labels, so that the
identities are known and the detector's own open problems stay out of this table). Writes
``reports/wire_mirror_rendered.npz`` (versioned) for ``scet study wire``.

Usage::

    python benchmarks/bench_wire_track.py [--spp 256] [--test 8] [--out reports/wire_mirror_rendered.npz]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.bench_wire_render import RENDER_LED_M  # noqa: E402
from estimator.geometry.wire import eye_wire_glints, led_disk_glints, setup_wire_mirrors  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from estimator.setup import LightGroup  # noqa: E402
from scet_render.study.wire_track import RENDERED_FORMAT, RENDERED_VERSION  # noqa: E402
from scet_render.simulate import parse_targets  # noqa: E402
from tests.scet_render.centroids import glint_centroids  # noqa: E402


def big_led(setup, led_m):
    ((gi, _, _),) = setup_wire_mirrors(setup)
    groups = list(setup.lights.groups)
    g0 = groups[gi]
    groups[gi] = LightGroup(g0.name, g0.kind, g0.points_local_m, g0.pose, g0.source_radius_m,
                            replace(g0.emitter, led_diameter_m=float(led_m)))
    return replace(setup, lights=replace(setup.lights, groups=tuple(groups)))


def render_frames(setup, targets, *, spp: int, seed: int = 2, log=print):
    """(centroids (m, n, 2), disk labels (m, n, 2), seconds (m,)); NaN where a turn's glint is
    not visible or not measured."""
    from scet_render.render import BandedRenderer

    ((_, first, mirror),) = setup_wire_mirrors(setup)
    n = setup.lights.count
    r = BandedRenderer(setup, spp=16, cornea="conductor", ambient=0.0, seed=1)
    yaw, pitch = setup.eye.angles_toward(targets)
    cents = np.full((len(targets), n, 2), np.nan)
    labels = np.full_like(cents, np.nan)
    secs = np.zeros(len(targets))
    for i, (y, p) in enumerate(zip(yaw, pitch)):
        g = eye_wire_glints(setup.eye, setup.camera, mirror, y, p)
        disk, _ = led_disk_glints(setup.eye, setup.camera, mirror, y, p)
        vis = g.visible & np.isfinite(disk).all(-1)
        if not vis.any():
            continue
        lab = disk[vis]
        rows = (max(int(lab[:, 1].min()) - 6, 0), min(int(lab[:, 1].max()) + 7, setup.camera.height_px))
        t0 = time.perf_counter()
        strobe, _ = r.render_rows(float(y), float(p), row_start=rows[0], row_stop=rows[1],
                                  seed=seed + i, spp=int(spp))
        secs[i] = time.perf_counter() - t0
        img = np.zeros((setup.camera.height_px, setup.camera.width_px), np.float32)
        img[rows[0]:rows[1]] = strobe
        c, _ = glint_centroids(img, lab, lab)
        idx = first + np.flatnonzero(vis)
        cents[i, idx], labels[i, idx] = c, lab
        err = np.linalg.norm(c - lab, axis=-1)
        log(f"frame {i + 1}/{len(targets)}: {vis.sum()} glints, rows {rows[0]}-{rows[1]}, "
            f"{secs[i]:.1f} s, centroid - label median {np.nanmedian(err):.3f} px")
    return cents, labels, secs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="prototype_ov5647_wire")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--test", type=int, default=8, help="test poses (seeded, uniform over the screen)")
    ap.add_argument("--out", default="reports/wire_mirror_rendered.npz")
    args = ap.parse_args(argv)
    setup = big_led(load_scene(args.scene), RENDER_LED_M)
    cal_t = parse_targets("calib:5x5", setup)
    rng = np.random.default_rng(35)
    test_t = np.column_stack([rng.uniform(*setup.screen.x_range_m, args.test),
                              rng.uniform(*setup.screen.y_range_m, args.test),
                              np.full(args.test, setup.screen.z_m)])
    out = {"format": RENDERED_FORMAT, "version": RENDERED_VERSION, "scene": args.scene,
           "spp": args.spp, "led_m": RENDER_LED_M}
    for name, t in (("test", test_t), ("calibration", cal_t)):
        c, lab, s = render_frames(setup, t, spp=args.spp, seed=1000 if name == "test" else 2)
        out.update({f"{name}_targets_m": t, f"{name}_centroids_px": c, f"{name}_labels_px": lab,
                    f"{name}_seconds": s})
        np.savez(args.out, **out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
