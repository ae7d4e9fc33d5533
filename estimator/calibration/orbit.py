"""The eye centre and the orbit radius of the cornea centre (Sec. 2.4): the paper's
law of sines and the Ahn et al. sphere fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..eye import BOHME_CORNEA_OFFSET_M, BOHME_CORNEA_RADIUS_M
from ..geometry import as_points

#: Orbit radius bounds for the joint fit (m): Böhme's 4.35 mm is ~0.55 r_c; anything outside
#: 1-10 mm is not an eye.
ORBIT_RADIUS_BOUNDS_M = (1e-3, 10e-3)


# --------------------------------------------------------------------------------------------
# Eye centre and orbit radius


@dataclass(frozen=True, slots=True)
class OrbitFit:
    """Eye rotation centre c_e and corneal orbit radius r_co.

    ``rms_m`` is the RMS of ||c_c,i - c_e|| - r_co over the frames used; ``iterations`` counts
    the outer iterations (law of sines) or solver evaluations; ``converged`` is False when an
    iteration limit ended the fit."""

    eye_center_m: np.ndarray
    orbit_radius_m: float
    rms_m: float
    iterations: int
    method: str
    converged: bool = True


def _check_centers(centers_m, targets_m=None, minimum=4):
    C = as_points(centers_m, "centers_m")
    if C.ndim != 2:
        raise ValueError(f"centers_m must have shape (m, 3), got {C.shape}")
    keep = np.isfinite(C).all(axis=1)
    T = None
    if targets_m is not None:
        T = as_points(targets_m, "targets_m")
        if T.shape != C.shape:
            raise ValueError(f"targets_m must have shape {C.shape}, got {T.shape}")
        keep &= np.isfinite(T).all(axis=1)
        T = T[keep]
    C = C[keep]
    if C.shape[0] < minimum:
        raise ValueError(f"need at least {minimum} finite cornea centres, got {C.shape[0]}")
    return C, T


def _fit_center_to_radius(C, radius, ce0):
    """c_e minimising sum_i (||c_i - c_e|| - radius)^2, Gauss-Newton (scipy LM) from ce0."""
    def fun(ce):
        return np.linalg.norm(C - ce, axis=1) - radius

    def jac(ce):
        v = C - ce
        return -v / np.linalg.norm(v, axis=1, keepdims=True)

    sol = least_squares(fun, ce0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return sol.x


def orbit_law_of_sines(centers_m, targets_m, eye_center0_m=None, *, max_iter: int = 100,
                       tol_m: float = 1e-13) -> OrbitFit:
    """The paper's method (Sec. 2.4): r_co from triangles by the law of sines, then c_e by least
    squares.

    For each pair of frames (i, j) the triangle (c_e, c_c,i, c_c,j) is isosceles with legs r_co
    and apex angle γ_ij between the gaze directions d_i and d_j; the law of sines gives
    ``r_co,ij = ||c_c,i - c_c,j|| sin((π - γ)/2) / sin γ = ||c_c,i - c_c,j|| / (2 sin(γ/2))``.
    r_co is the plain mean over all pairs; c_e then minimises Σ_i (||c_c,i - c_e|| - r_co)².

    Where the paper is vague we assumed:

    - d_i is the direction from the eye centre to the *known* target T_i (no angle kappa, as in
      the simulation). It depends on c_e, which is what we are solving for: we iterate
      (directions from the current c_e, then r_co, then c_e) until c_e moves less than
      ``tol_m``. The fixed point is exact for exact centres, because the targets are ~0.7 m
      away and the iteration contracts by ~r_co / 0.7 m per step.
    - The mean is over all pairs, unweighted; pairs with coincident directions (γ < 1e-9 rad),
      where the triangle is undefined, are left out.
    - The least squares has a mirror solution in front of the cornea; it is started behind it,
      at ``eye_center0_m`` or else at mean_i(c_c,i - r d_i) with Böhme's r_co for a 7.8 mm cornea.

    Parameters
    ----------
    centers_m : (m, 3) float
        Cornea centres of the calibration frames (non-finite rows are skipped).
    targets_m : (m, 3) float
        The targets fixated in those frames.
    eye_center0_m : (3,) float, optional
    """
    C, T = _check_centers(centers_m, targets_m, minimum=3)
    i, j = np.triu_indices(C.shape[0], k=1)
    chord = np.linalg.norm(C[i] - C[j], axis=1)
    if eye_center0_m is None:
        r_guess = BOHME_CORNEA_OFFSET_M * 7.8e-3 / BOHME_CORNEA_RADIUS_M
        d = T - C
        ce = (C - r_guess * d / np.linalg.norm(d, axis=1, keepdims=True)).mean(axis=0)
    else:
        ce = as_points(eye_center0_m, "eye_center0_m").reshape(3).copy()
    converged = False
    for it in range(1, max_iter + 1):
        d = T - ce
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        gamma = np.arctan2(np.linalg.norm(np.cross(d[i], d[j]), axis=1), np.einsum("ij,ij->i", d[i], d[j]))
        use = gamma > 1e-9
        if not use.any():
            raise ValueError("all gaze directions coincide: the calibration targets are degenerate")
        r = float(np.mean(chord[use] / (2 * np.sin(gamma[use] / 2))))
        ce_new = _fit_center_to_radius(C, r, ce)
        step = np.linalg.norm(ce_new - ce)
        ce = ce_new
        if step < tol_m:
            converged = True
            break
    rms = float(np.sqrt(np.mean((np.linalg.norm(C - ce, axis=1) - r) ** 2)))
    return OrbitFit(ce, r, rms, it, "law_of_sines", converged)


def orbit_sphere_fit(centers_m) -> OrbitFit:
    """Baseline: least-squares sphere through the cornea centres (Ahn et al. 2001, "Least-squares
    orthogonal distances fitting of circle, sphere, ellipse, hyperbola, and parabola", Pattern
    Recognition 34:2283-2303).

    Algebraic fit first (||c||² + a·c + b = 0, linear, on centred and scaled points), then the
    geometric (orthogonal-distance) fit Σ_i (||c_c,i - c_e|| - r_co)² by Levenberg-Marquardt
    from it. Needs four points not on one plane or circle.
    """
    C, _ = _check_centers(centers_m, minimum=4)
    mu = C.mean(axis=0)
    s = np.abs(C - mu).max()
    if s == 0:
        raise ValueError("all cornea centres coincide: cannot fit a sphere")
    P = (C - mu) / s
    A = np.column_stack([P, np.ones(len(P))])
    sv = np.linalg.svd(A, compute_uv=False)
    if sv[-1] < 1e-9 * sv[0]:
        raise ValueError("cornea centres are coplanar (degenerate calibration): cannot fit a sphere")
    coef = np.linalg.lstsq(A, -(P ** 2).sum(axis=1), rcond=None)[0]
    c_alg = -coef[:3] / 2
    r2 = c_alg @ c_alg - coef[3]
    if not r2 > 0:
        raise ValueError("algebraic sphere fit failed (imaginary radius): degenerate cornea centres")
    x0 = np.concatenate([mu + s * c_alg, [s * np.sqrt(r2)]])

    def fun(x):
        return np.linalg.norm(C - x[:3], axis=1) - x[3]

    def jac(x):
        v = C - x[:3]
        return np.column_stack([-v / np.linalg.norm(v, axis=1, keepdims=True), -np.ones(len(C))])

    sol = least_squares(fun, x0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    rms = float(np.sqrt(np.mean(sol.fun ** 2)))
    return OrbitFit(sol.x[:3].copy(), float(sol.x[3]), rms, int(sol.nfev), "sphere_fit", bool(sol.status > 0))
