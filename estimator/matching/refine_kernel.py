"""A sparse band's refinement from a prior (:meth:`estimator.matching.GlintMatcher.match_near`)
as one compiled call (optional, Numba).

``match_near`` refines up to five hypotheses of a band's 1-4 glints (the prior's assignment
and that assignment shifted by one or two lights along the arcs) through
:meth:`HypothesisSearch._refine`: match, refit with the prior, re-predict, re-match until
the assignment is stable, merge duplicates, a final assignment with the arcs' order, a refit
where it changed the matches, and the score: ~60 numpy and kernel calls per hypothesis.
:func:`refine_prior` runs the same steps in the same order inside one compiled function, on
the same kernels (:func:`estimator.geometry.compiled.glints_kernel`,
:func:`estimator.matching.kernels.nearest_assign`, ``optimal_assign`` where two detections
want one light, ``enforce_order``, the small fit :data:`estimator.cornea.small.lm_kernel`
with the prior's term). Measured on the quick validation's rendered frames (x86 core): a
refinement ~100 us against the Python form's ~240 us, ``match_near`` ~175 against ~350 us.
Where the optimal assignment would visit more than :data:`MAX_NODES` nodes it stops and
says so (:data:`FALLBACK`), and the caller runs the Python form, whose
``linear_sum_assignment`` solves it. ``tests/estimator/test_refine_kernel.py`` holds the two
forms to 1e-9 on sparse bands, and the optimal assignment to ``linear_sum_assignment``.
"""

from __future__ import annotations

import numpy as np

from ..geometry import compiled
from .follow_kernel import (  # noqa: F401 (MAX_NODES: the limit search.py passes)
    ENABLED, MAX_NODES, _assign, _candidates, _final, _fit)

#: :func:`refine_prior`'s outcomes: the hypotheses are in the outputs, or an assignment
#: needs the optimal solver (run the Python form).
REFINED, FALLBACK = 1, 2


