"""Cornea fits that the paper's reproduction needs and :mod:`estimator.cornea` does not offer.

- :func:`fit_center_radius`: the cornea centre *and* radius of every sample (4 unknowns, known
  lighting). Sec. 3.1 of the SCET paper says each calibration frame involves "estimating the
  corneal center (c_c) and radius (r_c)"; read literally for every gaze sample, this is the
  reading of the paper's polynomial gaze whose numbers match the paper's (see the report).
- :func:`fit_orbit_prior`: geometric gaze (the ``"orbit"`` model, 2 unknowns: Fick angles about
  the calibrated eye centre) with a Gaussian prior on the angles, added as two extra residual
  rows. Used for banded gaze: the previous band's estimate and covariance are the prior of the
  next band, so a band holding one or two glints still gives a well-posed fit.
- :func:`orbit_covariance`: the Gauss-Newton covariance of an orbit fit (the prior's source).

All are batched Levenberg-Marquardt over many samples at once, on the closed-form glint
Jacobians of :func:`estimator.projection.glint_jacobians`; bounds are enforced by projecting
each step onto the box.
"""

from __future__ import annotations

import numpy as np

from estimator.camera import Camera
from estimator.eye import gaze_direction
from estimator.gaze import ANGLE_BOUND_RAD
from estimator.projection import glint_jacobians

#: Stopping rules: a step below this in every unknown (m or rad), or a relative change of the
#: cost below ``_FTOL``. 1e-9 m is 1e-7 of the corneal radius and 1e-9 rad is 6e-8 degrees,
#: four orders of magnitude below what 0.5 px of glint noise resolves.
_XTOL = 1e-9
_FTOL = 1e-10
_MAX_LAMBDA = 1e12


def _lm(fun, x0, lo, hi, max_iter):
    """Batched Levenberg-Marquardt with Marquardt scaling, an active set on the bounds and steps
    projected onto [lo, hi] (the scheme of :func:`estimator.cornea.fit_cornea`).

    ``fun(x (b, p), idx (b,))`` returns residuals (b, m) and Jacobians (b, m, p) of the samples
    ``idx``. Returns the parameters (B, p), the final cost (B,) and whether each converged."""
    B, p = x0.shape
    x = np.clip(x0, lo, hi)
    every = np.arange(B)
    r, J = fun(x, every)
    cost = np.einsum("bi,bi->b", r, r)
    lam = np.full(B, 1e-3)
    nu = np.full(B, 2.0)
    active = np.isfinite(cost)
    converged = np.zeros(B, dtype=bool)
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        Ji, ri = J[idx], r[idx]
        Jt = Ji.transpose(0, 2, 1)
        JtJ = Jt @ Ji
        g = (Jt @ ri[..., None])[..., 0]
        diag = np.maximum(np.einsum("bii->bi", JtJ), 1e-30)
        A = JtJ + (lam[idx, None] * diag)[..., None] * np.eye(p)
        # Active set: an unknown on a bound that the gradient pushes outward is held there, so
        # the others still reach the constrained minimum (a clipped step would zig-zag).
        xi = x[idx]
        held = ((xi <= lo) & (g > 0)) | ((xi >= hi) & (g < 0))
        if held.any():
            free = ~held
            A = A * free[:, :, None] * free[:, None, :] + held[:, :, None] * np.eye(p)
            g = g * free
        step = -np.linalg.solve(A, g[..., None])[..., 0]
        x_new = np.clip(x[idx] + step, lo, hi)
        with np.errstate(invalid="ignore", over="ignore"):
            r_new, J_new = fun(x_new, idx)
        cost_new = np.einsum("bi,bi->b", r_new, r_new)
        better = np.isfinite(cost_new) & (cost_new <= cost[idx])
        small = (np.abs(x_new - x[idx]) <= _XTOL * np.maximum(1.0, np.abs(x[idx]))).all(axis=1)
        flat = np.abs(cost[idx] - cost_new) <= _FTOL * np.maximum(cost[idx], 1e-30)
        # Nielsen's damping update (1999): shrink by the gain ratio rho of actual to predicted
        # reduction, grow geometrically on failure; converges in a few steps along the narrow
        # valleys of the centre-and-radius problem, where a fixed factor of 10 oscillates.
        h = x_new - x[idx]
        pred = -(2 * np.einsum("bi,bi->b", h, g) + np.einsum("bi,bij,bj->b", h, JtJ, h))
        with np.errstate(invalid="ignore", divide="ignore"):
            rho = np.where(pred > 0, (cost[idx] - cost_new) / pred, 0.0)
        acc = idx[better]
        x[acc], r[acc], J[acc], cost[acc] = x_new[better], r_new[better], J_new[better], cost_new[better]
        lam[acc] = np.maximum(lam[acc] * np.maximum(1 / 3, 1 - (2 * np.clip(rho[better], 0, 1) - 1) ** 3), 1e-12)
        nu[acc] = 2.0
        rej = idx[~better]
        lam[rej] *= nu[rej]
        nu[rej] *= 2
        # Converged: a step that changes nothing (accepted or not: at the minimum rounding
        # decides), or a damping so large that no step lowers the cost.
        done = small | flat | (~better & (lam[idx] > _MAX_LAMBDA))
        converged[idx[done]] = True
        active[idx[done]] = False
    return x, cost, converged


