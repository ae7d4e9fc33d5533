"""A band the tracker cannot identify on its own, with the previous sample as prior.

A sparse band (fewer than :data:`~estimator.tracking.MIN_GLINTS` glints) or one whose
identification failed borrows from the previous sample when it is recent: its eye rotation,
with a covariance grown by the motion model (:class:`estimator.tracking.BandPrior`), is a
Gaussian prior for identifying the band's few glints
(:meth:`estimator.matching.GlintMatcher.match_near`) and for the orbit fit, which one glint
then determines. The sample carries ``prior_assisted=True``; its posterior is the prior of
the next band (the :class:`~estimator.tracking.StreamState` it returns).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..gaze import posterior_covariance
from ..reasons import Reason, prior_failure
from .context import BandContext
from .estimates import assisted_estimate
from .prior_kernel import (AMBIGUOUS, ESTIMATED, FALLBACK, FIT_FAILED, NO_HYPOTHESIS,
                           TOO_FEW_GLINTS)
from .samples import GazeSample, estimated_sample, failed_sample, inverse_2x2
from .state import StreamState

__all__ = ["assisted_sample"]


def assisted_sample(context: BandContext, state: StreamState, f: int, j: int, time_s: float, g,
                    rows, failed: GazeSample) -> tuple[GazeSample, StreamState]:
    """The prior-assisted sample of band j of frame f (time ``time_s``, detections g (k, 2),
    rows (first, last)) and the state after it.

    The last sample of ``state`` gives the prior, the posterior becomes the new last sample;
    ``failed`` (the band's own failure) is the sample when there is no usable prior or no
    glint, a NaN sample with reason ``prior_<reason>`` where the prior does not rescue it
    (the state unchanged then). Fits with an RMS above
    :data:`~estimator.tracking.MAX_RESIDUAL_PX` are refused."""
    last = state.last
    if last is None or g.shape[0] == 0:
        return failed, state
    mean, cov0 = last.angles_rad, last.cov_rad2
    prior = context.prior
    cov = prior.predict(cov0, time_s - last.time_s)
    if cov is None:
        return failed, state
    if context.prior_kernel is not None and context.fast_fits:
        got = compiled_assisted_sample(context, state, f, j, time_s, g, rows, failed, mean, cov)
        if got is not None:
            return got
    match = context.matcher.match_near(g, mean, cov, rows=rows)
    if not match.ok:
        return replace(failed, reason=prior_failure(match.reason)), state
    used = match.matched
    lights = match.light_index[used]
    glints = context.band_glints(g[used], lights)
    # The compiled small fit models the sphere: a conic calibration takes the batched fits.
    quick = assisted_estimate(context, g[used], lights, mean, cov) if context.fast_fits else None
    post = None
    if quick is not None:
        xy, center, angles, rms, JtJ = quick
        # (Σ_glints⁻¹ + Σ_prior⁻¹)⁻¹ from the fit's own JᵀJ, as posterior_covariance
        # builds it from the analytic one (glints that leave an angle undetermined add
        # nothing).
        info = inverse_2x2(cov, 0.0)  # the prior's: positive definite
        if inverse_2x2(JtJ) is not None:
            info = info + JtJ / prior.noise_px ** 2
        post = inverse_2x2(info, 0.0)
    else:
        est = context.batched_estimate(glints, prior_mean_rad=mean, prior_cov_rad2=cov)
        reason = context.reason_of(est)
        if reason != Reason.OK:
            return failed_sample(f, j, time_s, prior_failure(reason), g[used], lights), state
        xy, center, angles = est.screen_xy_m[0], est.cornea_center_m[0], est.angles_rad[0]
        rms = float(est.rms_px[0])
    if post is None:
        post = posterior_covariance(context.orbit, angles, np.isfinite(glints[..., 0]), cov,
                                    prior.noise_px)[0]
    # The next dense band is identified from the prior-assisted rotation; the fits' start is
    # the state's (none: the band was lost before it came here).
    after = state.estimated(time_s, angles, post, prior_angles_rad=angles.copy(),
                            start=state.start)
    return estimated_sample(f, j, time_s, screen_xy_m=xy, cornea_center_m=center,
                            glints_px=g[used], light_index=lights, residual_px=rms,
                            confidence=match.confidence[used], prior_assisted=True), after



#: The matcher's reason of each failure of the compiled step (prior_kernel's outcomes).
_MATCH_FAILURES = {NO_HYPOTHESIS: Reason.NO_HYPOTHESIS, FIT_FAILED: Reason.FIT_FAILED,
                   TOO_FEW_GLINTS: Reason.TOO_FEW_GLINTS, AMBIGUOUS: Reason.AMBIGUOUS}


def compiled_assisted_sample(context: BandContext, state: StreamState, f: int, j: int,
                             time_s: float, g, rows, failed: GazeSample, mean, cov):
    """:func:`assisted_sample` from the prior ``mean`` (2,), ``cov`` (2, 2) with its match,
    fit and posterior in one compiled call (:mod:`estimator.tracking.prior_kernel`): the
    same sample and state, or None where the Python form must decide."""
    outcome, rms, assign, conf, angles, center, xy, post = context.prior_kernel(
        np.ascontiguousarray(g, dtype=np.float64), rows, mean, np.ascontiguousarray(cov))
    if outcome == FALLBACK:
        return None
    if outcome != ESTIMATED:
        return replace(failed, reason=prior_failure(_MATCH_FAILURES[outcome])), state
    used = assign >= 0
    lights = assign[used]
    if not np.isfinite(post[0, 0]):
        glints = context.band_glints(g[used], lights)
        post = posterior_covariance(context.orbit, angles, np.isfinite(glints[..., 0]), cov,
                                    context.prior.noise_px)[0]
    after = state.estimated(time_s, angles, post, prior_angles_rad=angles.copy(),
                            start=state.start)
    return estimated_sample(f, j, time_s, screen_xy_m=xy, cornea_center_m=center,
                            glints_px=g[used], light_index=lights, residual_px=rms,
                            confidence=conf[used], prior_assisted=True), after