def refine_prior(g, lo, hi, X0, first, has_first, first_gate, R, O, intr, size, rc, offset,
                 radius, lights, cap, ce, rco, fit_radius, xtol, group, gate_px, band_margin_px,
                 noise_px, unmatched_cost, missing_cost, max_iter, max_nodes, pm, P, X,
                 assign_out, dist_out, pred_out, cand_out, score, iters, ok, alive):
    """:meth:`HypothesisSearch._refine` of the ``H`` starts ``X0`` (H, 2) rad with the prior
    (mean ``pm`` (2,), information ``P`` (2, 2), px²/rad²) in every refit, on the orbit.

    ``first`` (H, k): the first round's assignment where ``has_first`` (H,), else the gated
    assignment at ``first_gate``. Camera, orbit, lights and settings as
    :func:`estimator.matching.follow_kernel.follow_band`. Outputs per hypothesis: angles
    ``X`` (H, 2), the final ``assign_out`` and ``dist_out`` (H, k), ``pred_out`` (H, n, 2),
    ``cand_out`` (H, n), ``score`` (H,) (without the prior's distance), refit rounds
    ``iters``, whether its last fit converged (``ok``) and whether it survives the merging
    (``alive``). Returns :data:`REFINED` or :data:`FALLBACK`."""
    cam = (R, O, intr, size)
    H, k, n = X0.shape[0], g.shape[0], lights.shape[0]
    vis = np.empty(n, dtype=np.bool_)
    inside = np.empty((H, n), dtype=np.bool_)
    center = np.empty(3)
    axis = np.empty(3)
    no_jac = np.empty((0, 2, 3))
    JtJ = np.zeros((2, 2))
    x = np.empty(2)
    gate = np.empty(H)
    prev = np.full((H, k), -1, dtype=np.int64)
    has_prev = np.zeros(H, dtype=np.bool_)
    active = np.ones(H, dtype=np.bool_)
    registered = np.zeros(H, dtype=np.bool_)
    to_fit = np.zeros(H, dtype=np.bool_)
    a_h = np.empty(k, dtype=np.int64)
    d_h = np.empty(k)
    for h in range(H):
        X[h, 0], X[h, 1] = X0[h, 0], X0[h, 1]
        gate[h] = first_gate
        iters[h] = 0
        ok[h] = False
        alive[h] = True
    for it in range(max_iter):
        if not active.any():
            break
        for h in range(H):
            registered[h] = False
            to_fit[h] = False
        for h in range(H):
            if not active[h]:
                continue
            if it == 0 and has_first[h]:
                for d in range(k):
                    a_h[d] = first[h, d]
            else:
                _candidates(cam, X[h], rc, offset, radius, lights, cap, lo, hi, band_margin_px,
                            pred_out[h], vis, cand_out[h], inside[h], center, axis, no_jac,
                            False)
                if not _assign(g, pred_out[h], cand_out[h], gate[h], a_h, d_h, max_nodes):
                    return FALLBACK
            any_match = False
            for d in range(k):
                any_match = any_match or a_h[d] >= 0
            # The latest hypothesis of this round with the same assignment (Python's dict).
            dup = -1
            for e in range(h):
                if registered[e]:
                    same = True
                    for d in range(k):
                        same = same and assign_out[e, d] == a_h[d]
                    if same:
                        dup = e
            if not any_match or (dup >= 0 and gate[h] == gate[dup]):
                active[h] = False
                alive[h] = False
                continue
            registered[h] = True
            for d in range(k):
                assign_out[h, d] = a_h[d]  # this round's assignment, for the duplicates check
            if has_prev[h]:
                same = True
                for d in range(k):
                    same = same and a_h[d] == prev[h, d]
                if same and gate[h] == gate_px:
                    active[h] = False
                    continue
            for d in range(k):
                prev[h, d] = a_h[d]
            has_prev[h] = True
            to_fit[h] = True
        for h in range(H):
            if not to_fit[h]:
                continue
            fitted, _, _, _ = _fit(cam, g, lights, prev[h], X[h], ce, rco, fit_radius, xtol, pm,
                                   P, x, JtJ)
            if fitted:
                X[h, 0], X[h, 1] = x[0], x[1]
                gate[h] = gate_px
            ok[h] = fitted
            iters[h] += 1
    for h in range(H):
        if not alive[h]:
            continue
        if not _final(cam, g, X[h], rc, offset, radius, lights, cap, lo, hi, band_margin_px,
                      gate_px, group, max_nodes, pred_out[h], vis, cand_out[h], inside[h],
                      center, axis, no_jac, False, assign_out[h], dist_out[h]):
            return FALLBACK
        any_match = False
        changed = not has_prev[h]
        for d in range(k):
            any_match = any_match or assign_out[h, d] >= 0
            changed = changed or assign_out[h, d] != prev[h, d]
        if any_match and changed:
            fitted, _, _, _ = _fit(cam, g, lights, assign_out[h], X[h], ce, rco, fit_radius,
                                   xtol, pm, P, x, JtJ)
            if fitted:
                X[h, 0], X[h, 1] = x[0], x[1]
            ok[h] = fitted
            if not _final(cam, g, X[h], rc, offset, radius, lights, cap, lo, hi,
                          band_margin_px, gate_px, group, max_nodes, pred_out[h], vis,
                          cand_out[h], inside[h], center, axis, no_jac, False,
                          assign_out[h], dist_out[h]):
                return FALLBACK
        detected = np.zeros(n, dtype=np.bool_)
        sq = 0.0
        unmatched = 0
        for d in range(k):
            if assign_out[h, d] >= 0:
                sq += dist_out[h, d] * dist_out[h, d]
                detected[assign_out[h, d]] = True
            else:
                unmatched += 1
        missing = 0
        for c in range(n):
            if inside[h, c] and not detected[c]:
                missing += 1
        score[h] = sq / noise_px ** 2 + unmatched * unmatched_cost + missing_cost * missing
    return REFINED


if ENABLED:
    _jit = compiled.numba.njit(cache=True, nogil=True, error_model="numpy")
    refine_prior = _jit(refine_prior)
