"""The validation report: tables, the overlay of detections on a frame, error plots
and ``validation.md``.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write
from estimator.setup import Setup
from estimator.tracking import BandPrior

from .config import IDENTITY_RADIUS_PX

# --------------------------------------------------------------------------- report


def table_markdown(rows) -> str:
    """The accuracy and robustness table as markdown."""
    head = ("| source | pulses/frame | method | samples | valid | mean (SD) deg | median deg | "
            "p95 deg | robustness (<5 deg) | identities right |\n"
            "|---|---|---|---|---|---|---|---|---|---|\n")
    body = "".join(
        f"| {r.source} | {r.pulses_per_frame} | {r.method} | {r.n} | {100 * r.valid:.1f} % | "
        f"{r.mean_deg:.3f} ({r.sd_deg:.3f}) | {r.median_deg:.3f} | {r.p95_deg:.3f} | "
        f"{100 * r.robustness:.1f} % | "
        + ("n/a (given)" if r.source == "simulated" else f"{100 * r.identity_rate:.2f} %") + " |\n"
        for r in rows)
    return head + body


def prior_table_markdown(errors: dict, assisted: dict) -> str:
    """Rendered accuracy split by how each sample was estimated: from its band's own glints,
    or prior-assisted (shares of all samples; accuracy over the estimated ones)."""
    head = ("| pulses/frame | method | estimated from | samples | share of all | mean (SD) deg | "
            "median deg | p95 deg |\n|---|---|---|---|---|---|---|---|\n")
    body = ""
    for (ppf, method), a in sorted(assisted.items()):
        err = errors[("rendered", ppf, method)]
        for name, sel in (("own glints", ~a), ("prior-assisted", a)):
            e = err[sel & np.isfinite(err)]
            stats = (f"{e.mean():.3f} ({e.std(ddof=1) if e.size > 1 else math.nan:.3f}) | "
                     f"{np.median(e):.3f} | {np.percentile(e, 95):.3f}" if e.size
                     else "- | - | -")
            body += (f"| {ppf} | {method} | {name} | {e.size} | "
                     f"{100 * e.size / max(err.size, 1):.1f} % | {stats} |\n")
    return head + body


def _overlay(test_dir: Path, setup: Setup, samples, path: Path) -> None:
    """The busiest rendered frame, contrast-stretched, detections (circles: identified green,
    others red) and band limits overlaid."""
    import cv2

    from estimator.banding import band_layout
    from estimator.folders import frame_path, read_frame
    from estimator.glints import detect_glints

    counts = {}
    for s in samples:
        counts[s.frame_index] = counts.get(s.frame_index, 0) + s.n_glints * s.ok
    f = max(counts, key=counts.get)
    img = read_frame(frame_path(test_dir, f)).astype(np.float64)
    det = detect_glints(img.astype(np.uint16), setup, f)
    black = setup.sensor.black_level_dn
    v = np.clip((img - black) / max(np.percentile(img, 99.9) - black, 1.0), 0, 1) ** 0.5
    scale = 2 if setup.camera.width_px < 640 else 1
    rgb = cv2.cvtColor((255 * v).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    rgb = cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    used = {(round(u, 3), round(w, 3)) for s in samples if s.frame_index == f and s.ok
            for u, w in s.glints_px}
    for b in band_layout(setup.sensor, setup.strobe, f):
        if b.visible:
            cv2.line(rgb, (0, scale * b.first_row), (8 * scale, scale * b.first_row), (255, 160, 0), 1)
    for u, w in det.glints_px:
        colour = (0, 220, 0) if (round(u, 3), round(w, 3)) in used else (0, 0, 255)
        cv2.circle(rgb, (int(round(scale * (u + 0.5))), int(round(scale * (w + 0.5)))),
                   3 * scale, colour, 1)
    cv2.imwrite(str(path), rgb)


def _plots(errors: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for (source, ppf, method), err in sorted(errors.items()):
        e = np.sort(err[np.isfinite(err)])
        if e.size:
            axes[0].plot(e, np.arange(1, e.size + 1) / err.size,
                         label=f"{source} {method} P={ppf}",
                         ls="-" if source == "rendered" else "--")
    axes[0].set_xscale("log")
    axes[0].set_xlabel("angular error (deg)")
    axes[0].set_ylabel("share of samples")
    axes[0].legend(fontsize=8)
    axes[0].set_title("cumulative error")
    for source, ppf, method in sorted(k for k in errors if k[0] == "rendered"):
        r, s = errors[(source, ppf, method)], errors.get(("simulated", ppf, method))
        if s is not None and r.size:
            with warnings.catch_warnings():  # samples failed in every realisation stay NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                s = np.nanmedian(s.reshape(-1, r.size), axis=0)  # per pose, over realisations
            axes[1].scatter(s, r, s=4, label=f"{method} P={ppf}")
    lim = axes[1].get_xlim()
    axes[1].plot(lim, lim, "k:", lw=0.8)
    axes[1].set_xlabel("simulated error, median of realisations (deg)")
    axes[1].set_ylabel("rendered error (deg)")
    axes[1].legend(fontsize=8)
    axes[1].set_title("per sample, same pose")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _write_report(report_dir: Path, settings, cfg, rows, noise_by_ppf, correct, total,
                  reasons, timings, errors, tracked, assisted, assisted_ids) -> Path:
    figs = report_dir / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    shown = max(settings)  # the most bands per frame
    setup, test_dir = settings[shown]
    _overlay(test_dir, setup, tracked[(shown, "polynomial")], figs / "validation_frame.png")
    _plots(errors, figs / "validation_errors.png")
    reason_lines = "".join(f"- {m}, {p} pulses/frame: "
                           + ", ".join(f"{k} {v}" for k, v in r.items()) + "\n"
                           for (p, m), r in reasons.items())

    def mean(source, p, m):
        return next(r for r in rows if r.source == source and r.pulses_per_frame == p
                    and r.method == m).mean_deg

    def own_mean(p, m):
        e = errors[("rendered", p, m)][~assisted[(p, m)]]
        e = e[np.isfinite(e)]
        return float(e.mean()) if e.size else math.nan

    diff = "".join(
        f"- {m}, {p} pulses/frame: rendered (own glints) minus simulated mean error "
        f"{own_mean(p, m) - mean('simulated', p, m):+.3f} deg\n"
        for p in settings for m in ("polynomial", "geometric"))
    strobes = "; ".join(
        f"{p} pulses/frame: period {1e3 * s.strobe.period_s:.4f} ms, pulse "
        f"{1e3 * s.strobe.pulse_s:.4f} ms, exposure {1e3 * s.sensor.exposure_s:.4f} ms, "
        f"e_f = {noise_by_ppf[p]:.3f} px"
        for p, (s, _) in settings.items())
    text = f"""# End-to-end validation: rendered banded frames through the tracker

