"""Reproduction of every simulated experiment of Sec. 3 of the SCET paper, beside ours.

:func:`run_reproduction` runs the experiments and writes ``paper-reproduction.md`` and its
figures (:mod:`scet_render.report`). The experiments, each with the paper's method and ours on
the same simulated data:

- Fig. 5 (Sec. 3.1): eye centre, orbit radius, corneal radius and lighting pose from 25
  calibration frames lit by the 6 x 6 grid, for feature errors e_f from 0 to 0.5 px;
- Sec. 3.2 and Fig. 6: geometric and polynomial gaze over the 24 x 15 grid;
- Fig. 7 and 8 (Sec. 3.3): camera and lights translated after calibration, and the distance
  sensor compensation;
- Fig. 9 (Sec. 3.4): banding (:mod:`scet_render.reproduce_bands`).

The true rig sits off its nominal model (the apparatus' 3D model) by a known rigid error,
:data:`RIG_ROTATION_DEG` about :data:`RIG_ROTATION_AXIS` through the grid's centre and
:data:`RIG_TRANSLATION_M`, so that lighting calibration matters; every light group rides on
the same frame and moves with it. Everything is seeded: the same seed gives the same numbers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.calibration import (CORNEA_RADIUS_BOUNDS_M, Calibration, LightingFit, OrbitFit,
                                   calibrate_joint, calibrate_lighting_joint, calibrate_lighting_per_frame,
                                   fit_gaze_mapping, orbit_law_of_sines, orbit_sphere_fit,
                                   pose_correction)
from estimator.cornea import FitProblem, fit_cornea
from estimator.gaze import fit_cornea_centers, geometric_gaze
from estimator.geometry import RigidPose
from estimator.mapping import distance_reading
from estimator.metrics import angular_error_deg, light_position_error_m, summarize_errors
from estimator.scene import load_scene
from estimator.setup import Setup
from scet_render.reproduce_fits import fit_center_radius
from scet_render.simulate import parse_targets, simulate_glints

#: The true rig's offset from its nominal model: 1 degree about (1, 1, 0)/sqrt(2) through the
#: calibration grid's centre, then 1 mm along x. Small enough to be an assembly error, large
#: enough (it moves the arc's glints by 9 px on average, 15 px at most) that an uncalibrated
#: lighting visibly hurts.
RIG_ROTATION_DEG = 1.0
RIG_ROTATION_AXIS = (1.0, 1.0, 0.0)
RIG_TRANSLATION_M = (1e-3, 0.0, 0.0)
#: Sec. 3: "unless otherwise stated", e_f = 0.5 px.
NOISE_PX = 0.5
#: Eq. (1) from 9 points, truncated: singular values below 5 % of the largest are dropped.
#: The 3 x 3 pattern is mirror-symmetric, so one direction of Eq. (1) is determined only by the
#: noise (see :func:`estimator.mapping.fit_gaze_mapping`). Measured over 30 noise draws at
#: e_f = 0.5 px (centred, scaled design): that direction's singular value is 6e-4 to 1.8e-2 of
#: the largest, the next one 0.17 to 0.21; 5e-2 separates them, so the fit has rank 7.
EQ1_9_TRUNCATE_RTOL = 5e-2
#: Sec. 3.3: translations of camera and lights of s (w/2, 0, d/2) and s (0, h/2, d/2), w = h =
#: d = 1 mm, s from -1 to 1 in steps of 0.2 (0.1 mm).
TRANSLATION_HALF_M = 0.5e-3
#: Sec. 3.3.1: 9-point calibrations at these z translations (27 points) for the d_a mapping.
DA_DEPTHS_M = (0.0, -0.5e-3, -1.0e-3)


@dataclass(frozen=True, slots=True)
class ReproductionConfig:
    """Trial counts and sweeps of one run (:func:`config_for`)."""

    quick: bool
    seed: int
    noise_levels_px: tuple[float, ...]
    calibration_trials: int  # Fig. 5, per noise level
    gaze_trials: int  # Sec. 3.2: the first trials at e_f = 0.5 px also evaluate gaze
    trf_frames: int  # paper's TRF against our LM on the same frames / samples
    trf_samples: int
    translation_trials: int
    translation_steps: tuple[float, ...]
    band_trials: int
    band_counts: tuple[int, ...] = (1, 2, 4, 8, 12, 16, 20)


def config_for(quick: bool, seed: int = 0) -> ReproductionConfig:
    """The full protocol of the paper, or a quick one (3 noise levels x 5 trials, ...)."""
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if quick:
        return ReproductionConfig(True, int(seed), (0.0, 0.25, 0.5), 5, 2, 5, 40, 1,
                                  (-1.0, -0.5, 0.0, 0.5, 1.0), 2)
    return ReproductionConfig(False, int(seed), tuple(np.round(np.arange(11) * 0.05, 2)), 50, 50, 25, 360,
                              10, tuple(np.round(np.linspace(-1, 1, 11), 1)), 10)


@dataclass(frozen=True)
class Context:
    """Scenes, targets and the true rig shared by every experiment."""

    grid: Setup  # Sec. 3.1: the 6 x 6 lighting-calibration grid
    arc: Setup  # Fig. 3: the 40-light arc
    doubled: Setup  # Sec. 3.4: the arc and its 64-degree copy
    true_correction: RigidPose  # true lights = true_correction.apply(nominal lights)
    targets9: np.ndarray
    targets25: np.ndarray
    targets_grid: np.ndarray  # the 24 x 15 accuracy grid

    @property
    def eye_center(self) -> np.ndarray:
        return self.arc.eye.rotation_center_m

    def true_lights(self, setup: Setup) -> np.ndarray:
        return self.true_correction.apply(setup.lights_world_m)

    def truth(self) -> Calibration:
        eye = self.arc.eye
        return Calibration(self.true_correction, eye.cornea_radius_m, eye.rotation_center_m,
                           eye.cornea_offset_m, methods={"all": "ground_truth"})


def make_context() -> Context:
    grid = load_scene("lighting_grid")
    axis = np.asarray(RIG_ROTATION_AXIS) / np.linalg.norm(RIG_ROTATION_AXIS)
    corr = pose_correction(np.deg2rad(RIG_ROTATION_DEG) * axis, RIG_TRANSLATION_M,
                           grid.lights_world_m.mean(axis=0))
    arc = load_scene("paper_sim")
    return Context(grid, arc, load_scene("paper_sim_doubled"), corr, parse_targets("calib:3x3", arc),
                   parse_targets("calib:5x5", arc), parse_targets("grid:24x15", arc))


def trial_rng(seed: int, experiment: int, *index: int) -> np.random.Generator:
    """The generator of one trial: independent streams per experiment, level and trial."""
    return np.random.default_rng([seed, experiment, *index])


# --------------------------------------------------------------------------- calibration


@dataclass(frozen=True)
class Calibrations:
    """Every calibration of one trial, from the same 25 grid frames.

    ``paper``: the paper's per-frame lighting (10 unknowns per frame, averaged pose and r_c).
    The paper's eye centre comes from cornea centres read three ways: ``literal`` (the centres
    of the 10-unknown fits), ``cr`` (centre and radius refitted with the averaged lighting, "the
    corneal center (c_c) and radius (r_c)" of Sec. 3.1) and ``c`` (centre refitted with the
    averaged lighting and r_c, the most charitable). ``joint_lighting``: ours, one pose and r_c
    for all frames. ``joint``: ours, lighting, r_c, c_e and r_co at once.
    """

    paper: LightingFit | None  # None when every frame failed
    centers: dict  # reading -> (25, 3) cornea centres
    radius_cr_m: float  # mean r_c of the ``cr`` reading
    radius_cr_sd_m: float  # SD of the per-frame r_c of the ``cr`` reading
    joint_lighting: LightingFit | None  # None with ``readings=False``
    joint: tuple[LightingFit, OrbitFit]


def calibrate_all(ctx: Context, glints_px, visible, *, readings: bool = True) -> Calibrations:
    """Every calibration of :class:`Calibrations`; ``readings=False`` skips the refitted centres
    and the joint lighting (banding needs only the paper's lighting and our joint fit)."""
    grid, L = ctx.grid, ctx.grid.lights_world_m
    c0 = grid.eye.cornea_center(0.0, 0.0)
    pf = None
    # The paper's TRF, run by our batched LM with the same bounds (the solver check in the report
    # compares both on the same frames). estimator.cornea's LM can take a non-finite step on
    # a rare frame and then raises ValueError (a NaN radius reaches the projection); the paper's
    # own TRF is then used for that trial, and the report counts such trials.
    for solver in ("lm", "trf"):
        try:
            pf = calibrate_lighting_per_frame(grid.camera, L, glints_px, visible, center0_m=c0, solver=solver)
            break
        except ValueError:
            continue
    centers = {}
    r_cr = r_cr_sd = float("nan")
    if pf is not None and readings:
        centers["literal"] = pf.cornea_centers_m
        lights = pf.correction.apply(L)
        C, R = fit_center_radius(grid.camera, lights, glints_px, visible, center0_m=c0,
                                 radius0_m=pf.cornea_radius_m, radius_bounds_m=CORNEA_RADIUS_BOUNDS_M)
        centers["cr"] = C
        r = stats(R)
        r_cr, r_cr_sd = r["mean"], r["sd"]
        centers["c"] = fit_cornea(FitProblem(grid.camera, lights, pf.cornea_radius_m), glints_px, visible, c0,
                                  model="center").center_m
    jl = None
    if readings:
        jl = calibrate_lighting_joint(grid.camera, L, glints_px, visible, center0_m=c0)
        centers["joint_lighting"] = jl.cornea_centers_m
    joint = calibrate_joint(grid.camera, L, glints_px, ctx.targets25, visible, center0_m=c0)
    return Calibrations(pf, centers, r_cr, r_cr_sd, jl, joint)


def _orbit(method, centers, targets):
    try:
        return orbit_law_of_sines(centers, targets) if method == "los" else orbit_sphere_fit(centers)
    except ValueError:
        return None


def geometric_calibrations(cal: Calibrations, ctx: Context) -> dict:
    """Name -> (Calibration or None, OrbitFit or None) for geometric gaze."""
    out = {}
    for reading in ("literal", "cr", "c"):
        for method in ("los", "sphere"):
            name = f"paper_{reading}_{method}"
            if cal.paper is None:
                out[name] = (None, None)
                continue
            o = _orbit(method, cal.centers[reading], ctx.targets25)
            r_c = cal.radius_cr_m if reading == "cr" else cal.paper.cornea_radius_m
            out[name] = (None if o is None else Calibration(cal.paper.correction, r_c, o.eye_center_m,
                                                            o.orbit_radius_m), o)
    for method in ("los", "sphere"):
        o = _orbit(method, cal.centers["joint_lighting"], ctx.targets25)
        jl = cal.joint_lighting
        out[f"joint_lighting_{method}"] = (None if o is None else Calibration(
            jl.correction, jl.cornea_radius_m, o.eye_center_m, o.orbit_radius_m), o)
    light, orbit = cal.joint
    out["ours_joint"] = (Calibration.from_fits(light, orbit), orbit)
    return out


def lighting_calibrations(cal: Calibrations, ctx: Context) -> dict:
    """Lighting (and r_c) only, for polynomial gaze: ground truth, the paper's, ours."""
    light, _ = cal.joint
    return {"truth": Calibration(ctx.true_correction, ctx.arc.eye.cornea_radius_m),
            "paper": None if cal.paper is None else Calibration(cal.paper.correction, cal.paper.cornea_radius_m),
            "ours": Calibration(light.correction, light.cornea_radius_m)}


def cornea_centers(setup: Setup, cal: Calibration, glints_px, visible, model: str) -> np.ndarray:
    """Polynomial-gaze features: ``"c"`` fits the centre (3 unknowns, the calibrated r_c),
    ``"cr"`` the centre and radius of every sample (4 unknowns)."""
    if model == "c":
        return fit_cornea_centers(setup, cal, glints_px, visible).center_m
    return fit_center_radius(setup.camera, cal.lights_world_m(setup.lights_world_m), glints_px, visible,
                             center0_m=setup.eye.cornea_center(0.0, 0.0), radius0_m=cal.cornea_radius_m,
                             radius_bounds_m=CORNEA_RADIUS_BOUNDS_M)[0]


def fit_mapping(features, targets, kind: str, rank_rtol: float | None = None):
    """A gaze mapping from the finite calibration points (min-norm where rank-deficient), or
    None when too few points remain."""
    f = np.asarray(features, dtype=np.float64)
    keep = np.isfinite(f).all(axis=1)
    kwargs = {} if rank_rtol is None else {"rank_rtol": rank_rtol}
    try:
        return fit_gaze_mapping(f[keep], np.asarray(targets)[keep], kind, degenerate="min_norm", **kwargs)
    except ValueError:
        return None


def _errors(ctx: Context, points) -> np.ndarray:
    return angular_error_deg(points, ctx.targets_grid, ctx.eye_center)


def _nan_errors(ctx: Context) -> np.ndarray:
    return np.full(len(ctx.targets_grid), np.nan)


# --------------------------------------------------------------------------- Fig. 5, Sec. 3.2


def calibration_trial(ctx: Context, noise_px: float, rng: np.random.Generator, *, with_gaze: bool):
    """One Fig. 5 trial: scalars (mm) per quantity; with ``with_gaze`` also the Sec. 3.2 errors
    (degrees, one per accuracy target) and the mapping ranks."""
    obs = simulate_glints(ctx.grid, ctx.targets25, noise_px=noise_px, rng=rng,
                          lights_world_m=ctx.true_lights(ctx.grid))
    cal = calibrate_all(ctx, obs.glints_px, obs.visible)
    eye = ctx.arc.eye
    geo = geometric_calibrations(cal, ctx)
    row = {}
    for name, (_, o) in geo.items():
        row[f"ce_{name}"] = np.nan if o is None else float(np.linalg.norm(o.eye_center_m - eye.rotation_center_m) * 1e3)
        row[f"rco_{name}"] = np.nan if o is None else float((o.orbit_radius_m - eye.cornea_offset_m) * 1e3)
        row[f"rco_abs_{name}"] = abs(row[f"rco_{name}"])
    L_true = ctx.true_lights(ctx.grid)
    light, _ = cal.joint
    fits = {"paper": cal.paper, "joint_lighting": cal.joint_lighting, "ours_joint": light}
    for name, fit in fits.items():
        row[f"rc_{name}"] = np.nan if fit is None else fit.cornea_radius_m * 1e3
        row[f"light_{name}"] = np.nan if fit is None else light_position_error_m(
            fit.correction.apply(ctx.grid.lights_world_m), L_true) * 1e3
    row["rc_paper_within_sd"] = np.nan if cal.paper is None else cal.paper.cornea_radius_sd_m * 1e3
    row["paper_trf_fallback"] = float(cal.paper is not None and cal.paper.method.endswith("trf"))
    row["paper_failed"] = float(cal.paper is None)
    row["rc_paper_cr"] = cal.radius_cr_m * 1e3
    row["rc_paper_cr_within_sd"] = cal.radius_cr_sd_m * 1e3
    if not with_gaze:
        return row, None
    return row, gaze_trial(ctx, cal, geo, noise_px, rng)


MAPPINGS = {  # name -> (kind, calibration targets, rank_rtol)
    "eq1_9": ("eq1", 9, None),
    "eq1_9_truncated": ("eq1", 9, EQ1_9_TRUNCATE_RTOL),
    "eq1_25": ("eq1", 25, None),
    "quadratic_25": ("quadratic", 25, None),
}


def gaze_trial(ctx: Context, cal: Calibrations, geo: dict, noise_px: float, rng) -> dict:
    """Sec. 3.2: errors over the 24 x 15 grid for every method and reading, one trial."""
    arc = ctx.arc
    L_true = ctx.true_lights(arc)
    og = simulate_glints(arc, ctx.targets_grid, noise_px=noise_px, rng=rng, lights_world_m=L_true)
    calib = {n: simulate_glints(arc, T, noise_px=noise_px, rng=rng, lights_world_m=L_true)
             for n, T in ((9, ctx.targets9), (25, ctx.targets25))}
    targets = {9: ctx.targets9, 25: ctx.targets25}
    errors, ranks = {}, {}
    errors["geo_truth"] = _errors(ctx, geometric_gaze(arc, ctx.truth(), og.glints_px, og.visible).point_m)
    for name, (c, _) in geo.items():
        errors[f"geo_{name}"] = _nan_errors(ctx) if c is None else _errors(
            ctx, geometric_gaze(arc, c, og.glints_px, og.visible).point_m)
    for lname, lcal in lighting_calibrations(cal, ctx).items():
        for model in ("c", "cr"):
            if lcal is None:
                for mname in MAPPINGS:
                    errors[f"poly_{mname}_{lname}_{model}"] = _nan_errors(ctx)
                    ranks[f"poly_{mname}_{lname}_{model}"] = np.nan
                continue
            feats = cornea_centers(arc, lcal, og.glints_px, og.visible, model)
            cf = {n: cornea_centers(arc, lcal, o.glints_px, o.visible, model) for n, o in calib.items()}
            for mname, (kind, n, rtol) in MAPPINGS.items():
                mp = fit_mapping(cf[n], targets[n], kind, rtol)
                key = f"poly_{mname}_{lname}_{model}"
                errors[key] = _nan_errors(ctx) if mp is None else _errors(ctx, mp.predict(feats))
                ranks[key] = np.nan if mp is None else mp.rank
    return {"errors": errors, "ranks": ranks}


def solver_check(ctx: Context, cfg: ReproductionConfig) -> dict:
    """The paper's solver (scipy TRF, one sample at a time) against our batched LM on the same
    data at e_f = 0.5 px: the 10-unknown per-frame lighting fits and chained geometric gaze."""
    rng = trial_rng(cfg.seed, 99)
    grid, arc = ctx.grid, ctx.arc
    obs = simulate_glints(grid, ctx.targets25[:cfg.trf_frames], noise_px=NOISE_PX, rng=rng,
                          lights_world_m=ctx.true_lights(grid))
    fits = {s: calibrate_lighting_per_frame(grid.camera, grid.lights_world_m, obs.glints_px, obs.visible,
                                            center0_m=grid.eye.cornea_center(0.0, 0.0), solver=s)
            for s in ("lm", "trf")}
    lm, trf = fits["lm"], fits["trf"]
    og = simulate_glints(arc, ctx.targets_grid[:cfg.trf_samples], noise_px=NOISE_PX, rng=rng,
                         lights_world_m=ctx.true_lights(arc))
    est = {s: geometric_gaze(arc, ctx.truth(), og.glints_px, og.visible, solver=s, chain=(s == "trf"))
           for s in ("lm", "trf")}
    err = {s: angular_error_deg(e.point_m, ctx.targets_grid[:cfg.trf_samples], ctx.eye_center)
           for s, e in est.items()}
    d_angle = angular_error_deg(est["lm"].point_m, est["trf"].point_m, ctx.eye_center)
    return {
        "frames": int(cfg.trf_frames), "samples": int(cfg.trf_samples),
        "frame_center_diff_um": float(np.nanmax(np.linalg.norm(lm.cornea_centers_m - trf.cornea_centers_m,
                                                              axis=1)) * 1e6),
        "frame_radius_diff_um": float(np.nanmax(np.abs(lm.frame_radius_m - trf.frame_radius_m)) * 1e6),
        "light_error_lm_mm": light_position_error_m(lm.correction.apply(grid.lights_world_m),
                                                    ctx.true_lights(grid)) * 1e3,
        "light_error_trf_mm": light_position_error_m(trf.correction.apply(grid.lights_world_m),
                                                     ctx.true_lights(grid)) * 1e3,
        "gaze_lm_deg": float(np.nanmean(err["lm"])), "gaze_trf_deg": float(np.nanmean(err["trf"])),
        "gaze_diff_max_deg": float(np.nanmax(d_angle)),
    }


# --------------------------------------------------------------------------- Fig. 7 and 8


def translated(setup: Setup, offset_m) -> tuple[Setup, np.ndarray]:
    """The setup with its camera and every light moved by ``offset_m`` (the apparatus slipping
    on the face), and the moved lights."""
    offset = np.asarray(offset_m, dtype=np.float64)
    camera = dataclasses.replace(setup.camera, position_m=setup.camera.position_m + offset)
    return dataclasses.replace(setup, camera=camera), setup.lights_world_m + offset


TRANSLATION_METHODS = ("eq1_9_truncated", "eq1_25", "quadratic_25", "geometric", "quadratic_da_27")
#: Directions of the sweeps, scaled by s * TRANSLATION_HALF_M: the paper's x-z and y-z planes,
#: and ours along z alone, the one direction the distance sensor measures.
TRANSLATION_PLANES = {"xz": (1.0, 0.0, 1.0), "yz": (0.0, 1.0, 1.0), "z": (0.0, 0.0, 1.0)}


def translation_trial(ctx: Context, steps, rng) -> dict:
    """Fig. 7 and 8, one trial: accuracy (degrees) per plane, step and method.

    The rig is at its nominal pose when calibrating; lighting, r_c, c_e and r_co are known
    (Sec. 3.3 uses ground-truth c_e and r_co to isolate the translation)."""
    arc = ctx.arc
    truth = Calibration.ground_truth(arc)
    mappings = {}
    for mname in ("eq1_9_truncated", "eq1_25", "quadratic_25"):
        kind, n, rtol = MAPPINGS[mname]
        T = ctx.targets9 if n == 9 else ctx.targets25
        o = simulate_glints(arc, T, noise_px=NOISE_PX, rng=rng)
        mappings[mname] = fit_mapping(cornea_centers(arc, truth, o.glints_px, o.visible, "c"), T, kind, rtol)
    feats, xy = [], []
    for tz in DA_DEPTHS_M:
        s, L = translated(arc, (0.0, 0.0, tz))
        o = simulate_glints(s, ctx.targets9, noise_px=NOISE_PX, rng=rng, lights_world_m=L)
        d = distance_reading(np.full(len(ctx.targets9), tz), arc.distance_sensor, rng)
        feats.append(np.column_stack([cornea_centers(arc, truth, o.glints_px, o.visible, "c"), d]))
        xy.append(ctx.targets9)
    mp_da = fit_mapping(np.concatenate(feats), np.concatenate(xy), "quadratic_da")
    out = {"da_rank": np.nan if mp_da is None else mp_da.rank}
    for plane, direction in TRANSLATION_PLANES.items():
        acc = {m: [] for m in TRANSLATION_METHODS}
        for step in steps:
            offset = step * TRANSLATION_HALF_M * np.asarray(direction)
            s, L = translated(arc, offset)
            og = simulate_glints(s, ctx.targets_grid, noise_px=NOISE_PX, rng=rng, lights_world_m=L)
            C = cornea_centers(arc, truth, og.glints_px, og.visible, "c")
            for mname, mp in mappings.items():
                acc[mname].append(np.nan if mp is None else _mean(_errors(ctx, mp.predict(C))))
            acc["geometric"].append(_mean(_errors(ctx, geometric_gaze(arc, truth, og.glints_px, og.visible).point_m)))
            d = distance_reading(np.full(len(C), offset[2]), arc.distance_sensor, rng)
            acc["quadratic_da_27"].append(np.nan if mp_da is None else _mean(_errors(ctx, mp_da.predict(
                np.column_stack([C, d])))))
        out[plane] = {m: np.asarray(v) for m, v in acc.items()}
    return out


def _mean(x) -> float:
    x = np.asarray(x, dtype=np.float64)
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else float("nan")


# --------------------------------------------------------------------------- orchestration


def run_experiments(cfg: ReproductionConfig, progress=None) -> dict:
    """Run every experiment of ``cfg``; returns plain numbers and arrays (see
    :mod:`scet_render.report` for how they are read)."""
    from scet_render.reproduce_bands import band_trial, summarize_bands

    ctx = make_context()
    n_levels = len(cfg.noise_levels_px)
    total = n_levels * cfg.calibration_trials + 1 + cfg.translation_trials + cfg.band_trials
    done = 0

    def tick(label):
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total, label)

    fig5_rows, gaze = [], []
    for k, ef in enumerate(cfg.noise_levels_px):
        rows = []
        for t in range(cfg.calibration_trials):
            with_gaze = ef == NOISE_PX and t < cfg.gaze_trials
            row, g = calibration_trial(ctx, ef, trial_rng(cfg.seed, 5, k, t), with_gaze=with_gaze)
            rows.append(row)
            if g is not None:
                gaze.append(g)
            tick(f"Fig. 5 / Sec. 3.2: e_f = {ef:.2f} px, trial {t + 1} of {cfg.calibration_trials}")
        fig5_rows.append(rows)
    check = solver_check(ctx, cfg)
    tick("solver check: the paper's TRF against our LM")
    trans = []
    for t in range(cfg.translation_trials):
        trans.append(translation_trial(ctx, cfg.translation_steps, trial_rng(cfg.seed, 7, t)))
        tick(f"Fig. 7 and 8: trial {t + 1} of {cfg.translation_trials}")
    bands = []
    for t in range(cfg.band_trials):
        bands.append(band_trial(ctx, cfg.band_counts, trial_rng(cfg.seed, 9, t)))
        tick(f"Fig. 9: trial {t + 1} of {cfg.band_trials}")
    return {
        "config": dataclasses.asdict(cfg),
        "rig": {"rotation_deg": RIG_ROTATION_DEG, "rotation_axis": tuple(float(v) for v in RIG_ROTATION_AXIS),
                "translation_mm": tuple(float(v) * 1e3 for v in RIG_TRANSLATION_M),
                "pivot_mm": tuple(round(float(v) * 1e3, 3) for v in ctx.grid.lights_world_m.mean(axis=0))},
        "fig5": _summarize_fig5(cfg, fig5_rows),
        "sec32": _summarize_gaze(ctx, gaze),
        "solver_check": check,
        "translation": _summarize_translation(cfg, trans),
        "bands": summarize_bands(cfg.band_counts, bands),
        "targets": {"grid": ctx.targets_grid, "calib9": ctx.targets9, "calib25": ctx.targets25},
        "screen": {"x_range_m": ctx.arc.screen.x_range_m, "y_range_m": ctx.arc.screen.y_range_m},
    }


