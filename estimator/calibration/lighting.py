"""Lighting calibration (Sec. 2.4): the rigid pose of the light rig and the corneal
radius from the 6x6 grid, the paper's per-frame fit and our joint fit over all frames, and the
joint fit that adds the eye centre and orbit radius.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..cornea import FitProblem, fit_cornea
from ..eye import fick_angles, gaze_direction
from ..geometry import (
    Camera,
    RigidPose,
    as_points,
    glint_jacobians,
    rotation_from_vector,
    rotations_from_vectors,
)
from .orbit import ORBIT_RADIUS_BOUNDS_M, OrbitFit, orbit_law_of_sines

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


class _Stacked:
    """A least-squares problem whose residuals and Jacobian come from one evaluation,
    ``_eval(x)`` -> (residuals, J), which caches the last x (scipy asks for both there)."""

    def residuals(self, x):
        return self._eval(x)[0]

    def jacobian(self, x):
        return self._eval(x)[1]


class _Joint(_Stacked):
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
