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
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from estimator.calibration import Calibration
from estimator.camera import Camera
from estimator.eye import gaze_direction
from estimator.gaze import geometric_gaze, polynomial_gaze, screen_intersection
from estimator.metrics import angular_error_deg, summarize_errors
from estimator.scene import load_scene
from estimator.setup import Setup
from estimator.folders import (FRAMES_DIR, _atomic_write, calibrate_from_folder, samples_csv,
                               save_calibration, timing_document, track_folder)
from estimator.tracker import MAX_RESIDUAL_PX, RESIDUAL_TOO_LARGE, BandPrior

#: A detection is the glint of the light it was matched to when that light's ground-truth glint
#: is the labelled glint nearest to it and lies within this distance (px at full size, 640 x
#: 480; halved at half size): identity, not centroid accuracy. The closest neighbouring glints
#: of paper_sim are 5.7 px apart; rendered centroids sit within ~0.3 px of their glint on a
#: conductor cornea, but a dielectric cornea at 16 spp renders each glint as a few clipped
#: Monte Carlo pixels (a 2.5 % reflection sampled per camera ray; :mod:`scet_render.sensor`)
#: whose centroid is up to ~2 px off (median 0.9 px, measured on the full validation).
IDENTITY_RADIUS_PX = 3.0
#: Calibration frames: share of the slack between exposure and readout span given to the pulse.
CALIB_PULSE_SHARE = 0.5
#: Calibration fixation per target (s); one frame is rendered in its middle.
CALIB_FIXATION_S = 0.1


@dataclass(frozen=True, slots=True)
class ValidationConfig:
    scale: int
    spp: int
    cornea: str
    frames: int
    calib_grid: tuple = (5, 5)
    #: Strobe settings (pulses per frame); ``frames`` test frames are rendered for each.
    pulses_per_frame: tuple = (16,)


QUICK = ValidationConfig(scale=2, spp=4, cornea="conductor", frames=30, pulses_per_frame=(8, 16))
FULL = ValidationConfig(scale=1, spp=16, cornea="dielectric", frames=90,
                        pulses_per_frame=(4, 8, 16))


@dataclass(frozen=True, slots=True)
class ValidationRow:
    """One line of the table: a source ("rendered" or "simulated"), a band count (strobe
    pulses per frame) and a gaze method."""

    source: str
    pulses_per_frame: int
    method: str
    n: int
    valid: float
    mean_deg: float
    sd_deg: float
    median_deg: float
    p95_deg: float
    robustness: float
    identity_rate: float

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name in self.__slots__}


@dataclass(frozen=True, slots=True)
class ValidationResult:
    """Everything :func:`run_validation` measured.

    Attributes
    ----------
    rows : list of ValidationRow
    feature_noise_px : float
        RMS per-axis error of the rendered detections against the labels (px), over all
        strobe settings.
    feature_noise_by_ppf : dict
        pulses per frame -> that setting's RMS per-axis error (px): the e_f of its matching
        feature-level simulation (Gaussian).
    identity_rate : float
        Share of identified detections whose light is right (that light's ground-truth glint
        is the nearest to the detection, within :data:`IDENTITY_RADIUS_PX` at full size).
    n_identified : int
    calibration : Calibration
    errors_deg : dict
        (source, pulses_per_frame, method) -> (m,) per-sample errors (NaN = failed).
    reasons : dict
        (pulses_per_frame, method) -> {reason: count}.
    assisted : dict
        (pulses_per_frame, method) -> (m,) bool: prior-assisted samples
        (:attr:`estimator.tracker.GazeSample.prior_assisted`).
    assisted_identities : (int, int)
        Right and all identified glints of the prior-assisted samples (included in
        ``identity_rate``).
    timings_s : dict
        Wall time of each stage.
    report : Path
    """

    rows: list
    feature_noise_px: float
    identity_rate: float
    n_identified: int
    calibration: Calibration
    errors_deg: dict
    reasons: dict
    timings_s: dict
    report: Path
    config: ValidationConfig = field(default=QUICK)
    feature_noise_by_ppf: dict = field(default_factory=dict)
    assisted: dict = field(default_factory=dict)
    assisted_identities: tuple = (0, 0)

    def own_errors(self, method: str, pulses_per_frame: int) -> np.ndarray:
        """Rendered errors of the samples estimated from their own glints alone (the others
        NaN): what the feature-level simulation reproduces."""
        err = self.errors_deg[("rendered", pulses_per_frame, method)]
        return np.where(self.assisted[(pulses_per_frame, method)], np.nan, err)

    def row(self, source: str, method: str, pulses_per_frame: int | None = None) -> ValidationRow:
        """The row of ``source`` and ``method`` at ``pulses_per_frame`` (may be left out when
        only one strobe setting was run)."""
        found = [r for r in self.rows if r.source == source and r.method == method
                 and (pulses_per_frame is None or r.pulses_per_frame == pulses_per_frame)]
        if len(found) != 1:
            raise KeyError(f"{len(found)} rows for {(source, method, pulses_per_frame)}")
        return found[0]

    def errors(self, source: str, method: str, pulses_per_frame: int | None = None) -> np.ndarray:
        """Per-sample errors of ``source`` and ``method``: of one strobe setting, or of all
        of them concatenated."""
        return np.concatenate([e for (s, p, m), e in sorted(self.errors_deg.items())
                               if s == source and m == method
                               and (pulses_per_frame is None or p == pulses_per_frame)])


