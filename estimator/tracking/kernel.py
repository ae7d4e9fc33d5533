"""The cheap path's band step as one compiled call (optional, Numba): :class:`CheapBand`.

A band the cheap path accepts (:func:`estimator.tracking.cheap_sample`) took, in Python, one
compiled call for the follow step (:func:`estimator.matching.follow_kernel.follow_band`:
predict, assign, fit the orbit, re-predict, re-assign, rival check, confidences), and then
~40 Python and numpy calls around a second compiled call: the follower's wrapper (checked
inputs, seven output arrays, the match and fit objects), polynomial gaze's small fit of the
free centre (:func:`estimator.cornea.fit_small`: its own checks and arrays around the
Levenberg-Marquardt kernel), the mapping of that centre or the optical axis' screen point,
and the acceptance tests. Profiled on the benchmark's synthetic frames (60 frames, x86 core,
loaded machine, ``/tmp`` profile of ``benchmarks/bench_tracker.py``'s frames): an accepted
cheap band cost 96-160 us, of which the two compiled calls were ~40 %.

:func:`cheap_band` runs the same steps in the same order inside one compiled function: the
follow step (the very kernel, with the second try from the last sample's own rotation where
the first declines), polynomial gaze's small fit (the very kernel
:data:`estimator.cornea.small.lm_kernel`, from the same start with the same settings), the
mapping of the centre (:meth:`estimator.calibration.GazeMapping.predict_one`'s terms and
sums in the same order, each power as CPython's ``float ** int``: C ``pow`` on the magnitude,
the sign put back for odd powers) or the optical axis' screen point
(:meth:`~estimator.tracking.BandContext.gaze_point`'s scalar arithmetic), and the residual
and finiteness tests, then what the sample takes: the matched detections, lights and
confidences gathered in detection order, and the angles' covariance σ² (JᵀJ)⁻¹
(:func:`inverse_scaled`, :func:`~estimator.tracking.inverse_2x2`'s arithmetic; issue 31's
fourth pass: ~17 us of small numpy calls a cheap band before). The plausibility check
against the last sample, the state and the sample object stay in Python (they need the
stream's state), so every sample is the Python form's
bit for bit (``tests/estimator/test_tracking_kernel.py``, and ``benchmarks/bench_tracker.py``
on whole streams). Where the follow step needs the Python form (an assignment past the
compiled solver's node limit: :data:`FALLBACK`) or Numba is not installed, the tracker runs
the Python form.
"""

from __future__ import annotations

import math

import numpy as np

import estimator.matching.follow_kernel as follow_kernel

from ..calibration import MAPPING_TERMS
from ..cornea.small import XTOL_M, lm_kernel
from ..geometry import compiled
from ..matching.follow import MAX_ROUNDS

__all__ = ["CheapBand", "cheap_band", "mapped_point", "inverse_scaled", "ENABLED", "DECLINED",
           "ACCEPTED", "FALLBACK"]

#: Whether :func:`cheap_band` runs compiled (the follow kernel does).
ENABLED = follow_kernel.ENABLED
#: :func:`cheap_band`'s outcomes (the follow kernel's): declined (the search decides),
#: accepted, or the Python form decides (an assignment past the compiled solver's limit).
DECLINED, ACCEPTED, FALLBACK = follow_kernel.DECLINED, follow_kernel.ACCEPTED, follow_kernel.FALLBACK


def int_power(z, e):
    """``z ** e`` as CPython computes it for a float z and an int e >= 0: 1 for e = 0, NaN
    for NaN z, else C ``pow`` of |z| (1 for |z| = 1) with the sign put back for odd e."""
    if e == 0:
        return 1.0
    if math.isnan(z):
        return z
    negate = False
    if z < 0.0:
        z = -z
        negate = e % 2 == 1
    r = 1.0 if z == 1.0 else math.pow(z, float(e))
    return -r if negate else r


def mapped_point(center, offset, scale, exponents, coefficients, out):
    """:meth:`estimator.calibration.GazeMapping.predict_one` of the feature ``center`` (d,)
    into ``out`` (2,): the standardised feature (v - o) / s, each term's product of powers
    (``exponents`` (t, d) int) and the sums over the terms, in the same order."""
    d = offset.shape[0]
    z = np.empty(d)
    for i in range(d):
        z[i] = (center[i] - offset[i]) / scale[i]
    x = 0.0
    y = 0.0
    for t in range(exponents.shape[0]):
        p = 1.0
        for i in range(d):
            p *= int_power(z[i], exponents[t, i])
        x += coefficients[t, 0] * p
        y += coefficients[t, 1] * p
    out[0] = x
    out[1] = y


