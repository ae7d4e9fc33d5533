"""The small steps of a band's identification compiled with Numba (optional): the coarse
search's score over the grid of rotations, the gated assignment where no two detections want
the same light, the lights' order along their arcs, the cheap path's rival check, the
identities' confidences and a band's support (:meth:`estimator.matching.HypothesisSearch.band_support`).

A band has 5-40 detections and candidates, so the numpy forms of these steps
(:meth:`estimator.matching.HypothesisSearch._assign`, ``_enforce_order``,
:meth:`estimator.matching.BandFollower._rival_margin`, the confidences of
:meth:`estimator.matching.GlintMatcher._result`) cost the overhead of their ~20-60 numpy
calls each, not arithmetic: ~0.6 ms of the cheap path's ~1 ms per band on an x86 core; the
coarse score (:meth:`estimator.matching.HypothesisSearch._coarse`) builds arrays of every
(node, light, detection) triple, ~15 ms of a cold search's ~35 ms. These
kernels do the same arithmetic one element at a time, in the same order where an order
decides (ties of the assignment, the first order violation), so that both forms give the same
identities and scores to rounding (tested against each other on random and real bands).

The same switch, :data:`ENABLED`, has the prior-assisted bands refitted and estimated by the
compiled small fit with the prior (:func:`estimator.cornea.fit_small`, the batched fit's cost
and minimum to ~1e-9 m): such a band drops from ~6 to ~2.5 ms. Cold hypotheses (no prior)
keep the batched fit: on their poor ones (few glints, far from the truth) the two solvers'
stopping rules part, and the installs with and without Numba would then name different
failures.

Without Numba (or with ``NUMBA_DISABLE_JIT=1``) the numpy forms run (:data:`ENABLED` is
False): the estimator needs nothing beyond numpy, scipy and OpenCV.
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba
except ImportError:  # the numpy forms run instead
    numba = None

#: Whether the matcher and the cheap path use these kernels (Numba imports and its JIT is on).
ENABLED = numba is not None and not numba.config.DISABLE_JIT


def nearest_assign(g, pred, lights, gate2, assign, dist):
    """The gated assignment of detections ``g`` (k, 2) to the candidate ``lights`` (m,)
    predicted at ``pred`` (n, 2) where it needs no solver: each detection takes its nearest
    candidate within the gate (the first on a tie), unmatched without one. Fills ``assign``
    (k,) and ``dist`` (k,) and returns True where no two detections took the same light (then
    this is the optimal assignment); False otherwise (the caller solves it)."""
    k, m = g.shape[0], lights.shape[0]
    taken = np.zeros(pred.shape[0], dtype=np.bool_)
    unique = True
    for d in range(k):
        best, best_d2 = -1, math.inf
        for c in range(m):
            light = lights[c]
            dx = g[d, 0] - pred[light, 0]
            dy = g[d, 1] - pred[light, 1]
            d2 = dx * dx + dy * dy
            if d2 <= gate2 and d2 < best_d2:
                best, best_d2 = light, d2
        if best >= 0:
            if taken[best]:
                unique = False
            taken[best] = True
            assign[d] = best
            dist[d] = math.sqrt(best_d2)
        else:
            assign[d] = -1
            dist[d] = math.nan
    return unique


def optimal_assign(g, pred, lights, gate2, assign, dist, max_nodes):
    """The gated optimal assignment where two detections want one light, by a depth-first
    search over each detection's candidates within the gate (nearest first) and "unmatched"
    (at the gate's cost ``gate2``), pruned by the cost so far plus each remaining detection's
    least cost: the minimum of :meth:`HypothesisSearch._assign`'s problem (the sum of squared
    distances of the matches plus ``gate2`` per unmatched detection) that scipy's
    ``linear_sum_assignment`` solves there. Fills ``assign`` and ``dist`` (NaN unmatched)
    and returns True; False (outputs untouched) where the search would visit more than
    ``max_nodes`` nodes (the caller solves it)."""
    k, m = g.shape[0], lights.shape[0]
    opts = np.empty((k, m), dtype=np.int64)
    od2 = np.empty((k, m))
    nopt = np.zeros(k, dtype=np.int64)
    for d in range(k):
        for c in range(m):
            light = lights[c]
            dx = g[d, 0] - pred[light, 0]
            dy = g[d, 1] - pred[light, 1]
            d2 = dx * dx + dy * dy
            if d2 > gate2:
                continue
            i = nopt[d]  # insertion, nearest first (the first on a tie)
            while i > 0 and od2[d, i - 1] > d2:
                opts[d, i] = opts[d, i - 1]
                od2[d, i] = od2[d, i - 1]
                i -= 1
            opts[d, i] = c
            od2[d, i] = d2
            nopt[d] += 1
    # The least cost of detections d.. (each its nearest candidate or the gate).
    rest = np.zeros(k + 1)
    for d in range(k - 1, -1, -1):
        low = gate2 if nopt[d] == 0 else min(od2[d, 0], gate2)
        rest[d] = rest[d + 1] + low
    if k == 0:
        return True
    used = np.zeros(m, dtype=np.bool_)
    held = np.zeros(k, dtype=np.bool_)  # whether detection d's current choice holds its light
    choice = np.full(k, -1, dtype=np.int64)
    best = np.full(k, -1, dtype=np.int64)
    partial = np.zeros(k + 1)
    best_cost = math.inf
    nodes = 0
    level = 0
    while level >= 0:
        d = level
        if held[d]:
            used[opts[d, choice[d]]] = False
            held[d] = False
        choice[d] += 1
        if choice[d] > nopt[d]:
            choice[d] = -1
            level -= 1
            continue
        nodes += 1
        if nodes > max_nodes:
            return False
        matched = choice[d] < nopt[d]
        if matched:
            c = opts[d, choice[d]]
            if used[c]:
                continue
            cost = partial[d] + od2[d, choice[d]]
        else:
            cost = partial[d] + gate2
        if cost + rest[d + 1] >= best_cost:
            continue
        if matched:
            used[c] = True
            held[d] = True
        if d == k - 1:
            best_cost = cost
            for e in range(k):
                best[e] = choice[e]
        else:
            partial[d + 1] = cost
            level += 1
            choice[level] = -1
    for d in range(k):
        if best[d] >= 0 and best[d] < nopt[d]:
            assign[d] = lights[opts[d, best[d]]]
            dist[d] = math.sqrt(od2[d, best[d]])
        else:
            assign[d] = -1
            dist[d] = math.nan
    return True


def enforce_order(g, pred, assign, group):
    """Drop matches that break the lights' order along their arc, in place: repeatedly, the
    first (by arc, then light) neighbouring pair on one arc whose detections run against their
    predictions loses its match with the larger residual (the numpy form's loop)."""
    n_det = assign.shape[0]
    n_lights = group.shape[0]
    for _ in range(n_det):
        det = np.flatnonzero(assign >= 0)
        if det.size < 2:
            break
        key = np.empty(det.size, dtype=np.int64)
        for i in range(det.size):
            light = assign[det[i]]
            key[i] = group[light] * n_lights + light
        det = det[np.argsort(key)]
        bad = -1
        for i in range(det.size - 1):
            la, lb = assign[det[i]], assign[det[i + 1]]
            if group[la] != group[lb]:
                continue
            dot = ((pred[lb, 0] - pred[la, 0]) * (g[det[i + 1], 0] - g[det[i], 0])
                   + (pred[lb, 1] - pred[la, 1]) * (g[det[i + 1], 1] - g[det[i], 1]))
            if dot <= 0:
                bad = i
                break
        if bad < 0:
            break
        a, b = det[bad], det[bad + 1]
        ra = math.hypot(g[a, 0] - pred[assign[a], 0], g[a, 1] - pred[assign[a], 1])
        rb = math.hypot(g[b, 0] - pred[assign[b], 0], g[b, 1] - pred[assign[b], 1])
        if ra >= rb:
            assign[a] = -1
        else:
            assign[b] = -1


def _rival_light(assign, shifted, finite, d, r):
    """The light detection ``d`` takes in rival ``r`` (its match shifted along the arc), or
    -1 where it has none or the linearisation does not place it."""
    if assign[d] < 0:
        return -1
    light = shifted[assign[d], r]
    return light if light >= 0 and finite[light] else -1


def rival_margin(g, assign, pred, J, vis, shifted, x, prior, lo, hi, gate_px, band_margin_px,
                 noise_px, unmatched_cost, missing_cost, prior_sigma_rad, weight, score):
    """:meth:`estimator.matching.BandFollower._rival_margin` from its linearisation: ``pred``
    (n, 2) and ``J`` (n, 2, 2) px/rad at the fitted rotation ``x`` (2,) and the lights'
    visibility ``vis`` (n,) there (a light is placed where it is visible and finite),
    ``shifted`` (n, 4) each light's neighbours -2, -1, +1, +2 along its arc
    (-1 off it). The smallest rival score minus ``score``; inf without a rival, -inf where a
    rival's normal equations are singular."""
    k, n = g.shape[0], pred.shape[0]
    finite = np.empty(n, dtype=np.bool_)
    for light in range(n):
        finite[light] = vis[light] and np.isfinite(pred[light, 0]) and np.isfinite(pred[light, 1])
        for i in range(2):
            for a in range(2):
                finite[light] = finite[light] and np.isfinite(J[light, i, a])
    gate2 = gate_px * gate_px
    noise2 = noise_px * noise_px
    best = math.inf
    any_rival = False
    detected = np.zeros(n, dtype=np.bool_)
    # Every rival's normal equations first: a singular one stops the check (-inf) before
    # any score, as in the numpy form.
    deltas = np.zeros((4, 2))
    live = np.zeros(4, dtype=np.bool_)
    for r in range(4):
        a00 = a01 = a11 = b0 = b1 = 0.0
        used = False
        for d in range(k):
            light = _rival_light(assign, shifted, finite, d, r)
            if light < 0:
                continue
            used = True
            ry = g[d, 0] - pred[light, 0]
            rv = g[d, 1] - pred[light, 1]
            j00, j01 = J[light, 0, 0], J[light, 0, 1]
            j10, j11 = J[light, 1, 0], J[light, 1, 1]
            a00 += j00 * j00 + j10 * j10
            a01 += j00 * j01 + j10 * j11
            a11 += j01 * j01 + j11 * j11
            b0 += j00 * ry + j10 * rv
            b1 += j01 * ry + j11 * rv
        if not used:
            continue
        any_rival = True
        det = a00 * a11 - a01 * a01
        if not abs(det) > 1e-12 * a00 * a11:
            return -math.inf
        deltas[r, 0] = (a11 * b0 - a01 * b1) / det
        deltas[r, 1] = (a00 * b1 - a01 * b0) / det
        live[r] = True
    if not any_rival:
        return math.inf
    for r in range(4):
        if not live[r]:
            continue
        e0, e1 = deltas[r, 0], deltas[r, 1]
        detected[:] = False
        total = 0.0
        kept = 0
        for d in range(k):
            light = _rival_light(assign, shifted, finite, d, r)
            if light < 0:
                continue
            u = pred[light, 0] + (J[light, 0, 0] * e0 + J[light, 0, 1] * e1)
            v = pred[light, 1] + (J[light, 1, 0] * e0 + J[light, 1, 1] * e1)
            d2 = (g[d, 0] - u) ** 2 + (g[d, 1] - v) ** 2
            if d2 <= gate2:
                total += d2
                kept += 1
                detected[light] = True
        missing = 0
        for light in range(n):
            if finite[light] and not detected[light]:
                v = pred[light, 1] + (J[light, 1, 0] * e0 + J[light, 1, 1] * e1)
                if lo + band_margin_px <= v <= hi - band_margin_px:
                    missing += 1
        p0 = (x[0] + e0 - prior[0]) / prior_sigma_rad
        p1 = (x[1] + e1 - prior[1]) / prior_sigma_rad
        rival = (total / noise2 + (k - kept) * unmatched_cost + missing_cost * missing
                 + weight * (p0 * p0 + p1 * p1))
        best = min(best, rival)
    return best - score


def confidences(g, assign, residual, pred, lights, gate_px, c_hyp, conf):
    """Each matched detection's confidence (:meth:`estimator.matching.GlintMatcher._result`)
    into ``conf`` (k,): its residual against the gate, times the lead of its match over the
    nearest other candidate of the detection or other detection of the light, times
    ``c_hyp``. ``lights`` (m,) are the candidates, the matched ones among them."""
    k, m = g.shape[0], lights.shape[0]
    for d in range(k):
        conf[d] = 0.0
        if assign[d] < 0:
            continue
        own = assign[d]
        r = residual[d]
        other = math.inf
        for c in range(m):
            light = lights[c]
            if light != own:
                other = min(other, math.sqrt((g[d, 0] - pred[light, 0]) ** 2
                                             + (g[d, 1] - pred[light, 1]) ** 2))
        for e in range(k):
            if e != d:
                other = min(other, math.sqrt((g[e, 0] - pred[own, 0]) ** 2
                                             + (g[e, 1] - pred[own, 1]) ** 2))
        c_res = min(max(1.0 - r / gate_px, 0.0), 1.0)
        c_alt = min(max((other - r) / gate_px, 0.0), 1.0)
        conf[d] = c_res * c_alt * c_hyp


def coarse_scores(pred, vis, nodes, g, lo, hi, band_margin_px, gate2, unmatched_cost,
                  missing_cost, score):
    """The coarse search's score of every grid node into ``score`` (N,): each detection of
    ``g`` (k, 2) costs its squared distance to the node's nearest candidate glint, capped at
    the coarse gate ``gate2`` and scaled so that the cap costs ``unmatched_cost``; each
    candidate well inside the band with no detection within the gate costs
    ``missing_cost``; inf for a node without a candidate. ``pred`` (N, n, 2) and ``vis``
    (N, n) are the grid's glints, ``nodes`` (N,) the nodes to score."""
    n_nodes, n_lights = vis.shape
    k = g.shape[0]
    near = np.empty(k)
    # A glint only changes the costs of the detections within the gate of it (a farther
    # one's distance is capped or is not the node's nearest within it), and those lie within
    # the gate in u: the detections are taken by column, a glint's found by bisection with a
    # margin of 1e-9 of the gate (a cluttered band has hundreds of detections; the same
    # scores to the last bit).
    order = np.argsort(g[:, 0])
    columns = np.empty(k)
    for i in range(k):
        columns[i] = g[order[i], 0]
    reach = math.sqrt(gate2) * (1.0 + 1e-9) + 1e-9
    for node in range(n_nodes):
        score[node] = math.inf
        if not nodes[node]:
            continue
        near[:] = math.inf
        used = False
        missing = 0.0
        for light in range(n_lights):
            v = pred[node, light, 1]
            if not (vis[node, light] and lo - band_margin_px <= v <= hi + band_margin_px):
                continue
            used = True
            u = pred[node, light, 0]
            closest = math.inf
            first = np.searchsorted(columns, u - reach)
            last = np.searchsorted(columns, u + reach, side="right")
            for i in range(first, last):
                d = order[i]
                du = u - g[d, 0]
                dv = v - g[d, 1]
                d2 = du * du + dv * dv
                near[d] = min(near[d], d2)
                closest = min(closest, d2)
            if lo + band_margin_px <= v <= hi - band_margin_px and closest > gate2:
                missing += 1.0
        if used:
            total = 0.0
            for d in range(k):
                total += min(near[d], gate2)
            score[node] = total / gate2 * unmatched_cost + missing_cost * missing


def band_support(pred, vis, angles, center, reach, lo, hi, g, radius2):
    """Most lights one grid node within ``reach`` (rad) of ``center`` (2,) can have matched:
    per node, the fewer of its candidates (visible, rows within [lo, hi]) and of the
    detections ``g`` (k, 2) within ``radius2`` (px²) of one of them. ``pred`` (N, n, 2),
    ``vis`` (N, n), ``angles`` (N, 2)."""
    n_nodes, n_lights = vis.shape
    k = g.shape[0]
    best = 0
    reach2 = reach * reach
    near = np.zeros(k, dtype=np.bool_)
    cand = np.empty(n_lights, dtype=np.int64)
    for node in range(n_nodes):
        dy = angles[node, 0] - center[0]
        dp = angles[node, 1] - center[1]
        if dy * dy + dp * dp > reach2:
            continue
        # A node improves on the best only with more candidates than it has, and counts at
        # most as many detections as candidates: the detections are only scanned then, and
        # only until they reach that count (the same maximum as scanning them all).
        count = 0
        for light in range(n_lights):
            v = pred[node, light, 1]
            if vis[node, light] and lo <= v <= hi:
                cand[count] = light
                count += 1
        if count <= best or best >= k:
            continue
        near[:] = False
        found = 0
        for c in range(count):
            u, v = pred[node, cand[c], 0], pred[node, cand[c], 1]
            for d in range(k):
                if near[d]:
                    continue
                du, dv = u - g[d, 0], v - g[d, 1]
                if du * du + dv * dv <= radius2:
                    near[d] = True
                    found += 1
            if found >= count:
                break
        best = max(best, min(count, found))
    return best


if ENABLED:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _rival_light = _jit(_rival_light)
    nearest_assign = _jit(nearest_assign)
    optimal_assign = _jit(optimal_assign)
    enforce_order = _jit(enforce_order)
    rival_margin = _jit(rival_margin)
    confidences = _jit(confidences)
    coarse_scores = _jit(coarse_scores)
    band_support = _jit(band_support)
