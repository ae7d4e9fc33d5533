"""One band's sample from its glints: each step takes the stream's
:class:`~estimator.tracking.StreamState` and returns the sample with the state after it.

:func:`band_sample` is the step the tracker takes per band:

1. a band with at least :data:`~estimator.tracking.MIN_GLINTS` glints is identified on its
   own (:func:`dense_sample`): by the cheap path from a recent sample where it accepts the
   band (:func:`cheap_sample`), else by the hypothesis search (:func:`searched_sample`),
   unless no rotation the eye can have reached since the last sample fits the band
   (:attr:`Reason.OUT_OF_REACH <estimator.reasons.Reason.OUT_OF_REACH>`);
2. a sparse band, or one whose identification failed, borrows the last sample as a prior
   (:func:`estimator.tracking.assisted.assisted_sample`);
3. a band that fails loses the stream (:meth:`StreamState.lost`): the next dense band is
   identified cold.

``counts`` (a dict the caller keeps) counts the dense bands by the route that identified them:
"cheap", "search", and "unfillable" (left to the prior unsearched).
"""

from __future__ import annotations

import numpy as np

from ..cornea import fit_covariance
from ..reasons import IDENTITY_FAILURES, Reason, match_failure
from .assisted import assisted_sample
from .context import MAX_RESIDUAL_PX, MIN_GLINTS, BandContext
from .estimates import searched_estimate
from .kernel import ACCEPTED, FALLBACK
from .samples import GazeSample, estimated_sample, failed_sample, inverse_2x2
from .state import StreamState

__all__ = ["band_sample", "dense_sample", "cheap_sample", "searched_sample"]


def band_sample(context: BandContext, state: StreamState, f: int, g, band, time_s: float,
                counts: dict) -> tuple[GazeSample, StreamState]:
    """The sample of band ``band`` (pulse j, (first row, last row)) of frame f at ``time_s``
    from its detections g (k, 2), identified on its own or from the prior, and the state
    after it."""
    j, rows = band
    if g.shape[0] < MIN_GLINTS:
        sample = failed_sample(f, j, time_s, Reason.MATCH_TOO_FEW_GLINTS, g)
    else:
        sample, state = dense_sample(context, state, f, j, time_s, g, rows, counts)
        if sample.ok or sample.reason not in IDENTITY_FAILURES:
            return sample, (state if sample.ok else state.lost())
    state = state.lost()
    if context.prior is not None:
        sample, state = assisted_sample(context, state, f, j, time_s, g, rows, sample)
    return sample, (state if sample.ok else state.lost())


def dense_sample(context: BandContext, state: StreamState, f: int, j: int, time_s: float, g,
                 rows, counts: dict) -> tuple[GazeSample, StreamState]:
    """A band with enough glints, identified and fitted on its own: by the cheap path from a
    recent sample where it accepts the band, else by the hypothesis search."""
    if context.follower is not None:
        got = cheap_sample(context, state, f, j, time_s, g, rows)
        if got is not None:
            counts["cheap"] += 1
            return got
        recent = context.recent(state, time_s)
        if recent is not None and context.matcher.band_support(rows, recent[0], recent[3],
                                                                g) < MIN_GLINTS:
            counts["unfillable"] += 1
            return failed_sample(f, j, time_s, Reason.OUT_OF_REACH, g), state
    counts["search"] += 1
    return searched_sample(context, state, f, j, time_s, g, rows)


def searched_sample(context: BandContext, state: StreamState, f: int, j: int, time_s: float,
                    g, rows) -> tuple[GazeSample, StreamState]:
    """A band identified by the hypothesis search (from the state's prior rotation where it
    has one), fitted by the compiled small fit or the batched fits."""
    match = context.matcher.match(g, rows=rows, prior_angles_rad=state.prior_angles_rad)
    if not match.ok:
        return failed_sample(f, j, time_s, match_failure(match.reason), g), state
    used, lights = match.matched, match.light_index[match.matched]
    if lights.size < MIN_GLINTS:
        return failed_sample(f, j, time_s, Reason.TOO_FEW_GLINTS, g[used], lights), state
    quick = searched_estimate(context, g[used], lights, state.start,
                              match.cornea_center_m) if context.fast_fits else None
    if quick is not None:
        reason, (xy, center, rms, resume) = Reason.OK, quick
    else:
        start = state.start
        est = context.batched_estimate(context.band_glints(g[used], lights), start=start)
        reason = context.reason_of(est)
        xy, center = est.screen_xy_m[0], est.cornea_center_m[0]
        rms, resume = float(est.rms_px[0]), est.resume_from
    if reason == Reason.OK and context.implausible(state, time_s, match.angles_rad):
        reason = Reason.IMPLAUSIBLE_JUMP
    if reason != Reason.OK:
        return failed_sample(f, j, time_s, reason, g[used], lights), state
    if context.orbit is not None:
        mask = np.isfinite(context.band_glints(g[used], lights)[..., 0])
        cov = fit_covariance(context.orbit, match.angles_rad, mask, model="orbit",
                             noise_px=context.prior.noise_px)[0]
        after = state.estimated(time_s, match.angles_rad, cov,
                                prior_angles_rad=match.angles_rad, start=resume.copy())
    else:
        after = StreamState(match.angles_rad, resume.copy(), state.last, state.velocity_rad_s)
    return estimated_sample(f, j, time_s, screen_xy_m=xy, cornea_center_m=center,
                            glints_px=g[used], light_index=lights, residual_px=rms,
                            confidence=match.confidence[used]), after


