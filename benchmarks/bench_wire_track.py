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

``--ideal`` renders the same poses, camera, spp and cornea with the wire turns replaced by
0.8 mm spherical sources at the point-source model's positions
(:func:`scet_render.study.wire_track.ideal_setup`), labelled by the point projection, and writes
``reports/wire_mirror_rendered_ideal.npz``: the point-source ideal the option's row is held
against.

Usage::

    python benchmarks/bench_wire_track.py [--spp 256] [--test 8] [--ideal] [--out PATH]
    python benchmarks/bench_wire_track.py --spp 512 [--ideal] --more-test 16   # append poses

``--more-test K`` appends K test poses to an existing file, drawn from a seed set by the poses
it already holds, so that the wire and ideal files stay paired pose by pose.
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
from scet_render.study.wire_track import RENDERED_FORMAT, RENDERED_VERSION, ideal_setup  # noqa: E402
from scet_render.simulate import parse_targets  # noqa: E402
from tests.scet_render.centroids import glint_centroids  # noqa: E402


def big_led(setup, led_m):
    ((gi, _, _),) = setup_wire_mirrors(setup)
    groups = list(setup.lights.groups)
    g0 = groups[gi]
    groups[gi] = LightGroup(g0.name, g0.kind, g0.points_local_m, g0.pose, g0.source_radius_m,
                            replace(g0.emitter, led_diameter_m=float(led_m)))
    return replace(setup, lights=replace(setup.lights, groups=tuple(groups)))


def wire_labels(setup):
    """labels(yaw, pitch) -> (visible (n,), glints (k, 2) of the visible, their light indices):
    the wire turns' glints averaged over the LED's disk."""
    ((_, first, mirror),) = setup_wire_mirrors(setup)

    def labels(y, p):
        g = eye_wire_glints(setup.eye, setup.camera, mirror, y, p)
        disk, _ = led_disk_glints(setup.eye, setup.camera, mirror, y, p)
        vis = g.visible & np.isfinite(disk).all(-1)
        return vis, disk[vis], first + np.flatnonzero(vis)
    return labels


def point_labels(setup):
    """labels(yaw, pitch) as :func:`wire_labels` for point lights (the closed-form projection)."""
    def labels(y, p):
        g, vis, _ = setup.eye.glints(setup.camera, setup.lights_world_m, y, p)
        return vis, g[vis], np.flatnonzero(vis)
    return labels


def render_frames(setup, targets, *, spp: int, seed: int = 2, labels=None, log=print):
    """(centroids (m, n, 2), labels (m, n, 2), seconds (m,)); NaN where a light's glint is
    not visible or not measured. ``labels``: :func:`wire_labels` (default) or
    :func:`point_labels` of ``setup``."""
    from scet_render.render import BandedRenderer

    label_fn = wire_labels(setup) if labels is None else labels
    n = setup.lights.count
    r = BandedRenderer(setup, spp=16, cornea="conductor", ambient=0.0, seed=1)
    yaw, pitch = setup.eye.angles_toward(targets)
    cents = np.full((len(targets), n, 2), np.nan)
    labels = np.full_like(cents, np.nan)
    secs = np.zeros(len(targets))
    for i, (y, p) in enumerate(zip(yaw, pitch)):
        vis, lab, idx = label_fn(float(y), float(p))
        if not vis.any():
            continue
        rows = (max(int(lab[:, 1].min()) - 6, 0), min(int(lab[:, 1].max()) + 7, setup.camera.height_px))
        t0 = time.perf_counter()
        strobe, _ = r.render_rows(float(y), float(p), row_start=rows[0], row_stop=rows[1],
                                  seed=seed + i, spp=int(spp))
        secs[i] = time.perf_counter() - t0
        img = np.zeros((setup.camera.height_px, setup.camera.width_px), np.float32)
        img[rows[0]:rows[1]] = strobe
        c, _ = glint_centroids(img, lab, lab)
        cents[i, idx], labels[i, idx] = c, lab
        err = np.linalg.norm(c - lab, axis=-1)
        log(f"frame {i + 1}/{len(targets)}: {vis.sum()} glints, rows {rows[0]}-{rows[1]}, "
            f"{secs[i]:.1f} s, centroid - label median {np.nanmedian(err):.3f} px")
    return cents, labels, secs


def append_test(setup, labels, path, count: int, spp: int) -> int:
    """Render ``count`` more test poses into the rendered-glints file ``path`` (same spp)."""
    with np.load(path, allow_pickle=False) as z:
        out = {k: z[k] for k in z.files}
    if int(out["spp"]) != spp:
        raise SystemExit(f"{path}: spp: the file holds {int(out['spp'])}, --spp is {spp}")
    have = len(out["test_targets_m"])
    rng = np.random.default_rng(35 + have)
    t = np.column_stack([rng.uniform(*setup.screen.x_range_m, count),
                         rng.uniform(*setup.screen.y_range_m, count), np.full(count, setup.screen.z_m)])
    c, lab, sec = render_frames(setup, t, spp=spp, seed=1000 + have, labels=labels)
    for k, v in (("targets_m", t), ("centroids_px", c), ("labels_px", lab), ("seconds", sec)):
        out[f"test_{k}"] = np.concatenate([out[f"test_{k}"], v])
    np.savez(path, **out)
    print(f"wrote {path}: {have} + {count} test poses")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="prototype_ov5647_wire")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--test", type=int, default=8, help="test poses (seeded, uniform over the screen)")
    ap.add_argument("--ideal", action="store_true",
                    help="the turns as 0.8 mm point-like spheres (the point-source ideal)")
    ap.add_argument("--more-test", type=int, default=0,
                    help="append this many test poses to the existing --out file (seeded by the "
                         "poses it holds, so wire and ideal files get the same ones)")
    ap.add_argument("--out", help="default reports/wire_mirror_rendered[_ideal].npz")
    args = ap.parse_args(argv)
    out_path = args.out or f"reports/wire_mirror_rendered{'_ideal' if args.ideal else ''}.npz"
    wire = big_led(load_scene(args.scene), RENDER_LED_M)
    setup = ideal_setup(wire) if args.ideal else wire
    labels = point_labels(setup) if args.ideal else wire_labels(setup)
    if args.more_test:
        return append_test(setup, labels, out_path, args.more_test, args.spp)
    cal_t = parse_targets("calib:5x5", setup)
    rng = np.random.default_rng(35)
    test_t = np.column_stack([rng.uniform(*setup.screen.x_range_m, args.test),
                              rng.uniform(*setup.screen.y_range_m, args.test),
                              np.full(args.test, setup.screen.z_m)])
    out = {"format": RENDERED_FORMAT, "version": RENDERED_VERSION, "scene": args.scene,
           "spp": args.spp, "led_m": RENDER_LED_M, "sources": "ideal" if args.ideal else "wire"}
    for name, t in (("test", test_t), ("calibration", cal_t)):
        c, lab, s = render_frames(setup, t, spp=args.spp, seed=1000 if name == "test" else 2,
                                  labels=labels)
        out.update({f"{name}_targets_m": t, f"{name}_centroids_px": c, f"{name}_labels_px": lab,
                    f"{name}_seconds": s})
        np.savez(out_path, **out)
    print(f"wrote {out_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
