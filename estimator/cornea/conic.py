"""Cornea fits on a conic (aspheric) cornea: the spherical fit's unknowns, the conic's glints.

The cornea is a conic of revolution (apex radius r_c, conic constant Q;
:mod:`estimator.geometry.conic`) about the optical axis, the direction from the eye centre
c_e to the cornea centre c (the apex's centre of curvature, what the spherical fit aims at);
its apex is c + r_c (c - c_e) / |c - c_e|. The unknowns stay those of the sphere's models
(``"center"``: c; ``"orbit"``: the Fick angles of c about c_e), so a band needs no more
glints than on the sphere. :func:`fit_cornea_conic`:

1. fits the sphere (:func:`estimator.cornea.fit_cornea`, unchanged), which lands a few
   hundred um from the conic's answer at Q = -0.25;
2. from there runs a batched Levenberg-Marquardt on the conic's residuals (the exact conic
   reflections of :func:`estimator.geometry.project_glints_conic`), its Jacobian by central
   differences, the 2p + 1 poses of every sample in one projection.

Measured on paper_sim's 24 x 15 grid, noise-free glints, true calibration, every visible
glint: at Q = -0.25 both models recover the true centre to 4e-16 m (max) after 2-4 conic
iterations; at Q = -0.45 the orbit model to 6e-16 m, the centre model all but 1 of 360. The
alternative, fitting the sphere to glints corrected by the model difference (conic(c_k) -
sphere(c_k)) at the current estimate and iterating to a fixed point, converges linearly (its
normal equations lack the difference's own derivative): after 12 rounds the centre model was
still up to 234 um off (median 3e-10 m) at Q = -0.25, at the cost of 12 spherical fits.
"""

from __future__ import annotations

import numpy as np

from ..eye import gaze_direction
from ..geometry import project_glints_conic
from .fit import fit_cornea
from .problem import NON_FINITE, NOT_CONVERGED, OK, CorneaFit, FitProblem

#: The cornea models a calibration may record. ``"sphere"``: the paper's; ``"conic"``: a conic
#: of revolution about the optical axis with a calibrated conic constant Q.
CORNEA_MODELS = ("sphere", "conic")
#: Accepted conic constants: -1 < Q <= 1, as the scene's ``[eye] cornea_asphericity``
#: (Q <= -1 is no closed surface).
ASPHERICITY_RANGE = (-1.0, 1.0)
#: The conic iterations stop when a step moves the cornea centre by less than this (m): 1e-9 m
#: is a thousandth of the ~1 um scatter that 0.5 px of glint noise leaves in a band's centre
#: (noise-free, the fits above end 4e-16 m from the truth: the convergence is quadratic).
CONIC_STEP_TOL_M = 1e-9
#: ... or when an accepted step lowers the cost by less than this share of it: with noisy
#: glints the centre model's depth is weakly determined and its steps can stay above the step
#: tolerance while the cost no longer changes. 1e-10 of a cost of ~1 px² is far below anything
#: the glints resolve; the Jacobian's central differences are good to ~1e-8 relative, so a
#: tighter test only chases their rounding.
CONIC_FTOL = 1e-10
#: Most Levenberg-Marquardt iterations on the conic after the spherical start: most samples
#: take 2-4, but on the quick study's Q = -0.25 renders about 1 band in 10 took 22-27 (a cap of
#: 20 failed 24 of 236 polynomial samples as not converged, 21 with the flat-cost stop alone,
#: 7 with a cap of 50); the spherical fit's own cap is 50.
CONIC_MAX_ITERATIONS = 50
#: Initial damping relative to the diagonal of JᵀJ (the spherical fit's ``solve._LAMBDA0``:
#: from the sphere's answer the conic's minimum is a few hundred um away, Gauss-Newton's reach).
_LAMBDA0 = 1e-6


