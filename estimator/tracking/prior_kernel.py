"""A sparse band's step from the prior as one compiled call (optional, Numba):
:class:`PriorBand`.

A band the tracker cannot identify on its own borrows the last sample as a prior
(:func:`estimator.tracking.assisted.assisted_sample`): the matcher's ``match_near`` (the
prior's spread through every predicted glint, the first gated assignment, that assignment
shifted by one and two lights along the arcs, the compiled refinement
:func:`estimator.matching.refine_kernel.refine_prior`, the prior's distance, the choice, the
runner-up's margin, the confidences), then the small orbit fit with the prior
(:func:`estimator.tracking.estimates.assisted_estimate`), the screen point and the posterior.
Profiled on the benchmark's synthetic frames (60 frames, x86 core, loaded machine): such a
band cost 560-750 us, about as much in total as all the cheap bands; the compiled
refinement was under a third of ``match_near``, the rest ~60 numpy and Python calls.

:func:`prior_band` runs the same steps in the same order in one compiled function, on the same
kernels (:func:`estimator.matching.follow_kernel` ``_candidates``' projection,
:func:`estimator.matching.kernels.nearest_assign`, ``refine_prior``, ``confidences``,
:data:`estimator.cornea.small.lm_kernel`), sorting the hypotheses stably by score as Python's
``list.sort`` does. Two places compute in another order than numpy: the prior's spread
through the glints' Jacobians (numpy's ``matmul`` of (n, 2, 3) by (3, 2) goes through BLAS)
and the gate from it; the gate only bounds the first assignment's distances, so a last-bit
difference could change a band only where a detection lies within rounding of the gate. The
samples of whole streams are the Python form's bit for bit
(``tests/estimator/test_tracking_kernel.py``, ``benchmarks/bench_tracker.py``). Where a step
needs the Python form (two detections want one light in the first assignment, the
refinement's solver limit, a fit the batched fits must judge, a posterior the closed form
cannot invert) it returns :data:`FALLBACK` and the tracker runs the Python form.
"""

from __future__ import annotations

import math

import numpy as np

import estimator.matching.follow_kernel as follow_kernel
import estimator.matching.refine_kernel as refine_kernel

from ..cornea.small import XTOL_M, lm_kernel
from ..gaze import ANGLE_BOUND_RAD
from ..geometry import compiled
from ..geometry.compiled import glints_kernel
from ..matching.kernels import confidences, nearest_assign
from .kernel import axis_point, mapped_point, mapping_args

__all__ = ["PriorBand", "prior_band", "ENABLED", "ESTIMATED", "FALLBACK", "NO_HYPOTHESIS",
           "FIT_FAILED", "TOO_FEW_GLINTS", "AMBIGUOUS"]

#: Whether :func:`prior_band` runs compiled (the refinement kernel does).
ENABLED = refine_kernel.ENABLED and follow_kernel.ENABLED
#: :func:`prior_band`'s outcomes: the sample is estimated (posterior in the outputs, or NaN
#: where the closed form could not invert it), the Python form decides, or the match fails
#: for the matcher's reason (``prior_`` + no_hypothesis, fit_failed, too_few_glints,
#: ambiguous).
ESTIMATED, FALLBACK, NO_HYPOTHESIS, FIT_FAILED, TOO_FEW_GLINTS, AMBIGUOUS = range(6)


def _inverse_2x2(a, b, c, d, rcond, out):
    """:func:`estimator.tracking.samples.inverse_2x2` of [[a, b], [c, d]] into ``out``
    (2, 2); False where it returns None."""
    det = a * d - b * c
    if not det > rcond * a * d:
        return False
    out[0, 0], out[0, 1], out[1, 0], out[1, 1] = d / det, -b / det, -c / det, a / det
    return True


