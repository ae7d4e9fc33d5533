"""The reflection equation's root finders: a bracketed Newton iteration on its
trigonometric form (the default) and the companion-matrix quartic of Agrawal et al. 2010 (the
cross-check), in the local plane of :mod:`estimator.geometry.reflection`.
"""

from __future__ import annotations

import numpy as np

#: Newton iterations stop once every step is a Newton step below this (radians): convergence
#: is quadratic with |F''/2F'| of order one on the cornea, so the error left after such a step
#: is ~1e-16 rad, the double-precision limit. Saves one iteration over waiting for 1e-15.
_STEP_STOP_RAD = 1e-8
_MAX_NEWTON_ITER = 60


def _newton_unit(a, b, cp, sp, ct, st):
    """The root of (R) in [0, φ] as (cos θ, sin θ): two Newton steps from (ct, st) (the
    first-order closed form is within ~1e-4 rad, so the second step is already below the
    stopping size), then a bracketed Newton-bisection for the few pairs that did not settle
    (near-grazing light).

    A Newton step δ = F / F' turns the unit vector by -atan(δ) (a normalised (ct + δ st,
    st - δ ct)): the same fixed point as θ - δ and the same quadratic convergence, as
    atan(δ) = δ + O(δ³), without a trigonometric call."""
    ab = a * b
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(2):
            f, df, s1 = _reflection_condition_unit(a, b, ab, cp, sp, ct, st)
            step = f / df
            q = 1.0 / np.sqrt(1.0 + step * step)
            ct, st = (ct + step * st) * q, (st - step * ct) * q
        # Settled: a small last step and θ inside [0, φ] (sin θ >= 0, sin(φ - θ) >= 0).
        done = (np.abs(step) < _STEP_STOP_RAD) & (st >= 0) & (sp * ct - cp * st >= -1e-15)
    if not done.all():
        i = np.nonzero(~done)
        a, b = (np.broadcast_to(q, done.shape) for q in (a, b))
        p = np.arctan2(sp[i], cp[i])
        theta0 = np.clip(np.arctan2(st[i], ct[i]), 0.0, p)
        theta0 = np.where(np.isfinite(theta0), theta0, 0.5 * p)
        theta = _bracketed_root(a[i], b[i], p, sp[i], cp[i], theta0)
        ct, st = ct.copy(), st.copy()
        ct[i], st[i] = np.cos(theta), np.sin(theta)
    return ct, st


def _reflection_condition_unit(a, b, ab, cp, sp, ct, st):
    """F(θ) of (R), F'(θ) and sin(φ - θ) from the cosines and sines of θ and φ."""
    s1 = sp * ct - cp * st  # sin(φ - θ)
    c1 = cp * ct + sp * st  # cos(φ - θ)
    s2 = s1 * ct - c1 * st  # sin(φ - 2θ)
    c2 = c1 * ct + s1 * st  # cos(φ - 2θ)
    f = ab * s2 + a * st - b * s1
    df = a * ct + b * c1 - 2 * ab * c2
    return f, df, s1


def _reflection_condition(a, b, ab, sp, cp, theta):
    """F(θ) of (R) and F'(θ) at the angle θ (the bracketed fallback works in angles)."""
    f, df, _ = _reflection_condition_unit(a, b, ab, cp, sp, np.cos(theta), np.sin(theta))
    return f, df


def _bracketed_root(a, b, p, sp, cp, theta):
    """Safeguarded Newton on [0, φ]: F(0) > 0 > F(φ) and F decreases through the root; a step
    that leaves the bracket is replaced by bisection. Converged pairs drop out."""
    out = theta.copy()
    idx = np.arange(theta.size)
    lo, hi = np.zeros_like(p), p.copy()
    for _ in range(_MAX_NEWTON_ITER):
        f, df = _reflection_condition(a, b, a * b, sp, cp, theta)
        pos = f > 0
        np.copyto(lo, theta, where=pos)
        np.copyto(hi, theta, where=~pos)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = f / df
        new = theta - step
        bad = ~((new >= lo) & (new <= hi))  # also catches NaN from df == 0
        np.copyto(new, 0.5 * (lo + hi), where=bad)
        out[idx] = new
        active = bad | (np.abs(step) >= _STEP_STOP_RAD)
        if not active.any():
            break
        idx = idx[active]
        a, b, p, sp, cp = a[active], b[active], p[active], sp[active], cp[active]
        lo, hi, theta = lo[active], hi[active], new[active]
    return out


def reflection_quartic(alpha, beta, phi) -> np.ndarray:
    """(..., 5) coefficients, highest power first, of the reflection quartic in t = tan(θ/2)."""
    alpha, beta, phi = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (alpha, beta, phi)))
    s, c = np.sin(phi), np.cos(phi)
    ab = alpha * beta
    return np.stack(
        [
            beta * s * (alpha + 1),
            2 * (2 * ab * c + alpha + beta * c),
            -6 * ab * s,
            2 * (alpha + beta * c - 2 * ab * c),
            beta * s * (alpha - 1),
        ],
        axis=-1,
    )


def _quartic_root(alpha, beta, cp, sp):
    """The bracketed root of (R) from the eigenvalues of the quartic's companion matrix, as
    (cos θ, sin θ) after a Newton polish."""
    phi = np.arctan2(sp, cp)
    coeffs = reflection_quartic(alpha, beta, phi)
    lead = coeffs[..., 0]
    ok = np.abs(lead) > 1e-300
    norm = coeffs[..., 1:] / np.where(ok, lead, 1.0)[..., None]
    shape = coeffs.shape[:-1]
    comp = np.zeros(shape + (4, 4))
    comp[..., 0, :] = -norm
    comp[..., 1, 0] = comp[..., 2, 1] = comp[..., 3, 2] = 1.0
    roots = np.linalg.eigvals(comp.reshape(-1, 4, 4)).reshape(shape + (4,))
    t_max = np.tan(np.minimum(phi, np.pi * (1 - 1e-12)) / 2)[..., None]
    real = roots.real
    # Closest root to the real segment [0, tan(φ/2)], in the complex plane.
    dist = np.abs(roots.imag) + np.maximum(0.0, -real) + np.maximum(0.0, real - t_max)
    best = np.take_along_axis(real, np.argmin(dist, axis=-1)[..., None], axis=-1)[..., 0]
    theta = 2 * np.arctan(np.clip(best, 0.0, t_max[..., 0]))
    theta = np.where(ok, theta, phi / 2)
    # Newton polish (also the fallback where the companion matrix was ill-posed).
    return _newton_unit(alpha, beta, cp, sp, np.cos(theta), np.sin(theta))


def _first_order_root(alpha, beta, cp, sp):
    """(cos θ₀, sin θ₀): the first-order closed form around the bisector φ / 2, exact for a
    distant camera and light, θ₀ = φ/2 + (α - β) sin(φ/2) / (2αβ - (α + β) cos(φ/2))."""
    ch = np.sqrt(np.maximum(0.5 * (1 + cp), 0.0))  # cos(φ/2), φ in [0, π]
    sh = np.sqrt(np.maximum(0.5 * (1 - cp), 0.0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        d = (alpha - beta) * sh / (2 * alpha * beta - (alpha + beta) * ch)
    d = np.where(np.abs(d) < 1.0, d, 0.0)  # also NaN; the bisector is a safe start
    q = 1.0 / np.sqrt(1.0 + d * d)
    return (ch - d * sh) * q, (sh + d * ch) * q
