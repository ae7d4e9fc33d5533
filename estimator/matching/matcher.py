"""Glint identification: which light made which glint, one band (one gaze sample) at a time.

The SCET paper leaves this open (Sec. 5.1). A band shows only the glints whose rows its pulse
lights (Sec. 2.3): a contiguous stretch of each arc's chain of glints, with some glints missing
(dropouts, the limbus) and some blobs that are not glints (sclera and lid reflections that
passed the detector). Identification is model-based:

1. Hypotheses. Without a prior (cold start, lost track): a coarse search. The glints of every
   light are predicted once per matcher on a grid of eye rotations (``grid_step_deg``) over the
   orbit (Sec. 2.2.1: the cornea centre on a sphere of radius r_co about the eye centre); each
   grid pose is scored against the band's detections (the score below, at the coarse gate) and
   the best local minima are kept. With a prior (the previous sample's rotation): the prior,
   and the best local minima of the grid within ``prior_window_deg`` of it.
2. Refinement, per hypothesis and batched over them: predict the glints with the closed-form
   projection (:func:`estimator.geometry.project_glints`, on the corneal cap), keep as
   candidates only those inside the band's rows, assign detections to candidates with
   ``scipy.optimize.linear_sum_assignment`` on squared distances with a gate (each detection
   may stay unmatched at the cost of the gate), refit the cornea
   (:func:`estimator.cornea.fit_cornea`, ``"orbit"`` or ``"center"``), re-predict, re-assign,
   until the assignment no longer changes. The gate starts wide (the hypothesis is coarse) and
   closes to ``gate_px`` once the fit has locked on.
3. The arc's layout. The lights' order along each arc is preserved in the image (the
   reflection is continuous), which is used twice. (a) The classic wrong answer is the chain
   shifted by a light or two along itself (the glints are near-evenly spaced): those
   identities are refined explicitly, as hypotheses whose first assignment is the leader's
   shifted by ±1 and ±2 lights along their own arcs. (b) Consecutive matched lights of one arc
   must be met in the same direction by their detections as by their predictions; a pair that
   is not holds a false match (a blob taken for a missing glint): the worse-fitting one is
   dropped and the fit repeated.
4. Choice. Each refined hypothesis is scored as a negative log-likelihood,
   S = Σ_matched r² / σ² + ``unmatched_cost`` per unmatched detection + ``missing_cost`` per
   predicted glint well inside the band with no detection, plus, with a prior, the squared
   distance from it in units of ``prior_sigma_deg``. The lowest S wins; a winner less than
   ``min_margin`` ahead of a rival with other identities is "ambiguous", and, like a band with
   too few matches, returns no identities (a NaN sample with a reason, not a guess).
5. Confidence of each match: the product of (a) 1 - r / gate (the residual after the refit),
   (b) the margin to the second-best assignment of that detection, min(1, (d₂ - r) / gate)
   with d₂ the distance to the nearest other candidate or competing detection, and (c) the
   margin to the runner-up hypothesis, tanh((S₂ - S₁) / 4) (their likelihood-ratio odds
   mapped to [0, 1]).

Lights whose glints nearly coincide (in ``paper_sim_doubled`` light i and light 40 + i, i < 8,
sit within 1 mm of each other) are indistinguishable: either identity may be returned.
Everything is in pixels (image) and SI units (geometry); angles are Fick (yaw, pitch) in rad.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

import estimator.matching.kernels as kernels

from ..calibration import Calibration
from ..cornea import FitProblem
from ..cornea.scalar import camera_floats, glints_floats, lights_in_camera
from ..eye import fick_angles, gaze_direction
from ..geometry import camera_arrays, compiled, glints_and_rows_one_pose, glints_one_pose, project_glints
from ..setup import Setup
from .model import _Hypothesis, _Prior, calibrated_eye
from .params import (
    AMBIGUOUS,
    FIT_FAILED,
    NO_HYPOTHESIS,
    OK,
    TOO_FEW_GLINTS,
    GlintMatch,
    MatchParams,
)
from .search import _FEW_POSES, HypothesisSearch


class GlintMatcher(HypothesisSearch):
    """Identifies the glints of bands for one setup (camera, eye, lights).

    Building one predicts every light's glint over the coarse grid of eye rotations (about
    0.1 s for 40 lights); keep it for a whole sequence.

    Parameters
    ----------
    setup : Setup
        Camera, eye (rotation centre, cornea offset and radius, limbus) and lights.
    params : MatchParams
    calibration : Calibration, optional
        Predict the glints from the calibrated geometry: the corrected lighting pose, r_c and,
        where calibrated, c_e and r_co (:func:`calibrated_eye`). On the prototype the nominal
        lighting pose is off by millimetres, a pixel or more of every predicted glint. Default:
        the setup's nominal lights and eye.
    problem : FitProblem, optional
        The calibration's ``"orbit"`` problem when the caller has built it already
        (:func:`estimator.gaze.calibrated_problems`); it must be the one ``calibration`` gives.
        Its lights are then the matcher's (for a ``"wire_mirror"`` calibration, the turns'
        virtual sources at primary gaze: :func:`estimator.gaze.calibrated_lights`).
    """

    def __init__(self, setup: Setup, params: MatchParams = MatchParams(), *,
                 calibration: Calibration | None = None, problem: FitProblem | None = None):
        self.setup = setup
        self.params = params
        self.eye = calibrated_eye(setup.eye, calibration)
        eye = self.eye
        nominal = np.asarray(setup.lights_world_m, dtype=np.float64)
        self.lights_world_m = (np.array(problem.lights_world_m) if problem is not None else
                               np.ascontiguousarray(nominal if calibration is None
                                                    else calibration.lights_world_m(nominal)))
        #: The camera as the compiled kernels take it (:func:`estimator.geometry.camera_arrays`).
        self.arrays = camera_arrays(setup.camera)
        # Without Numba one rotation's glints are projected on floats (cornea.scalar).
        cam = camera_floats(*self.arrays)
        self._floats = None if compiled.ENABLED else (cam, lights_in_camera(cam, self.lights_world_m))
        self.group = np.asarray(setup.lights.group_index)
        self.problem = problem if problem is not None else FitProblem(
            setup.camera, self.lights_world_m, eye.cornea_radius_m, eye.rotation_center_m,
            eye.cornea_offset_m)
        yaw = np.arange(-params.grid_yaw_deg, params.grid_yaw_deg + 1e-9, params.grid_step_deg)
        pitch = np.arange(-params.grid_pitch_deg, params.grid_pitch_deg + 1e-9,
                          params.grid_step_deg)
        Y, P = np.meshgrid(np.radians(yaw), np.radians(pitch), indexing="ij")
        self._grid_shape = Y.shape
        self._grid_axes = (Y[:, 0].copy(), P[0].copy())  # the nodes' yaws, pitches (_near)
        self.grid_angles_rad = np.stack([Y.ravel(), P.ravel()], axis=-1)
        self.grid_glints_px, self.grid_visible = self.predict(self.grid_angles_rad)
        #: The furthest a glint moves between neighbouring grid nodes (px; :meth:`band_support`).
        self.grid_drift_px = self._grid_drift()

    # ----------------------------------------------------------------------- prediction

    def predict(self, angles_rad) -> tuple[np.ndarray, np.ndarray]:
        """Glints of every light for eye rotations on the orbit.

        Parameters
        ----------
        angles_rad : (..., 2) float
            Fick (yaw, pitch).

        Returns
        -------
        glints_px : (..., n, 2) float
        visible : (..., n) bool
            On the corneal cap, seen and inside the image.
        """
        a = np.asarray(angles_rad, dtype=np.float64)
        eye = self.eye
        center = eye.cornea_center(a[..., 0], a[..., 1])
        axis = gaze_direction(a[..., 0], a[..., 1])
        return project_glints(self.setup.camera, center, eye.cornea_radius_m, self.lights_world_m,
                              cornea_axis=axis, cap_cos_min=eye.cap_cos_min)

    def _predict_x(self, x):
        """Glints at fit parameters x (H, p) (angles for "orbit", centre for "center")."""
        if kernels.ENABLED and x.shape[0] <= _FEW_POSES:
            return self._predict_each(x)
        if self.params.model == "orbit":
            return self.predict(x)
        eye = self.eye
        axis = np.asarray(x, dtype=np.float64) - eye.rotation_center_m
        axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
        return project_glints(self.setup.camera, x, eye.cornea_radius_m, self.lights_world_m,
                              cornea_axis=axis, cap_cos_min=eye.cap_cos_min)

    def _predict_one(self, yaw: float, pitch: float, out=None):
        """Glints (n, 2) and visibility (n,) (into ``out``'s where given) at one rotation, by
        the compiled projection (:func:`estimator.geometry.glints_one_pose`: the same glints
        to ~1e-12 px and the same visibility as :meth:`predict`); gaze_direction and
        Eye.cornea_center of one rotation without numpy's per-call cost."""
        eye = self.eye
        center, axis = self._orbit_pose(yaw, pitch)
        if compiled.ENABLED:  # the kernel itself: glints_one_pose's checks cost half the call
            n = self.lights_world_m.shape[0]
            g, vis = (np.empty((n, 2)), np.empty(n, dtype=np.bool_)) if out is None else out
            compiled.glints_kernel(*self.arrays, center, eye.cornea_radius_m, self.lights_world_m,
                                   axis, eye.cap_cos_min, True, g, vis, False,
                                   compiled.NO_JACOBIAN)
            return g, vis
        if self._floats is not None:
            g, vis, _ = self._project_floats(center, axis, False)
            return g, vis
        return glints_one_pose(self.setup.camera, center, eye.cornea_radius_m,
                               self.lights_world_m, cornea_axis=axis,
                               cap_cos_min=eye.cap_cos_min, arrays=self.arrays)

    def _project_floats(self, center, axis, with_jacobian: bool):
        """:meth:`_predict_one`'s glints (n, 2), visibility (n,) and (``with_jacobian``)
        d glint / d centre (n, 2, 3) without Numba: the compiled kernel's arithmetic on Python
        floats (:func:`estimator.cornea.scalar.glints_floats`; numpy's projection of one pose,
        :func:`estimator.geometry.glints_one_pose`, costs ~0.3 ms in per-call overhead)."""
        cam, rq = self._floats
        g, vis, jac = glints_floats(cam, [float(v) for v in center], self.eye.cornea_radius_m,
                                    rq, [float(v) for v in axis], float(self.eye.cap_cos_min),
                                    with_jacobian)
        return (np.array(g).reshape(-1, 2), np.array(vis, dtype=bool),
                np.array(jac).reshape(-1, 2, 3) if with_jacobian else None)

    def _orbit_pose(self, yaw: float, pitch: float):
        """Cornea centre (3,) and optical axis (3,) of one rotation on the orbit
        (Eye.cornea_center and gaze_direction without numpy's per-call cost)."""
        cp = math.cos(pitch)
        axis = np.array([cp * math.sin(yaw), math.sin(pitch), -cp * math.cos(yaw)])
        return self.eye.rotation_center_m + self.eye.cornea_offset_m * axis, axis

    def _predict_one_rows(self, yaw: float, pitch: float):
        """:meth:`_predict_one` and d glint / d (yaw, pitch) (n, 2, 2) (px per rad) in closed
        form (:func:`estimator.geometry.glints_and_rows_one_pose` through the orbit)."""
        eye = self.eye
        center, axis = self._orbit_pose(yaw, pitch)
        cp, sp, cy, sy = math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
        if self._floats is not None:
            g, vis, d_center = self._project_floats(center, axis, True)
        else:
            g, vis, d_center = glints_and_rows_one_pose(
                self.setup.camera, center, eye.cornea_radius_m, self.lights_world_m,
                cornea_axis=axis, cap_cos_min=eye.cap_cos_min, arrays=self.arrays)
        r = eye.cornea_offset_m
        d_angles = np.array([[r * cp * cy, -r * sp * sy], [0.0, r * cp], [r * cp * sy, r * sp * cy]])
        return g, vis, d_center @ d_angles

    def _predict_each(self, x):
        """:meth:`_predict_x` one pose at a time by the compiled projection, where numpy's
        ~0.4 ms per call on a handful of poses is overhead (the kernel writing in place)."""
        eye, orbit = self.eye, self.params.model == "orbit"
        n = self.lights_world_m.shape[0]
        g, vis = np.empty((x.shape[0], n, 2)), np.empty((x.shape[0], n), dtype=bool)
        for h in range(x.shape[0]):
            if orbit:
                g[h], vis[h] = self._predict_one(float(x[h, 0]), float(x[h, 1]), (g[h], vis[h]))
                continue
            center = np.asarray(x[h], dtype=np.float64)
            axis = center - eye.rotation_center_m
            axis = axis / math.sqrt(float(axis @ axis))
            g[h], vis[h] = glints_one_pose(self.setup.camera, center, eye.cornea_radius_m,
                                           self.lights_world_m, cornea_axis=axis,
                                           cap_cos_min=eye.cap_cos_min, arrays=self.arrays)
        return g, vis

    def _x_from_angles(self, angles):
        if self.params.model == "orbit":
            return np.asarray(angles, dtype=np.float64)
        return self.eye.cornea_center(angles[0], angles[1])

    def _angles_center(self, x):
        eye = self.eye
        if self.params.model == "orbit":
            return np.asarray(x, dtype=np.float64), self._orbit_pose(float(x[0]), float(x[1]))[0]
        yaw, pitch = fick_angles(x - eye.rotation_center_m)
        return np.array([float(yaw), float(pitch)]), np.asarray(x, dtype=np.float64)

    # ----------------------------------------------------------------------- matching

    def match(self, glints_px, rows=None, prior_angles_rad=None) -> GlintMatch:
        """Identify the detections of one band.

        Parameters
        ----------
        glints_px : (k, 2) float
            Detected glints of the band (pixel-centre convention), spurious blobs included.
        rows : (float, float), optional
            First and last image row the band's pulse lights (e.g. ``Band.first_row`` and
            ``Band.last_row`` of :func:`estimator.banding.band_layout`): only glints predicted
            within them are candidates. Default: the whole image.
        prior_angles_rad : (2,) float, optional
            Eye rotation (Fick yaw, pitch) of the previous sample. Without it: coarse search
            over the whole grid.

        Returns
        -------
        GlintMatch
        """
        g, lo, hi = self._inputs(glints_px, rows)
        k = g.shape[0]
        if k == 0:
            return self._failure(0, TOO_FEW_GLINTS)
        p = self.params
        from_prior = None
        if prior_angles_rad is not None:
            prior = np.asarray(prior_angles_rad, dtype=np.float64).reshape(2)
            if not np.isfinite(prior).all():
                raise ValueError("prior_angles_rad must be finite")
            # The prior, and the best grid poses near it: a prior a few pixels off can lock
            # onto the arc's chain shifted by one light, which only a rival start exposes.
            near = self._near(prior, math.radians(p.prior_window_deg))
            starts = [prior] + (self._coarse(g, lo, hi, near, p.prior_hypotheses)
                                if p.prior_hypotheses else [])
            weight = np.eye(2) / math.radians(p.prior_sigma_deg) ** 2
            from_prior = self._choose(g, lo, hi, starts, p.prior_gate_px, p.min_matches_prior,
                                      _Prior(prior, weight))
            if from_prior is not None and from_prior.ok:
                n = int(from_prior.matched.sum())
                if n >= p.min_matches or n >= 0.5 * k:
                    return from_prior
        # No prior, or one that explains too little (stale after a blink or a saccade, or a
        # band with few glints among clutter): the coarse search, and the better of the two.
        starts = self._coarse(g, lo, hi, None, p.hypotheses)
        cold = self._choose(g, lo, hi, starts, p.coarse_gate_px, p.min_matches)
        results = [r for r in (from_prior, cold) if r is not None]
        good = [r for r in results if r.ok]
        if good:
            return min(good, key=lambda r: r.score)
        return results[-1] if results else self._failure(k, NO_HYPOTHESIS)

    def match_near(self, glints_px, prior_angles_rad, prior_cov_rad2, rows=None, *,
                   min_matches: int = 1) -> GlintMatch:
        """Identify the few detections of a sparse band from a prior alone (no coarse search).

        A band with one or two glints cannot be identified cold (the chain of an arc shifted
        by a light fits them as well), but it can from a prior on the eye rotation that is
        tight compared with the angular step between neighbouring lights (~2° in
        ``paper_sim``). The first assignment is gated at ``gate_px`` plus three prior standard
        deviations of each predicted glint; every hypothesis (the prior's assignment and that
        assignment shifted by ±1, ±2 lights along the arcs) is refitted with the prior (the
        maximum a posteriori rotation) and scored with its squared Mahalanobis distance from
        the prior mean; a runner-up within ``min_margin`` makes the band "ambiguous". Only the
        ``"orbit"`` model carries an angle prior.

        Parameters
        ----------
        glints_px : (k, 2) float
        prior_angles_rad : (2,) float
            Prior mean of the Fick (yaw, pitch).
        prior_cov_rad2 : (2, 2) float
            Prior covariance Σ (rad²), symmetric positive definite.
        rows : (float, float), optional
            As :meth:`match`.
        min_matches : int
            Fewest matched detections of an accepted identification: on the orbit one glint
            (two coordinates) fixes the two angles.

        Returns
        -------
        GlintMatch
        """
        p = self.params
        if p.model != "orbit":
            raise ValueError("match_near needs the 'orbit' model (its prior is on the angles)")
        g, lo, hi = self._inputs(glints_px, rows)
        mean = np.asarray(prior_angles_rad, dtype=np.float64).reshape(2)
        cov = np.asarray(prior_cov_rad2, dtype=np.float64)
        if cov.shape != (2, 2) or not np.isfinite(cov).all() or not np.isfinite(mean).all():
            raise ValueError(f"prior_angles_rad (2,) and prior_cov_rad2 (2, 2) must be finite, "
                             f"got shapes {mean.shape} and {cov.shape}")
        sym = 0.5 * (cov + cov.T)
        if not _eig_2x2(sym[0, 0], sym[0, 1], sym[1, 1])[0] > 0:
            raise ValueError("prior_cov_rad2 must be positive definite")
        if min_matches < 1:
            raise ValueError(f"min_matches must be >= 1, got {min_matches}")
        k = g.shape[0]
        if k == 0:
            return self._failure(0, TOO_FEW_GLINTS)
        det = sym[0, 0] * sym[1, 1] - sym[0, 1] * sym[1, 0]
        weight = np.array([[sym[1, 1], -sym[0, 1]], [-sym[1, 0], sym[0, 0]]]) / det
        prior = _Prior(mean, weight, (mean, p.noise_px ** 2 * weight))
        # Prior SD of each predicted glint: the largest over lights of the projected covariance
        # J Σ Jᵀ, J (n, 2, 2) the prediction's closed-form derivative at the prior's mean.
        _, both, J = self._predict_one_rows(float(mean[0]), float(mean[1]))
        spread = 0.0
        if both.any():
            C = J[both] @ cov @ np.swapaxes(J[both], 1, 2)
            top = _eig_2x2(C[:, 0, 0], 0.5 * (C[:, 0, 1] + C[:, 1, 0]), C[:, 1, 1])[1]
            spread = float(np.sqrt(top.max()))
        gate = math.hypot(p.gate_px, 3.0 * spread)
        result = self._choose(g, lo, hi, [mean], gate, min_matches, prior)
        return result if result is not None else self._failure(k, NO_HYPOTHESIS)

    def _inputs(self, glints_px, rows):
        """Checked detections (k, 2) and band rows (lo, hi)."""
        g = np.asarray(glints_px, dtype=np.float64)
        if g.ndim != 2 or g.shape[1] != 2:
            raise ValueError(f"glints_px must have shape (k, 2), got {g.shape}")
        if not np.isfinite(g).all():
            raise ValueError("glints_px must be finite")
        cam = self.setup.camera
        lo, hi = (-0.5, cam.height_px - 0.5) if rows is None else (float(rows[0]), float(rows[1]))
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"rows must be finite (first, last) with first <= last, got {rows!r}")
        return g, lo, hi

    def _choose(self, g, lo, hi, starts, first_gate, min_matches, prior: _Prior | None = None
                ) -> GlintMatch | None:
        """Refine the starting poses, keep the lowest score; None when none matches anything.
        With a prior, each hypothesis' score also pays for its distance from it (squared
        Mahalanobis distance of its angles), and its fit includes the prior where it has one."""
        if not starts:
            return None
        X = np.array([self._x_from_angles(a) for a in starts])
        # The arc's chain shifted by a light or two along itself is the classic wrong basin
        # (the glints are near-evenly spaced): those identities are tried explicitly, as
        # starts whose first assignment is shifted. With a prior, shifted from the prior's
        # own assignment, in the same batch; cold, from the leading refined hypotheses.
        steps = (-2, -1, 1, 2)
        first = None
        if prior is not None:
            pred, cand, _ = self._candidates(X[:1], lo, hi)
            base, _ = self._assign(g, pred[0], cand[0], first_gate)
            if len(starts) == 1 and not (base >= 0).any():
                return None  # what the refinement of this one start would find: nothing
            shifted = [a for a in (self._shift(base, s) for s in steps) if (a >= 0).any()]
            first = [None] * len(starts) + shifted
            X = np.concatenate([X, np.repeat(X[:1], len(shifted), axis=0)])
        fit_prior = None if prior is None else prior.fit
        refined = self._refine(g, lo, hi, X, first_gate, first, fit_prior)
        if not refined:
            return None
        if prior is None:
            refined.sort(key=lambda h: h.score)
            shifted = [(h, self._shift(h.assign, s))
                       for h in refined[: self.params.shift_sources] for s in steps]
            shifted = [(h, a) for h, a in shifted if (a >= 0).any()]
            if shifted:
                refined += self._refine(g, lo, hi, np.array([h.x for h, _ in shifted]),
                                        self.params.gate_px, [a for _, a in shifted])
        else:
            refined = [replace(h, score=h.score + prior.distance2(self._angles_center(h.x)[0]))
                       for h in refined]
        refined.sort(key=lambda h: h.score)
        best = refined[0]
        # Runner-up: the best hypothesis whose identities differ from the winner's.
        margin = math.inf
        for h in refined[1:]:
            if not np.array_equal(h.assign, best.assign):
                margin = h.score - best.score
                break
        return self._result(g, best, margin, min_matches)

    def _failure(self, k: int, reason: str) -> GlintMatch:
        return GlintMatch(np.full(k, -1, dtype=np.int64), np.zeros(k), np.full(k, np.nan),
                          np.full(3, np.nan), np.full(2, np.nan), math.nan, math.inf, 0.0, 0,
                          reason)

    # ----------------------------------------------------------------------- coarse search

    # ----------------------------------------------------------------------- refinement

    # ----------------------------------------------------------------------- result

    def _result(self, g, h: _Hypothesis, margin: float, min_matches: int) -> GlintMatch:
        p = self.params
        k = g.shape[0]
        matched = h.assign >= 0
        n_matched = int(matched.sum())
        if not h.fit_ok:
            reason = FIT_FAILED
        elif n_matched < min_matches:
            reason = TOO_FEW_GLINTS
        elif margin < p.min_margin:
            reason = AMBIGUOUS
        else:
            reason = OK
        if reason != OK:
            # No identity is claimed from a fit that cannot be trusted (STYLE: a result with a
            # reason, not a guess).
            return GlintMatch(np.full(k, -1, dtype=np.int64), np.zeros(k), np.full(k, np.nan),
                              np.full(3, np.nan), np.full(2, np.nan), math.nan, h.score, margin,
                              h.iterations, reason)
        angles, center = self._angles_center(h.x)
        rms = float(np.sqrt(np.mean(h.residual[matched] ** 2)))
        # Confidence: residual, margin to the second-best assignment, hypothesis margin.
        conf = np.zeros(k)
        lights = np.flatnonzero(h.cand)
        c_hyp = 1.0 if math.isinf(margin) else math.tanh(max(margin, 0.0) / 4.0)
        if kernels.ENABLED:
            kernels.confidences(g, h.assign, h.residual, h.pred, lights, p.gate_px, c_hyp, conf)
            return GlintMatch(h.assign.copy(), conf, h.residual.copy(), center, angles, rms,
                              h.score, margin, h.iterations, reason)
        d_all = np.sqrt(((g[:, None, :] - h.pred[None, lights, :]) ** 2).sum(-1))  # (k, m)
        det = np.flatnonzero(matched)
        own = np.searchsorted(lights, h.assign[det])
        r = h.residual[det]
        other_cand = d_all[det].copy()  # other candidates near the detection
        other_cand[np.arange(det.size), own] = np.inf
        other_det = d_all[:, own].copy()  # other detections near the matched prediction
        other_det[det, np.arange(det.size)] = np.inf
        d2 = np.minimum(other_cand.min(axis=1, initial=np.inf),
                        other_det.min(axis=0, initial=np.inf))
        c_res = np.clip(1.0 - r / p.gate_px, 0.0, 1.0)
        c_alt = np.clip((d2 - r) / p.gate_px, 0.0, 1.0)
        conf[det] = c_res * c_alt * c_hyp
        return GlintMatch(h.assign.copy(), conf, h.residual.copy(), center, angles, rms,
                          h.score, margin, h.iterations, reason)


def _eig_2x2(a, b, c):
    """Smaller and larger eigenvalues of the symmetric 2 x 2 [[a, b], [b, c]] (scalars or
    arrays) in closed form (np.linalg.eigh costs ~20 us a call; a prior-assisted band asks
    twice)."""
    mid, half = 0.5 * (a + c), np.hypot(0.5 * (a - c), b)
    return mid - half, mid + half


def match_glints(glints_px, setup: Setup, rows=None, prior_angles_rad=None,
                 params: MatchParams = MatchParams()) -> GlintMatch:
    """One-off :meth:`GlintMatcher.match` (builds the matcher's grid: keep a
    :class:`GlintMatcher` to match many bands)."""
    return GlintMatcher(setup, params).match(glints_px, rows, prior_angles_rad)
