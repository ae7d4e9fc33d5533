"""What the lit, textured iris does to glint detection: the validation's scene rendered twice
in one run, textures off and on, through the same detector and tracker.

Both runs render the same poses with the same seed: the scene (paper_sim by default) at half
resolution (320 x 240), the default dielectric cornea with strobe light through it (MNEE, so
the iris is lit), ``--spp`` samples, a 5 x 5 calibration and ``--frames`` test frames of
fixations at 16 pulses per frame, through :func:`scet_render.validate.validate_setup` (render,
calibrate, track). Then :func:`estimator.glints.detect_glints` is run on every test frame and
each detection is checked against the labelled glints of that frame's bands (every light's
ground-truth pixel where it is visible):

* clutter: detections farther than ``--radius-px`` from every labelled glint of the frame,
  per band (a band: one strobe sample), and what part of the eye they lie on
  (:func:`scet_render.render.region_labels` at the frame's first pulse pose);
* e_f: the RMS per-axis error (px) of the detections matched to a labelled glint;
* found: the share of the glints each band should show (visible, on the rows its whole pulse
  lights) with a detection within ``--radius-px``;
* valid: the tracker's share of valid samples (polynomial gaze) and its mean error.

Usage::

    python benchmarks/bench_appearance.py [--scene paper_sim] [--frames 20] [--spp 16]
        [--out /tmp/bench_appearance]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from estimator.banding import scaled_setup  # noqa: E402
from estimator.glints import DetectionParams, detect_glints  # noqa: E402
from estimator.scene import load_scene  # noqa: E402


def detection_figures(setup, test_dir: Path, radius_px: float, params=DetectionParams()):
    """Clutter, e_f and found share of one test dataset (module docstring)."""
    import cv2

    from scet_render.dataset import iter_labels

    by_frame = {}
    for lb in iter_labels(test_dir):
        by_frame.setdefault(lb.frame, []).append(lb)
    clutter, bands, err, found, wanted = [], 0, [], 0, 0
    for frame, labels in sorted(by_frame.items()):
        img = cv2.imread(str(test_dir / "frames" / f"{frame:06d}.png"), cv2.IMREAD_UNCHANGED)
        det = detect_glints(img, setup, frame, params)
        truth = np.concatenate([lb.glints_px[lb.glints_visible] for lb in labels])
        truth = truth[np.isfinite(truth).all(axis=1)]
        # The glints each band should show: visible, on the rows its whole pulse lights.
        in_band = []
        for lb in labels:
            g = lb.glints_px[lb.glints_visible]
            g = g[np.isfinite(g).all(axis=1)]
            in_band.append(g[(g[:, 1] >= lb.full_rows[0]) & (g[:, 1] < lb.full_rows[1] - 1)])
        in_band = np.concatenate(in_band)
        bands += len(labels)
        wanted += len(in_band)
        pts = det.glints_px
        if len(pts) and len(truth):
            d = np.linalg.norm(pts[:, None, :] - truth[None, :, :], axis=2)
            nearest = d.argmin(axis=1)
            hit = d[np.arange(len(pts)), nearest] <= radius_px
            err.append(pts[hit] - truth[nearest[hit]])
            clutter.extend((frame, *p) for p in pts[~hit])
            if len(in_band):
                near = np.linalg.norm(pts[:, None, :] - in_band[None, :, :], axis=2).min(axis=0)
                found += int((near <= radius_px).sum())
        else:
            clutter.extend((frame, *p) for p in pts)
    e = np.concatenate(err) if err else np.zeros((0, 2))
    return {"bands": bands, "clutter": clutter, "clutter_per_band": len(clutter) / max(bands, 1),
            "e_f_px": float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan"),
            "found": found / max(wanted, 1), "matched": len(e)}


def clutter_regions(setup, clutter, labels_by_key):
    """Where clutter lies: counts per region (iris, pupil, sclera, skin, other) of the render
    at the frame's first band's pose (lids static, as rendered)."""
    from scet_render.render import BandedRenderer
    from scet_render.render.regions import REGIONS, region_labels

    if not clutter:
        return {}
    r = BandedRenderer(setup, spp=1)
    counts, by_frame = {}, {}
    for frame, u, v in clutter:
        if frame not in by_frame:
            lb = min((lb for (f, _), lb in labels_by_key.items() if f == frame),
                     key=lambda lb: lb.strobe)
            by_frame[frame] = region_labels(r, lb.yaw_rad, lb.pitch_rad)
        k = by_frame[frame][int(round(v)), int(round(u))]
        name = REGIONS[k] if k >= 0 else "other"
        counts[name] = counts.get(name, 0) + 1
    return counts


def frame_cost(setup, spp: int, rounds: int) -> None:
    """Seconds per banded frame (the full-size setup, fixations, frame 1) with textures off and
    on, alternated ``rounds`` times after a warm-up frame each; the ratio per round."""
    from scet_render.dataset.writer import dataset_trajectory
    from scet_render.render import BandedRenderer

    traj = dataset_trajectory(setup, "fixations", 2, 0)
    r = {t: BandedRenderer(dataclasses.replace(setup, appearance=(("textured", t),)), spp=spp)
         for t in (False, True)}
    for t in r:
        r[t].render_frame(traj, 0)
    for k in range(rounds):
        sec = {}
        for t in r:
            t0 = time.perf_counter()
            r[t].render_frame(traj, 1)
            sec[t] = time.perf_counter() - t0
        print(f"cost round {k}: {setup.camera.width_px}x{setup.camera.height_px}, {spp} spp: "
              f"off {sec[False]:.2f} s, on {sec[True]:.2f} s a frame, on / off "
              f"{sec[True] / sec[False]:.3f}", flush=True)


def main(argv=None) -> int:
    from scet_render.validate import validate_setup
    from scet_render.validate.config import ValidationConfig

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="paper_sim")
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--radius-px", type=float, default=1.5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--calib-grid", type=int, default=5, help="n: an n x n calibration")
    p.add_argument("--out", type=Path, default=Path("/tmp/bench_appearance"))
    p.add_argument("--cost-rounds", type=int, default=0,
                   help="only time full-size frames, textures off and on, this many rounds")
    p.add_argument("--min-area-px", type=int, nargs="*", default=[1, 2],
                   help="detector min_area_px values to measure clutter, e_f, found with")
    args = p.parse_args(argv)
    full = load_scene(args.scene)
    if args.cost_rounds:
        frame_cost(full, args.spp, args.cost_rounds)
        return 0
    text = Path(full.source).read_text() if Path(full.source).is_file() else None
    setup = scaled_setup(full, 2)
    cfg = ValidationConfig(scale=2, spp=args.spp, cornea="dielectric", frames=args.frames,
                           calib_grid=(args.calib_grid,) * 2, pulses_per_frame=(16,))
    print(f"{args.scene} at {setup.camera.width_px}x{setup.camera.height_px}, {args.spp} spp, "
          f"dielectric cornea (MNEE), {args.frames} test frames at 16 pulses/frame, "
          f"{args.calib_grid}x{args.calib_grid} calibration, seed "
          f"{args.seed}; radius {args.radius_px} px")
    for textured in (False, True):
        s = dataclasses.replace(setup, appearance=(("textured", textured),))
        t = time.perf_counter()
        run = validate_setup(s, cfg, args.out / ("textured" if textured else "plain"),
                             seed=args.seed, scene_text=text)
        wall = time.perf_counter() - t
        sset, test_dir = run.settings[16]
        fig = detection_figures(sset, test_dir, args.radius_px)
        where = clutter_regions(sset, fig["clutter"], run.labels[16])
        for area in args.min_area_px:
            f = detection_figures(sset, test_dir, args.radius_px,
                                  DetectionParams(min_area_px=area))
            print(f"  textures {'on ' if textured else 'off'}, min_area_px {area}: clutter "
                  f"{len(f['clutter'])} ({f['clutter_per_band']:.3f} per band), e_f "
                  f"{f['e_f_px']:.4f} px ({f['matched']} glints), found "
                  f"{100 * f['found']:.1f} %", flush=True)
        rows = {(r.source, r.method): r for r in run.rows if r.pulses_per_frame == 16}
        poly = rows[("rendered", "polynomial")]
        geo = rows[("rendered", "geometric")]
        print(f"textures {'on ' if textured else 'off'}: bands {fig['bands']}, clutter "
              f"{len(fig['clutter'])} ({fig['clutter_per_band']:.3f} per band; {where}), "
              f"e_f {fig['e_f_px']:.3f} px over {fig['matched']} glints (tracker's e_f "
              f"{run.noise_px:.3f}), found {100 * fig['found']:.1f} % of visible "
              f"glints; valid {100 * poly.valid:.1f} %, polynomial {poly.mean_deg:.3f} deg, "
              f"geometric {geo.mean_deg:.3f} deg, identities right "
              f"{100 * poly.identity_rate:.2f} %; reasons {run.reasons[(16, 'polynomial')]}; "
              f"wall {wall:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
