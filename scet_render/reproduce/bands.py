"""Fig. 9 of the SCET paper (Sec. 3.4): accuracy and robustness against the number of bands.

Protocol (the paper's): a 60 Hz camera whose 480 visible rows are cut into ``bands`` bands of
480 / bands rows; a static eye fixates each of the 360 targets of the 24 x 15 grid; a gaze
sample uses only the glints that land in the central band, rows [240 - h/2, 240 + h/2) (a
glint belongs to the band its noise-free reflection lies in; the feature error moves only the
detection). 10 trials; robustness is the share of samples with an error below 5 degrees, and
the accuracy is over that subset.

Methods, all on the same glints of the same trial:

- ``paper_c``: the paper's, second-order polynomial from 25 calibration points, on the cornea
  centre fitted to the band's glints (3 unknowns; the paper's calibrated lighting and r_c);
- ``paper_cr``: the same with the centre and radius fitted per sample (4 unknowns), the reading
  of the paper whose Sec. 3.2 numbers match the paper's;
- ``ours_orbit``: geometric gaze with our joint calibration (c_e and r_co known, so the cornea
  has 2 unknowns and one glint is enough), the band's own glints only;
- ``ours_prior``: the same with a Gaussian prior on the Fick angles from the previous band. The
  previous band is the band just above the central one, rows [240 - 3h/2, 240 - h/2) clipped to
  the image, in the same frame and fixation, fitted to its own glints alone (no prior of its
  own). Prior mean: its estimate; prior covariance: its Gauss-Newton covariance for glint noise
  of SD e_f / sqrt(3) (the uniform feature error's SD) plus eye motion between bands of
  :data:`PRIOR_MOTION_SD_DEG` per axis. One band (the whole image) has no band above it, and
  a band above without an estimate gives no prior: the fit is then ``ours_orbit``'s.

A third lighting, ``sparse`` (every fourth light of the arc, 10 lights), is a stress test of
our own: it leaves bands with no glint, where only borrowing from another band can help.
"""

from __future__ import annotations

import numpy as np

from estimator.calibration import CORNEA_RADIUS_BOUNDS_M, Calibration
from estimator.eye import gaze_direction
from estimator.gaze import screen_intersection
from estimator.metrics import angular_error_deg, summarize_errors

from ..simulate import simulate_glints
from .common import NOISE_PX, Context, calibrate_all, cornea_centers, fit_mapping
from .fits import fit_center_radius, fit_orbit_prior, orbit_covariance

#: Eye motion allowed between two consecutive bands (degrees, SD per Fick angle): a saccade
#: peaks near 600 deg/s, i.e. 0.5 deg in the 0.83 ms between bands at 20 bands per frame; a
#: fixation moves far less, so this prior never pins a moving eye to a stale estimate.
PRIOR_MOTION_SD_DEG = 0.5
#: Every fourth light of the arc, for the ``sparse`` stress lighting.
SPARSE_STRIDE = 4
LIGHTINGS = ("single", "doubled", "sparse")
METHODS = ("paper_c", "paper_cr", "ours_orbit", "ours_prior")


def band_rows(bands: int, height: int = 480) -> tuple[float, float]:
    """First and one-past-last row of the central band of ``bands`` equal bands."""
    h = height / bands
    return height / 2 - h / 2, height / 2 + h / 2


def rows_mask(glints_true_px, visible, first: float, stop: float) -> np.ndarray:
    """(B, n) glints visible and inside rows [first, stop): row y covers v in [y - 1/2, y + 1/2)."""
    v = glints_true_px[..., 1]
    with np.errstate(invalid="ignore"):
        return visible & (v >= first - 0.5) & (v < stop - 0.5)


def _lighting(ctx: Context, name: str):
    """Setup and mask of the lights in use (``sparse`` keeps every fourth light of the arc)."""
    if name == "doubled":
        return ctx.doubled, np.ones(ctx.doubled.lights.count, dtype=bool)
    keep = np.ones(ctx.arc.lights.count, dtype=bool)
    if name == "sparse":
        keep[:] = False
        keep[::SPARSE_STRIDE] = True
    return ctx.arc, keep


def _gaze_points(cal: Calibration, angles, screen_z):
    points, _ = screen_intersection(cal.eye_center_m, gaze_direction(angles[:, 0], angles[:, 1]), screen_z)
    return points