def cheap_sample(context: BandContext, state: StreamState, f: int, j: int, time_s: float, g,
                 rows) -> tuple[GazeSample, StreamState] | None:
    """The cheap path's sample and state, or None where it declines (the search decides then).

    Its prior: the previous band's sample, or after bands without one the last sample up to
    :data:`~estimator.tracking.JUMP_AGE_S` old carried on at the eye's last measured velocity
    (across the bands between two frames' glints, ~11 ms in paper_sim, a saccade moves the eye
    by degrees; later the search runs cold). Every outcome but an accepted band with an
    estimate below :data:`~estimator.tracking.MAX_RESIDUAL_PX` and no implausible jump goes
    to the search, which gives those failures their reasons."""
    fresh = state.fresh_prior()
    prior = state.prior_angles_rad if fresh else state.carried_prior(time_s)
    if prior is None:
        return None
    if context.kernel is not None and context.fast_fits and context.follower.compiled:
        got = compiled_cheap_sample(context, state, f, j, time_s, g, rows, prior, fresh)
        if got is not FALLBACK:
            return got
    follower = context.follower
    got = follower.follow(g, rows, prior, prior_term=fresh)
    if got is None and not fresh and state.velocity_rad_s is not None:
        # The velocity of two bands 1 ms apart carries their estimation noise (tens of
        # deg/s in a fixation, degrees over the ~11 ms to the next frame's glints): the
        # last sample's own rotation, unextrapolated, is the second try.
        got = follower.follow(g, rows, state.last.angles_rad, prior_term=False)
    if got is None:
        return None
    match, orbit = got.match, got.fit
    used = match.matched
    lights = match.light_index[used]
    if context.calibration.conic:
        # The follower identifies on the sphere; the conic's estimate comes from the
        # batched fits of estimator.gaze, which know the cornea model.
        if context.method == "polynomial":
            start = match.cornea_center_m if state.start is None else state.start
        else:
            start = orbit.x
        est = context.batched_estimate(context.band_glints(g[used], lights), start=start)
        if context.reason_of(est) != Reason.OK:
            return None
        xy, center = est.screen_xy_m[0], est.cornea_center_m[0]
        rms, resume = float(est.rms_px[0]), est.resume_from
    elif context.method == "polynomial":  # the free centre by the compiled small fit
        quick = searched_estimate(context, g[used], lights, state.start, match.cornea_center_m)
        if quick is None:
            return None
        xy, center, rms, resume = quick
    else:
        center, rms, resume = match.cornea_center_m, orbit.rms_px, orbit.x
        xy = context.gaze_point(center, orbit.x)
    if not (np.isfinite(xy).all() and rms <= MAX_RESIDUAL_PX) or \
            context.implausible(state, time_s, match.angles_rad):
        return None
    inv = inverse_2x2(orbit.JtJ)
    cov = context.prior.noise_px ** 2 * inv if inv is not None else np.full((2, 2), np.inf)
    after = state.estimated(time_s, match.angles_rad, cov, prior_angles_rad=match.angles_rad,
                            start=resume.copy())
    return estimated_sample(f, j, time_s, screen_xy_m=xy, cornea_center_m=center,
                            glints_px=g[used], light_index=lights, residual_px=rms,
                            confidence=match.confidence[used]), after


def compiled_cheap_sample(context: BandContext, state: StreamState, f: int, j: int,
                          time_s: float, g, rows, prior, fresh: bool):
    """:func:`cheap_sample` with its identification and estimate in one compiled call
    (:mod:`estimator.tracking.kernel`), from the prior rotation ``prior`` (2,) (``fresh``:
    the previous band's); the same sample and state, None where it declines, or
    :data:`~estimator.tracking.kernel.FALLBACK` where the Python form must decide."""
    retry = None
    if not fresh and state.velocity_rad_s is not None:
        retry = state.last.angles_rad  # the second try (cheap_sample's comment)
    got = context.kernel(np.ascontiguousarray(g, dtype=np.float64), rows, prior, fresh, retry,
                         state.start)
    if got[0] != ACCEPTED:
        return FALLBACK if got[0] == FALLBACK else None
    _, rms, glints, lights, conf, x, center, cov, xy, fit_x = got
    if context.implausible(state, time_s, x):
        return None
    # The kernel's arrays are this band's own: the sample takes them without
    # estimated_sample's copies; the state takes a copy of the fit's start.
    if context.kernel.polynomial:
        center = fit_x
        after = state.estimated(time_s, x, cov, prior_angles_rad=x, start=fit_x.copy())
    else:
        after = state.estimated(time_s, x, cov, prior_angles_rad=x, start=x.copy())
    return GazeSample(f, j, time_s, xy, center, glints, lights, rms, Reason.OK, conf), after