def stats(values) -> dict:
    """Mean, SD (ddof 1), median and count of the finite values, without warnings."""
    v = np.asarray(values, dtype=np.float64).ravel()
    f = v[np.isfinite(v)]
    if f.size == 0:
        return {"mean": float("nan"), "sd": float("nan"), "median": float("nan"), "n": 0, "n_total": int(v.size)}
    return {"mean": float(f.mean()), "sd": float(f.std(ddof=1)) if f.size > 1 else 0.0,
            "median": float(np.median(f)), "n": int(f.size), "n_total": int(v.size)}


def _summarize_fig5(cfg, rows_per_level) -> dict:
    keys = list(rows_per_level[0][0])
    return {"noise_px": list(cfg.noise_levels_px),
            "series": {k: [stats([r[k] for r in rows]) for rows in rows_per_level] for k in keys}}


def _summarize_gaze(ctx, trials) -> dict:
    """Per method: the paper's statistic (mean and SD over the 360 targets of a trial, averaged
    over trials), the share of failed estimates, and the per-target mean error (Fig. 6)."""
    if not trials:
        return {"trials": 0, "methods": {}, "ranks": {}}
    methods = {}
    for name in trials[0]["errors"]:
        E = np.stack([t["errors"][name] for t in trials])  # (trials, 360)
        per = [summarize_errors(e) for e in E]
        finite = np.isfinite(E)
        counts = finite.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            per_target = np.where(counts > 0, np.where(finite, E, 0.0).sum(axis=0) / np.maximum(counts, 1), np.nan)
        methods[name] = {"mean": _mean([p.mean_deg for p in per]), "sd": _mean([p.sd_deg for p in per]),
                         "sd_of_trial_means": stats([p.mean_deg for p in per])["sd"],
                         "failed_share": float(1 - finite.mean()), "per_target": per_target}
    ranks = {k: stats([t["ranks"][k] for t in trials]) for k in trials[0]["ranks"]}
    return {"trials": len(trials), "methods": methods, "ranks": ranks}


def _summarize_translation(cfg, trials) -> dict:
    out = {"steps": list(cfg.translation_steps), "half_mm": TRANSLATION_HALF_M * 1e3,
           "da_rank": stats([t["da_rank"] for t in trials])}
    for plane in TRANSLATION_PLANES:
        out[plane] = {m: [stats([t[plane][m][i] for t in trials])["mean"] for i in range(len(cfg.translation_steps))]
                      for m in TRANSLATION_METHODS}
    return out


def run_reproduction(out_dir: Path, *, quick: bool, seed: int = 0, progress=None) -> Path:
    """Run every experiment and write ``out_dir/paper-reproduction.md`` and
    ``out_dir/figures/*.png``; returns the report's path. Deterministic for a seed.

    Parameters
    ----------
    out_dir : Path
    quick : bool
        A few trials and levels (under a minute on two cores) instead of the paper's protocol
        (about ten minutes).
    seed : int
    progress : callable, optional
        ``progress(done, total, label)`` after each trial.
    """
    from scet_render.report import write_report

    cfg = config_for(quick, seed)
    results = run_experiments(cfg, progress)
    return write_report(Path(out_dir), results)