def _check_glints(glints_px, mask, n):
    g = np.asarray(glints_px, dtype=np.float64)
    if g.ndim != 3 or g.shape[1:] != (n, 2):
        raise ValueError(f"glints_px must have shape (B, {n}, 2), got {g.shape}")
    m = np.isfinite(g).all(-1) if mask is None else np.asarray(mask, dtype=bool) & np.isfinite(g).all(-1)
    if m.shape != g.shape[:2]:
        raise ValueError(f"mask must have shape {g.shape[:2]}, got {m.shape}")
    return np.where(m[..., None], g, 0.0), m


def _gather(glints, mask, lights):
    """Each sample's seen glints first, cut to the largest count k: glints (B, k, 2), mask
    (B, k) and the matching lights (B, k, 3). A band holds a few of the n lights' glints, and
    the projection costs per (sample, light) pair, so this makes banded fits n / k times cheaper."""
    k = max(int(mask.sum(axis=1).max()), 1)
    order = np.argsort(~mask, axis=1, kind="stable")[:, :k]
    return (np.take_along_axis(glints, order[..., None], axis=1), np.take_along_axis(mask, order, axis=1),
            lights[order])


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
        None: the radius stays at ``radius0_m`` (the ``"center"`` model of
        :func:`estimator.cornea.fit_cornea`, on gathered glints).
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
    B = glints.shape[0]
    center = np.full((B, 3), np.nan)
    radius = np.full(B, np.nan)
    idx_ok = np.flatnonzero(m.sum(axis=1) >= 2)
    if idx_ok.size == 0:
        return center, radius
    gl, mk, lk = _gather(glints[idx_ok], m[idx_ok], L)

    def fun(x, idx):
        r_c = x[:, 3] if x.shape[1] == 4 else radius0_m
        g, _, d_c, d_r, _ = glint_jacobians(camera, x[:, :3], r_c, lk[idx], radius_and_lights=x.shape[1] == 4)
        res = np.where(mk[idx][..., None], g - gl[idx], 0.0)
        J = d_c if x.shape[1] == 3 else np.concatenate([d_c, d_r[..., None]], axis=-1)
        J = np.where(mk[idx][..., None, None], J, 0.0)
        b = idx.size
        return res.reshape(b, -1), J.reshape(b, -1, x.shape[1])

    if centers_at_radius0_m is None:
        x0 = np.broadcast_to(np.asarray(center0_m, dtype=np.float64), (idx_ok.size, 3)).copy()
        x, _, conv = _lm(fun, x0, np.full(3, -np.inf), np.full(3, np.inf), max_iter)
    else:
        x = np.asarray(centers_at_radius0_m, dtype=np.float64)[idx_ok]
        conv = np.isfinite(x).all(axis=1)
        x = np.where(conv[:, None], x, np.asarray(center0_m, dtype=np.float64))
    r = np.full(idx_ok.size, radius0_m)
    if radius_bounds_m is not None:
        x4 = np.column_stack([x, r])
        lo = np.array([-np.inf, -np.inf, -np.inf, radius_bounds_m[0]])
        hi = np.array([np.inf, np.inf, np.inf, radius_bounds_m[1]])
        x4, _, conv4 = _lm(fun, x4, lo, hi, max_iter)
        x, r, conv = x4[:, :3], x4[:, 3], conv & conv4
    good = idx_ok[conv]
    center[good], radius[good] = x[conv], r[conv]
    return center, radius


def _orbit_jacobian(camera, lights, r_c, c_e, r_co, angles):
    """Glints (b, k, 2) and d glint / d (yaw, pitch) (b, k, 2, 2) on the orbit, for lights
    (k, 3) or (b, k, 3)."""
    yaw, pitch = angles[:, 0], angles[:, 1]
    center = c_e + r_co * gaze_direction(yaw, pitch)
    g, _, d_c, _, _ = glint_jacobians(camera, center, r_c, lights, radius_and_lights=False)
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    dd = np.stack([np.stack([cp * cy, np.zeros_like(cy), cp * sy], -1),
                   np.stack([-sp * sy, cp, sp * cy], -1)], -1) * r_co  # (b, 3, 2)
    return g, d_c @ dd[:, None]


