"""One small cornea fit, warm-started: the tracker's cheap path fits the 5-15 glints of one
band on the calibrated problem from the previous sample's estimate (``"orbit"``: 2 unknowns,
``"center"``: 3), where :func:`estimator.cornea.fit_cornea`'s batched machinery costs more in
numpy calls than the fit itself.

Compiled with Numba (optional; :data:`estimator.geometry.compiled.ENABLED`): Levenberg-
Marquardt on the glints of :func:`estimator.geometry.compiled.glints_one_pose`, the Jacobian
in closed form (the projection's implicit derivative, :func:`_residuals_rows`, as
:mod:`estimator.geometry.jacobians`: one projection an iteration where central differences
took 2p more), stopped when a step is
below 1e-12 m of cornea-centre motion. :func:`fit_cornea` stops at 1e-7 m steps with an error
left of <= 4e-10 m (``solve._GN_STOP``), so both reach the same centre to ~1e-9 m, 1e-4 of the
scatter 0.5 px of glint noise leaves (tested against it). Without Numba, :func:`fit_small`
runs the same Levenberg-Marquardt on Python floats (:mod:`estimator.cornea.scalar`: numpy's
per-call cost on arrays of 5-15 glints is what the batched fit paid, ~2 ms a fit), with the
batched fit's stop: a Gauss-Newton step below 1e-7 m is taken and ends the fit without another
projection (``solve._GN_STOP``; the error it leaves is <= 4e-10 m), about half the
projections of the compiled fit's 1e-12 m stop.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..geometry import compiled
from .problem import FitProblem
from .scalar import camera_floats, lm_floats
from .solve import _GN_STOP

#: Stopping step (m of cornea-centre motion; the orbit's angles count r_co per radian).
_XTOL_M = 1e-12


class SmallFit(NamedTuple):
    """One band's fit: parameters x (p,) (Fick angles, rad, or the centre, m), the RMS glint
    residual (px), JᵀJ (p, p) of the glint residuals at x (px² per unit²), iterations, and
    whether it converged to finite parameters."""

    x: np.ndarray
    rms_px: float
    JtJ: np.ndarray
    iterations: int
    ok: bool


def _centre(model, x, ce, rco, out):
    if model == 0:
        out[0], out[1], out[2] = x[0], x[1], x[2]
    else:
        cp = math.cos(x[1])
        out[0] = ce[0] + rco * (cp * math.sin(x[0]))
        out[1] = ce[1] + rco * math.sin(x[1])
        out[2] = ce[2] + rco * (-cp * math.cos(x[0]))


def _residuals(cam, model, x, ce, rco, radius, lights, glints, g, vis, c, res):
    R, O, intr, size = cam
    _centre(model, x, ce, rco, c)
    compiled.glints_kernel(R, O, intr, size, c, radius, lights, c, 0.0, False, g, vis, False,
                           compiled.NO_JACOBIAN)
    cost = 0.0
    for i in range(glints.shape[0]):
        du, dv = g[i, 0] - glints[i, 0], g[i, 1] - glints[i, 1]
        res[2 * i], res[2 * i + 1] = du, dv
        cost += du * du + dv * dv
    return cost


def _residuals_rows(cam, model, x, ce, rco, radius, lights, glints, g, vis, c, res, jac, J):
    """:func:`_residuals` and their Jacobian J (2k, p) at x, in closed form: the projection's
    d glint / d centre (``jac``, (k, 2, 3) scratch), through the orbit for model 1."""
    R, O, intr, size = cam
    _centre(model, x, ce, rco, c)
    compiled.glints_kernel(R, O, intr, size, c, radius, lights, c, 0.0, False, g, vis, True,
                           jac)
    cost = 0.0
    k = glints.shape[0]
    for i in range(k):
        du, dv = g[i, 0] - glints[i, 0], g[i, 1] - glints[i, 1]
        res[2 * i], res[2 * i + 1] = du, dv
        cost += du * du + dv * dv
    if model == 0:
        for i in range(k):
            for j in range(3):
                J[2 * i, j], J[2 * i + 1, j] = jac[i, 0, j], jac[i, 1, j]
        return cost
    # d c / d (yaw, pitch) of c = c_e + r_co (cos p sin y, sin p, -cos p cos y).
    cy, sy, cp, sp = math.cos(x[0]), math.sin(x[0]), math.cos(x[1]), math.sin(x[1])
    dy0, dy2 = rco * cp * cy, rco * cp * sy
    dp0, dp1, dp2 = -rco * sp * sy, rco * cp, rco * sp * cy
    for i in range(k):
        for r in range(2):
            J[2 * i + r, 0] = jac[i, r, 0] * dy0 + jac[i, r, 2] * dy2
            J[2 * i + r, 1] = jac[i, r, 0] * dp0 + jac[i, r, 1] * dp1 + jac[i, r, 2] * dp2
    return cost


def _normal_sums(J, res, JtJ, Jtr):
    """JᵀJ (p, p) and Jᵀr (p,) of J (2k, p) and r (2k,), written out."""
    n, p = J.shape
    for a in range(p):
        s = 0.0
        for i in range(n):
            s += J[i, a] * res[i]
        Jtr[a] = s
        for b in range(p):
            s = 0.0
            for i in range(n):
                s += J[i, a] * J[i, b]
            JtJ[a, b] = s


def _solve(A, b, out):
    """out = A⁻¹ b by Gaussian elimination with partial pivoting (p <= 3); False if singular."""
    p = b.shape[0]
    M = A.copy()
    y = b.copy()
    for k in range(p):
        piv = k
        for i in range(k + 1, p):
            if abs(M[i, k]) > abs(M[piv, k]):
                piv = i
        if not abs(M[piv, k]) > 0:
            return False
        for j in range(p):
            M[k, j], M[piv, j] = M[piv, j], M[k, j]
        y[k], y[piv] = y[piv], y[k]
        for i in range(k + 1, p):
            f = M[i, k] / M[k, k]
            for j in range(k, p):
                M[i, j] -= f * M[k, j]
            y[i] -= f * y[k]
    for k in range(p - 1, -1, -1):
        s = y[k]
        for j in range(k + 1, p):
            s -= M[k, j] * out[j]
        out[k] = s / M[k, k]
    return True


def _prior_cost(x, pm, P):
    """(x - μ)ᵀ Λ (x - μ) (px²); 0 without a prior (Λ = 0)."""
    p = x.shape[0]
    cost = 0.0
    for a in range(p):
        for b in range(p):
            cost += (x[a] - pm[a]) * P[a, b] * (x[b] - pm[b])
    return cost


def _lm(R, O, intr, size, model, x0, ce, rco, radius, lights, glints, max_iter, xtol, pm, P,
        x, JtJ):
    """Levenberg-Marquardt from x0 on the glints' squared residuals plus the prior's
    (x - pm)ᵀ P (x - pm) (P = 0: none); x and the glints' JᵀJ at it are written out. Returns
    the glints' share of the cost, the iterations and whether it converged."""
    cam = (R, O, intr, size)
    k, p = glints.shape[0], x0.shape[0]
    g = np.empty((k, 2))
    vis = np.empty(k, dtype=np.bool_)
    c = np.empty(3)
    res = np.empty(2 * k)
    res_p = np.empty(2 * k)
    jac = np.empty((k, 2, 3))
    J = np.empty((2 * k, p))
    Jtr = np.empty(p)
    A = np.empty((p, p))
    step = np.empty(p)
    x_new = np.empty(p)
    for j in range(p):
        x[j] = x0[j]
    cost = (_residuals(cam, model, x, ce, rco, radius, lights, glints, g, vis, c, res)
            + _prior_cost(x, pm, P))
    lam = 1e-6
    iters = 0
    converged = False
    for _ in range(max_iter):
        if not math.isfinite(cost):
            break
        _residuals_rows(cam, model, x, ce, rco, radius, lights, glints, g, vis, c, res, jac, J)
        _normal_sums(J, res, JtJ, Jtr)
        for a in range(p):
            for b in range(p):
                Jtr[a] += P[a, b] * (x[b] - pm[b])
        iters += 1
        accepted = False
        while lam <= 1e12:
            for a in range(p):
                for b in range(p):
                    A[a, b] = JtJ[a, b] + P[a, b]
                A[a, a] += lam * max(JtJ[a, a] + P[a, a], 1e-30)
            if _solve(A, Jtr, step):
                for j in range(p):
                    x_new[j] = x[j] - step[j]
                cost_new = (_residuals(cam, model, x_new, ce, rco, radius, lights, glints, g,
                                       vis, c, res_p) + _prior_cost(x_new, pm, P))
                if math.isfinite(cost_new) and cost_new <= cost:
                    accepted = True
                    break
            lam *= 10
        if not accepted:
            converged = True  # no step lowers the cost: a minimum to machine precision
            break
        small = True
        for j in range(p):
            small = small and abs(step[j]) <= xtol * max(1.0, abs(x[j]))
            x[j] = x_new[j]
        for i in range(2 * k):
            res[i] = res_p[i]
        cost = cost_new
        lam = max(lam / 10, 1e-12)
        if small:
            converged = True
            break
    return cost - _prior_cost(x, pm, P), iters, converged


