"""A band the tracker cannot identify on its own, with the previous sample as prior.

A sparse band (fewer than the tracker's ``MIN_GLINTS`` glints) or one whose identification
failed borrows from the previous sample when it is recent: its eye rotation, with a
covariance grown by the motion model (:class:`estimator.samples.BandPrior`), is a Gaussian
prior for identifying the band's few glints (:meth:`estimator.matching.GlintMatcher.match_near`)
and for the orbit fit, which one glint then determines. The sample carries
``prior_assisted=True``; its posterior is the prior of the next band. Split from
:class:`estimator.tracker.Tracker`, whose state it reads and sets.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

import estimator.matching.kernels as match_kernels

from .estimates import assisted_estimate
from .gaze import geometric_gaze, polynomial_gaze, posterior_covariance
from .samples import PRIOR_PREFIX, GazeSample, failed_sample, inverse_2x2


def assisted_sample(tracker, f: int, j: int, time_s: float, g, rows, failed: GazeSample, *,
                    max_residual_px: float) -> GazeSample:
    """The prior-assisted sample of band j of frame f (time ``time_s``, detections g (k, 2),
    rows (first, last)) of ``tracker`` (:class:`estimator.tracker.Tracker`), whose state
    (the previous sample's time, rotation and covariance) gives the prior and takes the
    posterior; ``failed`` (the band's own failure) when there is no usable prior or no glint,
    a NaN sample with reason ``prior_<reason>`` where the prior does not rescue it. Fits with
    an RMS above ``max_residual_px`` are refused."""
    if tracker._state is None or g.shape[0] == 0:
        return failed
    t0, mean, cov0 = tracker._state
    cov = tracker.prior.predict(cov0, time_s - t0)
    if cov is None:
        return failed
    match = tracker.matcher.match_near(g, mean, cov, rows=rows)
    if not match.ok:
        return replace(failed, reason=PRIOR_PREFIX + match.reason)
    used = match.matched
    lights = match.light_index[used]
    glints = tracker._glints(g[used], lights)
    # The compiled small fit models the sphere: a conic calibration takes the batched fits.
    quick = (assisted_estimate(tracker._problems.orbit, g[used], lights, mean, cov,
                               tracker.prior.noise_px, tracker.follower.arrays,
                               tracker._gaze_point, max_residual_px)
             if tracker.follower and not tracker.calibration.conic and match_kernels.ENABLED
             else None)
    post = None
    if quick is not None:
        xy, center, angles, rms, JtJ = quick
        # (Σ_glints⁻¹ + Σ_prior⁻¹)⁻¹ from the fit's own JᵀJ, as posterior_covariance
        # builds it from the analytic one (glints that leave an angle undetermined add
        # nothing).
        info = inverse_2x2(cov, 0.0)  # the prior's: positive definite
        if inverse_2x2(JtJ) is not None:
            info = info + JtJ / tracker.prior.noise_px ** 2
        post = inverse_2x2(info, 0.0)
    else:
        prior = dict(prior_mean_rad=mean, prior_cov_rad2=cov, noise_px=tracker.prior.noise_px,
                     problems=tracker._problems)
        if tracker.method == "polynomial":
            est = polynomial_gaze(tracker.setup, tracker.calibration, glints,
                                  mapping=tracker.mapping, **prior)
        else:
            est = geometric_gaze(tracker.setup, tracker.calibration, glints, **prior)
        reason = tracker._reason(est)
        if reason != "ok":
            return failed_sample(f, j, time_s, PRIOR_PREFIX + reason, g[used], lights)
        xy, center, angles = est.screen_xy_m[0], est.cornea_center_m[0], est.angles_rad[0]
        rms = float(est.rms_px[0])
    if post is None:
        post = posterior_covariance(tracker._orbit, angles, np.isfinite(glints[..., 0]), cov,
                                    tracker.prior.noise_px)[0]
    tracker._set_state(time_s, angles, post)
    tracker._prior_angles = angles.copy()
    return GazeSample(f, j, time_s, xy.copy(), center.copy(), g[used], lights, rms, "ok",
                      match.confidence[used].copy(), prior_assisted=True)
