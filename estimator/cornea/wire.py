"""Cornea fits with the wire mirror's virtual sources (issue 35 c): the spherical fit's unknowns,
the glints of the highlights that move with the cornea.

A calibration with ``light_model = "wire_mirror"`` (:class:`estimator.calibration.Calibration`)
says that the turns of the rig's wire mirror are not fixed point lights but the LED's
highlights on the turns, W_k(c), which follow the cornea centre c
(:mod:`estimator.geometry.wire_fast`). :func:`fit_cornea_wire` keeps the unknowns of
:func:`estimator.cornea.fit_cornea`'s ``"center"`` (c) and ``"orbit"`` (the Fick angles of c
about c_e) models and fits them by a batched Levenberg-Marquardt on the glints of those
sources, its Jacobian the total derivative of :func:`~estimator.geometry.wire_fast.wire_glints_jacobian`
(the highlight's motion included). It starts where the caller's point-source fit ended (the
calibrated point lights: within ~1 deg of the answer on prototype_ov5647_wire) and takes 3-4
iterations there. The sources' derivative dW/dc is differenced once, at the start, and held
(a chord: it is 5-9 % of the Jacobian and changes little over the fit's steps); each iteration
solves the sources from their first-order prediction W + dW/dc Δc, a few rounds. An optional Gaussian prior (as ``fit_cornea``'s) adds
(x - μ)ᵀ Λ (x - μ) to the cost.
"""

from __future__ import annotations

import numpy as np

from ..geometry.wire_fast import WireLights, wire_glints_jacobian
from .problem import NON_FINITE, NOT_CONVERGED, OK, TOO_FEW_GLINTS, CorneaFit, FitProblem
from .solve import orbit_derivative, unpack

__all__ = ["fit_cornea_wire", "refit_on_wire", "FIT_SOURCE_TOL_M", "WIRE_XTOL", "WIRE_MAX_ITERATIONS"]

#: The iterations stop when an accepted step moves the cornea centre by less than this (m)
#: (for the orbit's angles: r_co times the step in rad): 1e-10 m is 1e-4 of the ~1 um scatter
#: 0.5 px of glint noise leaves in a band's centre; noise-free fits end at ~1e-13 m.
WIRE_XTOL = 1e-10
#: ... or when an accepted step lowers the cost by less than this share of it (noisy glints:
#: a weakly determined depth can keep stepping while the cost is flat).
WIRE_FTOL = 1e-12
#: The sources' tolerance inside the fits (m): 1e-11 m of highlight is ~1e-8 px of glint
#: (the cornea's 0.13x at 643-1300 px / 30 mm), far below any glint's noise, and saves the
#: alternation's last rounds.
FIT_SOURCE_TOL_M = 1e-11
#: Most iterations from the point-source start; 2-5 are typical.
WIRE_MAX_ITERATIONS = 30
_LAMBDA0 = 1e-6


def _centers(model, problem: FitProblem, x):
    """(B, 3) cornea centres and (B, 3, p) their derivative."""
    c = unpack(model, problem, x)[0]
    if model == "orbit":
        return c, orbit_derivative(problem, x)
    return c, np.broadcast_to(np.eye(3), (x.shape[0], 3, 3))