def check_conic(model: str, asphericity: float) -> tuple[str, float]:
    """(model, Q) checked: ``model`` one of :data:`CORNEA_MODELS`, Q in (-1, 1] and zero for
    the sphere. Raises ValueError naming the bad value."""
    if model not in CORNEA_MODELS:
        raise ValueError(f"cornea_model must be one of {CORNEA_MODELS}, got {model!r}")
    q = float(asphericity)
    if not (ASPHERICITY_RANGE[0] < q <= ASPHERICITY_RANGE[1]):
        raise ValueError(f"cornea_asphericity must lie in (-1, 1], got {asphericity!r}")
    if model == "sphere" and q != 0.0:
        raise ValueError(f"a spherical cornea has cornea_asphericity 0, got {asphericity!r}")
    return model, q


def conic_glints(camera, centers_m, eye_center_m, cornea_radius_m: float, asphericity: float,
                 lights_world_m):
    """Glints (B, n, 2) px of a conic cornea with centres (B, 3) (the apex's centre of
    curvature) whose optical axes point from ``eye_center_m`` (3,) or (B, 3) through them; NaN
    where the reflection does not converge. Lights (n, 3) or (B, n, 3). No cap or visibility test: the
    caller knows which glints were seen."""
    c = np.asarray(centers_m, dtype=np.float64).reshape(-1, 3)
    axis = c - np.asarray(eye_center_m, dtype=np.float64).reshape(-1, 3)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    g, _ = project_glints_conic(camera, c + cornea_radius_m * axis, axis, cornea_radius_m,
                                asphericity, lights_world_m)
    return g


def _centres(model, problem: FitProblem, x, eye_center_m):
    """Cornea centres (B, 3) of parameters x (B, p)."""
    if model == "center":
        return x
    return eye_center_m + problem.orbit_radius_m * gaze_direction(x[:, 0], x[:, 1])


def _steps(model, problem: FitProblem) -> float:
    """Central-difference step of each unknown: 1e-7 m of cornea-centre motion (the orbit's
    angles count r_co per radian). The conic's glints settle to ~1e-14 R (5e-13 px), so the
    Jacobian's rounding error is ~1e-8 relative and its truncation error O(h²) below that."""
    return 1e-7 if model == "center" else 1e-7 / problem.orbit_radius_m


def _residuals(model, problem, x, glints, mask, lights, eye_center_m, asphericity):
    """Masked residuals (B, k, 2) px of the conic at x (B, p); masked and unconverged glints
    give zero (and ``False`` in the returned finite mask)."""
    c = _centres(model, problem, x, eye_center_m)
    g = conic_glints(problem.camera, c, eye_center_m, problem.cornea_radius_m, asphericity, lights)
    r = g - glints
    good = mask & np.isfinite(r).all(axis=-1)
    return np.where(good[..., None], r, 0.0), good


def _normal_equations(model, problem, x, glints, mask, lights, eye_center_m, asphericity):
    """Glint cost (B,), JᵀJ (B, p, p) and Jᵀr (B, p) of the conic at x, the Jacobian by central
    differences, all 2p + 1 poses of every sample in one conic projection."""
    B, p = x.shape
    h = _steps(model, problem)
    E = np.concatenate([np.zeros((1, p)), h * np.eye(p), -h * np.eye(p)])  # (2p + 1, p)
    X = (x[:, None, :] + E[None]).reshape(-1, p)
    rep = lambda a: np.repeat(a, 2 * p + 1, axis=0)  # noqa: E731
    L = rep(lights) if lights.ndim == 3 else lights
    r, good = _residuals(model, problem, X, rep(glints), rep(mask), L, eye_center_m, asphericity)
    r = r.reshape(B, 2 * p + 1, -1)
    good = good.reshape(B, 2 * p + 1, -1).all(axis=1)  # a glint counts where every pose has it
    r = np.where(np.repeat(good, 2, axis=-1)[:, None], r, 0.0)
    J = (r[:, 1:p + 1] - r[:, p + 1:]) / (2 * h)  # (B, p, 2k)
    r0 = r[:, 0]
    cost = np.einsum("bi,bi->b", r0, r0)
    # A seen glint without a reflection at x is no cheaper fit: such a point is refused (the
    # LM keeps its previous point), else a step could drop glints to lower the cost.
    lost = (mask & ~good).any(axis=1)
    cost[lost] = np.inf
    return cost, J @ np.swapaxes(J, 1, 2), (J @ r0[..., None])[..., 0], good


