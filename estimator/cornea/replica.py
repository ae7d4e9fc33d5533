"""The batched Levenberg-Marquardt of :func:`estimator.cornea.fit_cornea` for one sample,
compiled with Numba (optional): the hypothesis search refits a few cold hypotheses of 3-8
glints at a time, where the batched solver's numpy calls cost ~390 µs per hypothesis and
iteration (measured on the quick validation's rendered frames: 296 refits of 2.4 hypotheses,
15 iterations each, 22 % of them running to ``max_iter``), and the arithmetic a few µs.

:func:`estimator.cornea.fit_small` is a different solver (its own damping schedule and a
1e-12 m stopping step); on the flat valleys of poor cold hypotheses (few glints far from
the truth) the two part: one ends converged where the other runs out of iterations, and the
search then names another failure. This module keeps :mod:`estimator.cornea.solve`'s rules
one for one, so that a hypothesis converges, or does not, as it does there:

- the damping starts at ``solve._LAMBDA0`` (``"center"``, ``"orbit"``), is divided by 10 on
  an accepted trial (not below 1e-12) and multiplied by 10 on a rejected one;
- every trial counts one iteration, a rejected or unusable (non-finite) one too;
- a Gauss-Newton step below ``solve._GN_STOP`` (in metres of cornea-centre motion) at a
  damping of at most 1e-3 is taken and ends the fit, its cost predicted to second order;
- an accepted trial converges when its step is below ``solve._XTOL`` relatively, the cost
  changed by at most ``solve._FTOL`` relatively, or the cost is zero; a rejected one when the
  damping passes 1e12;
- the damped system is solved by cofactors, as ``solve._solve_small``.

The glints are :func:`estimator.geometry.compiled.glints_kernel`'s (the closed-form projection
to ~1e-12 px) with its closed-form rows of d glint / d centre, the batched solver's analytic
rows written one glint at a time (to ~1e-15 relative): the steps agree to rounding
(``tests/estimator/test_cornea_replica.py`` holds both to 1e-9 rad / 1e-10 m and the
convergence flags equal on the search's own refits).
"""

from __future__ import annotations

import math

import numpy as np

import estimator.cornea.solve as solve

from ..geometry import compiled
from .problem import FitProblem
from .small import _normal_sums, _residuals_rows

__all__ = ["ENABLED", "fit_replica"]

#: Whether :func:`fit_replica` runs compiled (Numba imports and its JIT is on). Callers take
#: the batched solver where it does not: in the interpreter this loop is slower than numpy.
ENABLED = compiled.ENABLED


def _normal(cam, model, x, ce, rco, radius, lights, glints, g, vis, c, res, jac, J, JtJ, Jtr):
    """Cost Σ r² at x, and JᵀJ, Jᵀr (written out) with J in closed form."""
    cost = _residuals_rows(cam, model, x, ce, rco, radius, lights, glints, g, vis, c, res, jac, J)
    _normal_sums(J, res, JtJ, Jtr)
    return cost


