"""The solvers behind :func:`estimator.cornea.fit_cornea`: the models' residuals and normal
equations, the shared cold-start step, our batched Levenberg-Marquardt and the paper's TRF.

Parameters x (B, p) per model: ``"center"`` the cornea centre (m); ``"center_radius"`` the
centre and the corneal radius (m); ``"orbit"`` the Fick (yaw, pitch) of the centre on its orbit
about the eye centre (rad); ``"full"`` centre, radius, rotation vector (rad) and translation (m)
of the lighting. A Gaussian prior adds (x - μ)ᵀ Λ (x - μ) to the cost (px²).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from scipy.optimize import least_squares

from ..eye import gaze_direction
from ..geometry import glint_jacobians, project_glints
from ..geometry.fit_rows import centre_fit_rows
from ..geometry.jacobians import jacobian_terms, radius_rows

if TYPE_CHECKING:
    from .problem import FitProblem


#: LM stops when the step is below this in every unknown's natural unit (m, rad), or the cost
#: changes by less than ``_FTOL`` relatively: 1e-10 m is 1e-8 of the corneal radius, far below
#: what 0.1 px of glint noise can resolve (~1e-6 m).
_XTOL = 1e-10
_FTOL = 1e-14
#: A Gauss-Newton step below this is taken and ends the fit without another Jacobian. Units:
#: metres of cornea-centre motion (the orbit's angles count r_co per radian; the full model's
#: rotation counts in radians, its radius and translation in metres). The error left after a
#: step s was measured (paper_sim, centre and orbit models, 300 samples) at <= 4e4 /m x s²
#: with exact glints (quadratic convergence) and <= 1.2e-3 s with 0.5 px of glint noise,
#: <= 4e-3 s with 2 px (the residual at the minimum is not zero and Gauss-Newton converges
#: linearly there): <= 4e-10 m after a 1e-7 m step either way, 5e-5 of the ~8e-6 m scatter
#: that 0.5 px of noise leaves in the centre.
_GN_STOP = 1e-7
#: Initial LM damping (relative to the diagonal of JᵀJ). Marquardt's usual 1e-3 shrinks the
#: poorly constrained depth direction of a centre fit enough that a start 30 um away needs a
#: third Jacobian (measured on paper_sim: 63 % of samples); 1e-6 does not.
_LAMBDA0 = 1e-6
#: Models fitted with Marquardt's plain scheme: initial damping 1e-3, no early stop on a small
#: step. Their problems have flat valleys (a shifted cornea looks like a shifted lighting, a
#: larger radius like a nearer centre), along which Gauss-Newton crawls: there a 1e-7 step is
#: no sign of convergence (measured: the 10-unknown per-frame fits stopped up to 217 um from
#: scipy's TRF with the early stop, 0.14 um without).
_CAUTIOUS = ("center_radius", "full")


class Prior(NamedTuple):
    """Gaussian prior of each sample: cost term (x - mean)ᵀ information (x - mean), in px²;
    ``present`` is False where a sample has none (its mean and information are then zero)."""

    mean: np.ndarray  # (B, p)
    information: np.ndarray  # (B, p, p)
    present: np.ndarray  # (B,)

    def take(self, idx) -> "Prior":
        return Prior(self.mean[idx], self.information[idx], self.present[idx])


def unpack(model, problem: FitProblem, x):
    """Cornea centre, radius and lights (B, n, 3) or (n, 3) for parameters x (B, p)."""
    if model == "center":
        return x, problem.cornea_radius_m, problem.lights_world_m
    if model == "center_radius":
        return x[:, :3], x[:, 3], problem.lights_world_m
    if model == "orbit":
        d = gaze_direction(x[:, 0], x[:, 1])
        return problem.eye_center_m + problem.orbit_radius_m * d, problem.cornea_radius_m, problem.lights_world_m
    return x[:, :3], x[:, 3], problem.lights_posed(x[:, 4:7], x[:, 7:10])


def residuals_and_jacobian(model, problem: FitProblem, x, glints, mask):
    """Residuals (B, 2n) and Jacobian (B, 2n, p); masked glints give zero rows."""
    center, radius, lights = unpack(model, problem, x)
    g, _, d_c, d_r, d_l = glint_jacobians(problem.camera, center, radius, lights,
                                          radius_and_lights=model in ("full", "center_radius"))
    res = np.where(mask[..., None], g - glints, 0.0)
    B, n = mask.shape
    if model == "center":
        J = d_c
    elif model == "center_radius":
        J = np.concatenate([d_c, d_r[..., None]], axis=-1)
    elif model == "orbit":
        J = d_c @ orbit_derivative(problem, x)[:, None]
    else:
        # Lights depend on the pose: dL/d(rotvec) by central differences of the rotation
        # (cheap: rotating n points), dL/dt = I.
        h = 1e-7
        dL_dw = np.empty((B, n, 3, 3))
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            dL_dw[..., k] = (problem.lights_posed(x[:, 4:7] + e, x[:, 7:10])
                             - problem.lights_posed(x[:, 4:7] - e, x[:, 7:10])) / (2 * h)
        J = np.concatenate([d_c, d_r[..., None], d_l @ dL_dw, d_l], axis=-1)
    J = np.where(mask[..., None, None], J, 0.0)
    return res.reshape(B, 2 * n), J.reshape(B, 2 * n, -1)


def orbit_derivative(problem: FitProblem, x):
    """(B, 3, 2) derivative of the cornea centre on the orbit with respect to (yaw, pitch)."""
    yaw, pitch = x[:, 0], x[:, 1]
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    return np.stack([np.stack([cp * cy, np.zeros_like(cy), cp * sy], -1),
                     np.stack([-sp * sy, cp, sp * cy], -1)], -1) * problem.orbit_radius_m


def normal_equations(model, problem: FitProblem, x, glints, mask, lights=None, prior: Prior | None = None):
    """Cost Σ r² (B,), JᵀJ (B, p, p) and Jᵀr (B, p) of the masked glint residuals at x, plus the
    prior's terms: all that LM needs, without keeping the (B, 2n, p) Jacobian.

    ``lights`` (B, k, 3), if given, replaces the problem's lights (gathered glints: each
    sample's seen glints first). The centre's rows come from
    :func:`estimator.geometry.fit_rows.centre_fit_rows` in a basis per sample, are summed by one
    matrix product per sample and turned to world axes once (J_world = J_b N); the orbit's
    follow by the chain rule (Dᵀ JᵀJ D)."""
    if model == "full":
        r, J = residuals_and_jacobian(model, problem, x, glints, mask)
        Jt = J.transpose(0, 2, 1)
        cost, JtJ, Jtr = np.einsum("bi,bi->b", r, r), Jt @ J, (Jt @ r[..., None])[..., 0]
    else:
        center, radius, _ = unpack(model, problem, x)
        L = problem.lights_world_m if lights is None else lights
        if model == "center_radius":
            cost, JtJ, Jtr = _general_sums(problem.camera, center, radius, L, glints, mask, True)
        else:
            # One product per sample sums the fast path's rows; the few samples it does not
            # handle take the general path. (A product of an array with itself sums every
            # sample the same way whatever the batch, so blocks give the same answers.)
            G, N, fast = centre_fit_rows(problem.camera, center, radius, L, glints, mask)
            S = G @ np.swapaxes(G, 1, 2)
            fast &= np.isfinite(S).all(axis=(1, 2))
            Nt = np.swapaxes(N, 1, 2)
            cost = S[:, 3, 3].copy()
            JtJ = Nt @ S[:, :3, :3] @ N
            Jtr = (Nt @ S[:, :3, 3:])[..., 0]
            if not fast.all():
                s = ~fast
                cost[s], JtJ[s], Jtr[s] = _general_sums(
                    problem.camera, center[s], radius, L if L.ndim == 2 else L[s], glints[s], mask[s], False)
        if model == "orbit":
            D = orbit_derivative(problem, x)  # (B, 3, 2)
            Dt = np.swapaxes(D, -1, -2)
            JtJ, Jtr = Dt @ JtJ @ D, (Jtr[:, None, :] @ D)[:, 0]
    if prior is not None and prior.present.any():
        d = x - prior.mean
        Ld = (prior.information @ d[..., None])[..., 0]
        cost, JtJ, Jtr = cost + np.einsum("bi,bi->b", d, Ld), JtJ + prior.information, Jtr + Ld
    return cost, JtJ, Jtr


def _general_sums(camera, center, radius, lights, glints, mask, with_radius: bool):
    """Cost, JᵀJ and Jᵀr with respect to the world centre (and the radius) from
    :func:`estimator.geometry.jacobian_terms`: the path for every geometry."""
    T = jacobian_terms(camera, center, radius, lights, with_visibility=False)
    # A masked glint's rows and residual are zero; where() also drops the NaN of a glint
    # behind the camera.
    ru = np.where(mask, T.u - glints[..., 0], 0.0)
    rv = np.where(mask, T.v - glints[..., 1], 0.0)
    cols_u, cols_v = list(T.row_u), list(T.row_v)
    if with_radius:
        du, dv = radius_rows(T)
        cols_u.append(du)
        cols_v.append(dv)
    Ju = [np.where(mask, a, 0.0) for a in cols_u]
    Jv = [np.where(mask, a, 0.0) for a in cols_v]
    q = len(Ju)
    B = mask.shape[0]
    JtJ = np.empty((B, q, q))
    for i in range(q):
        for j in range(i, q):
            JtJ[:, i, j] = JtJ[:, j, i] = np.add.reduce(Ju[i] * Ju[j] + Jv[i] * Jv[j], axis=1)
    Jtr = np.stack([np.add.reduce(Ju[i] * ru + Jv[i] * rv, axis=1) for i in range(q)], -1)
    cost = np.add.reduce(ru * ru + rv * rv, axis=1)
    M = np.eye(q)
    M[:3, :3] = camera.rotation
    return cost, M.T @ JtJ @ M, (Jtr[:, None, :] @ M)[:, 0]


def shared_first_step(model, problem: FitProblem, glints, mask, x_ref, enough):
    """A Gauss-Newton step for every sample from one shared starting point, with the Jacobian
    evaluated once at that point (only the masks differ per sample): a cold start for the
    price of one projection. Samples whose step is not finite keep ``x_ref``."""
    n = mask.shape[1]
    key = (model, x_ref.tobytes())
    if key not in problem._start_cache:
        if len(problem._start_cache) >= 8:
            problem._start_cache.clear()
        r0, J0 = residuals_and_jacobian(model, problem, x_ref[None], np.zeros_like(glints[:1]),
                                        np.ones_like(mask[:1]))
        J0, g0 = J0.reshape(n, 2, -1), r0.reshape(n, 2)
        # A light without a reflection at x_ref (NaN) cannot inform the shared step.
        usable = np.isfinite(g0).all(-1) & np.isfinite(J0).all(axis=(1, 2))
        J0, g0 = np.where(usable[:, None, None], J0, 0.0), np.where(usable[:, None], g0, 0.0)
        # Glints predicted at x_ref (the residual against zeros), J and per-light JᵀJ.
        problem._start_cache[key] = (g0, J0, np.einsum("nki,nkj->nij", J0, J0), usable)
    g0, J0, JtJ_i, usable = problem._start_cache[key]
    mask = mask & usable
    B, p = mask.shape[0], J0.shape[-1]
    # Σ over the seen lights as matrix products (einsum's own loops are several times slower).
    A = (mask.astype(float) @ JtJ_i.reshape(n, p * p)).reshape(B, p, p)
    d = glints - g0  # finite: the glints are prepared, g0 zero where unusable
    if not mask.all():
        d *= mask[..., None]
    rhs = d.reshape(B, 2 * n) @ J0.reshape(2 * n, p)
    x = np.broadcast_to(x_ref, (glints.shape[0], x_ref.size)).copy()
    # Solvable: Hadamard's ratio det(A) / Π diag(A) of the positive semi-definite A (1 for an
    # orthogonal problem, 0 for a singular one) above 1e-12.
    step, det = _solve_small(A, rhs) if p <= 3 else (None, np.linalg.det(A))
    ok = enough & (det > 1e-12 * np.prod(np.einsum("bii->bi", A), axis=1))
    if ok.any():
        x[ok] += step[ok] if p <= 3 else np.linalg.solve(A[ok], rhs[ok][..., None])[..., 0]
    bad = ~np.isfinite(x).all(axis=1)
    x[bad] = x_ref
    return x


def _solve_small(A, b):
    """x = A⁻¹ b and det A for (B, p, p) systems, p = 2 or 3, by cofactors: a few passes over
    B instead of LAPACK's call per matrix. A singular system gives a non-finite x (the
    callers' tests catch it)."""
    p = A.shape[-1]
    a = A.reshape(-1, p * p).T
    if p == 2:
        C = np.stack([a[3], -a[2], -a[1], a[0]])
        det = a[0] * a[3] - a[1] * a[2]
    elif p == 3:
        C = np.empty((9, a.shape[1]))
        C[0] = a[4] * a[8] - a[5] * a[7]
        C[1] = a[5] * a[6] - a[3] * a[8]
        C[2] = a[3] * a[7] - a[4] * a[6]
        C[3] = a[2] * a[7] - a[1] * a[8]
        C[4] = a[0] * a[8] - a[2] * a[6]
        C[5] = a[1] * a[6] - a[0] * a[7]
        C[6] = a[1] * a[5] - a[2] * a[4]
        C[7] = a[2] * a[3] - a[0] * a[5]
        C[8] = a[0] * a[4] - a[1] * a[3]
        det = a[0] * C[0] + a[1] * C[1] + a[2] * C[2]
    else:
        raise ValueError(f"p must be 2 or 3, got {p}")
    # A⁻¹ = Cᵀ / det (C the cofactors): x_i = Σ_j C[j, i] b_j / det.
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        x = np.einsum("jib,bj->bi", C.reshape(p, p, -1), b) / det[:, None]
    return x, det