def prior_band(g, lo, hi, mean, cov, R, O, intr, size, rc, offset, radius, lights, cap, ce,
               rco, fit_radius, xtol, group, shifted, fp, ip, polynomial, orbit_lights,
               noise2, max_residual_px, angle_bound, map_offset, map_scale, map_exponents,
               map_coefficients, eye_center, screen_z, assign, conf, angles, center, xy, post):
    """The prior-assisted sample of detections ``g`` (k, 2) in rows [lo, hi] from the prior
    ``mean`` (2,) rad, ``cov`` (2, 2) rad² (the grown covariance of the last sample).

    Camera, orbit and lights as :func:`estimator.matching.follow_kernel.follow_band`; ``fp``
    (7,): the matcher's gate, band margin, noise, unmatched and missing costs, its
    ``min_margin`` and its noise squared (by Python's ``**``); ``ip`` (2,): its refits and the solver's node limit. ``orbit_lights``
    (n, 3): the orbit fit problem's lights; ``noise2``: the prior's glint noise squared;
    ``angle_bound``: :data:`estimator.gaze.ANGLE_BOUND_RAD`. Outputs: the match's ``assign``
    and ``conf`` (k,), the fitted ``angles`` (2,), the cornea ``center`` (3,), the screen
    point ``xy`` (2,) and the posterior covariance ``post`` (2, 2) (NaN where the closed form
    does not invert it). Returns (outcome, RMS px)."""
    nan = math.nan
    k, n = g.shape[0], lights.shape[0]
    gate_px, band_margin_px, noise_px = fp[0], fp[1], fp[2]
    unmatched_cost, missing_cost, min_margin = fp[3], fp[4], fp[5]
    max_iter, max_nodes = ip[0], ip[1]
    for i in range(k):
        if not (math.isfinite(g[i, 0]) and math.isfinite(g[i, 1])):
            return FALLBACK, nan
    s00, s11 = cov[0, 0], cov[1, 1]
    s01, s10 = 0.5 * (cov[0, 1] + cov[1, 0]), 0.5 * (cov[1, 0] + cov[0, 1])
    if not 0.5 * (s00 + s11) - math.hypot(0.5 * (s00 - s11), s01) > 0:
        return FALLBACK, nan  # the Python form refuses the prior with its message
    det = s00 * s11 - s01 * s10
    W = np.empty((2, 2))
    W[0, 0], W[0, 1], W[1, 0], W[1, 1] = s11 / det, -s01 / det, -s10 / det, s00 / det
    info = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            info[a, b] = fp[6] * W[a, b]
    # The prior's spread through every visible light's glint (the gate of the first match).
    pred = np.empty((n, 2))
    vis = np.empty(n, dtype=np.bool_)
    cand = np.empty(n, dtype=np.bool_)
    c0 = np.empty(3)
    axis = np.empty(3)
    jac = np.empty((n, 2, 3))
    follow_kernel.orbit_pose(mean, rc, offset, c0, axis)
    glints_kernel(R, O, intr, size, c0, radius, lights, axis, cap, True, pred, vis, True, jac)
    cp, sp = math.cos(mean[1]), math.sin(mean[1])
    cy, sy = math.cos(mean[0]), math.sin(mean[0])
    da = np.array([[offset * cp * cy, -offset * sp * sy], [0.0, offset * cp],
                   [offset * cp * sy, offset * sp * cy]])
    top = -math.inf
    any_vis = False
    J = np.empty((2, 2))
    JC = np.empty((2, 2))
    for c in range(n):
        if not vis[c]:
            continue
        any_vis = True
        for a in range(2):
            for b in range(2):
                J[a, b] = jac[c, a, 0] * da[0, b] + jac[c, a, 1] * da[1, b] + jac[c, a, 2] * da[2, b]
        for a in range(2):
            for b in range(2):
                JC[a, b] = J[a, 0] * cov[0, b] + J[a, 1] * cov[1, b]
        C00 = JC[0, 0] * J[0, 0] + JC[0, 1] * J[0, 1]
        C01 = JC[0, 0] * J[1, 0] + JC[0, 1] * J[1, 1]
        C10 = JC[1, 0] * J[0, 0] + JC[1, 1] * J[0, 1]
        C11 = JC[1, 0] * J[1, 0] + JC[1, 1] * J[1, 1]
        e = 0.5 * (C00 + C11) + math.hypot(0.5 * (C00 - C11), 0.5 * (C01 + C10))
        top = max(top, e)
    spread = math.sqrt(top) if any_vis else 0.0
    first_gate = math.hypot(gate_px, 3.0 * spread)
    # The first assignment at the prior, and its shifts along the arcs (match_near, _choose).
    follow_kernel.orbit_pose(mean, rc, offset, c0, axis)
    glints_kernel(R, O, intr, size, c0, radius, lights, axis, cap, True, pred, vis, False,
                  np.empty((0, 2, 3)))
    for c in range(n):
        v = pred[c, 1]
        cand[c] = vis[c] and v >= lo - band_margin_px and v <= hi + band_margin_px
    base = np.full(k, -1, dtype=np.int64)
    dist0 = np.full(k, nan)
    cl = np.flatnonzero(cand)
    if cl.size > 0 and not nearest_assign(g, pred, cl, first_gate * first_gate, base, dist0):
        return FALLBACK, nan  # the Python form's solver decides
    if cl.size == 0:
        for d in range(k):
            base[d] = -1
    matched0 = False
    for d in range(k):
        matched0 = matched0 or base[d] >= 0
    if not matched0:
        return NO_HYPOTHESIS, nan
    first = np.full((5, k), -1, dtype=np.int64)
    has_first = np.zeros(5, dtype=np.bool_)
    H = 1
    for col in range(4):
        anyv = False
        for d in range(k):
            v = shifted[base[d], col] if base[d] >= 0 else -1
            first[H, d] = v
            anyv = anyv or v >= 0
        if anyv:
            has_first[H] = True
            H += 1
    X0 = np.empty((H, 2))
    for h in range(H):
        X0[h, 0], X0[h, 1] = mean[0], mean[1]
    X = np.empty((H, 2))
    A = np.empty((H, k), dtype=np.int64)
    D = np.empty((H, k))
    P = np.empty((H, n, 2))
    Cd = np.empty((H, n), dtype=np.bool_)
    score = np.empty(H)
    iters = np.empty(H, dtype=np.int64)
    ok = np.empty(H, dtype=np.bool_)
    alive = np.empty(H, dtype=np.bool_)
    out = refine_kernel.refine_prior(g, lo, hi, X0, first[:H], has_first[:H], first_gate, R, O,
                                     intr, size, rc, offset, radius, lights, cap, ce, rco,
                                     fit_radius, xtol, group, gate_px, band_margin_px, noise_px,
                                     unmatched_cost, missing_cost, max_iter, max_nodes, mean,
                                     info, X, A, D, P, Cd, score, iters, ok, alive)
    if out != refine_kernel.REFINED:
        return FALLBACK, nan
    # The prior's distance, then Python's stable sort by score.
    order = np.empty(H, dtype=np.int64)
    total = np.empty(H)
    m = 0
    for h in range(H):
        if not alive[h]:
            continue
        d0, d1 = X[h, 0] - mean[0], X[h, 1] - mean[1]
        v0 = d0 * W[0, 0] + d1 * W[1, 0]
        v1 = d0 * W[0, 1] + d1 * W[1, 1]
        s = score[h] + (v0 * d0 + v1 * d1)
        if math.isnan(s):
            return FALLBACK, nan
        total[h] = s
        i = m
        while i > 0 and total[order[i - 1]] > s:
            order[i] = order[i - 1]
            i -= 1
        order[i] = h
        m += 1
    if m == 0:
        return NO_HYPOTHESIS, nan
    best = order[0]
    margin = math.inf
    for i in range(1, m):
        h = order[i]
        same = True
        for d in range(k):
            same = same and A[h, d] == A[best, d]
        if not same:
            margin = total[h] - total[best]
            break
    n_matched = 0
    for d in range(k):
        if A[best, d] >= 0:
            n_matched += 1
    if not ok[best]:
        return FIT_FAILED, nan
    if n_matched < 1:
        return TOO_FEW_GLINTS, nan
    if margin < min_margin:
        return AMBIGUOUS, nan
    c_hyp = 1.0 if math.isinf(margin) else math.tanh(max(margin, 0.0) / 4.0)
    for d in range(k):
        assign[d] = A[best, d]
    confidences(g, assign, D[best], P[best], np.flatnonzero(Cd[best]), gate_px, c_hyp, conf)
    # The small orbit fit with the prior (assisted_estimate), from the prior's mean.
    inv = np.empty((2, 2))
    if not _inverse_2x2(cov[0, 0], cov[0, 1], cov[1, 0], cov[1, 1], 1e-12, inv):
        return FALLBACK, nan
    Pi = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            if not math.isfinite(inv[a, b]):
                return FALLBACK, nan
            Pi[a, b] = noise2 * inv[a, b]
    gu, Lu = follow_kernel.matched_pairs(g, orbit_lights, assign)
    JtJ = np.zeros((2, 2))
    cost, _, converged = lm_kernel(R, O, intr, size, 1, mean, ce, rco, fit_radius, Lu, gu, 50,
                                   XTOL_M / rco, mean, Pi, angles, JtJ)
    fit_ok = (converged and math.isfinite(angles[0]) and math.isfinite(angles[1])
              and math.isfinite(cost))
    if not fit_ok:
        return FALLBACK, nan
    rms = math.sqrt(max(cost, 0.0) / n_matched)
    if not (rms <= max_residual_px and max(abs(angles[0]), abs(angles[1])) < angle_bound):
        return FALLBACK, nan
    cp = math.cos(angles[1])
    center[0] = ce[0] + rco * (cp * math.sin(angles[0]))
    center[1] = ce[1] + rco * math.sin(angles[1])
    center[2] = ce[2] + rco * (-cp * math.cos(angles[0]))
    if polynomial:
        mapped_point(center, map_offset, map_scale, map_exponents, map_coefficients, xy)
    else:
        axis_point(angles, eye_center, screen_z, xy)
    if not (math.isfinite(xy[0]) and math.isfinite(xy[1])):
        return FALLBACK, nan
    # The posterior (assisted_sample): the prior's information plus the glints'.
    pinfo = np.empty((2, 2))
    if not _inverse_2x2(cov[0, 0], cov[0, 1], cov[1, 0], cov[1, 1], 0.0, pinfo):
        return FALLBACK, nan
    tmp = np.empty((2, 2))
    if _inverse_2x2(JtJ[0, 0], JtJ[0, 1], JtJ[1, 0], JtJ[1, 1], 1e-12, tmp):
        for a in range(2):
            for b in range(2):
                pinfo[a, b] = pinfo[a, b] + JtJ[a, b] / noise2
    if not _inverse_2x2(pinfo[0, 0], pinfo[0, 1], pinfo[1, 0], pinfo[1, 1], 0.0, post):
        post[0, 0] = nan
    return ESTIMATED, rms


