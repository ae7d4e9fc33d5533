"""The joint calibration on a conic cornea: Q calibrated with the rest of the geometry.

:func:`estimator.calibration.calibrate_joint` (``angles="targets"``) fits r_c, the lighting
pose, c_e and r_co to every calibration frame's glints with a spherical cornea. On a conic
cornea (conic constant Q about the optical axis, :mod:`estimator.cornea.conic`) the sphere
absorbs part of Q into r_c and c_e and leaves the rest as residual (``reports/aspheric.md``:
r_c 8.116 mm for a 7.80 mm apex at Q = -0.25). :func:`calibrate_joint_conic` starts from that
spherical answer and fits the same 11 unknowns plus Q (12) to the exact conic reflections
(:func:`estimator.cornea.conic_glints`; the optical axis of frame i from c_e toward its
target, the cornea centre c_e + r_co (T_i - c_e)/|T_i - c_e|, as for the sphere), scipy's
TRF with the sphere's bounds and Q in :data:`Q_BOUNDS`, the Jacobian by central differences
(all 25 unknowns' poses in one conic projection per evaluation).

Q is determined by the glints far from the apex: near the axis a conic is its apex sphere to
second order. The 5x5 pattern's targets turn the eye by up to ~20 deg, which puts the lights'
reflections 5-40 deg from the axis, where Q = -0.25 moves them by pixels.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ..cornea import conic_glints
from ..geometry import Camera, as_points, rotation_from_vector
from .lighting import (LightingFit, _check_frames, _pose_bounds, _Stacked, calibrate_joint,
                       pose_correction)
from .lighting import CORNEA_RADIUS_BOUNDS_M, POSE_BOUND_M, POSE_BOUND_RAD
from .orbit import ORBIT_RADIUS_BOUNDS_M, OrbitFit

#: Bounds of the calibrated conic constant: the scene's (-1, 1] kept 0.05 away from the
#: paraboloid (Q = -1), where the ellipsoid's equator runs to infinity. Real corneas: Q =
#: -0.26 +/- 0.18 (Kiely et al. 1982), so the bound is 4 SD beyond the most prolate one.
Q_BOUNDS = (-0.95, 1.0)
#: Robust loss of the conic calibration (scipy's ``least_squares``): the glints it is given
#: were identified by the spherical matcher, which on a Q = -0.45 cornea gets a quarter of them
#: wrong (110 of 416 on the quick study's frames, 92 of 598 at Q = -0.25), each pulling the
#: squares far more than the right ones. soft_l1 with a 1 px scale counts residuals well below
#: 1 px (0.2 px of detection noise at 320 x 240) as squares and the wrong ones, pixels off,
#: about linearly.
ROBUST_LOSS, ROBUST_SCALE_PX = "soft_l1", 1.0
#: Central-difference step of each unknown, in its unit: r_c, translation, c_e, r_co (m),
#: rotation (rad), Q. 1e-8 m moves glints by ~5e-5 px; the conic's glints settle to ~5e-13 px.
_H = {"length_m": 1e-8, "angle_rad": 1e-6, "q": 1e-6}


class _ConicJoint(_Stacked):
    """Stacked conic residuals over m frames: x = [r_c, rotvec (3), translation (3), c_e (3),
    r_co, Q]."""

    def __init__(self, camera, lights, glints, mask, targets):
        self.camera, self.lights, self.glints, self.mask = camera, lights, glints, mask
        self.targets = targets
        self.pivot = lights.mean(axis=0)
        h = np.array([_H["length_m"]] + [_H["angle_rad"]] * 3 + [_H["length_m"]] * 7 + [_H["q"]])
        self.h = h
        self._cache_x, self._cache = None, None

    def glints_at(self, X):
        """Glints (k, m, n, 2) of k parameter vectors X (k, 12), in one conic projection."""
        k, m, n = X.shape[0], self.glints.shape[0], self.lights.shape[0]
        g = np.empty((k, m, n, 2))
        # One call per distinct (r_c, Q) is what project_glints_conic takes; group by them.
        keys = {}
        for i, x in enumerate(X):
            keys.setdefault((x[0], x[11]), []).append(i)
        for (r_c, q), idx in keys.items():
            C, L, ce = [], [], []
            for i in idx:
                x = X[i]
                R = rotation_from_vector(x[1:4])
                posed = (self.lights - self.pivot) @ R.T + self.pivot + x[4:7]
                L.append(np.broadcast_to(posed, (m, n, 3)))
                u = self.targets - x[7:10]
                u = u / np.linalg.norm(u, axis=1, keepdims=True)
                C.append(x[7:10] + x[10] * u)
                ce.append(np.broadcast_to(x[7:10], (m, 3)))
            C, L, ce = np.concatenate(C), np.concatenate(L), np.concatenate(ce)
            got = conic_glints(self.camera, C, ce, r_c, q, L)
            g[idx] = got.reshape(len(idx), m, n, 2)
        return g

    def _eval(self, x):
        if self._cache_x is not None and np.array_equal(x, self._cache_x):
            return self._cache
        E = np.concatenate([np.zeros((1, x.size)), np.diag(self.h), -np.diag(self.h)])
        g = self.glints_at(x[None] + E)
        r = g - self.glints[None]
        res = r[0][self.mask]
        # A glint that does not converge at some nearby pose is left out of every column.
        fin = np.isfinite(r).all(axis=(0, -1))[self.mask]
        res = np.where(fin[:, None], res, 0.0).ravel()
        p = x.size
        J = (r[1:p + 1] - r[p + 1:])[:, self.mask] / (2 * self.h[:, None, None])
        J = np.where(fin[None, :, None], J, 0.0).reshape(p, -1).T
        self._cache_x, self._cache = x.copy(), (res, J)
        return res, J


def calibrate_joint_conic(camera: Camera, lights_world_m, glints_px, targets_m, mask=None, *,
                          center0_m, radius_bounds_m=CORNEA_RADIUS_BOUNDS_M,
                          rotation_bound_rad: float = POSE_BOUND_RAD,
                          translation_bound_m: float = POSE_BOUND_M,
                          orbit_bounds_m=ORBIT_RADIUS_BOUNDS_M, q_bounds=Q_BOUNDS,
                          max_nfev: int = 100) -> tuple[LightingFit, OrbitFit, float]:
    """r_c, lighting pose, c_e, r_co and the conic constant Q fitted at once to the glints of
    every frame (module docstring), started from :func:`calibrate_joint`'s spherical answer.

    Parameters as :func:`calibrate_joint` (``angles="targets"``), plus ``q_bounds``.

    Returns
    -------
    (LightingFit, OrbitFit, float)
        The lighting (method ``"joint_targets_conic"``; ``rms_px`` the conic residual), the
        orbit, and Q.
    """
    sphere, orbit = calibrate_joint(camera, lights_world_m, glints_px, targets_m, mask,
                                    center0_m=center0_m, radius_bounds_m=radius_bounds_m,
                                    rotation_bound_rad=rotation_bound_rad,
                                    translation_bound_m=translation_bound_m,
                                    orbit_bounds_m=orbit_bounds_m)
    lights, glints, m = _check_frames(lights_world_m, glints_px, mask)
    T = as_points(targets_m, "targets_m")
    lo, hi = _pose_bounds(radius_bounds_m, rotation_bound_rad, translation_bound_m)
    lo = np.concatenate([lo, np.full(3, -np.inf), [orbit_bounds_m[0]], [q_bounds[0]]])
    hi = np.concatenate([hi, np.full(3, np.inf), [orbit_bounds_m[1]], [q_bounds[1]]])
    x0 = np.concatenate([[sphere.cornea_radius_m], sphere.rotvec_rad, sphere.translation_m,
                         orbit.eye_center_m, [orbit.orbit_radius_m], [0.0]])
    x0 = np.clip(x0, np.nextafter(lo, hi), np.nextafter(hi, lo))
    joint = _ConicJoint(camera, lights, glints, m, T)
    sol = least_squares(joint.residuals, x0, jac=joint.jacobian, bounds=(lo, hi), method="trf",
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev,
                        loss=ROBUST_LOSS, f_scale=ROBUST_SCALE_PX)
    x = sol.x
    r_c, w, t, ce = float(x[0]), x[1:4].copy(), x[4:7].copy(), x[7:10].copy()
    r_co, q = float(x[10]), float(x[11])
    u = T - ce
    C = ce + r_co * u / np.linalg.norm(u, axis=1, keepdims=True)
    rms = float(np.sqrt(np.sum(sol.fun ** 2) / max(m.sum(), 1)))
    light = LightingFit(pose_correction(w, t, joint.pivot), w, t, joint.pivot.copy(), r_c,
                        float("nan"), C, np.full(len(T), r_c), rms, "joint_targets_conic",
                        bool(sol.status > 0))
    orbit = OrbitFit(ce, r_co, 0.0, int(sol.nfev), "joint_targets_conic", bool(sol.status > 0))
    return light, orbit, q


#: Most rounds of re-identification of the calibration glints on the calibrated conic
#: (:func:`identify_on_conic`) and recalibration (:func:`reidentify_on_conic`). The spherical
#: matcher that identifies them first predicts a Q = -0.25 cornea's oblique glints up to ~15 px
#: off at 320 x 240: measured on the quick study's calibration frames, 92 of 598 identities
#: were wrong (8 of 20 frames), which left Q at -0.186, r_c at 7.52 mm and a 1.44 px RMS; with
#: the right identities the same fit gives Q = -0.252, r_c = 7.82 mm, 0.20 px. A round
#: re-assigns every detection; the loop ends earlier when the identities no longer change.
IDENTIFY_ROUNDS = 10
#: While the calibration is coarse, a predicted glint closer than CROWDED_RMS times the
#: calibration's RMS residual (px) to another predicted glint of its frame is left out of the
#: assignment: at that accuracy its identity is a guess. At Q = -0.45 the glints near the
#: cornea's edge crowd to ~3 px apart at 320 x 240, and a model a pixel or two off assigns a
#: chain of them shifted by one light, which the next fit then makes self-consistent: on the
#: quick study's calibration frames (25 frames, 865 identifiable glints) re-identifying without
#: this converged to 138 wrong identities, Q = -0.493, r_c = 8.52 mm and a 0.66 px RMS; leaving
#: the crowded glints out (2 x 2.0 px = 4.0 px, then 2 x 0.63 px, ...) takes every identity
#: right in two rounds: Q = -0.451, r_c = 7.83 mm, 0.22 px (true -0.45, 7.80 mm). The last
#: rounds assign every prediction; the exclusion shrinks with the RMS, so on a sphere-like
#: cornea it leaves nothing out. The RMS is the error of the glints fitted, not of those
#: extrapolated to: from the second round the radius is CROWDED_RMS times the RMS and each
#: prediction's standard error (:func:`prediction_sd_px`) in quadrature. With the moving lids
#: (Q = -0.45) the first such fit, 179 glints of lights 0-19 at 0.30 px, predicts the edge
#: lights 20-39 up to 6.1 px off; a radius of the RMS alone (3.6 px) let in 62 identities one
#: light off, which ended at Q = -0.493, r_c = 8.50 mm, 0.66 px (the plain rounds' answer);
#: with the standard error (radii up to 8.9 px) every identity is right: Q = -0.451,
#: r_c = 7.85 mm, 0.24 px (the labels' identities: -0.451, 7.84 mm, 0.24 px).
CROWDED_RMS = 2.0
#: Where leaving the crowded glints out keeps fewer than 4 frames with enough glints (a first
#: calibration many pixels off: 7.1 px RMS with the moving lids' clutter at Q = -0.45, whose
#: 14 px exclusion leaves nothing), the exclusion radius is halved down to this (px), then
#: none.
MIN_CROWDED_PX = 0.5


def identify_on_conic(calibration, setup, detections, targets_m, *, gate_px: float,
                      crowded_px: "float | np.ndarray" = 0.0) -> np.ndarray:
    """Identify the glints of calibration frames on a calibrated conic cornea.

    Each frame's eye fixates its target: the cornea centre is c_e + r_co (T - c_e)/|T - c_e|,
    the optical axis from c_e through it. Every light's glint is predicted on the conic
    (exact reflection, the cap ending ``setup.eye.limbus_depth_m`` behind the apex, inside the
    image), and the frame's detections are assigned to the predictions by the optimal
    assignment of their distances (scipy's ``linear_sum_assignment``), pairs further apart
    than ``gate_px`` left unmatched. A prediction closer than its ``crowded_px`` to another
    prediction of its frame takes no detection (0: every prediction does).

    Parameters
    ----------
    calibration : Calibration
        With ``cornea_model == "conic"``.
    setup : Setup
        Camera, nominal lights and eye (its limbus depth).
    detections : sequence of (k_i, 2) float
        Every detection of each frame (px).
    targets_m : (m, 3) float
    gate_px : float
    crowded_px : float or (m, n) float
        One radius (px) for every prediction, or each prediction's own.

    Returns
    -------
    (m, n, 2) float
        The identified detection of each light, NaN where none.
    """
    from scipy.optimize import linear_sum_assignment

    from ..geometry import project_glints_conic

    T = as_points(targets_m, "targets_m").reshape(-1, 3)
    ce, r_co, r_c = calibration.eye_center_m, calibration.orbit_radius_m, calibration.cornea_radius_m
    u = (T - ce) / np.linalg.norm(T - ce, axis=1, keepdims=True)
    lights = calibration.lights_world_m(setup.lights_world_m)
    pred, visible = project_glints_conic(setup.camera, ce + (r_co + r_c) * u, u, r_c,
                                         calibration.cornea_asphericity, lights,
                                         limbus_depth_m=setup.eye.limbus_depth_m)
    crowded = np.asarray(crowded_px, dtype=np.float64)
    if crowded.ndim and crowded.shape != pred.shape[:2]:
        raise ValueError(f"crowded_px must be a number or have shape {pred.shape[:2]}, got "
                         f"{crowded.shape}")
    crowded = np.broadcast_to(crowded, pred.shape[:2])
    out = np.full(pred.shape, np.nan)
    for i, det in enumerate(detections):
        det = np.asarray(det, dtype=np.float64).reshape(-1, 2)
        idx = np.flatnonzero(visible[i])
        if (crowded[i, idx] > 0).any() and idx.size > 1:
            p = pred[i, idx]
            apart = np.linalg.norm(p[:, None] - p[None], axis=-1)
            np.fill_diagonal(apart, np.inf)
            idx = idx[apart.min(axis=1) >= crowded[i, idx]]
        if det.shape[0] == 0 or idx.size == 0:
            continue
        dist = np.linalg.norm(pred[i, idx, None, :] - det[None], axis=-1)
        rows, cols = linear_sum_assignment(np.where(dist <= gate_px, dist, 1e6))
        keep = dist[rows, cols] <= gate_px
        out[i, idx[rows[keep]]] = det[cols[keep]]
    return out


def reidentify_on_conic(calibration, setup, detections, targets_m, calibrate, *,
                        gate_px: float, min_glints: int, rounds: int = IDENTIFY_ROUNDS,
                        fitted_px=None):
    """A conic calibration made again from the frames' glints identified on it, until the
    identities no longer change: first leaving out the glints crowded within
    :data:`CROWDED_RMS` times their predicted error (px: the calibration's RMS and, from the
    second round, the prediction's standard error from the glints last fitted,
    :func:`prediction_sd_px`) of another, then with every glint (:func:`identify_on_conic`);
    and the same rounds with every glint from the start. The calibration of lower RMS is
    returned: on the quick study's frames at Q = -0.45 the excluding rounds' (0.22-0.24 px,
    every identity right, lids off, still and moving) against the plain rounds' 0.66 px.

    Parameters
    ----------
    calibration : Calibration
        The first conic calibration (from the spherical matcher's identities).
    setup, detections, targets_m, gate_px
        As :func:`identify_on_conic`.
    calibrate : callable
        ``calibrate(glints_px (k, n, 2), targets_m (k, 3)) -> Calibration``.
    min_glints : int
        Fewest identified glints a frame is calibrated with; at least 4 such frames are needed
        (fewer: the last calibration is kept).
    rounds : int
        Most recalibrations.
    fitted_px : (m, n, 2) float, optional
        The glints ``calibration`` was fitted to (NaN: none), rows as ``targets_m``: its
        predictions' standard errors then widen the first round's exclusion too. Without
        them the first round trusts its RMS.

    Returns
    -------
    Calibration
    """
    targets = np.asarray(targets_m, dtype=np.float64)
    fitted = None if fitted_px is None else np.asarray(fitted_px, dtype=np.float64)
    runs = [_reidentify(calibration, setup, detections, targets, calibrate, factor, gate_px,
                        min_glints, rounds, fitted) for factor in (CROWDED_RMS, 0.0)]
    rms = [float(c.quality.get("rms_px", np.inf)) for c in runs]
    return runs[int(np.argmin(np.where(np.isfinite(rms), rms, np.inf)))]


def _reidentify(calibration, setup, detections, targets, calibrate, factor, gate_px,
                min_glints, rounds, fitted):
    """:func:`reidentify_on_conic`'s rounds with the crowded glints' exclusion at ``factor``
    times the error of each prediction (0: none): the RMS, and once the glints of the last fit
    are known, its prediction's standard error (:func:`prediction_sd_px`) in quadrature."""
    cal, previous, last = calibration, None, np.inf
    for _ in range(rounds):
        rms = float(cal.quality.get("rms_px", np.nan))
        crowded = factor * rms if factor > 0 and np.isfinite(rms) else 0.0
        if crowded > 0 and np.isfinite(last):
            # At most halving from round to round: the glints come in gradually.
            crowded = min(last, max(crowded, last / 2.0))
        if crowded < MIN_CROWDED_PX:
            crowded = 0.0
        spread = 0.0
        if factor > 0 and fitted is not None:
            spread = factor * prediction_sd_px(cal, setup, fitted, targets)
        while True:
            radius = np.hypot(crowded, spread)
            radius = np.where(radius >= MIN_CROWDED_PX, radius, 0.0)
            g = identify_on_conic(cal, setup, detections, targets, gate_px=gate_px,
                                  crowded_px=radius)
            enough = np.isfinite(g[..., 0]).sum(axis=1) >= min_glints
            if enough.sum() >= 4 or not radius.any():
                break
            # Too few frames keep enough glints (a first calibration many pixels off leaves
            # most out): a narrower exclusion, down to none.
            crowded = crowded / 2.0 if crowded / 2.0 >= MIN_CROWDED_PX else 0.0
            spread = spread / 2.0
        last = crowded
        same = previous is not None and np.array_equal(np.isfinite(g), np.isfinite(previous)) \
            and np.allclose(g, previous, equal_nan=True)
        if enough.sum() < 4 or same:
            if radius.any():  # settled without the crowded glints: now all of them
                factor, previous = 0.0, g
                continue
            break
        previous = g
        fitted = np.where(enough[:, None, None], g, np.nan)
        cal = calibrate(g[enough], targets[enough])
    return cal


def prediction_sd_px(calibration, setup, glints_px, targets_m) -> np.ndarray:
    """Standard error of each glint a conic calibration predicts, from the glints it was fitted
    to: the fit's covariance (RMS^2 / 2 per axis) (J^T J)^-1, J the Jacobian of those glints
    in the fit's 12 unknowns (:class:`_ConicJoint` about the calibrated lights), carried to
    every light's glint of every frame.

    Glints far from those fitted (an edge the fit left out) are extrapolated: on the moving
    lids' calibration at Q = -0.45 (320 x 240) a fit of 179 glints of lights 0-19 at 0.30 px
    RMS predicts, in the frame fixating the top centre target, those lights within 1.1 px
    (this gives 0.06-0.8 px) and the crowded edge lights 20-39 1.4-6.1 px off (0.9-3.8 px),
    steadily worse toward the edge; its RMS says 0.30 px for all.

    Parameters
    ----------
    calibration : Calibration
        With ``cornea_model == "conic"`` and ``quality["rms_px"]``.
    setup : Setup
    glints_px : (m, n, 2) float
        The glints the calibration was fitted to, NaN where none.
    targets_m : (m, 3) float

    Returns
    -------
    (m, n) float
        sqrt of the trace of each predicted glint's 2 x 2 covariance (px); inf where the
        reflection does not converge near the calibration.
    """
    lights = calibration.lights_world_m(setup.lights_world_m)
    glints = np.asarray(glints_px, dtype=np.float64)
    if glints.ndim != 3 or glints.shape[1:] != (lights.shape[0], 2):
        raise ValueError(f"glints_px must have shape (m, {lights.shape[0]}, 2), got "
                         f"{glints.shape}")
    T = as_points(targets_m, "targets_m").reshape(-1, 3)
    mask = np.isfinite(glints).all(axis=-1)
    joint = _ConicJoint(setup.camera, lights, np.where(mask[..., None], glints, 0.0), mask, T)
    x = np.concatenate([[calibration.cornea_radius_m], np.zeros(6), calibration.eye_center_m,
                        [calibration.orbit_radius_m], [calibration.cornea_asphericity]])
    p = x.size
    g = joint.glints_at(x[None] + np.concatenate([np.diag(joint.h), -np.diag(joint.h)]))
    D = np.moveaxis((g[:p] - g[p:]) / (2 * joint.h[:, None, None, None]), 0, -1)
    fin = np.isfinite(D).all(axis=(-2, -1))
    D = np.where(fin[..., None, None], D, 0.0)  # (m, n, 2, p)
    A = D[mask & fin].reshape(-1, p)
    scale = np.linalg.norm(A, axis=0)
    scale = np.where(scale > 0, scale, 1.0)  # conditioning: lengths (m) against Q
    rms = float(calibration.quality.get("rms_px", np.nan))
    cov = np.linalg.pinv((A / scale).T @ (A / scale)) / np.outer(scale, scale) * rms ** 2 / 2
    var = np.einsum("mnap,pq,mnaq->mn", D, cov, D)
    return np.where(fin, np.sqrt(np.maximum(var, 0.0)), np.inf)