def gather(glints, mask, lights):
    """Each sample's seen glints first, cut to the largest count k: glints (B, k, 2), mask
    (B, k) and the matching lights (B, k, 3). A band holds a few of the n lights' glints and a
    fit costs per (sample, light) pair, so this makes banded fits n / k times cheaper."""
    k = max(int(mask.sum(axis=1).max()), 1)
    order = np.argsort(~mask, axis=1, kind="stable")[:, :k]
    return (np.take_along_axis(glints, order[..., None], axis=1), np.take_along_axis(mask, order, axis=1),
            lights[order])


#: Samples per block of the batched LM: a block's (block, n) work arrays stay in the CPU cache
#: and are reused between calls (fit_rows._Scratch). Measured on paper_sim, 40 lights,
#: batches of 1,000 (median of 30 interleaved rounds): blocks of 500 run 12 % (centre) and
#: 18 % (orbit) faster than blocks of 200, 400 in between; one block of 1,000 no faster.
_BLOCK = 500


def lm(model, problem: FitProblem, glints, mask, x0, enough, lo, hi, max_iter, prior: Prior | None = None):
    """Batched Levenberg-Marquardt (Marquardt's diagonal scaling), one Jacobian per iteration,
    over blocks of :data:`_BLOCK` samples (the samples are independent).

    Each iteration evaluates the normal equations at the trial points of the samples still
    running; a trial that lowers the cost is kept (and its normal equations are the next
    ones), one that does not raises that sample's damping and keeps the old point. Returns
    x (B, p), rms (B,) of the glint residuals, iterations (B,) and converged (B,)."""
    B = x0.shape[0]
    if B <= 1.5 * _BLOCK:
        return _lm_block(model, problem, glints, mask, x0, enough, lo, hi, max_iter, prior)
    parts = [_lm_block(model, problem, glints[s], mask[s], x0[s], enough[s], lo, hi, max_iter,
                       None if prior is None else prior.take(s))
             for s in (slice(i, i + _BLOCK) for i in range(0, B, _BLOCK))]
    return tuple(np.concatenate(a) for a in zip(*parts))


