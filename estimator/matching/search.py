"""The matcher's hypothesis search: coarse hypotheses over a grid of eye rotations, gated
assignments of glints to predicted glints, small fits that refine a hypothesis, and the final
assignment with the lights' order enforced (steps 2-5 of :mod:`estimator.matching.matcher`).

:class:`HypothesisSearch` holds these steps apart from the matcher's public face; it uses the
matcher's setup, parameters, calibrated problem and prediction grid.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.optimize import linear_sum_assignment

import estimator.matching.follow_kernel as follow_kernel
import estimator.matching.kernels as kernels
import estimator.matching.refine_kernel as refine_kernel

from ..cornea import fit_cornea, fit_replica, fit_small
from .model import _Hypothesis

#: The shifts along the arcs the search tries (lights), and their column in the shift table.
_STEPS = {-2: 0, -1: 1, 1: 2, 2: 3}

#: Batches of at most this many poses are predicted one pose at a time by the compiled
#: projection (where Numba is): a search's hypotheses (2-12), not the coarse grid.
_FEW_POSES = 32


class HypothesisSearch:
    """Steps of :class:`estimator.matching.GlintMatcher`'s search (a base class: it reads
    ``self.params``, ``self.problem``, ``self.lights_world_m``, the prediction grid and
    ``self._predict_x`` of the matcher)."""

    def _shift(self, assign, step: int) -> np.ndarray:
        """Every matched light moved ``step`` places along its own arc (-1 where that leaves
        the arc); steps of one and two lights by a table of every light's (built once)."""
        col = _STEPS.get(step)
        if col is not None:
            return np.where(assign >= 0, self.shift_table()[assign, col], -1)
        return self._shift_any(assign, step)

    def shift_table(self) -> np.ndarray:
        """(n, 4) int64: each light moved -2, -1, +1, +2 places along its own arc (-1 off the
        arc), built once."""
        table = getattr(self, "_shift_table", None)
        if table is None:
            every = np.arange(self.lights_world_m.shape[0])
            table = np.ascontiguousarray(
                np.stack([self._shift_any(every, s) for s in _STEPS], axis=1), dtype=np.int64)
            self._shift_table = table
        return table

    def _shift_any(self, assign, step: int) -> np.ndarray:
        """:meth:`_shift` of any step, from the arcs."""
        out = np.full_like(assign, -1)
        m = assign >= 0
        moved = assign[m] + step
        n = self.lights_world_m.shape[0]
        inside = (moved >= 0) & (moved < n)
        same = np.zeros_like(inside)
        same[inside] = self.group[moved[inside]] == self.group[assign[m][inside]]
        out[np.flatnonzero(m)[same]] = moved[same]
        return out

    def band_support(self, rows, center_rad, reach_rad: float, glints_px) -> int:
        """Most lights a search of the band's detections ``glints_px`` (k, 2) on ``rows``
        (first, last) can match at an eye rotation within ``reach_rad`` of ``center_rad``
        (Fick yaw, pitch): an upper bound.

        The grid's nodes within the reach widened by a cell's half diagonal stand for every
        rotation of it, and :attr:`grid_drift_px`, the furthest a glint moves between
        neighbouring nodes, for the glints' motion from a node to a rotation within half a step
        of it in each angle. Per node: the fewer of its candidates (visible glints on the rows
        widened by the band margin and the drift) and of the detections within ``gate_px``
        plus the drift of one of them (a match lies within ``gate_px`` of its light's glint);
        the most over the nodes."""
        drift = self.grid_drift_px
        m = self.params.band_margin_px + drift
        lo, hi = float(rows[0]) - m, float(rows[1]) + m
        reach = float(reach_rad) + math.radians(self.params.grid_step_deg) / math.sqrt(2.0)
        center = np.asarray(center_rad, dtype=np.float64).reshape(2)
        g = np.ascontiguousarray(glints_px, dtype=np.float64).reshape(-1, 2)
        radius2 = (self.params.gate_px + drift) ** 2
        if kernels.ENABLED:
            return int(kernels.band_support(self.grid_glints_px, self.grid_visible,
                                            self.grid_angles_rad, center, reach, lo, hi, g,
                                            radius2))
        near = np.hypot(*(self.grid_angles_rad - center).T) <= reach
        if not near.any() or g.shape[0] == 0:
            return 0
        pred = self.grid_glints_px[near]
        cand = self.grid_visible[near] & (pred[..., 1] >= lo) & (pred[..., 1] <= hi)
        # Distances of the candidates alone, (pairs, k), node after node: a band of clutter
        # has hundreds of detections, and (nodes, n, k) of every light took ~0.3 s a band.
        node, light = np.nonzero(cand)
        if node.size == 0:
            return 0
        d2 = ((pred[node, light][:, None, :] - g[None]) ** 2).sum(-1)
        first = np.flatnonzero(np.r_[True, node[1:] != node[:-1]])
        found = np.logical_or.reduceat(d2 <= radius2, first, axis=0).sum(axis=1)
        return int(np.minimum(cand.sum(axis=1)[node[first]], found).max())

    def _near(self, angles, window):
        """(nodes,) bool: the grid nodes within ``window`` rad of ``angles`` (2,) on both axes,
        ``np.abs(grid_angles_rad - angles).max(axis=1) <= window`` by axis (the same floats
        compared: the grid is the yaws' and pitches' outer product; ~10 us where the
        whole grid's took ~0.5 ms of a searched band's ~2 ms, issue 31 sixth pass)."""
        yaw, pitch = self._grid_axes
        return ((np.abs(yaw - angles[0]) <= window)[:, None]
                & (np.abs(pitch - angles[1]) <= window)[None, :]).ravel()

    def _grid_drift(self) -> float:
        """The furthest any light's glint moves between neighbouring grid nodes (px), both
        visible: :attr:`grid_drift_px`, set by the matcher once its grid is predicted."""
        G = self.grid_glints_px.reshape(self._grid_shape + self.grid_glints_px.shape[1:])
        V = self.grid_visible.reshape(self._grid_shape + self.grid_visible.shape[1:])
        drift = 0.0
        for a, b, both in ((G[1:], G[:-1], V[1:] & V[:-1]),
                           (G[:, 1:], G[:, :-1], V[:, 1:] & V[:, :-1])):
            d = np.linalg.norm(a - b, axis=-1)[both]
            drift = max(drift, float(d.max()) if d.size else 0.0)
        return drift

    def _coarse(self, g, lo, hi, nodes, count) -> list[np.ndarray]:
        """Angles of the ``count`` best local minima of the score over the grid (or over the
        grid nodes where ``nodes`` is True)."""
        p = self.params
        pred, vis = self.grid_glints_px, self.grid_visible
        if kernels.ENABLED:
            score = np.empty(vis.shape[0])
            kernels.coarse_scores(pred, vis, np.ones(vis.shape[0], dtype=bool) if nodes is None
                                  else nodes, g, lo, hi, p.band_margin_px, p.coarse_gate_px ** 2,
                                  p.unmatched_cost, p.missing_cost, score)
            return self._minima(g, score, count)
        v = pred[..., 1]
        cand = vis & (v >= lo - p.band_margin_px) & (v <= hi + p.band_margin_px)
        if nodes is not None:
            cand &= nodes[:, None]
        n_nodes, n_lights = cand.shape
        pair = np.flatnonzero(cand)  # (node, light) pairs, node-major
        if pair.size == 0:
            return []
        node, light = pair // n_lights, pair % n_lights
        gate2 = p.coarse_gate_px ** 2
        # Squared distance of every detection to every candidate glint of every node.
        du = pred[node, light, 0][:, None] - g[None, :, 0]
        dv = pred[node, light, 1][:, None] - g[None, :, 1]
        d2 = du * du + dv * dv  # (pairs, k)
        first = np.flatnonzero(np.concatenate([[True], node[1:] != node[:-1]]))
        used = node[first]
        # A detection is scored at its node's nearest candidate; a candidate well inside the
        # band is missing when no detection lies within the gate. The grid is up to 2 px off,
        # so distances are scored against the coarse gate: a detection at the coarse gate
        # costs as much as an unmatched one.
        near = np.minimum(np.minimum.reduceat(d2, first, axis=0), gate2)  # (nodes used, k)
        vc = v[node, light]
        inside = (vc >= lo + p.band_margin_px) & (vc <= hi - p.band_margin_px)
        missing = np.add.reduceat((inside & (d2.min(axis=1) > gate2)).astype(np.float64), first)
        unmatched_cost = p.unmatched_cost
        score = np.full(n_nodes, np.inf)
        score[used] = near.sum(axis=1) / gate2 * unmatched_cost + p.missing_cost * missing
        return self._minima(g, score, count)

    def _minima(self, g, score, count) -> list[np.ndarray]:
        """Angles of the ``count`` best local minima of the grid's scores (N,)."""
        unmatched_cost = self.params.unmatched_cost
        score = score.reshape(self._grid_shape)
        # Local minima over 3x3 neighbourhoods, best first; a node no better than leaving
        # every detection unmatched is no hypothesis.
        # The eight neighbours' minimum by running minima in place (the same floats as the
        # minimum of their stack, without its (8, N) temporary; issue 31 seventh pass).
        h, w = score.shape
        padded = np.full((h + 2, w + 2), np.inf)
        padded[1:h + 1, 1:w + 1] = score
        nb = padded[0:h, 0:w].copy()
        for dy, dx in ((-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
            np.minimum(nb, padded[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx], out=nb)
        flat = score.ravel()
        minima = np.flatnonzero((flat <= nb.ravel()) & (flat < g.shape[0] * unmatched_cost))
        order = minima[np.argsort(flat[minima], kind="stable")][:count]
        return [self.grid_angles_rad[i] for i in order]

    def _assign(self, g, pred, cand, gate):
        """Gated optimal assignment: (k,) light per detection (-1 none) and its distance."""
        k = g.shape[0]
        lights = np.flatnonzero(cand)
        assign = np.full(k, -1, dtype=np.int64)
        dist = np.full(k, np.nan)
        if lights.size == 0:
            return assign, dist
        gate2 = gate * gate
        # Where no two detections share their nearest candidate inside the gate, that choice
        # is the optimal assignment (each detection pays its own least cost, a lower bound of
        # every assignment; the unmatched option costs the gate, no less than an inside one):
        # the common case of a band, answered without the solver.
        if kernels.ENABLED:
            if kernels.nearest_assign(g, pred, lights, gate2, assign, dist):
                return assign, dist
            assign[:], dist[:] = -1, np.nan
            d2 = ((g[:, None, :] - pred[None, lights, :]) ** 2).sum(-1)
        else:
            d2 = ((g[:, None, :] - pred[None, lights, :]) ** 2).sum(-1)
            near = np.where(d2 <= gate2, d2, np.inf)
            best = near.argmin(axis=1)
            best_d2 = near[np.arange(k), best]
            has = best_d2 < np.inf
            if not has.any() or np.bincount(best[has]).max() <= 1:
                assign[has] = lights[best[has]]
                dist[has] = np.sqrt(best_d2[has])
                return assign, dist
        big = 1e6 * gate2
        # Columns: the candidates, then one "unmatched" option per detection at the gate's cost.
        cost = np.full((k, lights.size + k), big)
        cost[:, : lights.size] = np.where(d2 <= gate2, d2, big)
        cost[np.arange(k), lights.size + np.arange(k)] = gate2
        r, c = linear_sum_assignment(cost)
        real = c < lights.size
        r, c = r[real], c[real]
        real = d2[r, c] <= gate2
        assign[r[real]] = lights[c[real]]
        dist[r[real]] = np.sqrt(d2[r[real], c[real]])
        return assign, dist

    def _fit(self, g, assigns, X, fit_prior=None):
        """Refit every hypothesis from X (H, p) with its matched detections, in one batched
        call, with the Gaussian prior ``fit_prior`` (mean, information) where given; returns
        (X, ok (H,))."""
        if fit_prior is not None and kernels.ENABLED and self.params.model == "orbit":
            return self._fit_each(g, assigns, X, fit_prior)
        if fit_prior is None and kernels.ENABLED:
            return self._fit_replica(g, assigns, X)
        # Only the lights matched in some hypothesis enter the fit (a fraction of the rig:
        # the fit's cost is the projection of every light it carries).
        used = np.unique(np.concatenate([a[a >= 0] for a in assigns]))
        slot = np.full(self.lights_world_m.shape[0], -1)
        slot[used] = np.arange(used.size)
        glints = np.full((len(assigns), used.size, 2), np.nan)
        for h, assign in enumerate(assigns):
            m = assign >= 0
            glints[h, slot[assign[m]]] = g[m]
        problem = replace(self.problem, lights_world_m=self.lights_world_m[used])
        mean, info = (None, None) if fit_prior is None else fit_prior
        fit = fit_cornea(problem, glints, None, X, model=self.params.model, prior_mean=mean,
                         prior_information=info)
        x_new = fit.angles_rad if self.params.model == "orbit" else fit.center_m
        ok = fit.ok & np.isfinite(x_new).all(axis=1)
        return np.where(ok[:, None], x_new, X), ok

    def _fit_replica(self, g, assigns, X):
        """:meth:`_fit` without a prior, one hypothesis at a time by the batched fit's own
        rules compiled (:func:`estimator.cornea.fit_replica`: the same convergence, and so
        the same failures, at a few µs per iteration instead of ~390)."""
        p = 2 if self.params.model == "orbit" else 3
        X_new = np.array(X, dtype=np.float64)
        ok = np.zeros(len(assigns), dtype=bool)
        for h, assign in enumerate(assigns):
            m = assign >= 0
            if 2 * m.sum() < p:
                continue
            x, ok[h], _ = fit_replica(self.problem, g[m], self.lights_world_m[assign[m]], X_new[h],
                                      model=self.params.model, arrays=self.arrays)
            if ok[h]:
                X_new[h] = x
        return X_new, ok

    def _fit_each(self, g, assigns, X, fit_prior):
        """:meth:`_fit` with a prior, one hypothesis at a time by the compiled small fit
        (:func:`estimator.cornea.fit_small`: the batched fit's cost and minimum without its
        numpy overhead; a prior-assisted band's refits drop from ~6 to ~2 ms). Without a prior
        the batched fit stays: on poor hypotheses (few glints far from the truth) the two
        solvers' stopping rules part, and installs with and without Numba would name
        different failures; the prior's term makes every refit well posed."""
        mean, info = fit_prior
        X_new = np.array(X, dtype=np.float64)
        ok = np.zeros(len(assigns), dtype=bool)
        for h, assign in enumerate(assigns):
            m = assign >= 0
            if not m.any():
                continue
            fit = fit_small(self.problem, g[m], self.lights_world_m[assign[m]], X_new[h],
                            model="orbit", arrays=self.arrays, prior_mean=mean,
                            prior_information=info)
            if fit.ok:
                X_new[h], ok[h] = fit.x, True
        return X_new, ok

    def _candidates(self, X, lo, hi):
        """Predicted glints (H, n, 2), candidates and glints well inside the band (H, n)."""
        pred, vis = self._predict_x(X)
        v = pred[..., 1]
        m = self.params.band_margin_px
        return pred, vis & (v >= lo - m) & (v <= hi + m), vis & (v >= lo + m) & (v <= hi - m)

    def _refine(self, g, lo, hi, X, first_gate, first_assign=None, fit_prior=None
                ) -> list[_Hypothesis]:
        """Match -> refit -> re-predict -> re-match every start in X (H, p) until its
        assignment is stable; hypotheses that reach the same assignment are merged.
        ``first_assign`` (H lists of (k,) lights) replaces the first round's matching;
        ``fit_prior`` (mean, information) enters every refit."""
        p = self.params
        X = np.array(X, dtype=np.float64)
        if (fit_prior is not None and p.model == "orbit" and kernels.ENABLED
                and refine_kernel.ENABLED):
            got = self._refine_compiled(g, lo, hi, X, first_gate, first_assign, fit_prior)
            if got is not None:
                return got
        H = X.shape[0]
        gate = np.full(H, first_gate)
        prev: list = [None] * H
        fit_ok = np.zeros(H, dtype=bool)
        iters = np.zeros(H, dtype=int)
        active = np.ones(H, dtype=bool)
        alive = np.ones(H, dtype=bool)
        # Each hypothesis' last prediction one pose at a time (pred, cand) while its pose
        # stands: the final assignment's, the same floats (issue 31 seventh pass).
        last: list = [None] * H
        for it in range(p.max_iter):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            given = it == 0 and first_assign is not None
            if not given or any(first_assign[h] is None for h in idx):
                pred, cand, _ = self._candidates(X[idx], lo, hi)
                if kernels.ENABLED and idx.size <= _FEW_POSES:
                    for a, h in enumerate(idx):
                        last[h] = (pred[a], cand[a])
            to_fit, assigns = [], []
            seen = {}
            for a, h in enumerate(idx):
                if given and first_assign[h] is not None:
                    assign = first_assign[h]
                else:
                    assign, _ = self._assign(g, pred[a], cand[a], gate[h])
                key = assign.tobytes()
                if not (assign >= 0).any() or (key in seen and gate[h] == gate[seen[key]]):
                    active[h] = alive[h] = False  # nothing matched, or a duplicate
                    continue
                seen[key] = h
                if prev[h] is not None and np.array_equal(assign, prev[h]) and gate[h] == p.gate_px:
                    active[h] = False
                    continue
                prev[h] = assign
                to_fit.append(h)
                assigns.append(assign)
            if to_fit:
                X[to_fit], ok = self._fit(g, assigns, X[to_fit], fit_prior)
                for h in to_fit:
                    last[h] = None
                fit_ok[to_fit] = ok
                iters[to_fit] += 1
                gate[np.array(to_fit)[ok]] = p.gate_px
        keep = np.flatnonzero(alive)
        if keep.size == 0:
            return []
        # Final assignment at the final gate, the arc order enforced, and one more refit where
        # it changed the matches.
        X = X[keep]
        pred, cand, inside = self._candidates_kept(X, [last[h] for h in keep], lo, hi)
        final = [self._final_assign(g, pred[a], cand[a]) for a in range(keep.size)]
        changed = [a for a in range(keep.size) if (final[a][0] >= 0).any() and (
            prev[keep[a]] is None or not np.array_equal(final[a][0], prev[keep[a]]))]
        ok = fit_ok[keep].copy()
        if changed:
            # Hypotheses whose matches stand keep their pose, predictions and matches.
            X[changed], ok_c = self._fit(g, [final[a][0] for a in changed], X[changed], fit_prior)
            ok[changed] = ok_c
            pred[changed], cand[changed], inside[changed] = self._candidates(X[changed], lo, hi)
            for a in changed:
                final[a] = self._final_assign(g, pred[a], cand[a])
        sigma2 = p.noise_px ** 2
        out = []
        for a in range(keep.size):
            assign, dist = final[a]
            matched = assign >= 0
            detected = np.zeros(self.lights_world_m.shape[0], dtype=bool)
            detected[assign[matched]] = True
            score = (np.sum(dist[matched] ** 2) / sigma2
                     + (~matched).sum() * p.unmatched_cost
                     + p.missing_cost * (inside[a] & ~detected).sum())
            out.append(_Hypothesis(X[a].copy(), assign, dist, pred[a], cand[a], float(score),
                                   int(iters[keep[a]]), bool(ok[a])))
        return out

    def _candidates_kept(self, X, last, lo, hi):
        """:meth:`_candidates` of X (H, p) reusing ``last`` (H,): each pose's (pred, cand)
        from one pose at a time, or None (predicted now); the same floats where the batch is
        predicted one pose at a time too (the glints well inside the band are candidates for a
        margin >= 0)."""
        todo = [a for a, c in enumerate(last) if c is None]
        if (not (kernels.ENABLED and X.shape[0] <= _FEW_POSES) or len(todo) == X.shape[0]
                or self.params.band_margin_px < 0):
            return self._candidates(X, lo, hi)
        n = self.lights_world_m.shape[0]
        pred, cand = np.empty((X.shape[0], n, 2)), np.empty((X.shape[0], n), dtype=bool)
        if todo:
            pred[todo], cand[todo], _ = self._candidates(X[todo], lo, hi)
        for a, c in enumerate(last):
            if c is not None:
                pred[a], cand[a] = c
        v, m = pred[..., 1], self.params.band_margin_px
        return pred, cand, cand & (v >= lo + m) & (v <= hi - m)

    def _refine_compiled(self, g, lo, hi, X, first_gate, first_assign, fit_prior):
        """:meth:`_refine` with a prior on the orbit by :func:`refine_kernel.refine_prior`, or
        None where an assignment needs the optimal solver (the Python form then runs)."""
        if getattr(self, "_refine_args", None) is None:
            p = self.params
            self._refine_args = (
                *follow_kernel.orbit_args(self), float(p.gate_px),
                float(p.band_margin_px), float(p.noise_px), float(p.unmatched_cost),
                float(p.missing_cost), int(p.max_iter), refine_kernel.MAX_NODES)
        H, k, n = X.shape[0], g.shape[0], self.lights_world_m.shape[0]
        first = np.full((H, k), -1, dtype=np.int64)
        has_first = np.zeros(H, dtype=np.bool_)
        if first_assign is not None:
            for h, a in enumerate(first_assign):
                if a is not None:
                    first[h], has_first[h] = a, True
        mean, info = fit_prior
        X_out, dist = np.empty((H, 2)), np.empty((H, k))
        assign = np.empty((H, k), dtype=np.int64)
        pred, cand = np.empty((H, n, 2)), np.empty((H, n), dtype=np.bool_)
        score, iters = np.empty(H), np.empty(H, dtype=np.int64)
        ok, alive = np.empty(H, dtype=np.bool_), np.empty(H, dtype=np.bool_)
        outcome = refine_kernel.refine_prior(
            np.ascontiguousarray(g, dtype=np.float64), lo, hi, X, first, has_first,
            float(first_gate), *self._refine_args, np.asarray(mean, dtype=np.float64),
            np.ascontiguousarray(info, dtype=np.float64), X_out, assign, dist, pred, cand,
            score, iters, ok, alive)
        if outcome != refine_kernel.REFINED:
            return None
        return [_Hypothesis(X_out[h].copy(), assign[h], dist[h], pred[h], cand[h],
                            float(score[h]), int(iters[h]), bool(ok[h]))
                for h in np.flatnonzero(alive)]

    def _final_assign(self, g, pred, cand):
        """Assignment at the final gate with the arc order enforced, and its distances (NaN
        where unmatched)."""
        assign, dist = self._assign(g, pred, cand, self.params.gate_px)
        assign = self._enforce_order(g, pred, assign)
        return assign, np.where(assign >= 0, dist, np.nan)

    def _enforce_order(self, g, pred, assign):
        """Drop matches that break the lights' order along their arc (module docstring, 3)."""
        assign = assign.copy()
        if kernels.ENABLED:
            kernels.enforce_order(g, pred, assign, self.group)
            return assign
        for _ in range(assign.size):
            det = np.flatnonzero(assign >= 0)
            if det.size < 2:
                break
            lights = assign[det]
            order = np.lexsort((lights, self.group[lights]))
            det, lights = det[order], lights[order]
            same = self.group[lights[1:]] == self.group[lights[:-1]]
            dp = pred[lights[1:]] - pred[lights[:-1]]
            dq = g[det[1:]] - g[det[:-1]]
            bad = np.flatnonzero(same & ((dp * dq).sum(axis=1) <= 0))
            if bad.size == 0:
                break
            a, b = det[bad[0]], det[bad[0] + 1]
            ra = np.linalg.norm(g[a] - pred[assign[a]])
            rb = np.linalg.norm(g[b] - pred[assign[b]])
            assign[a if ra >= rb else b] = -1
        return assign