def fit_cornea_wire(problem: FitProblem, lights: WireLights, glints_px, mask, x0, *,
                    model: str = "orbit", lower=None, upper=None,
                    max_iter: int = WIRE_MAX_ITERATIONS, prior_mean=None,
                    prior_information=None) -> CorneaFit:
    """Fit the cornea to the glints of the virtual sources (module docstring).

    Parameters
    ----------
    problem : FitProblem
        Camera, r_c, and for ``"orbit"`` c_e and r_co (its lights are not used).
    lights : WireLights
        The calibrated lights with the wire turns' virtual sources.
    glints_px : (B, n, 2) float
    mask : (B, n) bool
        The glints seen.
    x0 : (B, p) float
        Start, e.g. the point-source fit's answer.
    model : {"center", "orbit"}
    lower, upper : (p,) float, optional
        Bounds (steps are clipped to them).
    prior_mean : (B, p) float, optional
    prior_information : (B, p, p) float, optional
        As :func:`estimator.cornea.fit_cornea`; a sample whose mean is not finite has none.

    Returns
    -------
    CorneaFit
    """
    if model not in ("center", "orbit"):
        raise ValueError(f"model must be 'center' or 'orbit', got {model!r}")
    glints = np.asarray(glints_px, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool) & np.isfinite(glints).all(axis=-1)
    B, n = mask.shape
    if n != lights.count:
        raise ValueError(f"glints_px must have shape (B, {lights.count}, 2), got {glints.shape}")
    x = np.array(np.broadcast_to(np.asarray(x0, dtype=np.float64), (B, 3 if model == "center" else 2)))
    p = x.shape[1]
    lo = np.full(p, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(p, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    # Each sample's seen glints first, cut to the largest count k (a band holds a few of the
    # lights' glints, and the sources cost per glint).
    n_seen = mask.sum(axis=1)
    k = max(int(n_seen.max(initial=0)), 1)
    order = np.argsort(~mask, axis=1, kind="stable")[:, :k]
    glints = np.where(mask[..., None], glints, 0.0)
    glints = np.take_along_axis(glints, order[..., None], axis=1)
    mask = np.take_along_axis(mask, order, axis=1)
    has_prior = np.zeros(B, dtype=bool)
    if prior_mean is not None:
        mu = np.broadcast_to(np.asarray(prior_mean, dtype=np.float64), (B, p))
        info = np.broadcast_to(np.asarray(prior_information, dtype=np.float64), (B, p, p))
        has_prior = np.isfinite(mu).all(axis=1) & np.isfinite(info).all(axis=(1, 2))
        mu, info = np.where(has_prior[:, None], mu, 0.0), np.where(has_prior[:, None, None], info, 0.0)
    enough = (2 * mask.sum(axis=1) >= p) | has_prior
    start_ok = np.isfinite(x).all(axis=1)
    scale = problem.orbit_radius_m if model == "orbit" else 1.0

    def evaluate(xs, idx, W, dW=None, c_old=None):
        c, D = _centers(model, problem, xs)
        if W is not None and dW is not None:  # predict the sources to first order
            W = W + np.einsum("bnij,bj->bni", dW, c - c_old)
        g, Jc, W_new, ok, dW = wire_glints_jacobian(problem.camera, lights, c, problem.cornea_radius_m,
                                                    W, d_sources=dW, tol_m=FIT_SOURCE_TOL_M,
                                                    light_index=order[idx])
        m = mask[idx]
        r = np.where(m[..., None], g - glints[idx], 0.0)
        J = np.where(m[..., None, None], Jc @ D[:, None], 0.0).reshape(len(idx), 2 * k, p)
        r = r.reshape(len(idx), 2 * k)
        cost = np.einsum("bi,bi->b", r, r)
        JtJ = np.swapaxes(J, 1, 2) @ J
        Jtr = np.einsum("bij,bi->bj", J, r)
        if prior_mean is not None:
            d = xs - mu[idx]
            Ld = np.einsum("bij,bj->bi", info[idx], d)
            cost, JtJ, Jtr = cost + np.einsum("bi,bi->b", d, Ld), JtJ + info[idx], Jtr + Ld
        good = np.isfinite(cost) & (ok | ~m).all(axis=1)
        return np.where(good, cost, np.inf), JtJ, Jtr, W_new, dW, c

    run = np.flatnonzero(enough & start_ok)
    cost = np.full(B, np.inf)
    JtJ, Jtr = np.zeros((B, p, p)), np.zeros((B, p))
    W = np.full((B, k, 3), np.nan)
    dW = np.zeros((B, k, 3, 3))
    C = np.full((B, 3), np.nan)
    iters = np.zeros(B, dtype=int)
    converged = np.zeros(B, dtype=bool)
    lam = np.full(B, _LAMBDA0)
    if run.size:
        cost[run], JtJ[run], Jtr[run], W[run], dW[run], C[run] = evaluate(x[run], run, None)
    active = np.zeros(B, dtype=bool)
    active[run] = np.isfinite(cost[run])
    diag = slice(None, None, p + 1)
    for _ in range(max_iter):
        idx = np.flatnonzero(active & ~converged)
        if idx.size == 0:
            break
        A = JtJ[idx].copy()
        A.reshape(-1, p * p)[:, diag] += lam[idx, None] * np.maximum(JtJ[idx].reshape(-1, p * p)[:, diag], 1e-30)
        with np.errstate(invalid="ignore", over="ignore"):
            step = -np.linalg.solve(A, Jtr[idx][..., None])[..., 0]
        x_new = np.clip(x[idx] + step, lo, hi)
        usable = np.isfinite(x_new).all(axis=1)
        iters[idx] += 1
        lam[idx[~usable]] *= 10
        idx, x_new = idx[usable], x_new[usable]
        if idx.size == 0:
            continue
        with np.errstate(invalid="ignore", over="ignore"):
            c_new, H_new, g_new, W_new, _, C_new = evaluate(x_new, idx, W[idx], dW[idx], C[idx])
        better = c_new <= cost[idx]
        moved = scale * np.abs(x_new - x[idx]).max(axis=1)
        flat = np.abs(cost[idx] - c_new) <= WIRE_FTOL * np.maximum(cost[idx], 1e-30)
        acc = idx[better]
        x[acc], cost[acc], JtJ[acc], Jtr[acc], W[acc], C[acc] = (
            x_new[better], c_new[better], H_new[better], g_new[better], W_new[better], C_new[better])
        lam[acc] = np.maximum(lam[acc] / 10, 1e-12)
        lam[idx[~better]] *= 10
        converged[idx[(better & ((moved <= WIRE_XTOL) | flat | (c_new == 0)))
                      | (~better & (lam[idx] > 1e12))]] = True
    if prior_mean is not None:
        d = x - mu
        cost = cost - np.einsum("bi,bij,bj->b", d, info, d)
    rms = np.sqrt(np.maximum(cost, 0.0) / np.maximum(n_seen, 1))
    reason = np.full(B, OK, dtype=object)
    reason[~converged] = NOT_CONVERGED
    reason[enough & ~(active & np.isfinite(x).all(axis=1))] = NON_FINITE
    reason[~enough] = TOO_FEW_GLINTS
    ok = reason == OK
    c = _centers(model, problem, np.where(ok[:, None], x, 0.0))[0]
    nan3 = np.full((B, 3), np.nan)
    return CorneaFit(np.where(ok[:, None], c, np.nan), np.full(B, problem.cornea_radius_m),
                     np.where(ok[:, None], x, np.nan) if model == "orbit" else np.full((B, 2), np.nan),
                     nan3, nan3.copy(), np.where(ok, rms, np.nan), n_seen, iters,
                     reason.astype(str))


def refit_on_wire(problem: FitProblem, lights: WireLights, glints_px, mask, point_fit: CorneaFit,
                  model: str, start, *, lower=None, upper=None, prior_mean=None,
                  prior_information=None) -> CorneaFit:
    """:func:`fit_cornea_wire` started from a point-source fit's answers (``start`` (p,) where
    that fit failed): the estimators' second step for a ``"wire_mirror"`` calibration."""
    x_point = point_fit.angles_rad if model == "orbit" else point_fit.center_m
    x0 = np.where(np.isfinite(x_point).all(axis=1)[:, None], x_point,
                  np.broadcast_to(np.asarray(start, dtype=np.float64), x_point.shape))
    if prior_mean is not None:
        mu = np.broadcast_to(np.asarray(prior_mean, dtype=np.float64), x0.shape)
        x0 = np.where(np.isfinite(x_point).all(axis=1)[:, None] | ~np.isfinite(mu).all(axis=1)[:, None],
                      x0, mu)
    return fit_cornea_wire(problem, lights, glints_px, mask, x0, model=model, lower=lower,
                           upper=upper, prior_mean=prior_mean, prior_information=prior_information)