def axis_point(angles, eye_center, screen_z, out):
    """:meth:`estimator.tracking.BandContext.gaze_point` of geometric gaze: where the optical
    axis from ``eye_center`` (3,) at Fick ``angles`` (2,) meets the screen z = ``screen_z``,
    into ``out`` (2,); NaN where it does not."""
    yaw, pitch = angles[0], angles[1]
    cp = math.cos(pitch)
    dx, dy, dz = cp * math.sin(yaw), math.sin(pitch), -cp * math.cos(yaw)
    lam = (screen_z - eye_center[2]) / dz if dz != 0.0 else math.nan
    if not (math.isfinite(lam) and lam > 0):
        out[0] = math.nan
        out[1] = math.nan
        return
    out[0] = eye_center[0] + lam * dx
    out[1] = eye_center[1] + lam * dy


def cheap_band(g, lo, hi, prior, weight, retry, R, O, intr, size, rc, offset, radius, lights,
               cap, ce, rco, fit_radius, xtol, group, shifted, fp, ip, polynomial, start,
               center_lights, center_radius, map_offset, map_scale, map_exponents,
               map_coefficients, eye_center, screen_z, max_residual_px, noise2, glints, light,
               conf, x, center, cov, xy, fit_x):
    """The cheap path's identification and estimate of detections ``g`` (k, 2) in rows
    [lo, hi] from ``prior`` (2,) rad (``weight`` 1 with the prior's term, 0 without); where
    that declines and ``retry`` (2,) is finite, again from ``retry`` without the prior's term.

    ``fp`` (10,): the follow kernel's float settings (prior gate, gate, band margin, noise,
    unmatched and missing costs, prior SD rad, largest shift rad, rival margin, the search's
    margin); ``ip`` (4,): its int settings (the follower's and the search's fewest matches,
    rounds, node limit). ``polynomial``: the free centre is fitted (problem lights
    ``center_lights`` (n, 3), r_c ``center_radius``) from ``start`` (3,) (the match's centre
    where it is NaN) and mapped (``map_*``); else the screen point of the optical axis from
    the calibrated ``eye_center`` (3,). Outputs: the fitted angles ``x`` (2,), the match's
    cornea ``center`` (3,), the screen point ``xy`` (2,), polynomial gaze's centre ``fit_x``
    (3,), and what the sample and the state take from the follow kernel's outputs where the
    band is accepted: the matched detections in detection order in the first m rows of
    ``glints`` (k, 2), their lights and confidences in ``light`` and ``conf`` (k,), and the
    covariance ``cov`` (2, 2) of the angles: ``noise2`` (σ², px²) times the inverse of the
    orbit fit's JᵀJ (:func:`inverse_scaled`), infinite where that is singular.

    Returns (outcome, RMS px of the sample's fit, m): :data:`ACCEPTED` where the band is
    identified and its estimate has a finite screen point and an RMS within
    ``max_residual_px``, :data:`DECLINED` where the search decides, :data:`FALLBACK` where
    the Python form does."""
    k = g.shape[0]
    assign, dist, every = np.empty(k, dtype=np.int64), np.empty(k), np.empty(k)
    JtJ = np.zeros((2, 2))
    outcome, rms = _cheap_band(g, lo, hi, prior, weight, retry, R, O, intr, size, rc, offset,
                               radius, lights, cap, ce, rco, fit_radius, xtol, group, shifted,
                               fp, ip, polynomial, start, center_lights, center_radius,
                               map_offset, map_scale, map_exponents, map_coefficients,
                               eye_center, screen_z, max_residual_px, assign, dist, every, x,
                               center, JtJ, xy, fit_x)
    if outcome != ACCEPTED:
        return outcome, rms, 0
    m = 0
    for d in range(k):
        if assign[d] >= 0:
            glints[m, 0], glints[m, 1] = g[d, 0], g[d, 1]
            light[m], conf[m] = assign[d], every[d]
            m += 1
    inverse_scaled(JtJ, noise2, cov)
    return outcome, rms, m


