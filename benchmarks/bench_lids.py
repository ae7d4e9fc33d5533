"""Lids that follow the eye: their cost, and what lids and lashes do to detected glints.

Part 1 (cost): the same banded frames (a saccade, the upper lid blinking through them) with
the static lids of paper_sim and with paper_sim's moving lids and lashes (an ``[eyelids]``
table): seconds per frame, milliseconds per pose update (:meth:`EyeScene.set_pose`), and the
occlusion labels' milliseconds per frame (:class:`scet_render.render.LidOccluder`).

Part 2 (cut glints): frames of fixations along the screen's bottom row (down-gaze lowers the
upper lid and its lashes into the lights' paths) and through a blink, rendered with the default
dielectric cornea, read out by the OV5647 model and fed to :func:`estimator.glints.detect_glints`.
Each detection is matched to the nearest labelled glint of its strobe (within 3 px) and sorted
by its label: clear (no path blocked), cut by a lash, cut by a lid (0 < blocked fraction < 1).
The same poses rendered without lids give each glint's unoccluded flux and spot shape. Printed:
per class the count, the centroid error against the closed form (px), the flux ratio to the
unoccluded glint, and the spot's elongation (sqrt of the eigenvalue ratio of its intensity-
weighted second moments), the flux against the mean of the two neighbouring lights' glints in
the same band (what a tracker that knows identities can compute), with what a flag on each
would catch. Usage:

    python benchmarks/bench_lids.py [--spp 16] [--frames 12] [--cost-spp 4] [--skip-cost]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

from estimator.glints import detect_glints
from estimator.scene import parse_scene
from scet_render.dataset import frame_labels
from scet_render.motion import Blinks, fixation_sequence, with_blinks
from scet_render.render import BandedRenderer, LidOccluder, SensorModel

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "paper_sim.toml"
LIDS = "\n[eyelids]\nlash_count = 40\n"
MATCH_PX = 3.0
SPOT_HALF_PX = 3


def _setups():
    text = SCENE.read_text()
    lidded = parse_scene(text + LIDS, "paper_sim+eyelids")
    return parse_scene(text, str(SCENE)), lidded


def cost(spp: int, frames: int) -> None:
    static, lidded = _setups()
    still = fixation_sequence(static.eye, static.screen.grid(3, 3)[[0, 8, 2, 6]], 0.1)
    period = static.sensor.frame_period_s
    blinking = with_blinks(still, Blinks([2 * period], [1.0]))
    for name, setup, traj in (("static lids", static, still),
                              ("moving lids + 40 lashes", lidded, still),
                              ("the same, blinking", lidded, blinking)):
        r = BandedRenderer(setup, spp=spp, seed=1)
        r.render_frame(traj, 1)  # warm-up: kernels, frozen functions
        wall = []
        for f in range(2, 2 + frames):
            t0 = time.perf_counter()
            r.render_frame(traj, f)
            wall.append(time.perf_counter() - t0)
        es = r.eye_scene
        t0 = time.perf_counter()
        for k in range(100):
            es.set_pose(0.01 * (k % 7), -0.01 * (k % 5), 0.01 * (k % 11))
        pose_ms = (time.perf_counter() - t0) * 10.0
        print(f"{name:26s} {np.median(wall):6.2f} s/frame (median of {frames}, {spp} spp), "
              f"set_pose {pose_ms:5.2f} ms")
        if setup.eyelids is not None:
            occ = LidOccluder(setup)
            t = np.linspace(2 * period, 3 * period, 16)
            yaw, pitch = traj.angles_at(t)
            occ.glints(yaw, pitch, traj.lid_closure_at(t))
            t0 = time.perf_counter()
            occ.glints(yaw, pitch, traj.lid_closure_at(t))
            print(f"{'':26s} occlusion of 16 strobes x 40 glints: "
                  f"{(time.perf_counter() - t0) * 1e3:.1f} ms")


def _spot(img, u, v):
    """(flux, elongation) of the spot around (u, v): background-subtracted window sums."""
    h = SPOT_HALF_PX
    x, y = int(round(u)), int(round(v))
    if not (h <= x < img.shape[1] - h and h <= y < img.shape[0] - h):
        return np.nan, np.nan
    win = img[y - h:y + h + 1, x - h:x + h + 1].astype(np.float64)
    border = np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])
    w = np.clip(win - np.median(border), 0.0, None)
    if w.sum() <= 0:
        return 0.0, np.nan
    yy, xx = np.mgrid[-h:h + 1, -h:h + 1]
    mx, my = (w * xx).sum() / w.sum(), (w * yy).sum() / w.sum()
    c = np.cov(np.stack([xx.ravel() - mx, yy.ravel() - my]), aweights=w.ravel(), bias=True)
    ev = np.linalg.eigvalsh(c)
    return float(w.sum()), float(np.sqrt(ev[1] / max(ev[0], 1e-12)))


def cut_glints(spp: int, frames: int) -> None:
    _, lidded = _setups()
    bare = dataclasses.replace(lidded, eyelids=None)
    screen = lidded.screen
    xs = np.linspace(screen.x_range_m[0] + 0.03, screen.x_range_m[1] - 0.03, 4)
    targets = np.stack([xs, np.full(4, screen.y_range_m[0] + 0.02), np.full(4, screen.z_m)], -1)
    period = lidded.sensor.frame_period_s
    hold = frames * period / 5
    traj = fixation_sequence(lidded.eye, targets, hold)
    blink_at = 4.0 * hold - 3 * period
    traj = with_blinks(traj, Blinks([blink_at], [1.0]))
    picked = [int(round(k * hold / period)) + 2 for k in range(4)]
    picked += [int(blink_at / period) + k for k in range(1, max(2, frames - 3))]
    sensor = SensorModel.from_sensor(lidded.sensor)
    r_lid = BandedRenderer(lidded, spp=spp, seed=2)
    r_bare = BandedRenderer(bare, spp=spp, seed=2, eyelid_openness=None)
    rows = []  # (class, error px, flux ratio, elongation, unoccluded elongation)
    for f in picked[:frames]:
        labels = frame_labels(lidded, traj, f)
        imgs = []
        for r in (r_lid, r_bare):
            rad = r.render_frame(traj, f).radiance
            imgs.append(sensor.apply(rad, np.random.SeedSequence([3, f])).astype(np.float64))
        det = detect_glints(imgs[0], lidded, f)
        by_strobe = {lab["strobe"]: lab for lab in labels}
        first = len(rows)
        for k in range(len(det)):
            lab = by_strobe.get(int(det.strobe_index[k]))
            if lab is None:
                continue
            g = np.array([p if p is not None else [np.nan, np.nan] for p in lab["glints_px"]])
            d = np.hypot(g[:, 0] - det.u_px[k], g[:, 1] - det.v_px[k])
            if not np.any(np.isfinite(d)) or np.nanmin(d) > MATCH_PX:
                continue
            i = int(np.nanargmin(d))
            frac, occ = lab["glints_blocked_fraction"][i], lab["glints_occluder"][i]
            cls = "clear" if frac == 0 else ("hidden" if frac >= 1 else f"cut by {occ}")
            flux, elong = _spot(imgs[0], *g[i])
            flux0, elong0 = _spot(imgs[1], *g[i])
            same = det.strobe_index == det.strobe_index[k]
            band = det.intensity[k] / np.median(det.intensity[same]) if same.sum() >= 5 else np.nan
            rows.append([cls, d[i], flux / flux0 if flux0 > 0 else np.nan, elong, elong0, band,
                         det.area_px[k], int(det.strobe_index[k]), i, det.intensity[k], np.nan])
        # The tracker-side expectation: the mean flux of the glints of the two neighbouring
        # lights on the arc, detected in the same band (identities known from the matcher).
        mine = rows[first:]
        flux_of = {(x[7], x[8]): x[9] for x in mine}
        for x in mine:
            nb = [flux_of.get((x[7], x[8] + s)) for s in (-1, 1)]
            nb = [v for v in nb if v is not None]
            if len(nb) == 2:
                x[10] = x[9] / np.mean(nb)
    print(f"\n{len(picked[:frames])} frames, {spp} spp, {len(rows)} detections matched")
    print(f"{'class':12s} {'n':>4s} {'err med':>8s} {'err p90':>8s} {'err max':>8s} "
          f"{'flux/unocc med':>15s} {'elong med':>10s} {'elong/unocc med':>16s} "
          f"{'flux/band med':>14s} {'area med':>9s}")
    for cls in ("clear", "cut by lash", "cut by lid", "hidden"):
        sel = [x for x in rows if x[0] == cls]
        if not sel:
            print(f"{cls:12s} {0:4d}")
            continue
        e = np.array([x[1] for x in sel])
        fr = np.array([x[2] for x in sel])
        el = np.array([x[3] for x in sel])
        el0 = np.array([x[4] for x in sel])
        print(f"{cls:12s} {len(sel):4d} {np.median(e):8.3f} {np.percentile(e, 90):8.3f} "
              f"{e.max():8.3f} {np.nanmedian(fr):15.2f} {np.nanmedian(el):10.2f} "
              f"{np.nanmedian(el / el0):16.2f} {np.nanmedian([x[5] for x in sel]):14.2f} "
              f"{np.median([x[6] for x in sel]):9.1f}")
    e = np.array([x[1] for x in rows])
    fr = np.array([x[2] for x in rows])
    cut = np.array([x[0].startswith("cut") for x in rows])
    clear = np.array([x[0] == "clear" for x in rows])
    band = np.array([x[5] for x in rows])
    neighbours = np.array([x[10] for x in rows])
    has = np.isfinite(neighbours)
    print(f"flux / mean of the two neighbouring lights' glints (same band): clear "
          f"{np.percentile(neighbours[clear & has], [5, 50, 95]).round(2).tolist()} (p5, p50, p95; "
          f"{int((clear & has).sum())} with both neighbours), cut "
          f"{np.percentile(neighbours[cut & has], [5, 50, 95]).round(2).tolist()} "
          f"({int((cut & has).sum())})")
    for thr in (0.6, 0.7, 0.8):
        flag = has & (neighbours < thr)
        print(f"flag flux/neighbours < {thr:.1f}: {int((flag & cut).sum())} of "
              f"{int((cut & has).sum())} cut, {int((flag & clear).sum())} of "
              f"{int((clear & has).sum())} clear; unflagged cut glints: max error "
              f"{e[~flag & cut & has].max() if (~flag & cut & has).any() else np.nan:.2f} px")
    for thr in (0.5, 0.7, 0.8, 0.9):
        flag = band < thr
        print(f"flag flux/band median < {thr:.1f}: {int((flag & cut).sum())} of {int(cut.sum())} "
              f"cut, {int((flag & clear).sum())} of {int(clear.sum())} clear")
    for thr in (0.5, 0.7, 0.8, 0.9):
        flag = fr < thr
        print(f"flag flux/unoccluded < {thr:.1f}: {int((flag & cut).sum())} of {int(cut.sum())}"
              f" cut glints (their median error {np.median(e[flag & cut]) if (flag & cut).any() else np.nan:.2f} px), "
              f"{int((flag & clear).sum())} of {int(clear.sum())} clear ones; unflagged cut glints: "
              f"max error {e[~flag & cut].max() if (~flag & cut).any() else np.nan:.2f} px")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--cost-spp", type=int, default=4)
    ap.add_argument("--cost-frames", type=int, default=3)
    ap.add_argument("--skip-cost", action="store_true")
    args = ap.parse_args(argv)
    if not args.skip_cost:
        cost(args.cost_spp, args.cost_frames)
    cut_glints(args.spp, args.frames)


if __name__ == "__main__":
    main()
