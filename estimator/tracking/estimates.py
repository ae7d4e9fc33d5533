"""One band's estimate by the compiled small fit (:func:`estimator.cornea.fit_small`, the
sphere's) once the tracker knows its glints' identities: after the hypothesis search
(:func:`searched_estimate`) and for a band identified from the prior
(:func:`assisted_estimate`).

The batched fits of :mod:`estimator.gaze` (``polynomial_gaze``, ``geometric_gaze``) cost
~1 ms a band in numpy for one sample; the small fit reaches the same minimum (to ~1e-9 m,
``tests/estimator/test_cheap_path.py``) in ~20-40 us. Where it gives no accepted estimate (a
fit that does not converge, a residual above the tracker's limit, an angle past
:data:`estimator.gaze.ANGLE_BOUND_RAD`, no screen point) these return None and the tracker
runs the batched fits, which decide and name the failure; a conic calibration, whose cornea
the small fit does not model, always takes them (the caller's choice,
:attr:`~estimator.tracking.BandContext.fast_fits`). Without Numba ``fit_small`` runs its
float form (:mod:`estimator.cornea.scalar`, ~0.3 ms a fit: still several times cheaper than
the batched fit of one band); with Numba but the matcher's compiled steps switched off the
tracker does not call these.
"""

from __future__ import annotations

import math

import numpy as np

from ..cornea import fit_small
from ..gaze import ANGLE_BOUND_RAD
from .context import MAX_RESIDUAL_PX
from .samples import inverse_2x2

__all__ = ["searched_estimate", "assisted_estimate"]


def _orbit_center(orbit, angles):
    """The cornea centre (3,) of Fick ``angles`` on the calibrated orbit: c_e + r_co times
    :func:`estimator.eye.gaze_direction`, in scalar arithmetic (the same operations; numpy's
    on (3,) arrays cost ~10x more for one point)."""
    yaw, pitch = float(angles[0]), float(angles[1])
    cp, r, c = math.cos(pitch), float(orbit.orbit_radius_m), orbit.eye_center_m
    return np.array([float(c[0]) + r * (cp * math.sin(yaw)), float(c[1]) + r * math.sin(pitch),
                     float(c[2]) + r * (-cp * math.cos(yaw))])


def searched_estimate(context, glints_px, lights, start, match_center_m):
    """(screen point, cornea centre, RMS px, the next band's start) of a searched band's
    identified glints (k, 2) of ``lights`` (k,), or None (the batched fits decide).

    The gaze method of ``context`` (:class:`~estimator.tracking.BandContext`) "polynomial":
    the free centre (``problems.center``) from ``start`` (the last estimate's centre) or,
    without one, the match's centre ``match_center_m`` (3,), as ``polynomial_gaze`` from the
    stream's last centre; "geometric": the orbit (``problems.orbit``) from ``start`` (the last
    estimate's angles, default the primary position), as ``geometric_gaze``. Fits with an RMS
    above :data:`~estimator.tracking.MAX_RESIDUAL_PX` are refused."""
    problems, arrays, max_residual_px = context.problems, context.matcher.arrays, MAX_RESIDUAL_PX
    if context.method == "polynomial":
        problem, model = problems.center, "center"
        x0 = match_center_m if start is None else start
    else:
        problem, model = problems.orbit, "orbit"
        x0 = np.zeros(2) if start is None else start
    fit = fit_small(problem, glints_px, problem.lights_world_m[lights], x0, model=model,
                    arrays=arrays)
    if not (fit.ok and fit.rms_px <= max_residual_px):
        return None
    if model == "orbit":
        if not np.abs(fit.x).max() < ANGLE_BOUND_RAD:
            return None
        center, angles = _orbit_center(problem, fit.x), fit.x
    else:
        center, angles = fit.x, None
    xy = context.gaze_point(center, angles)
    if not np.isfinite(xy).all():
        return None
    return xy, center, float(fit.rms_px), fit.x


def assisted_estimate(context, glints_px, lights, mean, cov):
    """A prior-assisted band's (screen point, cornea centre, angles, RMS, the glints' JᵀJ) by
    the orbit fit with the prior that both gaze methods make, from the prior's mean (mean
    (2,) rad, covariance ``cov`` (2, 2) rad², glint noise: the ``context``'s
    :class:`~estimator.tracking.BandPrior`), as ``geometric_gaze`` with a prior; or None (the
    batched fits decide)."""
    orbit, noise_px, arrays = context.problems.orbit, context.prior.noise_px, context.matcher.arrays
    max_residual_px = MAX_RESIDUAL_PX
    inv = inverse_2x2(cov)  # σ² Σ⁻¹ in closed form (prior_information's eigh: ~60 us)
    if inv is None or not np.isfinite(inv).all():
        return None
    info = noise_px ** 2 * inv
    fit = fit_small(orbit, glints_px, orbit.lights_world_m[lights], mean, model="orbit",
                    arrays=arrays, prior_mean=mean, prior_information=info)
    if not (fit.ok and fit.rms_px <= max_residual_px and np.abs(fit.x).max() < ANGLE_BOUND_RAD):
        return None
    center = _orbit_center(orbit, fit.x)
    xy = context.gaze_point(center, fit.x)
    if not np.isfinite(xy).all():
        return None
    return xy, center, fit.x, float(fit.rms_px), fit.JtJ
