"""Cornea fits: the cornea centre (and radius, and lighting pose) from detected glints.

Sec. 2.2 of the SCET paper: minimise the sum of squared distances between the detected glints
and the glints re-projected by the closed-form forward projection. Three models:

- ``"center"``: the cornea centre c (3 unknowns; known r_c and lighting), for polynomial gaze;
- ``"center_radius"``: c and r_c (4 unknowns; known lighting), the paper's per-frame reading
  of Sec. 3.1;
- ``"orbit"``: the cornea centre on a sphere of radius r_co about the eye centre c_e, in Fick
  angles (2 unknowns), for geometric gaze (Sec. 2.2.1);
- ``"full"``: c, r_c and the lighting's rigid pose (10 unknowns), for calibration (Sec. 2.4).

Two solvers for each: the paper's trust-region-reflective ``scipy.optimize.least_squares``
with bounds, one sample at a time (``solver="trf"``, the reference), and our batched
Levenberg-Marquardt in numpy (``solver="lm"``, :mod:`estimator.cornea.solve`), which solves
many samples at once on the closed-form glint Jacobians and takes a warm start. Missing glints
are masks. An optional Gaussian prior on the parameters (the previous band's estimate, say)
adds (x - μ)ᵀ Λ (x - μ) to the cost. A sample with too few glints for its unknowns and no prior
is NaN with the reason ``"too_few_glints"``.
"""

from __future__ import annotations

import numpy as np

import estimator.cornea.solve as _solve

from ..eye import fick_angles
from .problem import MODELS, NON_FINITE, NOT_CONVERGED, OK, TOO_FEW_GLINTS, CorneaFit, FitProblem


def _prepare(glints_px, mask, n_lights, p):
    glints = np.asarray(glints_px, dtype=np.float64)
    if glints.ndim == 2:
        glints = glints[None]
    if glints.ndim != 3 or glints.shape[1:] != (n_lights, 2):
        raise ValueError(f"glints_px must have shape (B, {n_lights}, 2), got {np.shape(glints_px)}")
    finite = np.isfinite(glints[..., 0]) & np.isfinite(glints[..., 1])
    m = finite if mask is None else np.asarray(mask, dtype=bool).reshape(glints.shape[:2]) & finite
    if not m.all():
        glints = np.where(m[..., None], glints, 0.0)
    enough = 2 * m.sum(axis=1) >= p
    return glints, m, enough


def _prior(prior_mean, prior_information, B: int, p: int):
    """A :class:`estimator.cornea.solve.Prior` from the user's arrays, or None."""
    if prior_mean is None and prior_information is None:
        return None
    if prior_mean is None or prior_information is None:
        raise ValueError("prior_mean and prior_information must be given together")
    mean = np.broadcast_to(np.asarray(prior_mean, dtype=np.float64), (B, p))
    info = np.broadcast_to(np.asarray(prior_information, dtype=np.float64), (B, p, p))
    present = np.isfinite(mean).all(axis=1) & np.isfinite(info).all(axis=(1, 2))
    if present.any():
        Ip = info[present]
        if not np.allclose(Ip, np.swapaxes(Ip, 1, 2), rtol=1e-9, atol=0) or \
                np.linalg.eigvalsh(Ip).min(axis=1).min() < -1e-9 * np.abs(Ip).max():
            raise ValueError("prior_information must be symmetric positive semi-definite")
    return _solve.Prior(np.where(present[:, None], mean, 0.0),
                        np.where(present[:, None, None], info, 0.0), present)


