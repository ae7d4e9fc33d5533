"""The cheap path of a stream: a band identified from a recent sample's eye rotation with one
prediction, one gated assignment and one small fit, and checked so that it never claims what
the hypothesis search would not.

:meth:`GlintMatcher.match` with a prior refines the prior, the best grid poses within
``prior_window_deg`` of it and the chain shifted by ±1, ±2 lights (module docstring of
:mod:`estimator.matching.matcher`): ~15 ms a band in numpy. :class:`BandFollower` does what
wins there in the common case, once:

1. predict every light's glint at the prior (one projection,
   :func:`estimator.geometry.compiled.glints_one_pose`); candidates inside the band's rows;
2. assign the detections to them, gated at ``prior_gate_px`` (the matcher's gated optimal
   assignment);
3. fit the orbit to the matched glints from the prior (:func:`estimator.cornea.fit_small`),
   re-predict, re-assign at ``gate_px`` with the lights' order enforced (the matcher's final
   assignment), refit while the matches change (at most :data:`MAX_ROUNDS` rounds).

It then verifies, and returns None (the caller runs the search) unless all of these hold:

- at least ``min_matches`` matched detections: more than the search's own test for a prior
  that explains the band asks (:meth:`GlintMatcher.match` keeps the prior's identification
  where it matches the search's ``min_matches`` (3) *or* half the detections), so clutter
  beside the glints does not decline a band the search takes from the prior with the same
  lights (issue 31, sixth pass: until then the cheap path also asked for half the
  detections, and declined 183 of 229 searched bands of a designed-lighting render);
- the fitted rotation lies within ``max_shift_deg`` of the prior: the eye has not turned by
  anything near the ~2° between neighbouring glints' identities, so the prior's basin is the
  one the search would start from;
- every rival the search refines beside it, the chain shifted by ±1 and ±2 lights along its
  arcs, scores worse by at least ``rival_margin`` (the search's score: residuals, unmatched
  detections, predicted glints missing well inside the band, distance from the prior), each
  rival refitted to first order about the fitted pose (its Jacobian by central differences of
  one more projection per angle).

The search would call the band "ambiguous" below its ``min_margin`` (6); the rival margin
asks for twice that, so a band near the search's line falls back and gets the search's answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

import estimator.matching.follow_kernel as follow_kernel
import estimator.matching.kernels as kernels

from ..cornea import SmallFit, fit_small
from .matcher import GlintMatcher
from .model import _Hypothesis
from .params import OK, GlintMatch

#: Most assign-fit rounds before the path gives up (the assignment settles after 1-2).
MAX_ROUNDS = 3


@dataclass(frozen=True, slots=True)
class FollowParams:
    """Settings of :class:`BandFollower`.

    Attributes
    ----------
    min_matches : int
        Fewest matched detections (the tracker's :data:`estimator.tracker.MIN_GLINTS`).
    max_shift_deg : float
        Largest distance (largest axis) of the fitted rotation from the prior: half the ~2°
        between neighbouring glints' identities along an arc in ``paper_sim``; the eye turns
        0.6° in the 1 ms between bands at 600°/s.
    rival_margin : float
        Score by which every shifted chain must lose: twice the search's ``min_margin``.
    """

    min_matches: int = 5
    max_shift_deg: float = 1.0
    rival_margin: float = 12.0


@dataclass(frozen=True, slots=True)
class Followed:
    """A band the cheap path identified: the match (as :meth:`GlintMatcher.match` gives it)
    and the orbit fit of its matched glints (its JᵀJ sizes the sample's covariance)."""

    match: GlintMatch
    fit: SmallFit


class BandFollower:
    """The cheap path (module docstring) on a :class:`GlintMatcher`'s setup, calibrated eye,
    lights and parameters ("orbit" model only)."""

    def __init__(self, matcher: GlintMatcher, params: FollowParams = FollowParams()):
        if matcher.params.model != "orbit":
            raise ValueError("the cheap path needs the matcher's 'orbit' model")
        self.matcher, self.params = matcher, params
        #: The camera as the compiled kernels take it (the matcher's).
        self.arrays = matcher.arrays
        # Each light's neighbour -2, -1, +1, +2 places along its own arc (-1 off the arc).
        self._shifted = matcher.shift_table()
        #: Whether follow runs as one compiled call (:mod:`estimator.matching.follow_kernel`;
        #: not while the matching kernels are switched off, :data:`kernels.ENABLED`).
        self.compiled = follow_kernel.ENABLED
        p = matcher.params
        self._fixed = (
            *follow_kernel.orbit_args(matcher), self._shifted,
            float(p.prior_gate_px), float(p.gate_px), float(p.band_margin_px),
            float(p.noise_px), float(p.unmatched_cost), float(p.missing_cost),
            math.radians(p.prior_sigma_deg), int(params.min_matches),
            math.radians(params.max_shift_deg), float(params.rival_margin),
            int(p.min_matches), float(p.min_margin), MAX_ROUNDS, follow_kernel.MAX_NODES)

    def predict(self, angles_rad):
        """Glints (n, 2) and visibility (n,) of every light at one rotation (2,)."""
        return self.matcher._predict_one(float(angles_rad[0]), float(angles_rad[1]))

    def follow(self, glints_px, rows, prior_angles_rad, *, prior_term: bool = True
               ) -> Followed | None:
        """The band's identities from the prior ``prior_angles_rad`` (2,), or None where the
        checks fail (the caller runs :meth:`GlintMatcher.match`).

        ``prior_term``: the scores count the distance from the prior, as the search does with
        a prior (the previous band's sample). Without it (an older sample, after which the
        tracker runs the cold search, whose scores have no prior) the rivals must lose by
        their glints alone."""
        m, p, fp = self.matcher, self.matcher.params, self.params
        g, lo, hi = m._inputs(glints_px, rows)
        prior = np.asarray(prior_angles_rad, dtype=np.float64).reshape(2)
        if g.shape[0] < fp.min_matches:
            return None
        if self.compiled and kernels.ENABLED:
            got = self._follow_compiled(g, lo, hi, prior, 1.0 if prior_term else 0.0)
            if got is not follow_kernel.FALLBACK:
                return got
        pred, cand, _ = self._candidates(prior, lo, hi)
        assign, _ = m._assign(g, pred, cand, p.prior_gate_px)
        x, fit, prev = prior, None, None
        # Without Numba each round's projection at x carries the rival check's Jacobian
        # (glints_floats gives the same glints and visibility with or without it): the band
        # does not know which round is its last until the assignment repeats, and the rival
        # check then projects x no more (one round in each of the 301 follow calls that
        # reached a fit on the benchmark's 60 synthetic frames: no Jacobian computed in vain).
        rows_at_x = None
        for _ in range(MAX_ROUNDS):
            used = assign >= 0
            if used.sum() < fp.min_matches:
                return None
            fit = fit_small(m.problem, g[used], m.lights_world_m[assign[used]], x,
                            model="orbit", arrays=self.arrays)
            if not fit.ok:
                return None
            x, prev = fit.x, assign
            if m._floats is not None:
                rows_at_x = m._predict_one_rows(float(x[0]), float(x[1]))
                pred, cand, inside = self._candidates(x, lo, hi, rows_at_x[:2])
            else:
                pred, cand, inside = self._candidates(x, lo, hi)
            assign, dist = m._final_assign(g, pred, cand)
            if np.array_equal(assign, prev):
                break
        else:
            return None
        matched = assign >= 0
        n = int(matched.sum())
        if n < fp.min_matches:  # the search's test (n >= its min_matches or half) holds then
            return None
        if n < 0.5 * g.shape[0] and follow_kernel.crowded(
                g, assign, pred, cand, follow_kernel.CROWD_GATES * p.gate_px):
            return None
        if np.abs(x - prior).max() > math.radians(fp.max_shift_deg):
            return None
        weight = 1.0 if prior_term else 0.0
        score = self._score(g, assign, dist, inside, x, prior, weight)
        margin = self._rival_margin(g, assign, x, prior, lo, hi, score, weight, rows_at_x)
        if not margin >= fp.rival_margin:
            return None
        h = _Hypothesis(x.copy(), assign, dist, pred, cand, score, fit.iterations, True)
        match = m._result(g, h, margin, p.min_matches)
        return Followed(match, fit) if match.ok else None

    def _follow_compiled(self, g, lo, hi, prior, weight):
        """follow's answer by :func:`follow_kernel.follow_band`, or FALLBACK where an
        assignment needs the optimal solver (the Python form below then runs)."""
        k = g.shape[0]
        assign, dist, conf = np.empty(k, dtype=np.int64), np.empty(k), np.empty(k)
        x, center, JtJ = np.empty(2), np.empty(3), np.zeros((2, 2))
        outcome, score, margin, rms, cost, m, iters = follow_kernel.follow_band(
            np.ascontiguousarray(g), lo, hi, prior, weight, *self._fixed, assign, dist, conf, x,
            center, JtJ)
        if outcome != follow_kernel.ACCEPTED:
            return None if outcome == follow_kernel.DECLINED else follow_kernel.FALLBACK
        fit = SmallFit(x.copy(), math.sqrt(max(cost, 0.0) / m), JtJ, int(iters), True)
        match = GlintMatch(assign, conf, dist, center, x, rms, score, margin, int(iters), OK)
        return Followed(match, fit)

    def _candidates(self, angles, lo, hi, predicted=None):
        """Predicted glints (n, 2), candidates and glints well inside the band (n,); from
        ``predicted`` (glints (n, 2), visibility (n,) at ``angles``) where given."""
        pred, vis = self.predict(angles) if predicted is None else predicted
        v = pred[:, 1]
        b = self.matcher.params.band_margin_px
        return pred, vis & (v >= lo - b) & (v <= hi + b), vis & (v >= lo + b) & (v <= hi - b)

    def _score(self, g, assign, dist, inside, x, prior, weight) -> float:
        """The search's score of an assignment at rotation x (its ``_refine`` score plus the
        prior's squared distance in ``prior_sigma_deg``)."""
        p = self.matcher.params
        matched = assign >= 0
        detected = np.zeros(inside.shape[0], dtype=bool)
        detected[assign[matched]] = True
        d = (x - prior) / math.radians(p.prior_sigma_deg)
        return float(np.sum(dist[matched] ** 2) / p.noise_px ** 2
                     + (~matched).sum() * p.unmatched_cost
                     + p.missing_cost * (inside & ~detected).sum() + weight * (d @ d))

    def _rival_margin(self, g, assign, x, prior, lo, hi, score, weight, rows=None) -> float:
        """Smallest score lead over the chains shifted by ±1, ±2 lights, each refitted to
        first order about x (linearised glints pred + J δ, the four rivals at once); inf
        without a rival, -inf where the linearisation cannot place one (the search decides).
        ``rows``: :meth:`GlintMatcher._predict_one_rows` at x where the caller has it."""
        m, p = self.matcher, self.matcher.params
        if rows is None:
            rows = m._predict_one_rows(float(x[0]), float(x[1]))
        pred, vis, J = rows  # J (n, 2, 2) px / rad
        if kernels.ENABLED:
            return kernels.rival_margin(g, assign, pred, J, vis, self._shifted, x, prior, lo, hi,
                                        p.gate_px, p.band_margin_px, p.noise_px,
                                        p.unmatched_cost, p.missing_cost,
                                        math.radians(p.prior_sigma_deg), weight, score)
        finite = vis & np.isfinite(J).all(axis=(1, 2)) & np.isfinite(pred).all(axis=1)
        A = np.where(assign >= 0, self._shifted[np.maximum(assign, 0)].T, -1)  # (4, k) lights
        use = A >= 0
        use[use] = finite[A[use]]
        use &= use.any(axis=1, keepdims=True)
        rivals = np.flatnonzero(use.any(axis=1))
        if rivals.size == 0:
            return math.inf
        A, use = A[rivals], use[rivals]
        lights = np.where(use, A, 0)
        Jr = np.where(use[..., None, None], J[lights], 0.0)  # (r, k, 2, 2)
        res = np.where(use[..., None], g[None] - pred[lights], 0.0)  # (r, k, 2)
        AtA = np.einsum("rkia,rkib->rab", Jr, Jr)
        Atr = np.einsum("rkia,rki->ra", Jr, res)
        det = AtA[:, 0, 0] * AtA[:, 1, 1] - AtA[:, 0, 1] * AtA[:, 1, 0]
        if not (np.abs(det) > 1e-12 * AtA[:, 0, 0] * AtA[:, 1, 1]).all():
            return -math.inf
        delta = np.stack([AtA[:, 1, 1] * Atr[:, 0] - AtA[:, 0, 1] * Atr[:, 1],
                          AtA[:, 0, 0] * Atr[:, 1] - AtA[:, 1, 0] * Atr[:, 0]], -1) / det[:, None]
        at = pred[None] + np.einsum("nia,ra->rni", J, delta)  # (r, n, 2) glints at each rival
        d2 = ((g[None] - np.take_along_axis(at, lights[..., None], axis=1)) ** 2).sum(-1)
        keep = use & (d2 <= p.gate_px ** 2)
        v = at[..., 1]
        b = p.band_margin_px
        inside = finite[None] & (v >= lo + b) & (v <= hi - b)
        detected = np.zeros(inside.shape, dtype=bool)
        r_idx = np.broadcast_to(np.arange(rivals.size)[:, None], keep.shape)
        detected[r_idx[keep], lights[keep]] = True
        dprior = (x[None] + delta - prior) / math.radians(p.prior_sigma_deg)
        rival = (np.where(keep, d2, 0.0).sum(axis=1) / p.noise_px ** 2
                 + (g.shape[0] - keep.sum(axis=1)) * p.unmatched_cost
                 + p.missing_cost * (inside & ~detected).sum(axis=1)
                 + weight * (dprior ** 2).sum(axis=1))
        return float(rival.min() - score)
