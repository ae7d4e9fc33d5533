"""The cheap path of a band (:meth:`estimator.matching.BandFollower.follow`) as one compiled
call (optional, Numba).

:class:`~estimator.matching.BandFollower` runs its steps (predict, gated assignment, small fit,
re-predict, final assignment with the arcs' order, score, rival check, confidences) as ~60
Python and numpy calls around compiled kernels: ~150-300 us a band on an x86 core, most of it
call overhead, where the arithmetic is ~20 us. :func:`follow_band` runs the same kernels in the
same order inside one compiled function: the projection
(:func:`estimator.geometry.compiled.glints_kernel`), the assignment where no two detections
want one light (:func:`estimator.matching.kernels.nearest_assign`), the arcs' order
(``enforce_order``), the small fit (:data:`estimator.cornea.small.lm_kernel`), the rival check
(``rival_margin``) and the confidences. Where two detections want one light the compiled
optimal assignment (:func:`estimator.matching.kernels.optimal_assign`) gives what the Python
form's ``linear_sum_assignment`` gives; where that search would visit more than
:data:`MAX_NODES` nodes it stops and says so (:data:`FALLBACK`), and the caller runs the
Python form. The two forms give the same identities, fits and scores
(``tests/estimator/test_follow_kernel.py`` holds them to 1e-9 on synthetic bands with noise,
hidden glints, clutter and priors up to 3 deg off, and end to end in the tracker).
"""

from __future__ import annotations

import math

import numpy as np

from ..cornea.small import XTOL_M, lm_kernel
from ..geometry import compiled
from ..geometry.compiled import glints_kernel
from .kernels import (ENABLED as _KERNELS, confidences, enforce_order, nearest_assign,
                      optimal_assign, rival_margin)

#: :func:`follow_band`'s outcomes: the band declined (the search decides), accepted (the
#: outputs hold its match), or an assignment that needs the optimal solver (run the Python form).
DECLINED, ACCEPTED, FALLBACK = 0, 1, 2
#: The most nodes the compiled optimal assignment visits before the Python form takes the band
#: (a sparse band's 1-4 detections with 1-3 candidates each visit tens).
MAX_NODES = 20000
#: A band with more unmatched detections than matched (clutter beside the glints) is taken
#: only where each matched detection stands alone within this many gates (``gate_px``) of its
#: light's predicted glint, and no other candidate light is predicted that near it: there the
#: search, whose fit from the prior lands a fraction of a pixel from the follower's, assigns
#: the same detections (:meth:`estimator.matching.BandFollower.follow`).
CROWD_GATES = 2.0
#: Whether :func:`follow_band` is compiled (the matching kernels and the projection are).
ENABLED = _KERNELS and compiled.ENABLED


def orbit_args(matcher) -> tuple:
    """The arguments :func:`follow_band` and :func:`estimator.matching.refine_kernel.refine_prior`
    share, from a :class:`~estimator.matching.GlintMatcher` on the orbit: the camera arrays,
    the orbit (rotation centre, cornea offset), the eye's r_c, lights and cap, the fit
    problem's c_e, r_co, r_c and step tolerance, and the lights' arcs."""
    eye, problem = matcher.eye, matcher.problem
    rco = float(problem.orbit_radius_m)
    return (*matcher.arrays, np.asarray(eye.rotation_center_m, dtype=np.float64),
            float(eye.cornea_offset_m), float(eye.cornea_radius_m),
            np.ascontiguousarray(matcher.lights_world_m, dtype=np.float64),
            float(eye.cap_cos_min), np.asarray(problem.eye_center_m, dtype=np.float64), rco,
            float(problem.cornea_radius_m), XTOL_M / rco,
            np.ascontiguousarray(matcher.group, dtype=np.int64))