def fit_cornea_conic(problem: FitProblem, glints_px, mask=None, x0=None, *, model: str = "center",
                     asphericity: float, eye_center_m, max_iter: int = 50,
                     conic_iter: int = CONIC_MAX_ITERATIONS, prior_mean=None,
                     prior_information=None, lower=None, upper=None, solver: str = "lm",
                     conic_start=None) -> CorneaFit:
    """:func:`estimator.cornea.fit_cornea` with a conic cornea of constant ``asphericity``
    about the optical axis through ``eye_center_m`` (module docstring).

    Parameters
    ----------
    problem : FitProblem
        As for the sphere; ``cornea_radius_m`` is the apex radius (the ``"orbit"`` model also
        needs ``orbit_radius_m``; its ``eye_center_m`` is the axis' ``eye_center_m``).
    glints_px : (B, n, 2) or (n, 2) float
    mask : (B, n) bool, optional
    x0 : (B, p) or (p,) float
        Start of the spherical fit that starts the conic one.
    model : {"center", "orbit"}
    asphericity : float
        Q in (-1, 1]; 0 returns :func:`fit_cornea`'s answer unchanged.
    eye_center_m : (3,) float
        c_e: the optical axis runs from it through the cornea centre.
    max_iter : int
        Iterations of the spherical fit (:func:`fit_cornea`'s ``max_iter``).
    conic_iter : int
        Levenberg-Marquardt iterations on the conic after it.
    conic_start : (B, p) float, optional
        Where the conic iterations start, per sample (NaN rows: the spherical fit's answer);
        default the spherical fit's answer.
    prior_mean, prior_information, lower, upper, solver
        As :func:`fit_cornea` (the spherical start takes them all; the conic iterations add
        the prior's term and clip their steps to the bounds).

    Returns
    -------
    CorneaFit
        ``rms_px`` is the conic's RMS glint residual; ``iterations`` the spherical fit's plus
        the conic's.
    """
    if model not in ("center", "orbit"):
        raise ValueError(f"the conic cornea fits the 'center' and 'orbit' models, got {model!r}")
    check_conic("conic", asphericity)
    glints = np.asarray(glints_px, dtype=np.float64)
    if glints.ndim == 2:
        glints = glints[None]
    if mask is None:
        mask = np.isfinite(glints).all(axis=-1)
    mask = np.asarray(mask, dtype=bool).reshape(glints.shape[:2]) & np.isfinite(glints).all(-1)
    fit = fit_cornea(problem, glints, mask, x0, model=model, solver=solver, lower=lower,
                     upper=upper, max_iter=max_iter, prior_mean=prior_mean,
                     prior_information=prior_information)
    if asphericity == 0.0:
        return fit
    ce = np.asarray(eye_center_m, dtype=np.float64).reshape(3)
    idx = np.flatnonzero(fit.reason == OK)
    if idx.size == 0:
        return fit
    g, m = np.where(mask[idx, :, None], glints[idx], 0.0), mask[idx]
    k = max(int(m.sum(axis=1).max()), 1)
    order = np.argsort(~m, axis=1, kind="stable")[:, :k]  # each sample's seen glints first
    g, m = np.take_along_axis(g, order[..., None], axis=1), np.take_along_axis(m, order, axis=1)
    L = problem.lights_world_m[order]
    x = (fit.angles_rad if model == "orbit" else fit.center_m)[idx].copy()
    if conic_start is not None:
        x0c = np.asarray(conic_start, dtype=np.float64).reshape(glints.shape[0], -1)[idx]
        x = np.where(np.isfinite(x0c).all(axis=1, keepdims=True), x0c, x)
    p = x.shape[1]
    lo = np.full(p, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(p, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    pm = pinfo = None
    if prior_mean is not None and prior_information is not None:
        pm = np.broadcast_to(np.asarray(prior_mean, np.float64), (glints.shape[0], p))[idx]
        pinfo = np.broadcast_to(np.asarray(prior_information, np.float64),
                                (glints.shape[0], p, p))[idx]
        have = np.isfinite(pm).all(1) & np.isfinite(pinfo).all((1, 2))
        pm, pinfo = np.where(have[:, None], pm, 0.0), np.where(have[:, None, None], pinfo, 0.0)

    def total(x, sel):
        cost, A, b, good = _normal_equations(model, problem, x, g[sel], m[sel], L[sel], ce, asphericity)
        if pm is not None:
            d = x - pm[sel]
            Ld = (pinfo[sel] @ d[..., None])[..., 0]
            cost, A, b = cost + np.einsum("bi,bi->b", d, Ld), A + pinfo[sel], b + Ld
        return cost, A, b, good

    all_ = np.arange(idx.size)
    cost, A, b, good = total(x, all_)
    lam = np.full(idx.size, _LAMBDA0)
    running = np.ones(idx.size, dtype=bool)
    iters = np.zeros(idx.size, dtype=int)
    scale = 1.0 if model == "center" else problem.orbit_radius_m  # step in m of centre motion
    for _ in range(conic_iter):
        sel = np.flatnonzero(running)
        if sel.size == 0:
            break
        iters[sel] += 1
        D = np.einsum("bii->bi", A[sel])
        step = np.linalg.solve(A[sel] + lam[sel, None, None] * np.eye(p) * np.maximum(D, 1e-300)[:, :, None],
                               -b[sel][..., None])[..., 0]
        x_new = np.clip(x[sel] + step, lo, hi)
        c_new, A_new, b_new, good_new = total(x_new, sel)
        better = np.isfinite(c_new) & (c_new <= cost[sel])
        acc, rej = sel[better], sel[~better]
        small = np.linalg.norm(x_new - x[sel], axis=1) * scale < CONIC_STEP_TOL_M
        flat = np.abs(cost[sel] - c_new) <= CONIC_FTOL * np.maximum(cost[sel], 1e-30)
        x[acc], cost[acc], A[acc], b[acc] = x_new[better], c_new[better], A_new[better], b_new[better]
        good[acc] = good_new[better]
        lam[acc] = np.maximum(lam[acc] / 10, 1e-12)
        lam[rej] *= 10
        running[sel[(better & (small | flat)) | (~better & (lam[sel] > 1e12))]] = False
    glint_cost = cost
    if pm is not None:
        d = x - pm
        glint_cost = cost - np.einsum("bi,bij,bj->b", d, pinfo, d)
    n_used = good.sum(axis=1)
    rms = np.sqrt(np.maximum(glint_cost, 0.0) / np.maximum(n_used, 1))
    center = _centres(model, problem, x, ce)
    reason = fit.reason.astype(object)
    reason[idx[running]] = NOT_CONVERGED
    reason[idx[~np.isfinite(x).all(axis=1)]] = NON_FINITE
    out = {name: np.array(getattr(fit, name), copy=True) for name in CorneaFit.__slots__}
    out["center_m"][idx] = center
    if model == "orbit":
        out["angles_rad"][idx] = x
    out["rms_px"][idx] = rms
    out["iterations"][idx] += iters
    bad = reason != OK
    out["center_m"][bad] = np.nan
    out["angles_rad"][bad] = np.nan
    out["rms_px"][bad] = np.nan
    out["reason"] = reason.astype(str)
    return CorneaFit(**out)