Generated by `scet_render.validate.run_validation`. Scene `{setup.name}` at
{setup.camera.width_px}x{setup.camera.height_px} px, {cfg.spp} spp, {cfg.cornea} cornea,
{cfg.frames} test frames per strobe setting (fixations on the 24 x 15 grid, seeded order; the
same trajectory and seed for every setting), calibration on the
{cfg.calib_grid[0]}x{cfg.calib_grid[1]} pattern from single-pulse frames (every row lit by the
same pulse), shared by all settings. Strobe settings (the scene's own pulse count as configured;
the others with the period locked to the frame, the scene's pulse width and the exposure of
Eq. (8), so the bands tile): {strobes}. Ground truth: the optical axis at each strobe instant
(`labels.jsonl`). The feature-level simulation uses the same poses, the same identified lights
per sample, the same calibration and Gaussian feature noise e_f of the same strobe setting (the
RMS per-axis error of the detections of its own-glint samples against the labelled glints).

{table_markdown(rows)}
Rendered samples by how they were estimated: from their band's own glints, or, for bands with
too few glints to be identified alone, prior-assisted (the previous sample's eye rotation as a
Gaussian prior whose covariance grows with the time since it, at up to
{BandPrior().eye_speed_max_deg_s:.0f} deg/s per axis; `estimator.tracker.BandPrior`). The
simulated rows cover own-glint samples only (one pose has no previous band to borrow from).

{prior_table_markdown(errors, assisted)}
Identified glints: {total}, with the right light: {correct}
({100 * correct / max(total, 1):.2f} %; right = that light's labelled glint is the one nearest
to the detection, within {IDENTITY_RADIUS_PX / cfg.scale:g} px). Of these, in prior-assisted samples: {assisted_ids[1]}, right
{assisted_ids[0]}. The feature noise e_f is measured on the own-glint samples.

{diff}
Reasons (rendered):
{reason_lines}
Wall time (s, 2-core CPU): """ + ", ".join(f"{k} {v:.1f}" for k, v in timings.items()) + f"""

![banded frame with detections](figures/validation_frame.png)

Green: glints identified in estimated samples; red: other detections (clutter, or glints of
bands that failed); blue ticks: first row of each band (320x240 frames are shown at 2x).
The frame is from the {shown} pulses/frame sequence.

![errors](figures/validation_errors.png)
"""
    path = report_dir / "validation.md"
    atomic_write(path, text)
    return path