def orbit_pose(angles, rc, offset, center, axis):
    """Cornea centre and optical axis (3,) of Fick ``angles`` on the orbit, into the outputs
    (:meth:`estimator.matching.GlintMatcher._orbit_pose`)."""
    cp = math.cos(angles[1])
    axis[0] = cp * math.sin(angles[0])
    axis[1] = math.sin(angles[1])
    axis[2] = -cp * math.cos(angles[0])
    for i in range(3):
        center[i] = rc[i] + offset * axis[i]


def _candidates(cam, angles, rc, offset, radius, lights, cap, lo, hi, b, pred, vis, cand,
                inside, center, axis, jac, with_jacobian):
    """Predicted glints at ``angles``, their candidates (inside the band widened by ``b``)
    and those well inside it (narrowed by ``b``) (:meth:`BandFollower._candidates`)."""
    R, O, intr, size = cam
    orbit_pose(angles, rc, offset, center, axis)
    glints_kernel(R, O, intr, size, center, radius, lights, axis, cap, True, pred, vis,
                  with_jacobian, jac)
    for n in range(pred.shape[0]):
        v = pred[n, 1]
        cand[n] = vis[n] and v >= lo - b and v <= hi + b
        inside[n] = vis[n] and v >= lo + b and v <= hi - b


def _assign(g, pred, cand, gate, assign, dist, max_nodes):
    """The gated optimal assignment (:meth:`HypothesisSearch._assign`): each detection's
    nearest candidate where no two want one light, else the compiled optimal search
    (:func:`estimator.matching.kernels.optimal_assign`); False where that search would visit
    more than ``max_nodes`` nodes."""
    lights = np.flatnonzero(cand)
    if lights.size == 0:
        for d in range(g.shape[0]):
            assign[d] = -1
            dist[d] = math.nan
        return True
    if nearest_assign(g, pred, lights, gate * gate, assign, dist):
        return True
    return optimal_assign(g, pred, lights, gate * gate, assign, dist, max_nodes)


def crowded(g, assign, pred, cand, radius):
    """Whether a matched detection of ``assign`` (k,) has a rival within ``radius`` px: another
    detection of ``g`` (k, 2) that near its light's predicted glint (``pred`` (n, 2)), or
    another candidate light (``cand`` (n,)) predicted that near it
    (:meth:`estimator.matching.BandFollower.follow`, :data:`CROWD_GATES`)."""
    r2 = radius * radius
    for d in range(assign.shape[0]):
        a = assign[d]
        if a < 0:
            continue
        for e in range(g.shape[0]):
            if e != d and (g[e, 0] - pred[a, 0]) ** 2 + (g[e, 1] - pred[a, 1]) ** 2 <= r2:
                return True
        for c in range(pred.shape[0]):
            if c != a and cand[c] and \
                    (g[d, 0] - pred[c, 0]) ** 2 + (g[d, 1] - pred[c, 1]) ** 2 <= r2:
                return True
    return False


def matched_pairs(g, lights, assign):
    """The matched detections (m, 2) and their lights (m, 3), in detection order, of an
    assignment ``assign`` (k,) (light index, -1 unmatched) of detections ``g`` (k, 2)."""
    m = 0
    for d in range(assign.shape[0]):
        if assign[d] >= 0:
            m += 1
    gu = np.empty((m, 2))
    Lu = np.empty((m, 3))
    i = 0
    for d in range(assign.shape[0]):
        if assign[d] >= 0:
            gu[i, 0], gu[i, 1] = g[d, 0], g[d, 1]
            for c in range(3):
                Lu[i, c] = lights[assign[d], c]
            i += 1
    return gu, Lu


def _fit(cam, g, lights, assign, x0, ce, rco, radius, xtol, pm, P, x, JtJ):
    """:func:`estimator.cornea.fit_small` ("orbit") of the matched detections from ``x0``:
    (ok, cost, matched count, iterations); x and JᵀJ into the outputs."""
    R, O, intr, size = cam
    gu, Lu = matched_pairs(g, lights, assign)
    m = gu.shape[0]
    for a in range(2):
        for b in range(2):
            JtJ[a, b] = 0.0
    cost, iters, converged = lm_kernel(R, O, intr, size, 1, x0, ce, rco, radius, Lu, gu, 50,
                                       xtol, pm, P, x, JtJ)
    ok = converged and math.isfinite(x[0]) and math.isfinite(x[1]) and math.isfinite(cost)
    return ok, cost, m, iters