def _lm_block(model, problem: FitProblem, glints, mask, x0, enough, lo, hi, max_iter, prior: Prior | None):
    """:func:`lm` on one block."""
    B, p = x0.shape
    n_seen = mask.sum(axis=1)
    lights = None
    # Gather the seen glints when most lights are unseen (bands); not for "full", whose lights
    # move with the parameters.
    if model != "full" and 4 * n_seen.max(initial=0) < 3 * mask.shape[1]:
        glints, mask, lights = gather(glints, mask, problem.lights_world_m)

    def evaluate(x, idx):
        if idx.size == B:  # every sample, in order: no copies
            return normal_equations(model, problem, x, glints, mask, lights,
                                    None if prior is None else prior.take(idx))
        return normal_equations(model, problem, x, glints[idx], mask[idx],
                                None if lights is None else lights[idx],
                                None if prior is None else prior.take(idx))

    # The stopping step in each unknown's unit: metres of cornea-centre motion for the orbit's
    # angles (r_co per radian).
    gn_stop = 0.0 if model in _CAUTIOUS else _GN_STOP / problem.orbit_radius_m if model == "orbit" else _GN_STOP
    # Without bounds (the usual case) the active set and the clipping are skipped.
    bounded = bool(np.isfinite(lo).any() or np.isfinite(hi).any())
    x = np.clip(x0, lo, hi) if bounded else x0.copy()
    active = enough.copy()
    iters = np.zeros(B, dtype=int)
    converged = np.zeros(B, dtype=bool)
    cost = np.full(B, np.inf)
    # Nearly Gauss-Newton from the start (the starts are good: the previous sample, or the
    # shared first step); a rejected step raises the damping tenfold.
    lam = np.full(B, 1e-3 if model in _CAUTIOUS else _LAMBDA0)
    JtJ = np.zeros((B, p, p))
    Jtr = np.zeros((B, p))
    eye = np.eye(p)
    on_diag = slice(None, None, p + 1)
    idx = np.flatnonzero(active)
    if idx.size:
        cost[idx], JtJ[idx], Jtr[idx] = evaluate(x[idx], idx)
    for _ in range(max_iter):
        idx = np.flatnonzero(active & ~converged)
        if idx.size == 0:
            break
        H, g = JtJ[idx], Jtr[idx]
        A = H.copy()
        A.reshape(-1, p * p)[:, on_diag] += lam[idx, None] * np.maximum(H.reshape(-1, p * p)[:, on_diag], 1e-30)
        # Active set: an unknown sitting on a bound whose gradient pushes it outward is held
        # there (its row and column of the system become identity), so the others still reach
        # the constrained minimum instead of being dragged by a clipped step.
        xi = x[idx]
        held = ((xi <= lo) & (g > 0)) | ((xi >= hi) & (g < 0)) if bounded else None
        rhs = g
        if bounded and held.any():
            free = ~held
            A = A * free[:, :, None] * free[:, None, :] + held[:, :, None] * eye
            rhs = g * free
        with np.errstate(invalid="ignore", over="ignore"):
            step = -(_solve_small(A, rhs)[0] if p <= 3 else np.linalg.solve(A, rhs[..., None])[..., 0])
        x_new = np.clip(xi + step, lo, hi) if bounded else xi + step
        step = x_new - xi
        # A step the model cannot evaluate (a singular system's non-finite step, a radius
        # driven through zero) counts as a rejected step: more damping, same point.
        usable = np.isfinite(x_new).all(axis=1)
        if model in ("full", "center_radius"):
            usable &= x_new[:, 3] > 0
        if not usable.all():
            bad_idx = idx[~usable]
            lam[bad_idx] *= 10
            iters[bad_idx] += 1
            idx, x_new, step, xi, H, g = idx[usable], x_new[usable], step[usable], xi[usable], H[usable], g[usable]
            if idx.size == 0:
                continue
        # A Gauss-Newton step this small leaves an error far below the noise (see _GN_STOP):
        # take it and stop without paying for another Jacobian.
        tiny = (lam[idx] <= 1e-3) & (np.abs(step) <= gn_stop * np.maximum(1.0, np.abs(xi))).all(axis=1)
        if tiny.any():
            t_idx = idx[tiny]
            s = step[tiny]
            x[t_idx] = x_new[tiny]
            # The cost after the step, to second order in the step (the linearised residual).
            pred = cost[t_idx] + 2 * np.einsum("bi,bi->b", s, g[tiny]) + np.einsum("bi,bij,bj->b", s, H[tiny], s)
            cost[t_idx] = np.maximum(pred, 0.0)
            converged[t_idx] = True
            iters[t_idx] += 1
            keep = ~tiny
            idx, x_new, xi = idx[keep], x_new[keep], xi[keep]
            if idx.size == 0:
                continue
        with np.errstate(invalid="ignore", over="ignore"):
            cost_new, JtJ_new, Jtr_new = evaluate(x_new, idx)
        better = np.isfinite(cost_new) & (cost_new <= cost[idx])
        iters[idx] += 1
        acc = idx[better]
        small = (np.abs(x_new - xi) <= _XTOL * np.maximum(1.0, np.abs(xi))).all(axis=1)
        flat = np.abs(cost[idx] - cost_new) <= _FTOL * np.maximum(cost[idx], 1e-30)
        x[acc], cost[acc], JtJ[acc], Jtr[acc] = x_new[better], cost_new[better], JtJ_new[better], Jtr_new[better]
        lam[acc] = np.maximum(lam[acc] / 10, 1e-12)
        rej = idx[~better]
        lam[rej] *= 10
        # Converged: an accepted step that changed nothing, or a damping so large that no
        # step lowers the cost any more (a minimum to machine precision).
        converged[idx[(better & (small | flat | (cost_new == 0))) | (~better & (lam[idx] > 1e12))]] = True
    if prior is not None and prior.present.any():
        d = x - prior.mean
        cost = cost - np.einsum("bi,bij,bj->b", d, prior.information, d)  # the glints' share
    rms = np.sqrt(np.maximum(cost, 0.0) / np.maximum(n_seen, 1))
    return x, rms, iters, converged