def _cofactor_solve(A, b, out):
    """out = A⁻¹ b for p = 2 or 3 by cofactors, as ``solve._solve_small`` (non-finite where
    A is singular)."""
    p = b.shape[0]
    if p == 2:
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        out[0] = (A[1, 1] * b[0] - A[0, 1] * b[1]) / det
        out[1] = (-A[1, 0] * b[0] + A[0, 0] * b[1]) / det
        return
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    c10 = A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]
    c11 = A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]
    c12 = A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]
    c20 = A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]
    c21 = A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]
    c22 = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    out[0] = (c00 * b[0] + c10 * b[1] + c20 * b[2]) / det
    out[1] = (c01 * b[0] + c11 * b[1] + c21 * b[2]) / det
    out[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det


def _lm_rules(R, O, intr, size, model, x0, ce, rco, radius, lights, glints, max_iter, gn_stop,
              lam0, xtol, ftol, x):
    """``solve._lm_block`` for one sample (module docstring); x is written out. Returns the
    cost, the iterations and whether it converged."""
    cam = (R, O, intr, size)
    k, p = glints.shape[0], x0.shape[0]
    g = np.empty((k, 2))
    vis = np.empty(k, dtype=np.bool_)
    c = np.empty(3)
    res = np.empty(2 * k)
    jac = np.empty((k, 2, 3))
    J = np.empty((2 * k, p))
    JtJ, Jtr = np.empty((p, p)), np.empty(p)
    JtJ_n, Jtr_n = np.empty((p, p)), np.empty(p)
    A = np.empty((p, p))
    step, x_new = np.empty(p), np.empty(p)
    for j in range(p):
        x[j] = x0[j]
    cost = _normal(cam, model, x, ce, rco, radius, lights, glints, g, vis, c, res, jac, J, JtJ,
                   Jtr)
    lam = lam0
    iters = 0
    converged = False
    for _ in range(max_iter):
        if converged:
            break
        for a in range(p):
            for b in range(p):
                A[a, b] = JtJ[a, b]
            A[a, a] += lam * max(JtJ[a, a], 1e-30)
        _cofactor_solve(A, Jtr, step)
        usable = True
        for j in range(p):
            x_new[j] = x[j] - step[j]
            step[j] = x_new[j] - x[j]  # as solve._lm_block: the step actually taken
            usable = usable and math.isfinite(x_new[j])
        iters += 1
        if not usable:
            lam *= 10
            continue
        tiny = lam <= 1e-3
        for j in range(p):
            tiny = tiny and abs(step[j]) <= gn_stop * max(1.0, abs(x[j]))
        if tiny:
            pred = cost
            for a in range(p):
                pred += 2 * step[a] * Jtr[a]
                for b in range(p):
                    pred += step[a] * JtJ[a, b] * step[b]
            for j in range(p):
                x[j] = x_new[j]
            cost = max(pred, 0.0)
            converged = True
            break
        cost_new = _normal(cam, model, x_new, ce, rco, radius, lights, glints, g, vis, c, res,
                           jac, J, JtJ_n, Jtr_n)
        better = math.isfinite(cost_new) and cost_new <= cost
        small = True
        for j in range(p):
            small = small and abs(x_new[j] - x[j]) <= xtol * max(1.0, abs(x[j]))
        flat = abs(cost - cost_new) <= ftol * max(cost, 1e-30)
        if better:
            converged = small or flat or cost_new == 0
            for j in range(p):
                x[j] = x_new[j]
                Jtr[j] = Jtr_n[j]
                for b in range(p):
                    JtJ[j, b] = JtJ_n[j, b]
            cost = cost_new
            lam = max(lam / 10, 1e-12)
        else:
            lam *= 10
            converged = lam > 1e12
    return cost, iters, converged


if compiled.ENABLED:
    _jit = compiled.numba.njit(cache=True, nogil=True, error_model="numpy")
    _normal = _jit(_normal)
    _cofactor_solve = _jit(_cofactor_solve)
    _lm_rules = _jit(_lm_rules)


def fit_replica(problem: FitProblem, glints_px, lights_world_m, x0, *, model: str,
                max_iter: int = 50, arrays=None) -> tuple[np.ndarray, bool, int]:
    """One sample's fit as :func:`estimator.cornea.fit_cornea` (``solver="lm"``, no bounds,
    no prior, a start per sample) makes it: parameters x (p,) (Fick angles, rad, or the
    centre, m; NaN unless ok), whether it is ``"ok"`` (converged to finite parameters) and
    the iterations.

    Parameters
    ----------
    problem : FitProblem
        The calibrated problem; its lights are replaced by ``lights_world_m``.
    glints_px : (k, 2) float
        The sample's identified glints, 2k >= p.
    lights_world_m : (k, 3) float
    x0 : (p,) float
    model : {"orbit", "center"}
    arrays : tuple, optional
        :func:`estimator.geometry.camera_arrays` of the problem's camera.
    """
    if model not in ("orbit", "center"):
        raise ValueError(f"model must be 'orbit' or 'center', got {model!r}")
    if not ENABLED:
        raise RuntimeError("fit_replica needs Numba (estimator.cornea.replica.ENABLED)")
    p = 2 if model == "orbit" else 3
    g = np.ascontiguousarray(glints_px, dtype=np.float64).reshape(-1, 2)
    L = np.ascontiguousarray(lights_world_m, dtype=np.float64).reshape(-1, 3)
    x0 = np.asarray(x0, dtype=np.float64).reshape(p)
    if g.shape[0] != L.shape[0] or 2 * g.shape[0] < p:
        raise ValueError(f"need as many glints as lights and >= {p} coordinates, "
                         f"got {g.shape[0]} glints and {L.shape[0]} lights")
    if model == "orbit":
        ce, rco = np.asarray(problem.eye_center_m, dtype=np.float64), float(problem.orbit_radius_m)
        gn_stop = solve._GN_STOP / rco
    else:
        ce, rco, gn_stop = np.zeros(3), 0.0, solve._GN_STOP
    R, O, intr, size = compiled.camera_arrays(problem.camera) if arrays is None else arrays
    x = np.empty(p)
    _, iters, converged = _lm_rules(R, O, intr, size, 1 if model == "orbit" else 0, x0, ce,
                                    rco, float(problem.cornea_radius_m), L, g, int(max_iter),
                                    gn_stop, solve._LAMBDA0, solve._XTOL, solve._FTOL, x)
    ok = bool(converged and np.isfinite(x).all())
    return (x if ok else np.full(p, np.nan)), ok, int(iters)
