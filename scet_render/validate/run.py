"""End-to-end regression: rendered banded frames through the prototype's image pipeline.

:func:`run_validation` closes the loop:

1. Render single-pulse calibration frames (every visible row collects the same whole pulse,
   so the frame is one instant; :func:`calibration_setup`) with the eye fixating the 5x5
   calibration pattern, and a banded test sequence (fixations on the paper's 24 x 15 grid,
   :func:`scet_render.dataset.render_dataset`) per strobe setting (pulses per frame, i.e. band
   count; :func:`strobe_setup`): the same trajectory and seed each time.
2. Calibrate from the calibration frames and track the test frames of every strobe setting
   with the very same code that runs on the prototype (:mod:`estimator.tracker`) and the same
   calibration, both gaze methods.
3. Compare each sample with the ground truth of ``labels.jsonl`` (the true optical axis at the
   strobe instant), check every identified glint's light against the labels' glints, and run
   the feature-level simulator (:func:`scet_render.simulate.simulate_glints`) on the same poses,
   the same lights and the same calibration, at the feature noise the rendered detections of
   that strobe setting show.
4. Write ``reports/validation.md`` with the table, a banded frame with its detections overlaid
   and error plots.

Quick mode renders at half resolution (320 x 240), 4 spp, with the conductor cornea (exact
glints at low spp), 30 test frames at each of 8 and 16 pulses per frame, in about a minute on
2 cores; full mode renders at full resolution with the dielectric cornea at 16 spp, 90 test
frames at each of 4, 8 and 16 pulses per frame.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np

from estimator.banding import scaled_setup, strobe_setup
from estimator.calibration import Calibration
from estimator.folders import (
    calibrate_from_folder,
    save_calibration,
    track_folder,
    write_samples_csv,
)
from estimator.gaze import calibrated_problems, geometric_gaze, polynomial_gaze, screen_intersection
from estimator.metrics import angular_error_deg
from estimator.reasons import Reason
from estimator.scene import load_scene
from estimator.setup import Setup
from estimator.tracking import MAX_RESIDUAL_PX, TrackerInputError

from ..dataset import render_calibration
from .config import (
    FULL,
    IDENTITY_RADIUS_PX,
    QUICK,
    SIM_REPEATS,
    ValidationConfig,
    ValidationResult,
    ValidationRow,
    ValidationRun,
)
from .report import _write_report
from .score import error_statistics, true_gaze_points

# --------------------------------------------------------------------------- comparison


def _identities(samples, labels_by_key, radius_px: float):
    """(correct, total, residuals (k, 2)) of the identified glints of the estimated samples
    against the labels: right when the claimed light's labelled glint is the one nearest to
    the detection and within ``radius_px``."""
    correct = total = 0
    resid = []
    for s in samples:
        lb = labels_by_key.get((s.frame_index, s.strobe_index))
        if lb is None or not s.ok or s.n_glints == 0:
            continue
        labelled = np.asarray(lb.glints_px, dtype=np.float64)
        gt = labelled[s.light_index]
        d_all = np.linalg.norm(s.glints_px[:, None] - labelled[None], axis=-1)
        d = d_all[np.arange(s.n_glints), s.light_index]
        nearest = np.where(np.isfinite(d_all), d_all, np.inf).argmin(axis=1)
        good = np.isfinite(d) & (d <= radius_px) & (nearest == s.light_index)
        correct += int(good.sum())
        total += s.n_glints
        resid.append((s.glints_px - gt)[good])
    return correct, total, (np.concatenate(resid) if resid else np.zeros((0, 2)))


def _row(source, ppf, method, err, identity) -> ValidationRow:
    return ValidationRow(source, ppf, method, *error_statistics(err), identity)


def _simulate(setup, calibration, method, mapping, samples, gaze_pts, noise_px, seed,
              repeats: int = SIM_REPEATS):
    """(repeats * m,) errors of the feature-level simulation: the same poses, the same lights
    per sample, Gaussian feature noise of ``noise_px``, the same calibration and estimator
    (NaN where the rendered sample failed, and for prior-assisted samples: one pose has no
    previous band to take a prior from)."""
    from ..simulate import simulate_glints

    ok = np.array([s.ok and not s.prior_assisted for s in samples])
    err = np.full((repeats, len(samples)), np.nan)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return err.ravel()
    rng = np.random.default_rng(seed)
    problems = calibrated_problems(setup, calibration)
    for k in range(repeats):
        obs = simulate_glints(setup, gaze_pts[idx], noise_px=noise_px, noise_model="gaussian",
                              rng=rng)
        glints = np.full(obs.glints_px.shape, np.nan)
        for r, i in enumerate(idx):
            li = samples[i].light_index
            glints[r, li] = obs.glints_px[r, li]
        if method == "polynomial":
            est = polynomial_gaze(setup, calibration, glints, mapping=mapping, problems=problems)
        else:
            est = geometric_gaze(setup, calibration, glints, problems=problems)
        err[k, idx] = angular_error_deg(est.point_m, gaze_pts[idx], setup.eye.rotation_center_m)
    return err.ravel()


def geometric_from(setup: Setup, calibration: Calibration, samples) -> list:
    """Geometric-gaze samples from the identified glints of (polynomial) tracker samples: the
    same detections and identities, the cornea fitted on its calibrated orbit (the
    :class:`estimator.tracker.Tracker` with ``method="geometric"`` gives the same samples up
    to the solver's start). A prior-assisted sample's cornea centre already is that orbit fit
    with its prior (:func:`estimator.gaze.polynomial_gaze`): its optical axis is the ray from
    c_e through it."""
    out = []
    problems = calibrated_problems(setup, calibration)
    for s in samples:
        if not s.ok:
            out.append(s)
            continue
        if s.prior_assisted:
            p, hits = screen_intersection(calibration.eye_center_m,
                                          (s.cornea_center_m - calibration.eye_center_m)[None],
                                          setup.screen.z_m)
            out.append(replace(s, screen_xy_m=p[0, :2].copy()) if hits[0]
                       else replace(s, screen_xy_m=np.full(2, np.nan), reason="misses_screen"))
            continue
        g = np.full((1, setup.lights.count, 2), np.nan)
        g[0, s.light_index] = s.glints_px
        est = geometric_gaze(setup, calibration, g, problems=problems)
        reason = str(est.reason[0])
        if reason == "ok" and not est.rms_px[0] <= MAX_RESIDUAL_PX:
            reason = Reason.RESIDUAL_TOO_LARGE
        ok = reason == "ok"
        out.append(replace(s, screen_xy_m=est.screen_xy_m[0].copy() if ok else np.full(2, np.nan),
                           cornea_center_m=(est.cornea_center_m[0].copy() if ok
                                            else np.full(3, np.nan)),
                           residual_px=float(est.rms_px[0]) if ok else math.nan, reason=reason))
    return out


# --------------------------------------------------------------------------- the run


def run_validation(scene=None, *, quick: bool, out_dir, seed: int = 0,
                   progress: Callable[[str, int, int], None] | None = None,
                   config: ValidationConfig | None = None,
                   report_dir=None, workers: int | None = None,
                   address: str | None = None) -> ValidationResult:
    """Render, calibrate, track and compare; write the report.

    Parameters
    ----------
    scene : str or Path, optional
        Scene name or file (default ``paper_sim``).
    quick : bool
        Quick mode (:data:`QUICK`) or full mode (:data:`FULL`).
    out_dir : Path
        Work folder: ``calibration/``, ``test/`` (datasets), ``calibration.json``,
        ``samples_<method>.csv``. Existing renders of the same arguments are reused.
    seed : int
    progress : callable, optional
        ``progress(stage, done, total)``.
    config : ValidationConfig, optional
        Overrides the mode's settings (tests use a smaller one).
    report_dir : Path, optional
        Where ``validation.md`` and its figures go (default ``out_dir``; the CLI passes
        ``reports/``).
    workers, address : optional
        Render on Ray (:func:`validate_setup`).

    Returns
    -------
    ValidationResult
    """
    cfg = config or (QUICK if quick else FULL)
    out = Path(out_dir)
    report_dir = Path(report_dir) if report_dir is not None else out
    setup = scaled_setup(load_scene(scene), cfg.scale)
    r = validate_setup(setup, cfg, out, seed=seed, progress=progress, workers=workers,
                       address=address)
    report = _write_report(report_dir, r.settings, cfg, r.rows, r.noise_by_ppf, r.correct,
                           r.total, r.reasons, r.timings, r.errors, r.tracked, r.assisted,
                           r.assisted_ids)
    return ValidationResult(r.rows, r.noise_px, r.correct / r.total if r.total else math.nan,
                            r.total, r.calibration, r.errors, r.reasons, r.timings, report, cfg,
                            r.noise_by_ppf, r.assisted, r.assisted_ids)


def validate_setup(setup: Setup, cfg: ValidationConfig, out_dir, *, seed: int = 0,
                   progress: Callable[[str, int, int], None] | None = None,
                   eyelid_openness: float | None = 1.0,
                   scene_text: str | None = None, cornea_model: str = "sphere",
                   workers: int | None = None, address: str | None = None,
                   tracker_camera=None, tracker_name: str = "tracker") -> ValidationRun:
    """Steps 1-3 of the module docstring on a setup already at the render size (no report):
    what :func:`run_validation` runs on its scene, and ``scet study aspheric`` on derived eyes.

    Parameters
    ----------
    setup : Setup
        At the size to render (:func:`estimator.banding.scaled_setup`).
    cfg : ValidationConfig
    out_dir : Path
        Work folder, as :func:`run_validation`'s.
    seed : int
    progress : callable, optional
    eyelid_openness : float or None
        The renderer's static eyelids (None: none; :func:`scet_render.dataset.render_dataset`).
    scene_text : str, optional
        The scene TOML the datasets' manifests record; needed when ``setup`` is derived in
        memory (its text is not that of ``setup.source``, which is read otherwise).
    cornea_model : {"sphere", "conic"}
        The tracker's cornea (:func:`estimator.folders.calibrate_from_folder`); a conic run
        writes ``calibration_conic.json`` and ``samples_<method>_p<ppf>_conic.csv`` beside the
        sphere's, on the same renders.
    workers : int, optional
        Render the calibration frames and the datasets on a local Ray with this many workers
        (:mod:`scet_render.cluster`): the same bytes as the serial run, so the same report.
    address : str, optional
        Render on an existing Ray cluster instead (its workers must share ``out_dir``).
    tracker_camera : Camera, optional
        The camera the tracker calibrates and tracks with, in place of ``setup``'s (which the
        frames are rendered through): a pinhole or a board calibration of the rendered lens
        (``scet study lens --gaze``). Only the renders are shared with a run without it.
    tracker_name : str
        With ``tracker_camera``: the calibration and the samples are written as
        ``calibration_<name>.json`` and ``samples_<method>_p<ppf>_<name>.csv``.

    Returns
    -------
    ValidationRun
    """
    from ..dataset import iter_labels, render_dataset, render_dataset_ray

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    timings = {}

    def stage(name):
        return (lambda d, t: progress(name, d, t)) if progress is not None else None

    t = time.perf_counter()
    cal_dir = render_calibration(setup, out / "calibration", spp=cfg.spp, cornea=cfg.cornea,
                                 seed=seed, grid=cfg.calib_grid, progress=stage("calibration"),
                                 eyelid_openness=eyelid_openness, scene_text=scene_text,
                                 workers=workers, address=address)
    distributed = workers is not None or address is not None
    settings = {}  # pulses per frame -> (setup, test folder)
    for ppf in cfg.pulses_per_frame:
        sset = strobe_setup(setup, ppf)
        test_dir = out / f"test_p{ppf}"
        kwargs = dict(frames=cfg.frames, spp=cfg.spp, trajectory="fixations", seed=seed,
                      cornea=cfg.cornea, progress=stage(f"test {ppf} pulses/frame"),
                      scene_text=scene_text, eyelid_openness=eyelid_openness)
        if distributed:
            render_dataset_ray(sset, test_dir, workers=workers, address=address, **kwargs)
        else:
            render_dataset(sset, test_dir, **kwargs)
        settings[ppf] = (sset, test_dir)
    timings["render"] = time.perf_counter() - t

    if tracker_camera is not None:  # what the tracker believes the camera is
        setup = replace(setup, camera=tracker_camera)
        settings = {p: (replace(s, camera=tracker_camera), d) for p, (s, d) in settings.items()}
    t = time.perf_counter()
    tag = "" if cornea_model == "sphere" else f"_{cornea_model}"
    tag += "" if tracker_camera is None else f"_{tracker_name}"
    calibration = calibrate_from_folder(cal_dir, setup, cornea_model=cornea_model)
    save_calibration(calibration, out / f"calibration{tag}.json")
    timings["calibrate"] = time.perf_counter() - t
    eq1 = sorted(k for k in calibration.mappings if k.startswith("eq1"))
    if not eq1:  # too few calibration frames identified: the study cannot run polynomial gaze
        skipped = calibration.quality.get("mappings_skipped") or {}
        raise TrackerInputError(
            f"{out / f'calibration{tag}.json'}: no Eq. (1) gaze mapping (has "
            f"{sorted(calibration.mappings)}; skipped: {skipped or 'none'}): the calibration "
            f"renders in {cal_dir} gave too few usable frames; render them with more spp or a "
            "larger calibration grid")
    mapping = eq1[-1]

    rows, errors, reasons, noise_by_ppf, tracked, assisted = [], {}, {}, {}, {}, {}
    labels_by_ppf = {}
    correct = total = 0
    assisted_ids = (0, 0)
    resid_all = []
    timings["track"] = timings["simulate"] = 0.0
    radius = IDENTITY_RADIUS_PX / cfg.scale
    for ppf, (sset, test_dir) in settings.items():
        labels = list(iter_labels(test_dir))
        by_key = {(lb.frame, lb.strobe): lb for lb in labels}
        labels_by_ppf[ppf] = by_key
        resid_p = []
        for method in ("polynomial", "geometric"):
            t = time.perf_counter()
            csv = out / f"samples_{method}_p{ppf}{tag}.csv"
            if method == "polynomial":
                summary = track_folder(test_dir, sset, calibration, csv, method=method,
                                       mapping=mapping,
                                       progress=stage(f"track {method} {ppf} pulses/frame"))
                samples = list(summary.samples)
            else:
                # Detection and identification do not depend on the gaze method: refit the
                # polynomial run's identified glints on the orbit instead of tracking twice.
                samples = geometric_from(sset, calibration, tracked[(ppf, "polynomial")])
                write_samples_csv(csv, samples)
            timings["track"] += time.perf_counter() - t
            tracked[(ppf, method)] = samples
            keyed = [by_key[(s.frame_index, s.strobe_index)] for s in samples]
            truth = true_gaze_points(sset, keyed)
            est = np.array([[*s.screen_xy_m, sset.screen.z_m] for s in samples])
            err = angular_error_deg(est, truth, sset.eye.rotation_center_m)
            c, n, _ = _identities(samples, by_key, radius)
            if method == "polynomial":  # the same identities serve both methods
                correct, total = correct + c, total + n
                # e_f of the simulation, which covers the own-glint samples only.
                resid_p.append(_identities([s for s in samples if not s.prior_assisted],
                                           by_key, radius)[2])
                ca, na, _ = _identities([s for s in samples if s.prior_assisted], by_key,
                                        radius)
                assisted_ids = (assisted_ids[0] + ca, assisted_ids[1] + na)
            errors[("rendered", ppf, method)] = err
            assisted[(ppf, method)] = np.array([s.ok and s.prior_assisted for s in samples],
                                               dtype=bool)
            reasons[(ppf, method)] = {r: sum(s.reason == r for s in samples)
                                      for r in sorted({s.reason for s in samples})}
            rows.append(_row("rendered", ppf, method, err, c / n if n else math.nan))
        resid = np.concatenate(resid_p)
        resid_all.append(resid)
        noise_px = float(np.sqrt(np.mean(resid ** 2))) if resid.size else 0.0
        noise_by_ppf[ppf] = noise_px
        t = time.perf_counter()
        for method in ("polynomial", "geometric"):
            samples = tracked[(ppf, method)]
            keyed = [by_key[(s.frame_index, s.strobe_index)] for s in samples]
            err = _simulate(sset, calibration, method, mapping, samples,
                            true_gaze_points(sset, keyed), noise_px, seed)
            errors[("simulated", ppf, method)] = err
            rows.append(_row("simulated", ppf, method, err, 1.0))
        timings["simulate"] += time.perf_counter() - t
    resid = np.concatenate(resid_all)
    noise_px = float(np.sqrt(np.mean(resid ** 2))) if resid.size else 0.0
    timings["total"] = sum(timings.values())
    return ValidationRun(settings, rows, errors, reasons, tracked, assisted, assisted_ids,
                         labels_by_ppf, noise_by_ppf, noise_px, correct, total, calibration,
                         mapping, timings)