def trf(model, problem: FitProblem, glints, mask, x0, enough, lo, hi, max_iter, prior: Prior | None = None):
    """The paper's solver: scipy's trust-region-reflective per sample, 2-point Jacobian. A
    prior enters as p extra residual rows W (x - mean) with Wᵀ W = information."""
    B, p = x0.shape
    x = x0.copy()
    rms = np.full(B, np.nan)
    iters = np.zeros(B, dtype=int)
    converged = np.zeros(B, dtype=bool)
    for b in np.flatnonzero(enough):
        m = mask[b]
        W = None
        if prior is not None and prior.present[b]:
            w, V = np.linalg.eigh(prior.information[b])
            W = np.sqrt(np.maximum(w, 0.0))[:, None] * V.T

        def fun(xb, b=b, m=m, W=W):
            center, radius, lights = unpack(model, problem, xb[None])
            g, _ = project_glints(problem.camera, center[0] if np.ndim(center) == 2 else center,
                                  radius if np.ndim(radius) == 0 else radius[0],
                                  lights if lights.ndim == 2 else lights[0])
            res = (g[m] - glints[b, m]).ravel()
            return res if W is None else np.concatenate([res, W @ (xb - prior.mean[b])])

        x0b = np.clip(x0[b], np.nextafter(lo, hi), np.nextafter(hi, lo))
        res = least_squares(fun, x0b, bounds=(lo, hi), method="trf", max_nfev=max_iter * (p + 1),
                            xtol=1e-12, ftol=1e-12, gtol=1e-12)
        x[b], iters[b], converged[b] = res.x, res.nfev, res.status > 0
        glint_res = res.fun[:2 * m.sum()]
        rms[b] = np.sqrt(np.sum(glint_res ** 2) / max(m.sum(), 1))
    return x, rms, iters, converged