def inverse_scaled(A, scale, out):
    """``scale`` times :func:`estimator.tracking.inverse_2x2` of ``A`` (2, 2) (rcond 1e-12)
    into ``out`` (2, 2): its closed form and singularity test in the same operations and
    order, each element ``scale * (entry / det)`` as numpy computes ``scale * (adjugate /
    det)``; infinite where that inverse is None."""
    a, b, c, d = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
    det = a * d - b * c
    if not det > 1e-12 * a * d:
        for i in range(2):
            for j in range(2):
                out[i, j] = math.inf
        return
    out[0, 0] = scale * (d / det)
    out[0, 1] = scale * (-b / det)
    out[1, 0] = scale * (-c / det)
    out[1, 1] = scale * (a / det)


def _cheap_band(g, lo, hi, prior, weight, retry, R, O, intr, size, rc, offset, radius, lights,
                cap, ce, rco, fit_radius, xtol, group, shifted, fp, ip, polynomial, start,
                center_lights, center_radius, map_offset, map_scale, map_exponents,
                map_coefficients, eye_center, screen_z, max_residual_px, assign, dist, conf, x,
                center, JtJ, xy, fit_x):
    """:func:`cheap_band`'s identification and estimate into the follow kernel's ``assign``,
    ``dist``, ``conf`` (k,) and ``JtJ`` (2, 2) and the other outputs: (outcome, RMS px)."""
    nan = math.nan
    for i in range(g.shape[0]):
        if not (math.isfinite(g[i, 0]) and math.isfinite(g[i, 1])):
            return FALLBACK, nan  # the Python form refuses it with its message
    outcome, _, _, _, cost, m, _ = follow_kernel.follow_band(
        g, lo, hi, prior, weight, R, O, intr, size, rc, offset, radius, lights, cap, ce, rco,
        fit_radius, xtol, group, shifted, fp[0], fp[1], fp[2], fp[3], fp[4], fp[5], fp[6],
        ip[0], fp[7], fp[8], ip[1], fp[9], ip[2], ip[3], assign, dist, conf, x, center, JtJ)
    if outcome == DECLINED and math.isfinite(retry[0]) and math.isfinite(retry[1]):
        outcome, _, _, _, cost, m, _ = follow_kernel.follow_band(
            g, lo, hi, retry, 0.0, R, O, intr, size, rc, offset, radius, lights, cap, ce, rco,
            fit_radius, xtol, group, shifted, fp[0], fp[1], fp[2], fp[3], fp[4], fp[5], fp[6],
            ip[0], fp[7], fp[8], ip[1], fp[9], ip[2], ip[3], assign, dist, conf, x, center,
            JtJ)
    if outcome != ACCEPTED:
        return outcome, nan
    if not polynomial:
        rms = math.sqrt(max(cost, 0.0) / m)
        axis_point(x, eye_center, screen_z, xy)
    else:
        gu, Lu = follow_kernel.matched_pairs(g, center_lights, assign)
        k = gu.shape[0]
        x0 = np.empty(3)
        for c in range(3):
            x0[c] = center[c] if math.isnan(start[0]) else start[c]
        JtJ3 = np.zeros((3, 3))
        cost, _, converged = lm_kernel(R, O, intr, size, 0, x0, np.zeros(3), 0.0,
                                       center_radius, Lu, gu, 50, XTOL_M, np.zeros(3),
                                       np.zeros((3, 3)), fit_x, JtJ3)
        ok = (converged and math.isfinite(fit_x[0]) and math.isfinite(fit_x[1])
              and math.isfinite(fit_x[2]) and math.isfinite(cost))
        if not ok:
            return DECLINED, nan
        rms = math.sqrt(max(cost, 0.0) / k)
        if not rms <= max_residual_px:
            return DECLINED, nan
        mapped_point(fit_x, map_offset, map_scale, map_exponents, map_coefficients, xy)
    if not (math.isfinite(xy[0]) and math.isfinite(xy[1]) and rms <= max_residual_px):
        return DECLINED, nan
    return ACCEPTED, rms


if ENABLED:
    _jit = compiled.numba.njit(cache=True, nogil=True, error_model="numpy")
    int_power = _jit(int_power)
    mapped_point = _jit(mapped_point)
    axis_point = _jit(axis_point)
    inverse_scaled = _jit(inverse_scaled)
    _cheap_band = _jit(_cheap_band)
    cheap_band = _jit(cheap_band)