# --------------------------------------------------------------------------- setups


def scaled_setup(setup: Setup, factor: int) -> Setup:
    """The setup imaged at 1/``factor`` of the resolution: same field of view, same strobe
    timing (S scaled with N, so the line time fraction and the bands keep their timing)."""
    if factor == 1:
        return setup
    cam = setup.camera
    camera = Camera(cam.position_m, cam.rotation, cam.fx_px / factor, cam.fy_px / factor,
                    (cam.cx_px + 0.5) / factor - 0.5, (cam.cy_px + 0.5) / factor - 0.5,
                    cam.width_px // factor, cam.height_px // factor)
    if setup.sensor.total_lines % factor or cam.height_px % factor:
        raise ValueError(f"cannot scale setup {setup.name!r} by 1/{factor}: total_lines "
                         f"{setup.sensor.total_lines} and height {cam.height_px} must divide")
    sensor = replace(setup.sensor, total_lines=setup.sensor.total_lines // factor,
                     visible_lines=cam.height_px // factor)
    return replace(setup, camera=camera, sensor=sensor)


def calibration_setup(setup: Setup, exposure_share: float = 0.9) -> Setup:
    """The setup with single-pulse calibration timing: one pulse per frame that every visible
    row collects whole, so the whole frame shows one instant.

    Row y is exposed over [R(y) - Δe, R(y)] with R(y) = t0 + (y / S) Δt (Eqs. (2)-(3)); all
    visible rows share [R(N - 1) - Δe, R(0)], which is non-empty when Δe exceeds the readout
    span (N - 1) Δt / S. The exposure is set to ``exposure_share`` Δt and the pulse, centred in
    the shared window, takes :data:`CALIB_PULSE_SHARE` of it. (A pulse as wide as the exposure
    cannot be collected whole by every row of a rolling shutter; this one can.)
    """
    sensor = setup.sensor
    dt = sensor.frame_period_s
    span = (sensor.visible_lines - 1) * dt / sensor.total_lines
    exposure = exposure_share * dt
    slack = exposure - span
    if slack <= 0:
        raise ValueError(f"setup {setup.name!r}: an exposure of {exposure:.4g} s does not cover "
                         f"the readout span {span:.4g} s")
    pulse = CALIB_PULSE_SHARE * slack
    phase = -0.5 * slack - 0.5 * pulse  # centre of [span - Δe, 0] relative to t0_f
    strobe = replace(setup.strobe, pulses_per_frame=1, pulse_s=pulse, period_s=dt, phase_s=phase)
    return replace(setup, sensor=replace(sensor, exposure_s=exposure), strobe=strobe)


def strobe_setup(setup: Setup, pulses_per_frame: int) -> Setup:
    """The setup strobed ``pulses_per_frame`` times a frame: the period locked to the frame
    (Δ_clk = Δt / P), the setup's pulse width kept and the exposure of Eq. (8), Δe = Δ_clk - Δs,
    so the bands tile the frame (:func:`estimator.banding.plan_strobe`). The setup's own pulse
    count returns the setup unchanged (its exposure as configured)."""
    from estimator.banding import plan_strobe

    if pulses_per_frame == setup.strobe.pulses_per_frame:
        return setup
    if pulses_per_frame < 1:
        raise ValueError(f"pulses_per_frame must be >= 1, got {pulses_per_frame}")
    sensor = setup.sensor
    # plan_strobe asks for visible bands: ceil(b S / N) = P for b just under P N / S.
    plan = plan_strobe(sensor, pulses_per_frame * sensor.visible_lines / sensor.total_lines
                       * (1 - 1e-9), pulse_s=setup.strobe.pulse_s)
    if plan.pulses_per_frame != pulses_per_frame:  # pragma: no cover - rounding guard
        raise RuntimeError(f"planned {plan.pulses_per_frame} pulses, wanted {pulses_per_frame}")
    strobe = replace(setup.strobe, pulses_per_frame=plan.pulses_per_frame,
                     pulse_s=plan.pulse_s, period_s=plan.period_s)
    return replace(setup, sensor=replace(sensor, exposure_s=plan.exposure_s), strobe=strobe)


# --------------------------------------------------------------------------- rendering


def render_calibration(setup: Setup, out_dir, *, spp: int, cornea: str, seed: int = 0,
                       grid=(5, 5), progress=None) -> Path:
    """Render single-pulse calibration frames of the eye fixating the calib grid.

    Writes ``frames/NNNNNN.png`` (frames in the middle of each fixation), ``labels.jsonl``
    (:func:`scet_render.dataset.frame_labels`) and ``timing.json`` (with the calibration
    exposure and strobe), each atomically. Returns the folder.
    """
    import json

    import cv2

    from scet_render.dataset import frame_labels
    from scet_render.motion import fixation_sequence
    from scet_render.rolling_shutter import BandedRenderer
    from scet_render.sensor import SensorModel

    out = Path(out_dir)
    (out / FRAMES_DIR).mkdir(parents=True, exist_ok=True)
    cal = calibration_setup(setup)
    targets = setup.screen.grid(grid[0], grid[1], margin=0.0)
    traj = fixation_sequence(setup.eye, targets, CALIB_FIXATION_S)
    dt = cal.sensor.frame_period_s
    ends = np.cumsum(traj.segment_duration_s)
    starts = ends - traj.segment_duration_s
    fix = np.flatnonzero(np.asarray(traj.kind) == 0)
    mid = 0.5 * (starts[fix] + ends[fix])
    instant = cal.strobe.phase_s + 0.5 * cal.strobe.pulse_s  # pulse centre relative to t0_f
    frames = [int(round((t - instant) / dt)) for t in mid]
    renderer = BandedRenderer(cal, spp=spp, cornea=cornea, seed=seed)
    sensor = SensorModel.from_sensor(cal.sensor)
    word = np.uint8 if sensor.bit_depth <= 8 else np.uint16
    labels = []
    for i, f in enumerate(frames):
        path = out / FRAMES_DIR / f"{f:06d}.png"
        if not path.is_file():
            radiance = renderer.render_frame(traj, f).radiance
            dn = sensor.apply(radiance, np.random.SeedSequence([seed, 3, f]))
            ok, png = cv2.imencode(".png", dn.astype(word))
            if not ok:
                raise RuntimeError(f"OpenCV could not encode calibration frame {f}")
            _atomic_write(path, png.tobytes())
        labels.extend(frame_labels(cal, traj, f))
        if progress is not None:
            progress(i + 1, len(frames))
    _atomic_write(out / "labels.jsonl", "".join(json.dumps(x) + "\n" for x in labels).encode())
    _atomic_write(out / "timing.json", timing_document({f: f * dt for f in frames},
                                                       exposure_s=cal.sensor.exposure_s,
                                                       strobe=cal.strobe).encode())
    return out


# --------------------------------------------------------------------------- comparison


def _true_gaze_points(setup: Setup, labels) -> np.ndarray:
    yaw = np.array([lb.yaw_rad for lb in labels])
    pitch = np.array([lb.pitch_rad for lb in labels])
    p, _ = screen_intersection(setup.eye.rotation_center_m, gaze_direction(yaw, pitch),
                               setup.screen.z_m)
    return p


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
    s = summarize_errors(err)
    fin = err[np.isfinite(err)]
    return ValidationRow(source, ppf, method, s.n, 1.0 - s.n_nan / max(s.n, 1), s.mean_deg,
                         s.sd_deg, float(np.median(fin)) if fin.size else math.nan,
                         float(np.percentile(fin, 95)) if fin.size else math.nan, s.robustness,
                         identity)


#: Noise realisations of the feature-level simulation per sample: one realisation of ~20
#: samples (the fast test) leaves the median of polynomial gaze, whose cornea-centre fit
#: amplifies feature noise, uncertain to ~0.3 deg; ten bring it to ~0.1 deg.
SIM_REPEATS = 10


def _simulate(setup, calibration, method, mapping, samples, gaze_pts, noise_px, seed,
              repeats: int = SIM_REPEATS):
    """(repeats * m,) errors of the feature-level simulation: the same poses, the same lights
    per sample, Gaussian feature noise of ``noise_px``, the same calibration and estimator
    (NaN where the rendered sample failed, and for prior-assisted samples: one pose has no
    previous band to take a prior from)."""
    from scet_render.simulate import simulate_glints

    ok = np.array([s.ok and not s.prior_assisted for s in samples])
    err = np.full((repeats, len(samples)), np.nan)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return err.ravel()
    rng = np.random.default_rng(seed)
    for k in range(repeats):
        obs = simulate_glints(setup, gaze_pts[idx], noise_px=noise_px, noise_model="gaussian",
                              rng=rng)
        glints = np.full(obs.glints_px.shape, np.nan)
        for r, i in enumerate(idx):
            li = samples[i].light_index
            glints[r, li] = obs.glints_px[r, li]
        if method == "polynomial":
            est = polynomial_gaze(setup, calibration, glints, mapping=mapping)
        else:
            est = geometric_gaze(setup, calibration, glints)
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
        est = geometric_gaze(setup, calibration, g)
        reason = str(est.reason[0])
        if reason == "ok" and not est.rms_px[0] <= MAX_RESIDUAL_PX:
            reason = RESIDUAL_TOO_LARGE
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
                   report_dir=None) -> ValidationResult:
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

    Returns
    -------
    ValidationResult
    """
    from scet_render.dataset import iter_labels, render_dataset

    cfg = config or (QUICK if quick else FULL)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    report_dir = Path(report_dir) if report_dir is not None else out
    base = load_scene(scene)
    setup = scaled_setup(base, cfg.scale)
    timings = {}

    def stage(name):
        return (lambda d, t: progress(name, d, t)) if progress is not None else None

    t = time.perf_counter()
    cal_dir = render_calibration(setup, out / "calibration", spp=cfg.spp, cornea=cfg.cornea,
                                 seed=seed, grid=cfg.calib_grid, progress=stage("calibration"))
    settings = {}  # pulses per frame -> (setup, test folder)
    for ppf in cfg.pulses_per_frame:
        sset = strobe_setup(setup, ppf)
        test_dir = out / f"test_p{ppf}"
        render_dataset(sset, test_dir, frames=cfg.frames, spp=cfg.spp, trajectory="fixations",
                       seed=seed, cornea=cfg.cornea, progress=stage(f"test {ppf} pulses/frame"))
        settings[ppf] = (sset, test_dir)
    timings["render"] = time.perf_counter() - t

    t = time.perf_counter()
    calibration = calibrate_from_folder(cal_dir, setup)
    save_calibration(calibration, out / "calibration.json")
    timings["calibrate"] = time.perf_counter() - t
    mapping = sorted(k for k in calibration.mappings if k.startswith("eq1"))[-1]

    rows, errors, reasons, noise_by_ppf, tracked, assisted = [], {}, {}, {}, {}, {}
    correct = total = 0
    assisted_ids = (0, 0)
    resid_all = []
    timings["track"] = timings["simulate"] = 0.0
    radius = IDENTITY_RADIUS_PX / cfg.scale
    for ppf, (sset, test_dir) in settings.items():
        labels = list(iter_labels(test_dir))
        by_key = {(lb.frame, lb.strobe): lb for lb in labels}
        resid_p = []
        for method in ("polynomial", "geometric"):
            t = time.perf_counter()
            csv = out / f"samples_{method}_p{ppf}.csv"
            if method == "polynomial":
                summary = track_folder(test_dir, sset, calibration, csv, method=method,
                                       mapping=mapping,
                                       progress=stage(f"track {method} {ppf} pulses/frame"))
                samples = list(summary.samples)
            else:
                # Detection and identification do not depend on the gaze method: refit the
                # polynomial run's identified glints on the orbit instead of tracking twice.
                samples = geometric_from(sset, calibration, tracked[(ppf, "polynomial")])
                _atomic_write(csv, samples_csv(samples).encode("utf-8"))
            timings["track"] += time.perf_counter() - t
            tracked[(ppf, method)] = samples
            keyed = [by_key[(s.frame_index, s.strobe_index)] for s in samples]
            truth = _true_gaze_points(sset, keyed)
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
                            _true_gaze_points(sset, keyed), noise_px, seed)
            errors[("simulated", ppf, method)] = err
            rows.append(_row("simulated", ppf, method, err, 1.0))
        timings["simulate"] += time.perf_counter() - t
    resid = np.concatenate(resid_all)
    noise_px = float(np.sqrt(np.mean(resid ** 2))) if resid.size else 0.0
    timings["total"] = sum(timings.values())
    report = _write_report(report_dir, settings, cfg, rows, noise_by_ppf, correct, total,
                           reasons, timings, errors, tracked, assisted, assisted_ids)
    return ValidationResult(rows, noise_px, correct / total if total else math.nan, total,
                            calibration, errors, reasons, timings, report, cfg, noise_by_ppf,
                            assisted, assisted_ids)


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
    from estimator.glints import detect_glints
    from estimator.folders import frame_path, read_frame

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
    _atomic_write(path, text.encode("utf-8"))
    return path