def orbit_covariance(camera: Camera, lights_world_m, cornea_radius_m: float, eye_center_m,
                     orbit_radius_m: float, angles_rad, mask, sigma_px: float) -> np.ndarray:
    """(B, 2, 2) Gauss-Newton covariance (rad²) of orbit fits at ``angles_rad`` with glint noise
    of standard deviation ``sigma_px`` on each axis: sigma² (Jᵀ J)⁻¹ over the glints in ``mask``.
    Infinite where the angles are not finite or the glints do not determine both angles."""
    a = np.asarray(angles_rad, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    B = a.shape[0]
    cov = np.full((B, 2, 2), np.inf)
    ok = np.isfinite(a).all(axis=1) & m.any(axis=1)
    if not ok.any():
        return cov
    L = np.asarray(lights_world_m, dtype=np.float64)
    _, mk, lk = _gather(np.zeros(m[ok].shape + (2,)), m[ok], L)
    _, J = _orbit_jacobian(camera, lk, cornea_radius_m, np.asarray(eye_center_m, float), orbit_radius_m, a[ok])
    J = np.where(mk[..., None, None], J, 0.0).reshape(ok.sum(), -1, 2)
    info = J.transpose(0, 2, 1) @ J
    det = info[:, 0, 0] * info[:, 1, 1] - info[:, 0, 1] ** 2
    well = det > 1e-12 * np.einsum("bii->b", info) ** 2
    sub = np.full((ok.sum(), 2, 2), np.inf)
    if well.any():
        sub[well] = sigma_px ** 2 * np.linalg.inv(info[well])
    cov[ok] = sub
    return cov


def fit_orbit_prior(camera: Camera, lights_world_m, cornea_radius_m: float, eye_center_m,
                    orbit_radius_m: float, glints_px, mask, *, prior_mean_rad, prior_cov_rad2,
                    sigma_px: float, max_iter: int = 200):
    """Orbit fit (Fick angles about c_e) with a Gaussian prior on the angles.

    Minimises Σ |g_i(θ) - ĝ_i|² / σ² + (θ - μ)ᵀ P⁻¹ (θ - μ): the glint rows of
    :func:`estimator.cornea.fit_cornea` (``"orbit"``) whitened by the glint noise ``sigma_px``,
    plus two prior rows. A sample without a prior (non-finite ``prior_mean_rad`` or
    ``prior_cov_rad2``) is a plain orbit fit from the primary position; a sample with a prior
    and no glint returns the prior mean (the estimate is held from the previous band).

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
    c_e = np.asarray(eye_center_m, dtype=np.float64)
    glints, m = _check_glints(glints_px, mask, L.shape[0])
    B = glints.shape[0]
    mu = np.asarray(prior_mean_rad, dtype=np.float64).reshape(B, 2)
    P = np.asarray(prior_cov_rad2, dtype=np.float64).reshape(B, 2, 2)
    has_prior = np.isfinite(mu).all(axis=1) & np.isfinite(P).all(axis=(1, 2))
    # Prior rows W (θ - μ) with Wᵀ W = P⁻¹; zero rows where there is no prior.
    W = np.zeros((B, 2, 2))
    if has_prior.any():
        w, V = np.linalg.eigh(P[has_prior])
        W[has_prior] = (V / np.sqrt(np.maximum(w, 1e-30))[:, None, :]).transpose(0, 2, 1)
    mu0 = np.where(has_prior[:, None], mu, 0.0)
    n_glints = m.sum(axis=1)
    solvable = has_prior | (n_glints >= 1)
    angles = np.full((B, 2), np.nan)
    idx_ok = np.flatnonzero(solvable)
    if idx_ok.size:
        gl, mk, lk = _gather(glints[idx_ok], m[idx_ok], L)
        Wk, muk = W[idx_ok], mu0[idx_ok]

        def fun(x, idx):
            g, J = _orbit_jacobian(camera, lk[idx], cornea_radius_m, c_e, orbit_radius_m, x)
            res = np.where(mk[idx][..., None], g - gl[idx], 0.0) / sigma_px
            J = np.where(mk[idx][..., None, None], J, 0.0) / sigma_px
            b = idx.size
            prior_res = np.einsum("bij,bj->bi", Wk[idx], x - muk[idx])
            return (np.concatenate([res.reshape(b, -1), prior_res], axis=1),
                    np.concatenate([J.reshape(b, -1, 2), Wk[idx]], axis=1))

        lim = np.full(2, ANGLE_BOUND_RAD)
        x, _, conv = _lm(fun, muk.copy(), -lim, lim, max_iter)
        angles[idx_ok[conv]] = x[conv]
    held = has_prior & (n_glints == 0) & np.isfinite(angles).all(axis=1)
    return angles, held