def band_trial(ctx: Context, band_counts, rng: np.random.Generator) -> dict:
    """One Fig. 9 trial: per lighting, band count and method, the errors (degrees) of the 360
    samples, and the number of glints in each sample's band."""
    grid_obs = simulate_glints(ctx.grid, ctx.targets25, noise_px=NOISE_PX, rng=rng,
                               lights_world_m=ctx.true_lights(ctx.grid))
    cal = calibrate_all(ctx, grid_obs.glints_px, grid_obs.visible, readings=False)
    paper = None if cal.paper is None else Calibration(cal.paper.correction, cal.paper.cornea_radius_m)
    ours = Calibration.from_fits(*cal.joint)
    sigma_px = NOISE_PX / np.sqrt(3.0)
    motion = np.deg2rad(PRIOR_MOTION_SD_DEG) ** 2 * np.eye(2)
    out = {}
    for lighting in LIGHTINGS:
        setup, keep = _lighting(ctx, lighting)
        L_true = ctx.true_lights(setup)
        o25 = simulate_glints(setup, ctx.targets25, noise_px=NOISE_PX, rng=rng, lights_world_m=L_true)
        og = simulate_glints(setup, ctx.targets_grid, noise_px=NOISE_PX, rng=rng, lights_world_m=L_true)
        visible = og.visible & keep
        mappings = {}
        for model in ("c", "cr"):
            mappings[model] = None if paper is None else fit_mapping(
                cornea_centers(setup, paper, o25.glints_px, o25.visible & keep, model), ctx.targets25, "quadratic")
        lights = ours.lights_world_m(setup.lights_world_m)

        def orbit(band_mask, mean, cov):
            return fit_orbit_prior(setup.camera, lights, ours.cornea_radius_m, ours.eye_center_m,
                                   ours.orbit_radius_m, og.glints_px, band_mask, prior_mean_rad=mean,
                                   prior_cov_rad2=cov, sigma_px=sigma_px)

        res = {}
        for bands in band_counts:
            first, stop = band_rows(bands, setup.camera.height_px)
            mask = rows_mask(og.glints_true_px, visible, first, stop)
            h = stop - first
            prev = rows_mask(og.glints_true_px, visible, max(first - h, 0.0), first) if first > 0 else None
            errs = {}
            C = None
            for model in ("c", "cr"):
                mp = mappings[model]
                if mp is None:
                    errs[f"paper_{model}"] = np.full(len(ctx.targets_grid), np.nan)
                    continue
                # The centre-only fit, then the radius freed from it (the same first phase).
                C, _ = fit_center_radius(setup.camera, paper.lights_world_m(setup.lights_world_m), og.glints_px,
                                         mask, center0_m=setup.eye.cornea_center(0.0, 0.0),
                                         radius0_m=paper.cornea_radius_m, centers_at_radius0_m=C,
                                         radius_bounds_m=CORNEA_RADIUS_BOUNDS_M if model == "cr" else None)
                errs[f"paper_{model}"] = _err(ctx, mp.predict(C))
            B = len(ctx.targets_grid)
            no_prior = (np.full((B, 2), np.nan), np.full((B, 2, 2), np.nan))
            own, _ = orbit(mask, *no_prior)
            errs["ours_orbit"] = _err(ctx, _gaze_points(ours, own, setup.screen.z_m))
            mu, P = no_prior
            if prev is not None:
                mu, _ = orbit(prev, *no_prior)
                P = orbit_covariance(setup.camera, lights, ours.cornea_radius_m, ours.eye_center_m,
                                     ours.orbit_radius_m, mu, prev, sigma_px) + motion
            angles, held = orbit(mask, mu, P)
            errs["ours_prior"] = _err(ctx, _gaze_points(ours, angles, setup.screen.z_m))
            res[bands] = {"errors": errs, "glints": mask.sum(axis=1), "held": held}
        out[lighting] = res
    return out


def _err(ctx: Context, points) -> np.ndarray:
    return angular_error_deg(points, ctx.targets_grid, ctx.eye_center)


def summarize_bands(band_counts, trials) -> dict:
    """Pool the samples of every trial: per lighting, band count and method the paper's
    statistics (accuracy and SD over the samples below 5 degrees, robustness), plus the share of
    samples whose band holds no glint (an upper bound on the robustness of any method that does
    not borrow from another band) and the mean number of glints per band."""
    out = {}
    for lighting in LIGHTINGS:
        rows = {}
        for bands in band_counts:
            per = [t[lighting][bands] for t in trials]
            glints = np.concatenate([p["glints"] for p in per])
            row = {"rate_hz": 60 * bands, "rows": 480 / bands, "no_glint_share": float(np.mean(glints == 0)),
                   "one_glint_share": float(np.mean(glints == 1)), "glints_mean": float(glints.mean()),
                   "glints_min": int(glints.min()),
                   "held_share": float(np.mean(np.concatenate([p["held"] for p in per])))}
            for m in METHODS:
                s = summarize_errors(np.concatenate([p["errors"][m] for p in per]))
                row[m] = {"accuracy_deg": s.robust_mean_deg, "sd_deg": s.robust_sd_deg,
                          "robustness": s.robustness, "mean_all_deg": s.mean_deg, "failed": s.n_nan, "n": s.n}
            rows[bands] = row
        out[lighting] = rows
    return out