def mapping_args(context, polynomial: bool) -> tuple:
    """The gaze map as the compiled band steps take it: (offset (3,), scale (3,), exponents
    (terms, features) int64, coefficients (terms, 2)); placeholders for geometric gaze."""
    if not polynomial:
        return (np.zeros(3), np.ones(3), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 2)))
    gm = context.gaze_map
    return (np.ascontiguousarray(gm.offset_m, dtype=np.float64),
            np.ascontiguousarray(gm.scale_m, dtype=np.float64),
            np.array(MAPPING_TERMS[gm.kind], dtype=np.int64).reshape(-1, gm.n_features),
            np.ascontiguousarray(gm.coefficients, dtype=np.float64))


class CheapBand:
    """:func:`cheap_band` with a stream's fixed arguments (its
    :class:`~estimator.tracking.BandContext`'s follower, fit problems, mapping and screen).

    Built by :meth:`of`; :meth:`__call__` runs one band."""

    __slots__ = ("fixed", "polynomial", "tail")

    def __init__(self, fixed: tuple, polynomial: bool, tail: tuple):
        self.fixed, self.polynomial, self.tail = fixed, polynomial, tail

    @classmethod
    def of(cls, context, max_residual_px: float):
        """The compiled band step of ``context``, or None where the cheap path has no
        compiled form (no follower, Numba absent, a conic calibration, a mapping that is not
        of the centre's three coordinates)."""
        follower = context.follower
        if follower is None or not ENABLED or context.calibration.conic:
            return None
        polynomial = context.method == "polynomial"
        if polynomial and context.gaze_map.n_features != 3:
            return None
        matcher, fparams = follower.matcher, follower.params
        p = matcher.params
        fp = np.array([p.prior_gate_px, p.gate_px, p.band_margin_px, p.noise_px,
                       p.unmatched_cost, p.missing_cost, math.radians(p.prior_sigma_deg),
                       math.radians(fparams.max_shift_deg), fparams.rival_margin, p.min_margin],
                      dtype=np.float64)
        ip = np.array([fparams.min_matches, p.min_matches, MAX_ROUNDS, follow_kernel.MAX_NODES],
                      dtype=np.int64)
        fixed = (*follow_kernel.orbit_args(matcher), matcher.shift_table(), fp, ip, polynomial)
        center = context.problems.center
        mapping = mapping_args(context, polynomial)
        tail = (np.ascontiguousarray(center.lights_world_m, dtype=np.float64),
                float(center.cornea_radius_m), *mapping,
                np.asarray(context.calibration.eye_center_m, dtype=np.float64).reshape(3),
                float(context.setup.screen.z_m), float(max_residual_px),
                float(context.prior.noise_px ** 2))
        return cls(fixed, polynomial, tail)

    def __call__(self, g, rows, prior, prior_term: bool, retry, start):
        """One band: detections ``g`` (k, 2), ``rows`` (first, last), ``prior`` (2,) rad,
        ``prior_term`` (the follow step's prior weight), the second try's rotation ``retry``
        (2,) or None, the free centre's ``start`` (3,) or None. Returns (outcome, RMS px,
        matched detections (m, 2), their lights (m,) and confidences (m,), angles (2,),
        centre (3,), covariance of the angles (2, 2) (σ² (JᵀJ)⁻¹), screen point (2,), fitted
        centre (3,)); each array its own (views of arrays made for this call)."""
        k = g.shape[0]
        glints, light, conf = np.empty((k, 2)), np.empty(k, dtype=np.int64), np.empty(k)
        x, center, cov = np.empty(2), np.empty(3), np.empty((2, 2))
        xy, fit_x = np.empty(2), np.empty(3)
        outcome, rms, m = cheap_band(
            g, float(rows[0]), float(rows[1]), prior, 1.0 if prior_term else 0.0,
            _NAN2 if retry is None else retry, *self.fixed,
            _NAN3 if start is None else start, *self.tail, glints, light, conf, x, center,
            cov, xy, fit_x)
        return (outcome, rms, glints[:m], light[:m], conf[:m], x, center, cov, xy, fit_x)


_NAN2, _NAN3 = np.full(2, np.nan), np.full(3, np.nan)