def fit_cornea(problem: FitProblem, glints_px, mask=None, x0=None, *, model: str = "center",
               solver: str = "lm", lower=None, upper=None, max_iter: int = 50,
               prior_mean=None, prior_information=None) -> CorneaFit:
    """Fit the cornea to detected glints of a batch of samples.

    Parameters
    ----------
    problem : FitProblem
    glints_px : (B, n, 2) or (n, 2) float
        Detected glint of each light (any value where masked; NaN counts as missing).
    mask : (B, n) bool, optional
        True where light i's glint was detected. Default: the finite glints.
    x0 : (B, p) or (p,) float
        Initial parameters: centre (m) for ``"center"``; centre and radius (m) for
        ``"center_radius"``; (yaw, pitch) in rad for ``"orbit"``; centre, radius, rotation
        vector (rad) and translation (m) of the lighting for ``"full"``. A shared (p,) start
        gets one Gauss-Newton step for all samples at the price of one projection first.
    model : {"center", "center_radius", "orbit", "full"}
    solver : {"lm", "trf"}
        Our batched Levenberg-Marquardt, or the paper's scipy trust-region-reflective.
    lower, upper : (p,) float, optional
        Bounds. TRF enforces them its own way; LM holds an unknown on its bound while the
        gradient pushes it outward (an active set) and clips steps to the box.
    max_iter : int
    prior_mean : (B, p) or (p,) float, optional
        Mean μ of a Gaussian prior on the parameters; a sample whose mean or information is not
        finite has no prior.
    prior_information : (B, p, p) or (p, p) float, optional
        Λ, in px² per unit²: the fit minimises Σ |glint residual|² + (x - μ)ᵀ Λ (x - μ). For a
        prior covariance Σ and glint noise σ px per axis, Λ = σ² Σ⁻¹. A sample with a prior
        needs no glints (with none it returns μ).
    """
    if model not in MODELS:
        raise ValueError(f"model must be one of {sorted(MODELS)}, got {model!r}")
    if model == "orbit" and (problem.eye_center_m is None or problem.orbit_radius_m is None):
        raise ValueError("the orbit model needs eye_center_m and orbit_radius_m in the FitProblem")
    if solver not in ("lm", "trf"):
        raise ValueError(f"solver must be 'lm' or 'trf', got {solver!r}")
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
    prior = _prior(prior_mean, prior_information, B, p)
    if prior is not None:
        enough = enough | prior.present
    # The shared step linearises about one point for all samples; not for the 10-unknown
    # model, whose flat valley makes that linearisation meaningless far from the minimum.
    if solver == "lm" and shared and B > 1 and prior is None and model != "full":
        if model == "orbit":
            # The Fick angles bend the orbit: a shared step in angles from primary gaze lands
            # 0.2 rad off at 17 deg of gaze, the centre's nearly linear map 3-7 mrad (measured
            # on paper_sim). Step the centre, then put it back on the orbit.
            c_ref = _solve.unpack("orbit", problem, x0[:1])[0][0]
            c = _solve.shared_first_step("center", problem, glints, mask, c_ref, enough)
            x0 = np.column_stack(fick_angles(c - problem.eye_center_m))
        else:
            x0 = _solve.shared_first_step(model, problem, glints, mask, x0[0], enough)
        x0 = np.clip(x0, lo, hi)
    run = _solve.lm if solver == "lm" else _solve.trf
    x, rms, iters, converged = run(model, problem, glints, mask, x0, enough, lo, hi, max_iter, prior)
    reason = np.full(B, OK, dtype=object)
    reason[~converged] = NOT_CONVERGED
    reason[~np.isfinite(x).all(axis=1)] = NON_FINITE
    reason[~enough] = TOO_FEW_GLINTS
    bad = reason != OK
    x[bad] = np.nan
    rms = np.where(bad | (mask.sum(axis=1) == 0), np.nan, rms)
    center, radius, _ = _solve.unpack(model, problem, x)
    nan3 = np.full((B, 3), np.nan)
    return CorneaFit(
        center_m=np.asarray(center, dtype=np.float64).reshape(B, 3),
        radius_m=np.broadcast_to(np.asarray(radius, dtype=np.float64), (B,)).copy(),
        angles_rad=x[:, :2].copy() if model == "orbit" else np.full((B, 2), np.nan),
        light_pose_rotvec=x[:, 4:7].copy() if model == "full" else nan3,
        light_pose_translation_m=x[:, 7:10].copy() if model == "full" else nan3.copy(),
        rms_px=rms, glints_used=mask.sum(axis=1), iterations=iters, reason=reason.astype(str))


def fit_covariance(problem: FitProblem, x, mask, *, model: str, noise_px: float) -> np.ndarray:
    """(B, p, p) Gauss-Newton covariance σ² (JᵀJ)⁻¹ of fits at parameters x (B, p) with glint
    noise of standard deviation ``noise_px`` on each image axis, over the glints in ``mask``
    (B, n). Infinite where x is not finite or the glints do not determine every unknown
    (Hadamard's ratio of JᵀJ below 1e-12)."""
    if model not in MODELS or model == "full":
        raise ValueError(f"model must be one of 'center', 'center_radius', 'orbit', got {model!r}")
    p = MODELS[model]
    x = np.asarray(x, dtype=np.float64).reshape(-1, p)
    m = np.asarray(mask, dtype=bool).reshape(x.shape[0], problem.lights_world_m.shape[0])
    cov = np.full((x.shape[0], p, p), np.inf)
    ok = np.isfinite(x).all(axis=1) & m.any(axis=1)
    if ok.any():
        _, info, _ = _solve.normal_equations(model, problem, x[ok], np.zeros(m[ok].shape + (2,)), m[ok])
        diag = np.einsum("bii->bi", info)
        well = np.linalg.det(info) > 1e-12 * np.prod(diag, axis=1)
        sub = np.full((ok.sum(), p, p), np.inf)
        if well.any():
            sub[well] = noise_px ** 2 * np.linalg.inv(info[well])
        cov[ok] = sub
    return cov
