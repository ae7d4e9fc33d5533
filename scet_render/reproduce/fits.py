"""Cornea fits in the shape the paper's reproduction needs, on :func:`estimator.cornea.fit_cornea`.

- :func:`fit_center_radius`: the cornea centre *and* radius of every sample (4 unknowns, known
  lighting). Sec. 3.1 of the SCET paper says each calibration frame involves "estimating the
  corneal center (c_c) and radius (r_c)"; read literally for every gaze sample, this is the
  reading of the paper's polynomial gaze whose numbers match the paper's (see the report).
  The centre is fitted at a given radius first, then the radius is freed within bounds.
- :func:`fit_orbit_prior`: geometric gaze (the ``"orbit"`` model, 2 unknowns: Fick angles about
  the calibrated eye centre) with a Gaussian prior on the angles. Used for banded gaze: the
  previous band's estimate and covariance are the prior of the next band, so a band holding
  one or two glints still gives a well-posed fit.
- :func:`orbit_covariance`: the Gauss-Newton covariance of an orbit fit (the prior's source).
"""

from __future__ import annotations

import numpy as np

from estimator.cornea import FitProblem, fit_cornea, fit_covariance
from estimator.gaze import ANGLE_BOUND_RAD
from estimator.geometry import Camera


def _check_glints(glints_px, mask, n):
    g = np.asarray(glints_px, dtype=np.float64)
    if g.ndim != 3 or g.shape[1:] != (n, 2):
        raise ValueError(f"glints_px must have shape (B, {n}, 2), got {g.shape}")
    m = np.isfinite(g).all(-1) if mask is None else np.asarray(mask, dtype=bool) & np.isfinite(g).all(-1)
    if m.shape != g.shape[:2]:
        raise ValueError(f"mask must have shape {g.shape[:2]}, got {m.shape}")
    return g, m


def fit_center_radius(camera: Camera, lights_world_m, glints_px, mask, *, center0_m, radius0_m: float,
                      radius_bounds_m: tuple[float, float] | None, centers_at_radius0_m=None,
                      max_iter: int = 200):
    """Cornea centre, and radius unless ``radius_bounds_m`` is None, of each sample (4 or 3
    unknowns; lighting known).

    With a free radius, the centre is first fitted at ``radius0_m`` and the radius is then
    freed within ``radius_bounds_m`` (the paper's bounds, from Read et al. 2006).

    Parameters
    ----------
    camera : Camera
    lights_world_m : (n, 3) float
    glints_px : (B, n, 2) float
        Detected glints (NaN = missing).
    mask : (B, n) bool or None
    center0_m : (3,) float
        Start of the fit (the primary position, as the paper).
    radius0_m : float
    radius_bounds_m : (2,) float or None
        None: the radius stays at ``radius0_m`` (the ``"center"`` model).
    centers_at_radius0_m : (B, 3) float, optional
        The centres already fitted at ``radius0_m`` to the same glints (this function's result
        with ``radius_bounds_m=None``): the radius is freed from there, skipping the first fit.

    Returns
    -------
    center_m : (B, 3) float
        NaN where too few glints were seen (2 for 3 or 4 unknowns) or the fit failed.
    radius_m : (B,) float
    """
    L = np.asarray(lights_world_m, dtype=np.float64)
    glints, m = _check_glints(glints_px, mask, L.shape[0])
    problem = FitProblem(camera, L, radius0_m)
    c0 = np.asarray(center0_m, dtype=np.float64)
    if centers_at_radius0_m is None:
        centers = fit_cornea(problem, glints, m, c0, model="center", max_iter=max_iter).center_m
    else:
        centers = np.asarray(centers_at_radius0_m, dtype=np.float64).reshape(glints.shape[0], 3)
    radius = np.where(np.isfinite(centers).all(axis=1), radius0_m, np.nan)
    if radius_bounds_m is None:
        return centers, radius
    ok = np.isfinite(centers).all(axis=1)
    x0 = np.column_stack([np.where(ok[:, None], centers, c0), np.full(len(centers), radius0_m)])
    fit = fit_cornea(problem, glints, m & ok[:, None], x0, model="center_radius", max_iter=max_iter,
                     lower=[-np.inf, -np.inf, -np.inf, radius_bounds_m[0]],
                     upper=[np.inf, np.inf, np.inf, radius_bounds_m[1]])
    return fit.center_m, np.where(fit.ok, fit.radius_m, np.nan)