def _final(cam, g, x, rc, offset, radius, lights, cap, lo, hi, band_margin_px, gate_px, group,
           max_nodes, pred, vis, cand, inside, center, axis, jac, with_jacobian, assign, dist):
    """Candidates at ``x`` (with ``with_jacobian``, d glint / d centre (n, 2, 3) into
    ``jac``) and the final assignment (gate ``gate_px``, the arcs' order, NaN distances where
    unmatched) (:meth:`HypothesisSearch._final_assign`); False where the assignment needs the
    solver."""
    _candidates(cam, x, rc, offset, radius, lights, cap, lo, hi, band_margin_px, pred, vis,
                cand, inside, center, axis, jac, with_jacobian)
    if not _assign(g, pred, cand, gate_px, assign, dist, max_nodes):
        return False
    enforce_order(g, pred, assign, group)
    for d in range(assign.shape[0]):
        if assign[d] < 0:
            dist[d] = np.nan
    return True


def follow_band(g, lo, hi, prior, weight, R, O, intr, size, rc, offset, radius, lights, cap,
                ce, rco, fit_radius, xtol, group, shifted, prior_gate_px, gate_px,
                band_margin_px, noise_px, unmatched_cost, missing_cost, prior_sigma_rad,
                follow_min_matches, max_shift_rad, rival_margin_min, match_min_matches,
                min_margin, max_rounds, max_nodes, assign, dist, conf, x, center, JtJ):
    """:meth:`estimator.matching.BandFollower.follow` of detections ``g`` (k, 2) in rows
    [lo, hi] from ``prior`` (2,) rad (``weight`` 1 with the prior's term, 0 without).

    The camera (R, O, intr, size), the orbit (rotation centre ``rc``, cornea offset), the
    eye's r_c, lights (n, 3) and cap, the fit problem's c_e, r_co, r_c and step tolerance, the
    arcs (``group`` (n,), ``shifted`` (n, 4)) and the matcher's and follower's settings as
    scalars. Outputs: the match's ``assign``, ``dist`` (residuals, NaN unmatched), ``conf``
    (k,), the fitted angles ``x`` (2,), the cornea ``center`` (3,) and the last fit's ``JtJ``
    (2, 2). Returns (outcome, score, margin, match RMS px, fit cost px², fit glints, fit
    iterations); outcome :data:`DECLINED`, :data:`ACCEPTED` or :data:`FALLBACK`."""
    cam = (R, O, intr, size)
    k, n = g.shape[0], lights.shape[0]
    nan = math.nan
    out = (DECLINED, nan, nan, nan, nan, 0, 0)
    if k < follow_min_matches:
        return out
    pred = np.empty((n, 2))
    vis = np.empty(n, dtype=np.bool_)
    cand = np.empty(n, dtype=np.bool_)
    inside = np.empty(n, dtype=np.bool_)
    axis = np.empty(3)
    jac = np.empty((n, 2, 3))
    no_jac = np.empty((0, 2, 3))
    pm = np.zeros(2)
    P = np.zeros((2, 2))
    x0 = np.empty(2)
    prev = np.empty(k, dtype=np.int64)
    _candidates(cam, prior, rc, offset, radius, lights, cap, lo, hi, band_margin_px, pred, vis,
                cand, inside, center, axis, no_jac, False)
    if not _assign(g, pred, cand, prior_gate_px, assign, dist, max_nodes):
        return (FALLBACK, nan, nan, nan, nan, 0, 0)
    x0[0], x0[1] = prior[0], prior[1]
    cost, m, iters = nan, 0, 0
    settled = False
    for _ in range(max_rounds):
        used = 0
        for d in range(k):
            if assign[d] >= 0:
                used += 1
        if used < follow_min_matches:
            return out
        ok, cost, m, iters = _fit(cam, g, lights, assign, x0, ce, rco, fit_radius, xtol, pm, P,
                                  x, JtJ)
        if not ok:
            return out
        x0[0], x0[1] = x[0], x[1]
        for d in range(k):
            prev[d] = assign[d]
        # With the Jacobian: the rival check's, should this round's assignment be the last.
        if not _final(cam, g, x, rc, offset, radius, lights, cap, lo, hi, band_margin_px,
                      gate_px, group, max_nodes, pred, vis, cand, inside, center, axis, jac,
                      True, assign, dist):
            return (FALLBACK, nan, nan, nan, nan, 0, 0)
        same = True
        for d in range(k):
            same = same and assign[d] == prev[d]
        if same:
            settled = True
            break
    if not settled:
        return out
    matched = 0
    sq = 0.0
    detected = np.zeros(n, dtype=np.bool_)
    for d in range(k):
        if assign[d] >= 0:
            matched += 1
            sq += dist[d] * dist[d]
            detected[assign[d]] = True
    if matched < follow_min_matches:  # BandFollower.follow's test: the search's holds then
        return out
    if matched < 0.5 * k and crowded(g, assign, pred, cand, CROWD_GATES * gate_px):
        return out
    if max(abs(x[0] - prior[0]), abs(x[1] - prior[1])) > max_shift_rad:
        return out
    missing = 0
    for c in range(n):
        if inside[c] and not detected[c]:
            missing += 1
    d0 = (x[0] - prior[0]) / prior_sigma_rad
    d1 = (x[1] - prior[1]) / prior_sigma_rad
    score = (sq / noise_px ** 2 + (k - matched) * unmatched_cost + missing_cost * missing
             + weight * (d0 * d0 + d1 * d1))
    # The rival check's linearisation: d glint / d (yaw, pitch) through the orbit at x
    # (BandFollower._rival_margin, GlintMatcher._predict_one_rows), from the last round's
    # projection at x (the same glints, visibility and Jacobian as projecting x again).
    cp, sp = math.cos(x[1]), math.sin(x[1])
    cy, sy = math.cos(x[0]), math.sin(x[0])
    r = offset
    da = np.array([[r * cp * cy, -r * sp * sy], [0.0, r * cp], [r * cp * sy, r * sp * cy]])
    J = np.empty((n, 2, 2))
    for c in range(n):
        for a in range(2):
            for b in range(2):
                J[c, a, b] = jac[c, a, 0] * da[0, b] + jac[c, a, 1] * da[1, b] \
                    + jac[c, a, 2] * da[2, b]
    margin = rival_margin(g, assign, pred, J, vis, shifted, x, prior, lo, hi, gate_px,
                          band_margin_px, noise_px, unmatched_cost, missing_cost,
                          prior_sigma_rad, weight, score)
    if not margin >= rival_margin_min:
        return out
    if matched < match_min_matches or margin < min_margin:
        return out
    c_hyp = 1.0 if math.isinf(margin) else math.tanh(max(margin, 0.0) / 4.0)
    confidences(g, assign, dist, pred, np.flatnonzero(cand), gate_px, c_hyp, conf)
    return (ACCEPTED, score, margin, math.sqrt(sq / matched), cost, m, iters)


if ENABLED:
    _jit = compiled.numba.njit(cache=True, nogil=True, error_model="numpy")
    orbit_pose = _jit(orbit_pose)
    crowded = _jit(crowded)
    matched_pairs = _jit(matched_pairs)
    _candidates = _jit(_candidates)
    _assign = _jit(_assign)
    _fit = _jit(_fit)
    _final = _jit(_final)
    follow_band = _jit(follow_band)