if compiled.ENABLED:
    _jit = compiled.numba.njit(cache=True, nogil=True, error_model="numpy")
    _centre = _jit(_centre)
    _residuals = _jit(_residuals)
    _residuals_rows = _jit(_residuals_rows)
    _normal_sums = _jit(_normal_sums)
    _solve = _jit(_solve)
    _prior_cost = _jit(_prior_cost)
    _lm = _jit(_lm)

#: The compiled Levenberg-Marquardt of :func:`fit_small` itself (``_lm``'s arguments), for
#: kernels that run a whole band in one compiled call (:mod:`estimator.matching.follow_kernel`).
lm_kernel = _lm
#: The step below which :func:`fit_small` stops (m; divided by r_co for the orbit's angles).
XTOL_M = _XTOL_M


def fit_small(problem: FitProblem, glints_px, lights_world_m, x0, *, model: str,
              max_iter: int = 50, arrays=None, prior_mean=None,
              prior_information=None) -> SmallFit:
    """Fit one sample's identified glints (k, 2) of lights (k, 3) from ``x0``.

    Parameters
    ----------
    problem : FitProblem
        The calibrated problem (camera, r_c and, for ``"orbit"``, c_e and r_co); its lights
        are replaced by ``lights_world_m``.
    glints_px : (k, 2) float
    lights_world_m : (k, 3) float
    x0 : (p,) float
        Start: Fick (yaw, pitch) rad for ``"orbit"``, the centre (m) for ``"center"``.
    model : {"orbit", "center"}
    arrays : tuple, optional
        :func:`estimator.geometry.compiled.camera_arrays` of the problem's camera.
    prior_mean : (p,) float, optional
    prior_information : (p, p) float, optional
        A Gaussian prior on the parameters, as :func:`estimator.cornea.fit_cornea`'s: the
        cost gains (x - μ)ᵀ Λ (x - μ) (px²). The RMS residual and JᵀJ are the glints' alone.
    """
    if model not in ("orbit", "center"):
        raise ValueError(f"model must be 'orbit' or 'center', got {model!r}")
    p = 2 if model == "orbit" else 3
    g = np.ascontiguousarray(glints_px, dtype=np.float64).reshape(-1, 2)
    L = np.ascontiguousarray(lights_world_m, dtype=np.float64).reshape(-1, 3)
    x0 = np.asarray(x0, dtype=np.float64).reshape(p)
    if (prior_mean is None) != (prior_information is None):
        raise ValueError("prior_mean and prior_information must be given together")
    has_prior = prior_mean is not None
    if has_prior:
        pm = np.asarray(prior_mean, dtype=np.float64).reshape(p)
        P = np.ascontiguousarray(prior_information, dtype=np.float64).reshape(p, p)
        if not (np.isfinite(pm).all() and np.isfinite(P).all()):
            raise ValueError("prior_mean and prior_information must be finite")
    else:
        pm, P = np.zeros(p), np.zeros((p, p))
    if g.shape[0] != L.shape[0] or (2 * g.shape[0] < p and not has_prior) or g.shape[0] < 1:
        raise ValueError(f"need as many glints as lights and >= {p} coordinates (or a prior), "
                         f"got {g.shape[0]} glints and {L.shape[0]} lights")
    if model == "orbit":
        ce, rco = problem.eye_center_m, float(problem.orbit_radius_m)
        xtol = _XTOL_M / rco
    else:
        ce, rco, xtol = np.zeros(3), 0.0, _XTOL_M
    R, O, intr, size = compiled.camera_arrays(problem.camera) if arrays is None else arrays
    if not compiled.ENABLED:
        return _fit_floats((R, O, intr, size), 1 if model == "orbit" else 0, x0, ce, rco,
                           problem.cornea_radius_m, L, g, max_iter, xtol,
                           _GN_STOP / rco if model == "orbit" else _GN_STOP, pm, P)
    x = np.empty(p)
    JtJ = np.zeros((p, p))
    cost, iters, converged = _lm(R, O, intr, size, 1 if model == "orbit" else 0, x0,
                                 np.asarray(ce, dtype=np.float64), rco,
                                 problem.cornea_radius_m, L, g, max_iter, xtol, pm, P, x, JtJ)
    ok = bool(converged and np.isfinite(x).all() and math.isfinite(cost))
    return SmallFit(x, math.sqrt(max(cost, 0.0) / g.shape[0]) if ok else math.nan, JtJ,
                    int(iters), ok)


def _fit_floats(arrays, model, x0, ce, rco, radius, L, g, max_iter, xtol, gn_stop, pm,
                P) -> SmallFit:
    """:func:`fit_small` without Numba: the same fit on Python floats, with the batched
    fit's Gauss-Newton stop (:func:`estimator.cornea.scalar.lm_floats`)."""
    x, JtJ, cost, iters, converged = lm_floats(camera_floats(*arrays), model, x0, ce, rco,
                                               radius, L, g, max_iter, xtol, gn_stop, pm, P)
    x, JtJ = np.array(x), np.array(JtJ)
    ok = bool(converged and np.isfinite(x).all() and math.isfinite(cost))
    return SmallFit(x, math.sqrt(max(cost, 0.0) / g.shape[0]) if ok else math.nan, JtJ,
                    int(iters), ok)