def orbit_covariance(camera: Camera, lights_world_m, cornea_radius_m: float, eye_center_m,
                     orbit_radius_m: float, angles_rad, mask, sigma_px: float) -> np.ndarray:
    """(B, 2, 2) Gauss-Newton covariance (rad²) of orbit fits at ``angles_rad`` with glint noise
    of standard deviation ``sigma_px`` on each axis: sigma² (Jᵀ J)⁻¹ over the glints in ``mask``.
    Infinite where the angles are not finite or the glints do not determine both angles."""
    problem = FitProblem(camera, lights_world_m, cornea_radius_m, eye_center_m, orbit_radius_m)
    return fit_covariance(problem, angles_rad, mask, model="orbit", noise_px=sigma_px)


def fit_orbit_prior(camera: Camera, lights_world_m, cornea_radius_m: float, eye_center_m,
                    orbit_radius_m: float, glints_px, mask, *, prior_mean_rad, prior_cov_rad2,
                    sigma_px: float, max_iter: int = 200):
    """Orbit fit (Fick angles about c_e) with a Gaussian prior on the angles.

    Minimises Σ |g_i(θ) - ĝ_i|² / σ² + (θ - μ)ᵀ P⁻¹ (θ - μ): the ``"orbit"`` model of
    :func:`estimator.cornea.fit_cornea` with the prior information σ² P⁻¹. A sample without a
    prior (non-finite ``prior_mean_rad`` or ``prior_cov_rad2``) is a plain orbit fit from the
    primary position; a sample with a prior and no glint returns the prior mean (the estimate
    is held from the previous band).

    Parameters
    ----------
    glints_px : (B, n, 2) float
    mask : (B, n) bool or None
    prior_mean_rad : (B, 2) float
    prior_cov_rad2 : (B, 2, 2) float
    sigma_px : float

    Returns
    -------
    angles_rad : (B, 2) float
        NaN where neither glints nor a prior determine the angles, or the fit failed.
    held : (B,) bool
        True where the band had no glint and the estimate is the prior mean.
    """
    L = np.asarray(lights_world_m, dtype=np.float64)
    glints, m = _check_glints(glints_px, mask, L.shape[0])
    B = glints.shape[0]
    mu = np.asarray(prior_mean_rad, dtype=np.float64).reshape(B, 2)
    P = np.asarray(prior_cov_rad2, dtype=np.float64).reshape(B, 2, 2)
    has_prior = np.isfinite(mu).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
    info = np.full((B, 2, 2), np.nan)
    if has_prior.any():
        # σ² P⁻¹, through the eigen-decomposition so that a near-singular P stays finite.
        w, V = np.linalg.eigh(P[has_prior])
        info[has_prior] = sigma_px ** 2 * (V / np.maximum(w, 1e-30)[:, None, :]) @ V.transpose(0, 2, 1)
    problem = FitProblem(camera, L, cornea_radius_m, eye_center_m, orbit_radius_m)
    lim = np.full(2, ANGLE_BOUND_RAD)
    fit = fit_cornea(problem, glints, m, np.where(has_prior[:, None], mu, 0.0), model="orbit",
                     lower=-lim, upper=lim, max_iter=max_iter, prior_mean=mu, prior_information=info)
    angles = fit.angles_rad
    held = has_prior & (m.sum(axis=1) == 0) & np.isfinite(angles).all(axis=1)
    return angles, held
