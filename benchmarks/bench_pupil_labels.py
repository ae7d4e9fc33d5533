"""Pupil labels and segmentation masks on rendered frames: an outside detector's error, and
what masks and pupil-size changes cost.

Renders one frame at each of ``--poses`` gaze targets (a grid over the screen, fixations) of a
scene at ``--scale`` of its resolution, with the default renderer (dielectric cornea, MNEE),
applies the scene's sensor model, and runs an OpenCV dark-pupil detector
(``tests/scet_render/pupil_detector.py``: threshold, contours, ``cv2.fitEllipse``) on the
sensor counts. It prints, per frame and as a distribution, the detector's centre minus the
label ellipse's centre (``pupil_ellipse_px``), minus the refracted centre
(``pupil_center_px``), and its axes over the label's; then the seconds a frame's render and its
mask take (after a warm-up frame), and one frame re-rendered with another pupil size (the
band kernels replay: no recompile).

Usage::

    python benchmarks/bench_pupil_labels.py [--scene paper_sim] [--scale 2] [--spp 16]
        [--poses 9]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from estimator.geometry import Camera  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from scet_render.dataset import frame_labels  # noqa: E402
from scet_render.motion import (  # noqa: E402
    PupilModel,
    PupilTrace,
    fixation_sequence,
    with_pupil,
)
from scet_render.render import BandedRenderer, SensorModel, frame_mask  # noqa: E402
from tests.scet_render.pupil_detector import detect_pupil  # noqa: E402

FRAME = 3


def scaled(setup, scale: int):
    cam = setup.camera
    if setup.sensor.total_lines % scale or cam.height_px % scale:
        raise SystemExit(f"--scale {scale} must divide the sensor's lines and the image height")
    camera = Camera(cam.position_m, cam.rotation, cam.fx_px / scale, cam.fy_px / scale,
                    (cam.cx_px + 0.5) / scale - 0.5, (cam.cy_px + 0.5) / scale - 0.5,
                    cam.width_px // scale, cam.height_px // scale)
    sensor = dataclasses.replace(setup.sensor, total_lines=setup.sensor.total_lines // scale,
                                 visible_lines=cam.height_px // scale)
    return dataclasses.replace(setup, camera=camera, sensor=sensor)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="paper_sim")
    ap.add_argument("--scale", type=int, default=2)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--poses", type=int, default=9, help="a square number: the target grid")
    args = ap.parse_args(argv)
    setup = scaled(load_scene(args.scene), args.scale)
    side = int(round(np.sqrt(args.poses)))
    targets = setup.screen.grid(side, side)
    renderer = BandedRenderer(setup, spp=args.spp, seed=29)
    sensor = SensorModel.from_sensor(setup.sensor)
    rows, t_render, t_mask = [], [], []
    print(f"{args.scene} at {setup.camera.width_px}x{setup.camera.height_px}, {args.spp} spp")
    print("| target | found | du, dv to ellipse (px) | to refracted centre (px) | axes / label |")
    print("|---:|:---:|---:|---:|---:|")
    for k, target in enumerate(targets):
        traj = fixation_sequence(setup.eye, target[None, :], [1.0])
        t0 = time.perf_counter()
        out = renderer.render_frame(traj, FRAME)
        t1 = time.perf_counter()
        labels = frame_labels(setup, traj, FRAME)
        t2 = time.perf_counter()
        frame_mask(renderer, traj, FRAME, labels)
        t3 = time.perf_counter()
        if k > 0:  # the first frame records the kernels
            t_render.append(t1 - t0)
            t_mask.append(t3 - t2)
        counts = sensor.apply(out.radiance, np.random.SeedSequence([29, k]))
        found = detect_pupil(counts, setup.sensor.black_level_dn)
        ell = np.array([lb["pupil_ellipse_px"] for lb in labels
                        if lb["pupil_ellipse_px"] is not None])
        cen = np.array([lb["pupil_center_px"] for lb in labels
                        if lb["pupil_center_px"] is not None])
        if found is None or not len(ell):
            print(f"| {k} | {'no' if found is None else 'yes'} | (pupil edge not all seen) | | |")
            continue
        e, c = ell.mean(axis=0), cen.mean(axis=0)
        d_e, d_c = found[:2] - e[:2], found[:2] - c
        rows.append(np.r_[d_e, d_c, found[2:4] / e[2:4]])
        print(f"| {k} | yes | {d_e[0]:+.2f}, {d_e[1]:+.2f} | {d_c[0]:+.2f}, {d_c[1]:+.2f} | "
              f"{found[2] / e[2]:.3f}, {found[3] / e[3]:.3f} |")
    if rows:
        r = np.array(rows)
        n_e, n_c = np.hypot(r[:, 0], r[:, 1]), np.hypot(r[:, 2], r[:, 3])
        print(f"\ndetector - label ellipse centre: median {np.median(n_e):.2f} px, max "
              f"{n_e.max():.2f} px over {len(r)} frames")
        print(f"detector - refracted centre:    median {np.median(n_c):.2f} px, max "
              f"{n_c.max():.2f} px (the ellipse's centre is not the centre's image)")
        print(f"axes over the label's: {r[:, 4:].min():.3f} - {r[:, 4:].max():.3f}")
    if t_render:
        ratio = np.array(t_mask) / np.array(t_render)
        print(f"\nrender {min(t_render):.2f}-{max(t_render):.2f} s a frame, mask "
              f"{min(t_mask):.2f}-{max(t_mask):.2f} s: mask / render {ratio.min():.3f}-"
              f"{ratio.max():.3f} (median {np.median(ratio):.3f})")
    kernels = set(renderer._kernels)
    traj = with_pupil(fixation_sequence(setup.eye, targets[:1], [1.0]),
                      PupilTrace(3e-3, [], [], [], [], [], PupilModel(hippus_rms_mm=0.0)))
    t0 = time.perf_counter()
    renderer.render_frame(traj, FRAME)
    print(f"a 3 mm pupil: {time.perf_counter() - t0:.2f} s, kernels recorded anew: "
          f"{len(set(renderer._kernels) - kernels)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
