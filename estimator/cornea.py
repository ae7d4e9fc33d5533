"""Cornea fits: the cornea centre (and radius, and lighting pose) from detected glints.

Sec. 2.2 of the SCET paper: minimise the sum of squared distances between the detected glints
and the glints re-projected by the closed-form forward projection. Three models:

- ``"center"``: the cornea centre c (3 unknowns; known r_c and lighting), for polynomial gaze;
- ``"orbit"``: the cornea centre on a sphere of radius r_co about the eye centre c_e, in Fick
  angles (2 unknowns), for geometric gaze (Sec. 2.2.1);
- ``"full"``: c, r_c and the lighting's rigid pose (10 unknowns), for calibration (Sec. 2.4).

Two solvers for each: the paper's trust-region-reflective ``scipy.optimize.least_squares``
with bounds, one sample at a time (``solver="trf"``, the reference), and our batched
Levenberg-Marquardt in numpy (``solver="lm"``), which solves many samples at once with the
closed-form glint Jacobians of :func:`estimator.projection.glint_jacobians` and takes a warm
start. Missing glints are masks. A sample with too few glints for its unknowns is NaN with the
reason ``"too_few_glints"``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .camera import Camera
from .eye import fick_angles, gaze_direction
from .geometry import rotations_from_vectors
from .projection import _jacobian_terms, glint_jacobians, project_glints

MODELS = {"center": 3, "orbit": 2, "full": 10}
#: Reason codes of a fit, per sample.
OK, TOO_FEW_GLINTS, NOT_CONVERGED, NON_FINITE = "ok", "too_few_glints", "not_converged", "non_finite"

#: LM stops when the step is below this in every unknown's natural unit (m, rad), or the cost
#: changes by less than ``_FTOL`` relatively: 1e-10 m is 1e-8 of the corneal radius, far below
#: what 0.1 px of glint noise can resolve (~1e-6 m).
_XTOL = 1e-10
_FTOL = 1e-14
#: A Gauss-Newton step below this is taken and ends the fit without another Jacobian. Units:
#: metres of cornea-centre motion (the orbit's angles count r_co per radian; the full model's
#: rotation counts in radians, its radius and translation in metres). The error left after a step s was measured (paper_sim, centre and orbit models,
#: 300 samples) at <= 4e4 /m x s² with exact glints (quadratic convergence) and <= 1.2e-3 s
#: with 0.5 px of glint noise, <= 4e-3 s with 2 px (the residual at the minimum is not zero
#: and Gauss-Newton converges linearly there): <= 4e-10 m after a 1e-7 m step either way,
#: 5e-5 of the ~8e-6 m scatter that 0.5 px of noise leaves in the centre.
_GN_STOP = 1e-7
#: Initial LM damping (relative to the diagonal of JᵀJ). Marquardt's usual 1e-3 shrinks the
#: poorly constrained depth direction of a centre fit enough that a start 30 um away needs a
#: third Jacobian (measured on paper_sim: 63 % of samples); 1e-6 does not.
_LAMBDA0 = 1e-6


@dataclass(frozen=True, slots=True)
class CorneaFit:
    """Per-sample results of a cornea fit (B samples).

    Attributes
    ----------
    center_m : (B, 3) float
        Cornea centre; NaN where the fit failed.
    radius_m : (B,) float
        Corneal radius (fitted by ``"full"``, given otherwise).
    angles_rad : (B, 2) float
        Fick (yaw, pitch) of the centre about the eye centre (``"orbit"`` only, else NaN).
    light_pose_rotvec : (B, 3) float
        Rotation vector of the lighting relative to its nominal pose about its centroid
        (``"full"`` only, else NaN).
    light_pose_translation_m : (B, 3) float
        Translation of the lighting relative to its nominal pose (``"full"`` only, else NaN).
    rms_px : (B,) float
        Root mean square glint residual.
    glints_used : (B,) int
    iterations : (B,) int
    reason : (B,) str
        ``"ok"``, ``"too_few_glints"``, ``"not_converged"`` or ``"non_finite"``.
    """

    center_m: np.ndarray
    radius_m: np.ndarray
    angles_rad: np.ndarray
    light_pose_rotvec: np.ndarray
    light_pose_translation_m: np.ndarray
    rms_px: np.ndarray
    glints_used: np.ndarray
    iterations: np.ndarray
    reason: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.reason == OK


@dataclass(frozen=True, slots=True)
class FitProblem:
    """What a cornea fit knows: camera, lights, and the model's fixed quantities."""

    camera: Camera
    lights_world_m: np.ndarray  # (n, 3) nominal light positions
    cornea_radius_m: float
    eye_center_m: np.ndarray | None = None  # "orbit"
    orbit_radius_m: float | None = None  # "orbit"
    # Glints and Jacobian at a shared starting point, per (model, start): what every batch
    # started there reuses (the arrays above are read-only copies, so this cannot go stale).
    _start_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        lights = np.array(self.lights_world_m, dtype=np.float64)
        if lights.ndim != 2 or lights.shape[1] != 3:
            raise ValueError(f"lights_world_m must have shape (n, 3), got {lights.shape}")
        lights.setflags(write=False)
        object.__setattr__(self, "lights_world_m", lights)
        object.__setattr__(self, "cornea_radius_m", float(self.cornea_radius_m))
        if self.eye_center_m is not None:
            c = np.array(self.eye_center_m, dtype=np.float64).reshape(3)
            c.setflags(write=False)
            object.__setattr__(self, "eye_center_m", c)

    def lights_posed(self, rotvec, translation_m) -> np.ndarray:
        """(B, n, 3) lights moved rigidly about their centroid."""
        L = self.lights_world_m
        pivot = L.mean(axis=0)
        R = rotations_from_vectors(np.atleast_2d(rotvec))
        return np.einsum("bij,nj->bni", R, L - pivot) + pivot + np.atleast_2d(translation_m)[:, None]