if ENABLED:
    _jit = compiled.numba.njit(cache=True, nogil=True, error_model="numpy")
    _inverse_2x2 = _jit(_inverse_2x2)
    prior_band = _jit(prior_band)


class PriorBand:
    """:func:`prior_band` with a stream's fixed arguments (its
    :class:`~estimator.tracking.BandContext`'s matcher, orbit problem, prior, mapping and
    screen). Built by :meth:`of`; :meth:`__call__` runs one band."""

    __slots__ = ("fixed", "tail")

    def __init__(self, fixed: tuple, tail: tuple):
        self.fixed, self.tail = fixed, tail

    @classmethod
    def of(cls, context, max_residual_px: float):
        """The compiled prior step of ``context``, or None where it has none (no prior, Numba
        absent, a conic calibration, the matcher not on the orbit, a mapping that is not of the
        centre's three coordinates)."""
        if (context.prior is None or not ENABLED or context.calibration.conic
                or context.matcher.params.model != "orbit"):
            return None
        polynomial = context.method == "polynomial"
        if polynomial and context.gaze_map.n_features != 3:
            return None
        matcher, p = context.matcher, context.matcher.params
        fp = np.array([p.gate_px, p.band_margin_px, p.noise_px, p.unmatched_cost,
                       p.missing_cost, p.min_margin, p.noise_px ** 2], dtype=np.float64)
        ip = np.array([p.max_iter, refine_kernel.MAX_NODES], dtype=np.int64)
        fixed = (*follow_kernel.orbit_args(matcher), matcher.shift_table(), fp, ip, polynomial,
                 np.ascontiguousarray(context.problems.orbit.lights_world_m, dtype=np.float64),
                 float(context.prior.noise_px ** 2), float(max_residual_px),
                 float(ANGLE_BOUND_RAD))
        mapping = mapping_args(context, polynomial)
        tail = (*mapping, np.asarray(context.calibration.eye_center_m,
                                     dtype=np.float64).reshape(3),
                float(context.setup.screen.z_m))
        return cls(fixed, tail)

    def __call__(self, g, rows, mean, cov):
        """One band: detections ``g`` (k, 2), ``rows`` (first, last), the prior's ``mean``
        (2,) and ``cov`` (2, 2). Returns (outcome, RMS px, assign (k,), conf (k,), angles
        (2,), centre (3,), screen point (2,), posterior (2, 2))."""
        k = g.shape[0]
        assign, conf = np.empty(k, dtype=np.int64), np.zeros(k)
        angles, center, xy, post = np.empty(2), np.empty(3), np.empty(2), np.empty((2, 2))
        outcome, rms = prior_band(g, float(rows[0]), float(rows[1]), mean, cov, *self.fixed,
                                  *self.tail, assign, conf, angles, center, xy, post)
        return outcome, rms, assign, conf, angles, center, xy, post
