"""Lighting calibration with the wire mirror's virtual sources (issue 35 c).

:func:`estimator.calibration.calibrate_joint` fits r_c, the lighting pose, c_e and r_co to the
calibration frames' glints with every light a fixed point. A wire mirror's glints come from
the LED's highlights on the turns, which move with the cornea (:mod:`estimator.geometry.wire_fast`);
fitted with fixed points, the pose and r_c soak up the highlights' mean offset and leave the
part that moves with the eye (0.69 px RMS on prototype_ov5647_wire's 5 x 5 pattern, 0.15-0.18
deg on its grid). :func:`calibrate_joint_wire` fits the same 11 unknowns (the ``"targets"``
model: the cornea centre of frame i at c_e + r_co (T_i - c_e)/|T_i - c_e|) to the glints of
the virtual sources: the lighting pose moves the mirror and its LED (about the point lights'
centroid, as the point fit's pose), and each frame's sources are solved at its cornea centre.

Jacobian: the glints' closed-form derivatives with the sources held (∂g/∂c through the
centres' dependence on c_e and r_co, ∂g/∂r_c) plus ∂g/∂L times the sources' derivative with
respect to each of the 11 unknowns, by forward differences of
:data:`~estimator.geometry.wire_fast.JACOBIAN_ROUNDS` rounds of the warm-started alternation
(the module's contraction argument). TRF with the point fit's bounds, started from its answer.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ..geometry import glint_jacobians
from ..geometry.wire_fast import JACOBIAN_ROUNDS, WireLights
from .lighting import (CORNEA_RADIUS_BOUNDS_M, POSE_BOUND_M, POSE_BOUND_RAD, LightingFit, _pose_bounds,
                       pose_correction)
from .orbit import ORBIT_RADIUS_BOUNDS_M, OrbitFit

__all__ = ["calibrate_joint_wire", "calibrate_wire", "WIRE_STEPS"]

#: Forward-difference steps of the sources per unknown: r_c (m), rotation (rad), translation
#: (m), c_e (m), r_co (m). 1e-6 m and 1e-6 rad move a highlight ~1 um (the lever arm of the
#: pose is ~30 mm: 3e-8 m per 1e-6 rad), far above the solve's 1e-13 m and small against the
#: curvature of the mapping (mm).
WIRE_STEPS = np.array([1e-6, 1e-5, 1e-5, 1e-5, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6])


class _WireJoint:
    """The stacked problem over m frames: x = [r_c, rotvec (3), t (3), c_e (3), r_co]."""

    def __init__(self, camera, lights: WireLights, glints, mask, targets, pivot):
        self.camera, self.lights, self.glints, self.mask = camera, lights, glints, mask
        self.targets, self.pivot = targets, pivot
        self.W = None
        self._x, self._out = None, None

    def centers(self, x):
        ce, r = x[7:10], x[10]
        v = self.targets - ce
        D = np.linalg.norm(v, axis=1)
        u = v / D[:, None]
        dC = np.zeros((len(v), 3, 4))
        dC[:, :, :3] = np.eye(3) - (r / D)[:, None, None] * (np.eye(3) - u[:, :, None] * u[:, None, :])
        dC[:, :, 3] = u
        return ce + r * u, dC

    def sources(self, x, start, rounds=None):
        posed = self.lights.posed(pose_correction(x[1:4], x[4:7], self.pivot))
        return posed.sources(self.centers(x)[0], x[0], start, rounds=rounds)

    def evaluate(self, x):
        if self._x is not None and np.array_equal(x, self._x):
            return self._out
        W, ok = self.sources(x, self.W)
        self.W = W
        C, dC = self.centers(x)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            g, _, d_c, d_r, d_l = glint_jacobians(self.camera, C, x[0], W)
        dW = np.empty(W.shape + (x.size,))
        for j, h in enumerate(WIRE_STEPS):
            xj = x.copy()
            xj[j] += h
            dW[..., j] = (self.sources(xj, W, JACOBIAN_ROUNDS)[0] - W) / h
        J = d_l @ dW  # (m, n, 2, 11)
        J[..., 0] += d_r
        J[..., 7:] += np.einsum("mnkj,mjq->mnkq", d_c, dC)
        m = self.mask
        res = np.where(ok[m][:, None], (g - self.glints)[m], 1e3)
        self._x, self._out = x.copy(), (res.ravel(), J[m].reshape(-1, x.size))
        return self._out

    def residuals(self, x):
        return self.evaluate(x)[0]

    def jacobian(self, x):
        return self.evaluate(x)[1]


def calibrate_joint_wire(camera, lights: WireLights, glints_px, targets_m, mask, start: tuple, *,
                         radius_bounds_m=None, rotation_bound_rad=None, translation_bound_m=None,
                         orbit_bounds_m=ORBIT_RADIUS_BOUNDS_M,
                         max_nfev: int = 100) -> tuple[LightingFit, OrbitFit]:
    """r_c, the lighting pose (the mirror, its LED and any point lights moved rigidly), c_e and
    r_co fitted to the virtual sources' glints (module docstring).

    Parameters
    ----------
    camera : Camera
    lights : WireLights
        The nominal lights (:meth:`WireLights.from_setup` without a correction).
    glints_px : (m, n, 2) float
        Calibration frames' glints, NaN where not seen.
    targets_m : (m, 3) float
    mask : (m, n) bool
    start : (LightingFit, OrbitFit)
        The point-source joint fit (:func:`estimator.calibration.calibrate_joint`,
        ``angles="targets"``): the start, the pivot of the pose and the default bounds.
    radius_bounds_m, rotation_bound_rad, translation_bound_m : optional
        Default: those of :func:`~estimator.calibration.calibrate_joint`.

    Returns
    -------
    (LightingFit, OrbitFit)
        ``method`` ``"wire_joint_targets"``.
    """
    light0, orbit0 = start
    g = np.asarray(glints_px, dtype=np.float64)
    m = np.asarray(mask, dtype=bool) & np.isfinite(g).all(axis=-1)
    T = np.asarray(targets_m, dtype=np.float64).reshape(-1, 3)
    if g.shape != (T.shape[0], lights.count, 2):
        raise ValueError(f"glints_px must have shape ({T.shape[0]}, {lights.count}, 2), got {g.shape}")
    lo, hi = _pose_bounds(CORNEA_RADIUS_BOUNDS_M if radius_bounds_m is None else radius_bounds_m,
                          POSE_BOUND_RAD if rotation_bound_rad is None else rotation_bound_rad,
                          POSE_BOUND_M if translation_bound_m is None else translation_bound_m)
    lo = np.concatenate([lo, np.full(3, -np.inf), [orbit_bounds_m[0]]])
    hi = np.concatenate([hi, np.full(3, np.inf), [orbit_bounds_m[1]]])
    x0 = np.concatenate([[light0.cornea_radius_m], light0.rotvec_rad, light0.translation_m,
                         orbit0.eye_center_m, [orbit0.orbit_radius_m]])
    x0 = np.clip(x0, np.nextafter(lo, hi), np.nextafter(hi, lo))
    joint = _WireJoint(camera, lights, np.where(m[..., None], g, 0.0), m, T, light0.pivot_m)
    sol = least_squares(joint.residuals, x0, jac=joint.jacobian, bounds=(lo, hi), method="trf",
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev)
    x = sol.x
    C, _ = joint.centers(x)
    rms = float(np.sqrt(2 * sol.cost / max(m.sum(), 1)))
    method = "wire_joint_targets"
    light = LightingFit(pose_correction(x[1:4], x[4:7], light0.pivot_m), x[1:4].copy(), x[4:7].copy(),
                        light0.pivot_m.copy(), float(x[0]), float("nan"), C, np.full(len(C), x[0]),
                        rms, method, bool(sol.status > 0))
    ce, r_co = x[7:10].copy(), float(x[10])
    orms = float(np.sqrt(np.mean((np.linalg.norm(C - ce, axis=1) - r_co) ** 2)))
    return light, OrbitFit(ce, r_co, orms, int(sol.nfev), method, bool(sol.status > 0))


def calibrate_wire(setup, glints_px, targets_m, mask, start: tuple) -> tuple[LightingFit, OrbitFit]:
    """:func:`calibrate_joint_wire` on ``setup``'s camera and nominal lights (its wire mirrors
    in the world frame)."""
    return calibrate_joint_wire(setup.camera, WireLights.from_setup(setup), glints_px, targets_m,
                                mask, start)
