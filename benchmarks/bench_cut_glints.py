"""The cut-glint flag (``Tracker(flag_cut_glints=True)``, :mod:`estimator.tracking.cut_glints`) against
the renderer's labels: recall and precision on lash-cut glints, the expected-flux model's spread
against each light's median flux alone, and the accuracy with the flag and without on the same
frames.

Renders (once; a folder is reused) paper_sim at 320 x 240 with 40 lashes (the moving lids of
``scet study aspheric``, :func:`scet_render.study.aspheric.moving_lid_scene`) or without
(``--no-lashes``: the static lids): 5 x 5 calibration frames and ``--frames`` banded frames of
saccades, calibrates (:func:`estimator.folders.calibrate_from_folder`, which fits
``glint_flux``), tracks with geometric gaze both ways and scores every checked glint by its
label (clear: blocked fraction 0; lash-cut: a lash blocks 0-1 of it). Usage:

    python benchmarks/bench_cut_glints.py --out DIR [--spp 16] [--cornea dielectric]
                                          [--frames 48] [--no-lashes] [--residual-flag K]

Numbers measured with it are in docs/guide/rendering.md, "Glints cut by a lash".
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's packages

import numpy as np  # noqa: E402

import estimator.tracking.cut_glints as cut_glints  # noqa: E402
import estimator.tracking.tracker as tracker_module  # noqa: E402
from estimator.banding import scaled_setup  # noqa: E402
from estimator.folders import (calibrate_from_folder, calibration_glints, iter_folder,  # noqa: E402
                               load_calibration, save_calibration)
from estimator.metrics import angular_error_deg  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from estimator.tracking import Tracker  # noqa: E402
from scet_render.dataset import iter_labels, render_calibration, render_dataset  # noqa: E402
from scet_render.study.aspheric import moving_lid_scene  # noqa: E402
from scet_render.validate.score import true_gaze_points  # noqa: E402


def robust_sd(x) -> float:
    x = np.asarray(x)[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def prepare(out: Path, spp: int, cornea: str, frames: int, lashes: bool):
    base = load_scene("paper_sim")
    text = Path(base.source).read_text()
    if lashes:
        base, text = moving_lid_scene(base, text)
    setup = scaled_setup(base, 2)
    if not (out / "calibration.json").exists():
        render_calibration(setup, out / "calibration", spp=spp, cornea=cornea, seed=0)
        render_dataset(setup, out / "test", frames=frames, spp=spp, trajectory="saccades",
                       seed=0, cornea=cornea, scene_text=text)
        save_calibration(calibrate_from_folder(out / "calibration", setup), out / "calibration.json")
    return setup, load_calibration(out / "calibration.json")


def reference_spread(setup, out: Path, cal) -> tuple[float, float]:
    """Log-SD over the calibration glints of each light's median flux alone, and the model's."""
    _, cg = calibration_glints(out / "calibration", setup)
    lr = np.log(cg.flux) - np.nanmedian(np.log(cg.flux), axis=0)
    return robust_sd(lr.ravel()), cal.glint_flux.log_sd


def track(setup, cal, frames, flag: bool, checked: list):
    """Samples of the frames; with the flag, each checked glint's (frame, strobe, light, flagged)
    appended to ``checked``."""
    orig = tracker_module.flagged

    def spy(calibration, camera, lights, sample, g, flux, arrays=None):
        bad = orig(calibration, camera, lights, sample, g, flux, arrays)
        checked.extend((sample.frame_index, sample.strobe_index, int(i), bool(b))
                       for i, b in zip(sample.light_index, bad))
        return bad

    tracker_module.flagged = spy
    try:
        tr = Tracker(setup, cal, "geometric", flag_cut_glints=flag)
        return [s for f, t0, img in frames for s in tr.process(img, f, t0)]
    finally:
        tracker_module.flagged = orig


def errors(setup, samples, labels) -> np.ndarray:
    truth = true_gaze_points(setup, [labels[(s.frame_index, s.strobe_index)] for s in samples])
    est = np.array([[*s.screen_xy_m, setup.screen.z_m] for s in samples])
    return angular_error_deg(est, truth, setup.eye.rotation_center_m)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="work folder (reused)")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--cornea", default="dielectric", choices=("dielectric", "conductor"))
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--no-lashes", action="store_true")
    ap.add_argument("--residual-flag", type=float, default=cut_glints.RESIDUAL_FLAG,
                    help="the displacement a flagged glint needs, in calibration glint RMS "
                         f"(default {cut_glints.RESIDUAL_FLAG:g}: estimator.tracking.cut_glints)")
    args = ap.parse_args(argv)
    if not (np.isfinite(args.residual_flag) and args.residual_flag >= 0):
        raise SystemExit(f"--residual-flag: a number >= 0 expected, got {args.residual_flag}")
    cut_glints.RESIDUAL_FLAG = args.residual_flag
    setup, cal = prepare(args.out, args.spp, args.cornea, args.frames, not args.no_lashes)
    ref, model = reference_spread(setup, args.out, cal)
    print(f"{args.spp} spp, {args.cornea}, {'no lashes' if args.no_lashes else '40 lashes'}: "
          f"flux log-SD over the calibration glints: model {model:.3f} "
          f"(fresnel {cal.glint_flux.fresnel}), each light's median alone {ref:.3f}; "
          f"glint RMS {cal.glint_flux.noise_px:.3f} px")
    frames = [(f, t0, img) for f, t0, img, err in iter_folder(args.out / "test", setup)
              if err is None]
    labels = {(lb.frame, lb.strobe): lb for lb in iter_labels(args.out / "test")}
    checked = []
    off, on = track(setup, cal, frames, False, []), track(setup, cal, frames, True, checked)
    counts = {"clear": [0, 0], "lash": [0, 0], "other": [0, 0]}
    for f, j, i, bad in checked:
        lab = labels[(f, j)]
        frac = 0.0 if lab.glints_blocked_fraction is None else lab.glints_blocked_fraction[i]
        occ = "none" if lab.glints_occluder is None else lab.glints_occluder[i]
        cls = "clear" if frac == 0 else ("lash" if occ == "lash" and frac < 1 else "other")
        counts[cls][0] += 1
        counts[cls][1] += bad
    (nc, fc), (nl, fl) = counts["clear"], counts["lash"]
    print(f"checked glints: {nc} clear ({fc} flagged), {nl} cut by a lash ({fl} flagged), "
          f"{counts['other'][0]} other ({counts['other'][1]} flagged); residual flag "
          f"{cut_glints.RESIDUAL_FLAG:g} x RMS; recall "
          f"{fl / max(nl, 1):.2f}, precision {fl / max(fl + fc + counts['other'][1], 1):.2f}")
    e_off, e_on = errors(setup, off, labels), errors(setup, on, labels)
    both = np.isfinite(e_off) & np.isfinite(e_on)
    flagged = np.array([s.flux_flagged.size > 0 for s in on])
    print(f"valid samples {np.isfinite(e_off).sum()} without the flag, {np.isfinite(e_on).sum()} "
          f"with; on the {both.sum()} valid both ways mean error {e_off[both].mean():.3f} -> "
          f"{e_on[both].mean():.3f} deg, p95 {np.percentile(e_off[both], 95):.3f} -> "
          f"{np.percentile(e_on[both], 95):.3f}; the {(both & flagged).sum()} with a flag "
          f"{np.nanmean(e_off[both & flagged]):.3f} -> {np.nanmean(e_on[both & flagged]):.3f} deg")


if __name__ == "__main__":
    main()