def _unpack(model, problem: FitProblem, x):
    """Cornea centre, radius and lights (B, n, 3) or (n, 3) for parameters x (B, p)."""
    if model == "center":
        return x, problem.cornea_radius_m, problem.lights_world_m
    if model == "orbit":
        d = gaze_direction(x[:, 0], x[:, 1])
        return problem.eye_center_m + problem.orbit_radius_m * d, problem.cornea_radius_m, problem.lights_world_m
    return x[:, :3], x[:, 3], problem.lights_posed(x[:, 4:7], x[:, 7:10])


def _residuals_and_jacobian(model, problem: FitProblem, x, glints, mask):
    """Residuals (B, 2n) and Jacobian (B, 2n, p); masked glints give zero rows."""
    center, radius, lights = _unpack(model, problem, x)
    g, _, d_c, d_r, d_l = glint_jacobians(problem.camera, center, radius, lights,
                                          radius_and_lights=model == "full")
    res = np.where(mask[..., None], g - glints, 0.0)
    B, n = mask.shape
    if model == "center":
        J = d_c
    elif model == "orbit":
        J = d_c @ _orbit_derivative(problem, x)[:, None]
    else:
        # Lights depend on the pose: dL/d(rotvec) by central differences of the rotation
        # (cheap: rotating n points), dL/dt = I.
        h = 1e-7
        dL_dw = np.empty((B, n, 3, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            dL_dw[..., k] = (problem.lights_posed(x[:, 4:7] + e, x[:, 7:10])
                             - problem.lights_posed(x[:, 4:7] - e, x[:, 7:10])) / (2 * h)
        J = np.concatenate([d_c, d_r[..., None], d_l @ dL_dw, d_l], axis=-1)
    J = np.where(mask[..., None, None], J, 0.0)
    return res.reshape(B, 2 * n), J.reshape(B, 2 * n, -1)


def _orbit_derivative(problem: FitProblem, x):
    """(B, 3, 2) derivative of the cornea centre on the orbit with respect to (yaw, pitch)."""
    yaw, pitch = x[:, 0], x[:, 1]
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    return np.stack([np.stack([cp * cy, np.zeros_like(cy), cp * sy], -1),
                     np.stack([-sp * sy, cp, sp * cy], -1)], -1) * problem.orbit_radius_m


def _normal_equations(model, problem: FitProblem, x, glints, mask):
    """Cost Σ r² (B,), JᵀJ (B, p, p) and Jᵀr (B, p) of the masked glint residuals at x: all
    that LM needs, without keeping the (B, 2n, p) Jacobian. The orbit's come from the centre's
    by the chain rule (Dᵀ JᵀJ D, Dᵀ Jᵀr with D the (3, 2) orbit derivative)."""
    if model == "full":
        r, J = _residuals_and_jacobian(model, problem, x, glints, mask)
        Jt = J.transpose(0, 2, 1)
        return np.einsum("bi,bi->b", r, r), Jt @ J, (Jt @ r[..., None])[..., 0]
    center, _, _ = _unpack(model, problem, x)
    T = _jacobian_terms(problem.camera, center, problem.cornea_radius_m, problem.lights_world_m,
                        with_visibility=False)
    # Sums over the glints of the camera-frame rows, rotated once per sample (J_world =
    # J_camera R). A masked glint's rows and residual are zero; the where() also drops the NaN
    # of a glint behind the camera.
    ru = np.where(mask, T.u - glints[..., 0], 0.0)
    rv = np.where(mask, T.v - glints[..., 1], 0.0)
    Ju = [np.where(mask, a, 0.0) for a in T.row_u]
    Jv = [np.where(mask, a, 0.0) for a in T.row_v]
    B = mask.shape[0]
    JtJ = np.empty((B, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            JtJ[:, i, j] = JtJ[:, j, i] = np.add.reduce(Ju[i] * Ju[j] + Jv[i] * Jv[j], axis=1)
    Jtr = np.stack([np.add.reduce(Ju[i] * ru + Jv[i] * rv, axis=1) for i in range(3)], -1)
    cost = np.add.reduce(ru * ru + rv * rv, axis=1)
    R = problem.camera.rotation
    JtJ, Jtr = R.T @ JtJ @ R, Jtr @ R
    if model == "orbit":
        D = _orbit_derivative(problem, x)
        Dt = D.transpose(0, 2, 1)
        JtJ, Jtr = Dt @ JtJ @ D, (Dt @ Jtr[..., None])[..., 0]
    return cost, JtJ, Jtr


def _prepare(glints_px, mask, n_lights, p):
    glints = np.asarray(glints_px, dtype=np.float64)
    if glints.ndim == 2:
        glints = glints[None]
    if glints.ndim != 3 or glints.shape[1:] != (n_lights, 2):
        raise ValueError(f"glints_px must have shape (B, {n_lights}, 2), got {np.shape(glints_px)}")
    m = np.isfinite(glints).all(-1) if mask is None else np.asarray(mask, dtype=bool).reshape(glints.shape[:2])
    m = m & np.isfinite(glints).all(-1)
    glints = np.where(m[..., None], glints, 0.0)
    enough = 2 * m.sum(axis=1) >= p
    return glints, m, enough


def fit_cornea(problem: FitProblem, glints_px, mask=None, x0=None, *, model: str = "center",
               solver: str = "lm", lower=None, upper=None, max_iter: int = 50) -> CorneaFit:
    """Fit the cornea to detected glints of a batch of samples.

    Parameters
    ----------
    problem : FitProblem
    glints_px : (B, n, 2) or (n, 2) float
        Detected glint of each light (any value where masked; NaN counts as missing).
    mask : (B, n) bool, optional
        True where light i's glint was detected. Default: the finite glints.
    x0 : (B, p) or (p,) float
        Initial parameters: centre (m) for ``"center"``; (yaw, pitch) in rad for ``"orbit"``;
        centre, radius, rotation vector (rad) and translation (m) of the lighting for ``"full"``.
    model : {"center", "orbit", "full"}
    solver : {"lm", "trf"}
        Our batched Levenberg-Marquardt, or the paper's scipy trust-region-reflective.
    lower, upper : (p,) float, optional
        Bounds. TRF enforces them its own way; LM holds an unknown on its bound while the
        gradient pushes it outward (an active set) and clips steps to the box.
    max_iter : int
    """
    if model not in MODELS:
        raise ValueError(f"model must be one of {sorted(MODELS)}, got {model!r}")
    if model == "orbit" and (problem.eye_center_m is None or problem.orbit_radius_m is None):
        raise ValueError("the orbit model needs eye_center_m and orbit_radius_m in the FitProblem")
    p = MODELS[model]
    n = problem.lights_world_m.shape[0]
    glints, mask, enough = _prepare(glints_px, mask, n, p)
    B = glints.shape[0]
    if x0 is None:
        raise ValueError("x0 (initial parameters) is required")
    x0 = np.asarray(x0, dtype=np.float64)
    shared = x0.ndim == 1
    if x0.shape[-1] != p:
        raise ValueError(f"x0 must have {p} parameters for the {model!r} model, got shape {x0.shape}")
    x0 = np.broadcast_to(x0, (B, p)).copy()
    lo = np.full(p, -np.inf) if lower is None else np.asarray(lower, dtype=np.float64)
    hi = np.full(p, np.inf) if upper is None else np.asarray(upper, dtype=np.float64)
    if solver == "lm" and shared and B > 1:
        if model == "orbit":
            # The Fick angles bend the orbit: a shared step in angles from primary gaze lands
            # 0.2 rad off at 17 deg of gaze, the centre's nearly linear map 3-7 mrad (measured
            # on paper_sim). Step the centre, then put it back on the orbit.
            c_ref = _unpack("orbit", problem, x0[:1])[0][0]
            c = _shared_first_step("center", problem, glints, mask, c_ref, enough)
            x0 = np.column_stack(fick_angles(c - problem.eye_center_m))
        else:
            x0 = _shared_first_step(model, problem, glints, mask, x0[0], enough)
        x0 = np.clip(x0, lo, hi)
    if solver == "lm":
        x, rms, iters, converged = _lm(model, problem, glints, mask, x0, enough, lo, hi, max_iter)
    elif solver == "trf":
        x, rms, iters, converged = _trf(model, problem, glints, mask, x0, enough, lo, hi, max_iter)
    else:
        raise ValueError(f"solver must be 'lm' or 'trf', got {solver!r}")
    reason = np.full(B, OK, dtype=object)
    reason[~converged] = NOT_CONVERGED
    reason[~np.isfinite(x).all(axis=1)] = NON_FINITE
    reason[~enough] = TOO_FEW_GLINTS
    bad = reason != OK
    x[bad] = np.nan
    rms = np.where(bad, np.nan, rms)
    center, radius, _ = _unpack(model, problem, x)
    nan3 = np.full((B, 3), np.nan)
    return CorneaFit(
        center_m=np.asarray(center, dtype=np.float64).reshape(B, 3),
        radius_m=np.broadcast_to(np.asarray(radius, dtype=np.float64), (B,)).copy(),
        angles_rad=x[:, :2].copy() if model == "orbit" else np.full((B, 2), np.nan),
        light_pose_rotvec=x[:, 4:7].copy() if model == "full" else nan3,
        light_pose_translation_m=x[:, 7:10].copy() if model == "full" else nan3.copy(),
        rms_px=rms, glints_used=mask.sum(axis=1), iterations=iters, reason=reason.astype(str))


def _shared_first_step(model, problem, glints, mask, x_ref, enough):
    """A Gauss-Newton step for every sample from one shared starting point, with the Jacobian
    evaluated once at that point (only the masks differ per sample): a cold start for the
    price of one projection. Samples whose step is not finite keep ``x_ref``."""
    n = mask.shape[1]
    key = (model, x_ref.tobytes())
    if key not in problem._start_cache:
        if len(problem._start_cache) >= 8:
            problem._start_cache.clear()
        r0, J0 = _residuals_and_jacobian(model, problem, x_ref[None], np.zeros_like(glints[:1]),
                                         np.ones_like(mask[:1]))
        J0 = J0.reshape(n, 2, -1)
        # Glints predicted at x_ref (the residual against zeros), J and per-light JᵀJ.
        problem._start_cache[key] = (r0.reshape(n, 2), J0, np.einsum("nki,nkj->nij", J0, J0))
    g0, J0, JtJ_i = problem._start_cache[key]
    A = np.einsum("bn,nij->bij", mask.astype(float), JtJ_i)
    d = np.where(mask[..., None], glints - g0, 0.0)
    rhs = np.einsum("nki,bnk->bi", J0, d)
    x = np.broadcast_to(x_ref, (glints.shape[0], x_ref.size)).copy()
    # Solvable: Hadamard's ratio det(A) / Π diag(A) of the positive semi-definite A (1 for an
    # orthogonal problem, 0 for a singular one) above 1e-12.
    ok = enough & (np.linalg.det(A) > 1e-12 * np.prod(np.einsum("bii->bi", A), axis=1))
    if ok.any():
        x[ok] += np.linalg.solve(A[ok], rhs[ok][..., None])[..., 0]
    bad = ~np.isfinite(x).all(axis=1)
    x[bad] = x_ref
    return x


def _lm(model, problem, glints, mask, x0, enough, lo, hi, max_iter):
    """Batched Levenberg-Marquardt (Marquardt's diagonal scaling), one Jacobian per iteration.

    Each iteration evaluates the normal equations at the trial points of the samples still
    running; a trial that lowers the cost is kept (and its normal equations are the next
    ones), one that does not raises that sample's damping and keeps the old point."""
    B, p = x0.shape
    # The stopping step in each unknown's unit: metres of cornea-centre motion for the orbit's
    # angles (r_co per radian).
    gn_stop = _GN_STOP / problem.orbit_radius_m if model == "orbit" else _GN_STOP
    x = np.clip(x0, lo, hi)
    active = enough.copy()
    iters = np.zeros(B, dtype=int)
    converged = np.zeros(B, dtype=bool)
    cost = np.full(B, np.inf)
    # Nearly Gauss-Newton from the start (the starts are good: the previous sample, or the
    # shared first step); a rejected step jumps to Marquardt's usual 1e-3 and grows from there.
    lam = np.full(B, _LAMBDA0)
    JtJ = np.zeros((B, p, p))
    Jtr = np.zeros((B, p))
    eye = np.eye(p)
    idx = np.flatnonzero(active)
    if idx.size:
        cost[idx], JtJ[idx], Jtr[idx] = _normal_equations(model, problem, x[idx], glints[idx], mask[idx])
    for _ in range(max_iter):
        idx = np.flatnonzero(active & ~converged)
        if idx.size == 0:
            break
        H, g = JtJ[idx], Jtr[idx]
        diag = np.einsum("bii->bi", H)
        A = H + (lam[idx, None] * np.maximum(diag, 1e-30))[..., None] * eye
        # Active set: an unknown sitting on a bound whose gradient pushes it outward is held
        # there (its row and column of the system become identity), so the others still reach
        # the constrained minimum instead of being dragged by a clipped step.
        xi = x[idx]
        held = ((xi <= lo) & (g > 0)) | ((xi >= hi) & (g < 0))
        rhs = g
        if held.any():
            free = ~held
            A = A * free[:, :, None] * free[:, None, :] + held[:, :, None] * eye
            rhs = g * free
        with np.errstate(invalid="ignore", over="ignore"):
            step = -np.linalg.solve(A, rhs[..., None])[..., 0]
        x_new = np.clip(xi + step, lo, hi)
        step = x_new - xi
        # A step the model cannot evaluate (a singular system's non-finite step, a radius
        # driven through zero) counts as a rejected step: more damping, same point.
        usable = np.isfinite(x_new).all(axis=1)
        if model == "full":
            usable &= x_new[:, 3] > 0
        if not usable.all():
            bad_idx = idx[~usable]
            lam[bad_idx] = np.maximum(lam[bad_idx] * 10, 1e-3)
            iters[bad_idx] += 1
            idx, x_new, step, xi, H, g = idx[usable], x_new[usable], step[usable], xi[usable], H[usable], g[usable]
            if idx.size == 0:
                continue
        # A Gauss-Newton step this small leaves an error far below the noise (see _GN_STOP):
        # take it and stop without paying for another Jacobian.
        tiny = (lam[idx] <= 1e-3) & (np.abs(step) <= gn_stop * np.maximum(1.0, np.abs(xi))).all(axis=1)
        if tiny.any():
            t_idx = idx[tiny]
            s = step[tiny]
            x[t_idx] = x_new[tiny]
            # The cost after the step, to second order in the step (the linearised residual).
            pred = cost[t_idx] + 2 * np.einsum("bi,bi->b", s, g[tiny]) + np.einsum("bi,bij,bj->b", s, H[tiny], s)
            cost[t_idx] = np.maximum(pred, 0.0)
            converged[t_idx] = True
            iters[t_idx] += 1
            keep = ~tiny
            idx, x_new, xi = idx[keep], x_new[keep], xi[keep]
            if idx.size == 0:
                continue
        with np.errstate(invalid="ignore", over="ignore"):
            cost_new, JtJ_new, Jtr_new = _normal_equations(model, problem, x_new, glints[idx], mask[idx])
        better = np.isfinite(cost_new) & (cost_new <= cost[idx])
        iters[idx] += 1
        acc = idx[better]
        small = (np.abs(x_new - xi) <= _XTOL * np.maximum(1.0, np.abs(xi))).all(axis=1)
        flat = np.abs(cost[idx] - cost_new) <= _FTOL * np.maximum(cost[idx], 1e-30)
        x[acc], cost[acc], JtJ[acc], Jtr[acc] = x_new[better], cost_new[better], JtJ_new[better], Jtr_new[better]
        lam[acc] = np.maximum(lam[acc] / 10, 1e-12)
        rej = idx[~better]
        lam[rej] = np.maximum(lam[rej] * 10, 1e-3)
        # Converged: an accepted step that changed nothing, or a damping so large that no
        # step lowers the cost any more (a minimum to machine precision).
        converged[idx[(better & (small | flat | (cost_new == 0))) | (~better & (lam[idx] > 1e12))]] = True
    rms = np.sqrt(cost / np.maximum(mask.sum(axis=1), 1))
    return x, rms, iters, converged


def _trf(model, problem, glints, mask, x0, enough, lo, hi, max_iter):
    """The paper's solver: scipy's trust-region-reflective per sample, 2-point Jacobian."""
    B, p = x0.shape
    x = x0.copy()
    rms = np.full(B, np.nan)
    iters = np.zeros(B, dtype=int)
    converged = np.zeros(B, dtype=bool)
    for b in np.flatnonzero(enough):
        m = mask[b]

        def fun(xb, b=b, m=m):
            center, radius, lights = _unpack(model, problem, xb[None])
            g, _ = project_glints(problem.camera, center[0] if np.ndim(center) == 2 else center,
                                  radius if np.ndim(radius) == 0 else radius[0],
                                  lights if lights.ndim == 2 else lights[0])
            return (g[m] - glints[b, m]).ravel()

        x0b = np.clip(x0[b], np.nextafter(lo, hi), np.nextafter(hi, lo))
        res = least_squares(fun, x0b, bounds=(lo, hi), method="trf", max_nfev=max_iter * (p + 1),
                            xtol=1e-12, ftol=1e-12, gtol=1e-12)
        x[b], iters[b], converged[b] = res.x, res.nfev, res.status > 0
        rms[b] = np.sqrt(2 * res.cost / max(m.sum(), 1))
    return x, rms, iters, converged
