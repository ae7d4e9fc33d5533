"""System calibration (Sec. 2.4 and 3.1 of the SCET paper) and gaze mappings (Sec. 2.2.2, 3.3.1).

Four steps, each in two flavours: the paper's as described, and ours.

1. **Lighting pose and corneal radius** from frames of the eye fixating calibration targets,
   lit by a rigid light group of known shape (the 6x6 grid of Sec. 3.1). Unknowns: cornea
   centre c_c, radius r_c and the group's rigid pose (rotation vector about the nominal
   centroid plus translation). The paper fits all ten per frame
   (:func:`calibrate_lighting_per_frame`); that problem is badly conditioned (pose and centre
   trade off), so ours fits all frames at once with one r_c and one pose shared and a centre per
   frame (:func:`calibrate_lighting_joint`). The result is a world-frame :class:`RigidPose`
   correction; since every light group is mounted on the same frame, the same correction moves
   any of them (:func:`corrected_lights`): the grid's calibrates the arc's.
2. **Eye centre c_e and orbit radius r_co** from the cornea centres of the calibration frames:
   the paper's law of sines (:func:`orbit_law_of_sines`) and its baseline, the least-squares
   sphere (:func:`orbit_sphere_fit`, Ahn et al. 2001).
3. **Ours, all at once**: :func:`calibrate_joint` fits r_c, the lighting pose, c_e and r_co to
   the glints of every calibration frame, the cornea centre of frame i being
   c_e + r_co d_i with d_i the direction from c_e to the known target (or free Fick angles).
4. **Gaze mappings** from cornea centre (and the distance reading d_a) to screen point:
   :func:`fit_gaze_mapping` -> :class:`GazeMapping`.

Everything ends up in a :class:`Calibration`, written as versioned JSON.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .camera import Camera
from .cornea import FitProblem, fit_cornea
from .eye import BOHME_CORNEA_OFFSET_M, BOHME_CORNEA_RADIUS_M, fick_angles, gaze_direction
from .geometry import RigidPose, as_points, rotation_from_vector, rotations_from_vectors
from .projection import glint_jacobians
from .mapping import (MAPPING_TERMS, RANK_RTOL, GazeMapping, _check_format,  # noqa: F401
                      distance_reading, fit_gaze_mapping)

#: Corneal radius prior, Read et al. (2006), "The topography of the central and peripheral
#: cornea", IOVS 47(4):1404-1415: conic fits to 100 young adults gave an apical radius of
#: 7.77 +/- 0.2 mm (mean +/- SD, 6 mm corneal diameter). Initial value: the mean; bounds: the
#: mean +/- 5 SD, which holds essentially every normal cornea and keeps the solver away from
#: unphysical radii (the paper's simulated eye, 7.8 mm, sits 0.15 SD above the mean).
CORNEA_RADIUS_INIT_M = 7.77e-3
CORNEA_RADIUS_SD_M = 0.2e-3
CORNEA_RADIUS_BOUNDS_M = (CORNEA_RADIUS_INIT_M - 5 * CORNEA_RADIUS_SD_M,
                          CORNEA_RADIUS_INIT_M + 5 * CORNEA_RADIUS_SD_M)
#: Lighting pose bounds about the nominal pose of the apparatus' 3D model (Sec. 2.4): the
#: frame is assembled and worn to within a few millimetres and degrees.
POSE_BOUND_M = 5e-3
POSE_BOUND_RAD = np.deg2rad(5.0)
#: Orbit radius bounds for the joint fit (m): Böhme's 4.35 mm is ~0.55 r_c; anything outside
#: 1-10 mm is not an eye.
ORBIT_RADIUS_BOUNDS_M = (1e-3, 10e-3)

CALIBRATION_FORMAT, CALIBRATION_VERSION = "scet-calibration", 1


# --------------------------------------------------------------------------------------------
# Lighting pose


def pose_correction(rotvec_rad, translation_m, pivot_m) -> RigidPose:
    """World-frame rigid correction of a rotation ``rotvec_rad`` about ``pivot_m`` followed by a
    translation: ``L -> R (L - pivot) + pivot + t`` (the parametrisation of
    :meth:`estimator.cornea.FitProblem.lights_posed`)."""
    R = rotation_from_vector(rotvec_rad)
    pivot = as_points(pivot_m, "pivot_m").reshape(3)
    return RigidPose(R, pivot + as_points(translation_m, "translation_m").reshape(3) - R @ pivot)


def corrected_lights(correction: RigidPose, lights_world_m) -> np.ndarray:
    """(n, 3) lights moved by a lighting correction. Every light group rides on the same rigid
    frame, so the correction estimated with the calibration grid applies to the arc as well."""
    return correction.apply(as_points(lights_world_m, "lights_world_m"))


@dataclass(frozen=True, slots=True)
class LightingFit:
    """Lighting pose and corneal radius from calibration frames.

    Attributes
    ----------
    correction : RigidPose
        World-frame correction: true lights = ``correction.apply(nominal lights)``.
    rotvec_rad, translation_m : (3,) float
        The same correction as a rotation about ``pivot_m`` (the nominal centroid) and a shift.
    pivot_m : (3,) float
    cornea_radius_m : float
        Estimated r_c (per-frame method: the mean over frames).
    cornea_radius_sd_m : float
        SD of the per-frame r_c (per-frame method); NaN for the joint fit.
    cornea_centers_m : (m, 3) float
        Cornea centre of each frame (NaN where the frame's fit failed).
    frame_radius_m : (m,) float
        Per-frame r_c (the shared value repeated for the joint fit).
    rms_px : float
        RMS glint residual over all frames.
    method : str
    converged : bool
        False when the solver stopped at its evaluation limit (the result is then a best effort).
    """

    correction: RigidPose
    rotvec_rad: np.ndarray
    translation_m: np.ndarray
    pivot_m: np.ndarray
    cornea_radius_m: float
    cornea_radius_sd_m: float
    cornea_centers_m: np.ndarray
    frame_radius_m: np.ndarray
    rms_px: float
    method: str
    converged: bool = True


def _check_frames(lights_m, glints_px, mask):
    lights = as_points(lights_m, "lights_world_m")
    if lights.ndim != 2:
        raise ValueError(f"lights_world_m must have shape (n, 3), got {lights.shape}")
    g = np.asarray(glints_px, dtype=np.float64)
    if g.ndim == 2:
        g = g[None]
    if g.ndim != 3 or g.shape[1:] != (lights.shape[0], 2):
        raise ValueError(f"glints_px must have shape (m, {lights.shape[0]}, 2), got {np.shape(glints_px)}")
    m = np.isfinite(g).all(-1)
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != g.shape[:2]:
            raise ValueError(f"mask must have shape {g.shape[:2]}, got {mask.shape}")
        m &= mask
    return lights, np.where(m[..., None], g, 0.0), m


def _start_centers(camera, lights, radius, glints, mask, center0_m):
    """Cornea centre of each frame with the nominal lights: the joint fits' starting point."""
    problem = FitProblem(camera, lights, radius)
    fit = fit_cornea(problem, np.where(mask[..., None], glints, np.nan), mask, center0_m, model="center")
    c = fit.center_m
    return np.where(np.isfinite(c), c, center0_m)


def calibrate_lighting_per_frame(camera: Camera, lights_world_m, glints_px, mask=None, *, center0_m,
                                 solver: str = "trf", radius0_m: float = CORNEA_RADIUS_INIT_M,
                                 radius_bounds_m=CORNEA_RADIUS_BOUNDS_M,
                                 rotation_bound_rad: float = POSE_BOUND_RAD,
                                 translation_bound_m: float = POSE_BOUND_M, max_iter: int = 100) -> LightingFit:
    """The paper's lighting calibration (Sec. 2.4): ten unknowns fitted to each frame alone.

    Each frame gets its own c_c, r_c and lighting pose (``fit_cornea(model="full")``, TRF with
    bounds by default, as in the paper). The paper does not say how the frames are combined;
    we average r_c, the rotation vector and the translation over the frames whose fit succeeded
    (a plain mean, exact to second order for rotations of a few degrees).

    Parameters
    ----------
    camera : Camera
    lights_world_m : (n, 3) float
        Nominal light positions (from the apparatus' 3D model).
    glints_px : (m, n, 2) float
        Detected glints of m frames (NaN = missing).
    mask : (m, n) bool, optional
    center0_m : (3,) float
        Initial cornea centre (the primary position of the nominal eye, as in Sec. 2.2.1).
    """
    lights, glints, m = _check_frames(lights_world_m, glints_px, mask)
    c0 = as_points(center0_m, "center0_m").reshape(3)
    x0 = np.concatenate([c0, [radius0_m], np.zeros(6)])
    lo = np.concatenate([np.full(3, -np.inf), [radius_bounds_m[0]], np.full(3, -rotation_bound_rad),
                         np.full(3, -translation_bound_m)])
    hi = -lo
    hi[3] = radius_bounds_m[1]
    problem = FitProblem(camera, lights, radius0_m)
    fit = fit_cornea(problem, np.where(m[..., None], glints, np.nan), m, x0, model="full", solver=solver,
                     lower=lo, upper=hi, max_iter=max_iter)
    ok = fit.ok
    if not ok.any():
        raise ValueError(f"lighting calibration failed on every frame (reasons: {sorted(set(fit.reason))})")
    rotvec = fit.light_pose_rotvec[ok].mean(axis=0)
    trans = fit.light_pose_translation_m[ok].mean(axis=0)
    pivot = lights.mean(axis=0)
    radius = fit.radius_m[ok]
    res2 = (fit.rms_px[ok] ** 2 * fit.glints_used[ok]).sum() / fit.glints_used[ok].sum()
    return LightingFit(pose_correction(rotvec, trans, pivot), rotvec, trans, pivot, float(radius.mean()),
                       float(radius.std(ddof=1)) if radius.size > 1 else float("nan"),
                       fit.center_m, fit.radius_m, float(np.sqrt(res2)), f"per_frame_{solver}", True)


def _pose_derivative(lights, pivot, rotvec):
    """(n, 3, 3) d light / d rotation vector, by central differences of the rotation (cheap:
    rotating n points; error ~h^2 ~ 1e-14 relative)."""
    h = 1e-7
    out = np.empty(lights.shape + (3,))
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        Rp, Rm = rotations_from_vectors(np.stack([rotvec + e, rotvec - e]))
        out[..., k] = (lights - pivot) @ (Rp - Rm).T / (2 * h)
    return out


class _Joint:
    """Stacked least squares over m frames: shared r_c and lighting pose, and cornea centres
    given by an eye model.

    Parameters are ``[r_c, rotvec (3), translation (3), *eye]`` where ``eye`` is
    ``"centers"``: one free centre per frame (3m); ``"targets"``: c_e (3), r_co, with the
    centre of frame i at c_e + r_co (T_i - c_e)/|T_i - c_e|; ``"angles"``: c_e, r_co and free
    Fick angles per frame (2m), centre c_e + r_co d(yaw_i, pitch_i).
    """

    def __init__(self, camera, lights, glints, mask, eye, targets=None):
        self.camera, self.lights, self.glints, self.mask = camera, lights, glints, mask
        self.eye, self.targets = eye, targets
        self.pivot = lights.mean(axis=0)
        self.m = glints.shape[0]
        self._cache_x, self._cache = None, None

    def centers(self, q):
        """Cornea centres (m, 3) and their Jacobian (m, 3, len(q)) for eye parameters q."""
        m = self.m
        if self.eye == "centers":
            C = q.reshape(m, 3)
            dC = np.zeros((m, 3, 3 * m))
            for i in range(m):
                dC[i, :, 3 * i:3 * i + 3] = np.eye(3)
            return C, dC
        ce, r = q[:3], q[3]
        if self.eye == "targets":
            v = self.targets - ce
            D = np.linalg.norm(v, axis=1)
            u = v / D[:, None]
            dC = np.zeros((m, 3, 4))
            dC[:, :, :3] = np.eye(3) - (r / D)[:, None, None] * (np.eye(3) - u[:, :, None] * u[:, None, :])
            dC[:, :, 3] = u
            return ce + r * u, dC
        yaw, pitch = q[4::2], q[5::2]
        d = gaze_direction(yaw, pitch)
        cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
        dC = np.zeros((m, 3, 4 + 2 * m))
        dC[:, :, :3] = np.eye(3)
        dC[:, :, 3] = d
        idx = np.arange(m)
        dC[idx, :, 4 + 2 * idx] = r * np.stack([cp * cy, np.zeros_like(cy), cp * sy], -1)
        dC[idx, :, 5 + 2 * idx] = r * np.stack([-sp * sy, cp, sp * cy], -1)
        return ce + r * d, dC

    def _eval(self, x):
        if self._cache_x is not None and np.array_equal(x, self._cache_x):
            return self._cache
        r_c, w, t, q = x[0], x[1:4], x[4:7], x[7:]
        R = rotation_from_vector(w)
        L = (self.lights - self.pivot) @ R.T + self.pivot + t
        C, dC = self.centers(q)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            g, _, d_c, d_r, d_l = glint_jacobians(self.camera, C, r_c, L)
        res = (g - self.glints)[self.mask].ravel()
        J = np.concatenate([d_r[..., None], d_l @ _pose_derivative(self.lights, self.pivot, w),
                            d_l, np.einsum("mnkj,mjq->mnkq", d_c, dC)], axis=-1)
        J = J[self.mask].reshape(res.size, x.size)
        self._cache_x, self._cache = x.copy(), (res, J)
        return res, J

    def residuals(self, x):
        return self._eval(x)[0]

    def jacobian(self, x):
        return self._eval(x)[1]

    def solve(self, x0, lo, hi, max_nfev):
        x0 = np.clip(x0, np.nextafter(lo, hi), np.nextafter(hi, lo))
        return least_squares(self.residuals, x0, jac=self.jacobian, bounds=(lo, hi), method="trf",
                             x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev)


def _pose_bounds(radius_bounds_m, rotation_bound_rad, translation_bound_m):
    lo = np.concatenate([[radius_bounds_m[0]], np.full(3, -rotation_bound_rad), np.full(3, -translation_bound_m)])
    hi = np.concatenate([[radius_bounds_m[1]], np.full(3, rotation_bound_rad), np.full(3, translation_bound_m)])
    return lo, hi


def _lighting_fit(joint, sol, method):
    r_c, w, t = float(sol.x[0]), sol.x[1:4].copy(), sol.x[4:7].copy()
    C, _ = joint.centers(sol.x[7:])
    rms = float(np.sqrt(2 * sol.cost / max(joint.mask.sum(), 1)))
    return LightingFit(pose_correction(w, t, joint.pivot), w, t, joint.pivot.copy(), r_c, float("nan"),
                       C.copy(), np.full(joint.m, r_c), rms, method, bool(sol.status > 0))


def calibrate_lighting_joint(camera: Camera, lights_world_m, glints_px, mask=None, *, center0_m,
                             radius0_m: float = CORNEA_RADIUS_INIT_M, radius_bounds_m=CORNEA_RADIUS_BOUNDS_M,
                             rotation_bound_rad: float = POSE_BOUND_RAD, translation_bound_m: float = POSE_BOUND_M,
                             max_nfev: int = 200) -> LightingFit:
    """Ours: one r_c and one lighting pose shared by all m frames, a free cornea centre per frame
    (7 + 3m unknowns), TRF with the paper's bounds on r_c and pose.

    The per-frame problem cannot tell a shifted cornea from a shifted lighting; across frames
    the cornea moves and the lighting does not, which separates them. The centres start from
    a centre-only fit with the nominal lights and ``radius0_m``.

    Parameters as :func:`calibrate_lighting_per_frame`.
    """
    lights, glints, m = _check_frames(lights_world_m, glints_px, mask)
    if m.sum() * 2 < 7 + 3 * m.shape[0]:
        raise ValueError(f"{m.sum()} glints cannot determine {7 + 3 * m.shape[0]} unknowns")
    c0 = _start_centers(camera, lights, radius0_m, glints, m, as_points(center0_m, "center0_m").reshape(3))
    lo, hi = _pose_bounds(radius_bounds_m, rotation_bound_rad, translation_bound_m)
    lo = np.concatenate([lo, np.full(c0.size, -np.inf)])
    hi = np.concatenate([hi, np.full(c0.size, np.inf)])
    joint = _Joint(camera, lights, glints, m, "centers")
    sol = joint.solve(np.concatenate([[radius0_m], np.zeros(6), c0.ravel()]), lo, hi, max_nfev)
    return _lighting_fit(joint, sol, "joint")


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


def calibrate_joint(camera: Camera, lights_world_m, glints_px, targets_m, mask=None, *, center0_m,
                    angles: str = "targets", radius0_m: float = CORNEA_RADIUS_INIT_M,
                    radius_bounds_m=CORNEA_RADIUS_BOUNDS_M, rotation_bound_rad: float = POSE_BOUND_RAD,
                    translation_bound_m: float = POSE_BOUND_M, orbit_bounds_m=ORBIT_RADIUS_BOUNDS_M,
                    max_nfev: int = 200) -> tuple[LightingFit, OrbitFit]:
    """Ours: r_c, lighting pose, c_e and r_co fitted at once to the glints of every frame.

    ``angles="targets"`` (11 unknowns): the optical axis of frame i points from c_e at the known
    target T_i, as the paper's calibration assumes and its simulation makes true (no angle
    kappa), so the cornea centre is c_e + r_co (T_i - c_e)/||T_i - c_e||. ``angles="free"``
    (11 + 2m): each frame has free Fick angles, i.e. a sphere fit done on the glints rather than
    on fitted centres; it needs no targets (they only seed the angles).

    Starting point: centres from a centre-only fit with the nominal lights, c_e and r_co from
    :func:`orbit_law_of_sines` on them. Bounds: as :func:`calibrate_lighting_joint`, r_co in
    ``orbit_bounds_m``, c_e free.

    Returns
    -------
    (LightingFit, OrbitFit)
    """
    if angles not in ("targets", "free"):
        raise ValueError(f"angles must be 'targets' or 'free', got {angles!r}")
    lights, glints, m = _check_frames(lights_world_m, glints_px, mask)
    T = as_points(targets_m, "targets_m")
    if T.shape != (glints.shape[0], 3) or not np.isfinite(T).all():
        raise ValueError(f"targets_m must be finite with shape ({glints.shape[0]}, 3), got {T.shape}")
    used = m.any(axis=1)
    if used.sum() < 4:
        raise ValueError(f"need glints in at least 4 calibration frames, got {used.sum()}")
    c0 = _start_centers(camera, lights, radius0_m, glints, m, as_points(center0_m, "center0_m").reshape(3))
    orbit0 = orbit_law_of_sines(c0[used], T[used])
    r_co0 = float(np.clip(orbit0.orbit_radius_m, *orbit_bounds_m))
    lo, hi = _pose_bounds(radius_bounds_m, rotation_bound_rad, translation_bound_m)
    lo = np.concatenate([lo, np.full(3, -np.inf), [orbit_bounds_m[0]]])
    hi = np.concatenate([hi, np.full(3, np.inf), [orbit_bounds_m[1]]])
    x0 = np.concatenate([[radius0_m], np.zeros(6), orbit0.eye_center_m, [r_co0]])
    eye = "targets"
    if angles == "free":
        eye = "angles"
        yaw, pitch = fick_angles(T - orbit0.eye_center_m)
        x0 = np.concatenate([x0, np.column_stack([yaw, pitch]).ravel()])
        lim = np.full(2 * len(T), np.pi / 2)
        lo, hi = np.concatenate([lo, -lim]), np.concatenate([hi, lim])
    joint = _Joint(camera, lights, glints, m, eye, T)
    sol = joint.solve(x0, lo, hi, max_nfev)
    light = _lighting_fit(joint, sol, f"joint_{angles}")
    C = light.cornea_centers_m
    ce, r_co = sol.x[7:10].copy(), float(sol.x[10])
    rms = float(np.sqrt(np.mean((np.linalg.norm(C - ce, axis=1) - r_co) ** 2)))
    return light, OrbitFit(ce, r_co, rms, int(sol.nfev), f"joint_{angles}", bool(sol.status > 0))


# --------------------------------------------------------------------------------------------
# Everything together


@dataclass(frozen=True, slots=True)
class Calibration:
    """Everything the gaze estimators need beyond the nominal setup.

    Attributes
    ----------
    lighting_correction : RigidPose
        World-frame correction of the whole light rig (identity = nominal).
    cornea_radius_m : float
    eye_center_m : (3,) float
        c_e; NaN when not calibrated (polynomial gaze does not need it).
    orbit_radius_m : float
        r_co; NaN when not calibrated.
    mappings : dict[str, GazeMapping]
        Named gaze mappings, e.g. ``{"eq1_9": ..., "eq1_25": ..., "quadratic_25": ...}``.
    methods : dict[str, str]
        How each part was obtained (free text, e.g. ``{"lighting": "joint"}``).
    """

    lighting_correction: RigidPose = field(default_factory=RigidPose)
    cornea_radius_m: float = CORNEA_RADIUS_INIT_M
    eye_center_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    orbit_radius_m: float = float("nan")
    mappings: dict = field(default_factory=dict)
    methods: dict = field(default_factory=dict)

    def __post_init__(self):
        ce = np.asarray(self.eye_center_m, dtype=np.float64).reshape(3).copy()
        ce.setflags(write=False)
        object.__setattr__(self, "eye_center_m", ce)
        object.__setattr__(self, "cornea_radius_m", float(self.cornea_radius_m))
        object.__setattr__(self, "orbit_radius_m", float(self.orbit_radius_m))
        object.__setattr__(self, "mappings", dict(self.mappings))
        object.__setattr__(self, "methods", {str(k): str(v) for k, v in self.methods.items()})
        for name, m in self.mappings.items():
            if not isinstance(m, GazeMapping):
                raise ValueError(f"Calibration.mappings[{name!r}] must be a GazeMapping, got {type(m).__name__}")

    @classmethod
    def ground_truth(cls, setup, **kwargs) -> "Calibration":
        """The calibration a perfect procedure would give for ``setup`` (nominal lighting)."""
        return cls(RigidPose(), setup.eye.cornea_radius_m, setup.eye.rotation_center_m,
                   setup.eye.cornea_offset_m, methods={"all": "ground_truth"}, **kwargs)

    @classmethod
    def from_fits(cls, lighting: LightingFit, orbit: OrbitFit | None = None,
                  mappings: dict | None = None) -> "Calibration":
        """A calibration from the results of the fits above (``orbit`` only for geometric gaze)."""
        methods = {"lighting": lighting.method}
        if orbit is not None:
            methods["orbit"] = orbit.method
        return cls(lighting.correction, lighting.cornea_radius_m,
                   np.full(3, np.nan) if orbit is None else orbit.eye_center_m,
                   float("nan") if orbit is None else orbit.orbit_radius_m, mappings or {}, methods)

    @property
    def has_orbit(self) -> bool:
        return bool(np.isfinite(self.eye_center_m).all() and np.isfinite(self.orbit_radius_m))

    def lights_world_m(self, nominal_lights_m) -> np.ndarray:
        """(n, 3) calibrated positions of the nominal lights."""
        return corrected_lights(self.lighting_correction, nominal_lights_m)

    def with_mappings(self, **mappings: GazeMapping) -> "Calibration":
        return Calibration(self.lighting_correction, self.cornea_radius_m, self.eye_center_m,
                           self.orbit_radius_m, {**self.mappings, **mappings}, self.methods)

    def to_dict(self) -> dict:
        finite = self.has_orbit
        return {
            "format": CALIBRATION_FORMAT, "version": CALIBRATION_VERSION,
            "lighting_correction": {"rotation": self.lighting_correction.rotation.tolist(),
                                    "translation_m": self.lighting_correction.translation_m.tolist()},
            "cornea_radius_m": self.cornea_radius_m,
            "eye_center_m": self.eye_center_m.tolist() if finite else None,
            "orbit_radius_m": self.orbit_radius_m if finite else None,
            "mappings": {k: v.to_dict() for k, v in self.mappings.items()},
            "methods": dict(self.methods),
        }

    @classmethod
    def from_dict(cls, data: dict) -> "Calibration":
        _check_format(data, CALIBRATION_FORMAT, CALIBRATION_VERSION)
        try:
            lc = data["lighting_correction"]
            ce, r_co = data["eye_center_m"], data["orbit_radius_m"]
            return cls(RigidPose(lc["rotation"], lc["translation_m"]), data["cornea_radius_m"],
                       np.full(3, np.nan) if ce is None else ce, float("nan") if r_co is None else r_co,
                       {k: GazeMapping.from_dict(v) for k, v in data["mappings"].items()},
                       data.get("methods", {}))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{CALIBRATION_FORMAT}: malformed document ({exc!r})") from None

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_json(cls, text: str) -> "Calibration":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{CALIBRATION_FORMAT}: not JSON ({exc})") from None
        return cls.from_dict(data)
