"""The local fits of :mod:`estimator.events.velocity`, compiled with Numba (optional).

The event detector fits a line through every sample's neighbours at three scales, and the event
gate a quadratic through a flagged sample's neighbours: in numpy each fit is a row of a
(samples, neighbours) block, and on the stream's short windows (a frame's push re-runs the
detector over the last ~0.25 s, ~260 samples) the cost is numpy's overhead, not arithmetic:
~0.55 ms a scale, more than half of a push (``benchmarks/bench_events.py``). Here each fit is a
loop over its window's samples: the stream 1.7-2.0x faster, the gated stream 1.9-2.1x. The sums run in another order than numpy's, so the results
agree to rounding (tested to 1e-9 relative), not to the bit.

Without Numba (``pip install scet`` without the ``fast`` extra, or ``NUMBA_DISABLE_JIT=1``) the
numpy path runs; :data:`ENABLED` says which. Compiled on first use (~2 s) and cached beside this
file (:mod:`estimator.jitcache`).
"""

from __future__ import annotations

import math

import numpy as np

try:
    import numba
except ImportError:  # the numpy path of estimator.events.velocity runs instead
    numba = None

#: Whether :mod:`estimator.events.velocity` uses these kernels.
ENABLED = numba is not None and not numba.config.DISABLE_JIT


def line_fits(tv, xv, lo, hi, velocity, centroid, gain):
    """For each valid sample i (times ``tv`` (m,), positions ``xv`` (m, 2)) the least-squares
    line through the samples ``lo[i]`` .. ``hi[i] - 1`` (itself included), times relative to
    its own: the slope into ``velocity`` (m, 2), the fit's mean instant into ``centroid`` and
    the slope's standard error per unit position noise into ``gain``; NaN where fewer than two
    samples or no spread in time (:func:`estimator.events.velocity.local_velocity`)."""
    for i in range(tv.shape[0]):
        n = 0
        s_t = s_tt = s_x0 = s_x1 = s_tx0 = s_tx1 = 0.0
        for j in range(lo[i], hi[i]):
            dt = tv[j] - tv[i]
            d0 = xv[j, 0] - xv[i, 0]
            d1 = xv[j, 1] - xv[i, 1]
            n += 1
            s_t += dt
            s_tt += dt * dt
            s_x0 += d0
            s_x1 += d1
            s_tx0 += dt * d0
            s_tx1 += dt * d1
        den = n * s_tt - s_t * s_t
        if n >= 2 and den > 0:
            velocity[i, 0] = (n * s_tx0 - s_t * s_x0) / den
            velocity[i, 1] = (n * s_tx1 - s_t * s_x1) / den
            centroid[i] = tv[i] + s_t / n
            gain[i] = math.sqrt(n / den)
        else:
            velocity[i, 0] = velocity[i, 1] = centroid[i] = gain[i] = np.nan


def loo_quadratic(tv, xv, lo, hi, scale, out):
    """For each valid sample i the position minus the least-squares quadratic's value at its
    instant, the quadratic through the samples ``lo[i]`` .. ``hi[i] - 1`` but itself (times
    relative to its own over ``scale``), into ``out`` (m, 2); NaN without a sample on each
    side or with fewer than 4 (:func:`estimator.events.velocity.leave_one_out_residual`)."""
    mom = np.empty(5)  # sums of u^0 .. u^4
    rhs = np.empty((3, 2))  # sums of u^k x
    m = np.empty((3, 5))  # the normal matrix and both right-hand sides
    for i in range(tv.shape[0]):
        mom[:] = 0.0
        rhs[:] = 0.0
        n = 0
        before = after = False
        for j in range(lo[i], hi[i]):
            if j == i:
                continue
            u = (tv[j] - tv[i]) / scale
            before |= u < 0
            after |= u > 0
            n += 1
            p = 1.0
            for k in range(5):
                mom[k] += p
                if k < 3:
                    rhs[k, 0] += p * xv[j, 0]
                    rhs[k, 1] += p * xv[j, 1]
                p *= u
        if n < 4 or not (before and after):
            out[i, 0] = out[i, 1] = np.nan
            continue
        for r in range(3):
            for c in range(3):
                m[r, c] = mom[r + c]
            m[r, 3] = rhs[r, 0]
            m[r, 4] = rhs[r, 1]
        for c in range(3):  # Gaussian elimination with partial pivoting
            piv = c
            for r in range(c + 1, 3):
                if abs(m[r, c]) > abs(m[piv, c]):
                    piv = r
            if piv != c:
                for k in range(5):
                    m[c, k], m[piv, k] = m[piv, k], m[c, k]
            for r in range(c + 1, 3):
                f = m[r, c] / m[c, c]
                for k in range(c, 5):
                    m[r, k] -= f * m[c, k]
        for d in range(2):  # back substitution; the constant term is the fit's value at u = 0
            c2 = m[2, 3 + d] / m[2, 2]
            c1 = (m[1, 3 + d] - m[1, 2] * c2) / m[1, 1]
            c0 = (m[0, 3 + d] - m[0, 1] * c1 - m[0, 2] * c2) / m[0, 0]
            out[i, d] = xv[i, d] - c0


if ENABLED:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    line_fits = _jit(line_fits)
    loo_quadratic = _jit(loo_quadratic)
