"""The tracker on images: banded frames in, one gaze sample per lit band out.

This is the thin orchestrator on top of the estimator (the pipeline that runs on the
prototype). Per frame:

1. :class:`estimator.glints.GlintDetector` (:func:`estimator.glints.detect_glints` with the noise
   model kept over the stream) finds the glints and stamps each with its strobe.
2. Glints are grouped by strobe; every band the banding model says lights visible rows
   (:func:`estimator.banding.band_layout`) gives one sample, glints or not.
3. :class:`estimator.matching.GlintMatcher` identifies the band's glints, from the previous
   sample's eye rotation as prior (cold search for the first sample and after a failure). The
   matcher predicts glints from the calibrated geometry (lighting pose, r_c, c_e, r_co).
4. The cornea is fitted to the identified glints and mapped to the screen
   (:func:`estimator.gaze.polynomial_gaze` or :func:`estimator.gaze.geometric_gaze`). A band
   whose identification puts the eye further from a recent previous sample than it can turn
   in between is NaN (:data:`IMPLAUSIBLE_JUMP`): clutter matched to a chain of lights.
5. Sparse bands (fewer than :data:`MIN_GLINTS` glints, or whose identification failed) borrow
   from the previous sample when it is recent (:class:`BandPrior`): its eye rotation, with a
   covariance grown by the motion model, is a Gaussian prior for identifying the few glints
   (:meth:`estimator.matching.GlintMatcher.match_near`) and for the orbit fit, which one glint
   then determines (the "ours + prior" rows of ``reports/paper-reproduction.md``). Such samples
   carry ``prior_assisted=True``. A band without any glint stays NaN: no sample is invented.

Each sample carries the strobe instant s_j + Δs / 2 of its pulse (Sec. 2.3 of the SCET paper:
the time of a band is its pulse's, not the frame's), shifted by the frame's measured start
when a timing sidecar gives one. A sample that cannot be estimated is NaN with a reason code;
any exception raised inside a frame becomes NaN samples with a reason and a log record: the
stream never stops half way.

Folders of frames (rendered datasets, prototype captures) are read and tracked by
:mod:`estimator.folders`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

import estimator.cut_glints as cut_glints
import estimator.matching.kernels as match_kernels

from .banding import band_rows, strobe_instant
from .calibration import Calibration
from .cornea import fit_covariance
from .assisted import assisted_sample
from .estimates import searched_estimate
from .eye import gaze_direction
from .gaze import (
    calibrated_problems,
    geometric_gaze,
    polynomial_gaze,
    screen_intersection,
)
from .glints import NO_BAND, DetectionParams, GlintDetector
from .matching import BandFollower, FollowParams, GlintMatcher, MatchParams
from .samples import (  # noqa: F401 (the reason codes: re-exported)
    FLUX_CUT_GLINTS, IDENTITY_FAILURES, IMPLAUSIBLE_JUMP, INTERNAL_ERROR, MISSING_FRAME,
    OUT_OF_REACH, PRIOR_PREFIX, RESIDUAL_TOO_LARGE, SATURATED_FRAME, UNREADABLE_FRAME,
    WRONG_FRAME_SIZE,
    BandPrior, GazeSample, TrackerInputError, failed_sample, inverse_2x2)
from .setup import Setup

log = logging.getLogger(__name__)

METHODS = ("polynomial", "geometric")

#: A frame with more than this share of its pixels at full scale is not an eye image the
#: detector can read (a lamp in view, a failed exposure): its samples fail with
#: :data:`SATURATED_FRAME` rather than with whatever the clutter makes of them.
SATURATED_FRAME_SHARE = 0.25
#: Fewest identified glints a sample is fitted from. Three unknowns (the cornea centre) need
#: two glints, but a band with 3-4 glints among clutter is fitted by a wrong pose too often:
#: measured on 40 quick-mode frames (320x240, 4 spp, ~50 clutter blobs per frame), samples
#: from 3-4 identified glints had a wrong identity 1 time in 3 (2 % of all identities), those
#: from 5 or more none in 1433.
MIN_GLINTS = 5
#: Largest RMS glint residual (px) of an accepted fit. Measured on quick-mode renders: right
#: identities fit to 0.18 px (median), 0.39 px at most over 289 samples; five clutter blobs in
#: a band without glints, taken for glints, fitted to 1.4-1.7 px.
MAX_RESIDUAL_PX = 1.0
#: A band identified on its own is checked against the previous sample when that sample is at
#: most this old (s): a little over one frame period, so the first band of a frame is checked
#: against the last of the one before. Older samples do not gate (a wrong one would otherwise
#: hold back the right ones for long).
JUMP_AGE_S = 0.02
#: Slack of that check beyond the turn the eye can make, v_max √2 Δt (v_max per axis, the
#: :class:`BandPrior`'s): the two samples' estimation error. In the full validation, three
#: 5-glint bands of clutter with no glint at all (top rows, dielectric renders) were matched
#: to a chain 19-28 deg away from the previous sample 1 ms before; right samples differ from
#: the previous one by well under a degree.
JUMP_SLACK_DEG = 2.0
#: The eye's velocity is measured from two samples at most this far apart (s): neighbouring
#: bands (1.04 ms at 16 pulses per frame, 2.08 ms at 8), where 0.05° of estimation error
#: makes 25-50°/s, against saccades at hundreds.
VELOCITY_AGE_S = 2.5e-3


class Tracker:
    """Streaming gaze tracker on banded frames.

    Parameters
    ----------
    setup : Setup
        Camera, sensor and strobe timing, lights, eye model and screen.
    calibration : Calibration
        Lighting correction and r_c, plus the mapping (polynomial) or c_e, r_co (geometric).
    method : {"polynomial", "geometric"}
    mapping : str
        Name of the calibration's mapping used by polynomial gaze.
    detection : DetectionParams
    matching : MatchParams
    prior : BandPrior or None
        Motion model of the prior sparse bands borrow from the previous sample; None turns
        prior assistance off. It needs the calibration's eye centre and orbit radius (without
        them there is no prior either).
    cheap : bool
        Identify a band from a recent sample with the cheap path
        (:class:`estimator.matching.BandFollower`: one prediction, one gated assignment, one
        small fit, verified) before the hypothesis search, which runs where it declines: the
        first band, after a sample older than :data:`JUMP_AGE_S`, and wherever its checks
        fail. ``False`` runs the search on every band (the reference it is compared with).
        Needs the calibration's eye centre and orbit radius and the ``"orbit"`` model.
    flag_cut_glints : bool or None
        Drop glints whose flux says a lash cuts them and do the band again without them
        (:meth:`_band`, :mod:`estimator.cut_glints`; README "Moving lids, blinks and
        lashes"). It needs the calibration's ``glint_flux`` for the rig's lights: ``True``
        refuses a calibration without it, ``None`` (the default) flags where the calibration
        has it (a calibration from images, spherical or conic), ``False`` never flags.
    """

    def __init__(self, setup: Setup, calibration: Calibration, method: str = "polynomial", *,
                 mapping: str = "eq1_25", detection: DetectionParams = DetectionParams(),
                 matching: MatchParams = MatchParams(), prior: BandPrior | None = BandPrior(),
                 cheap: bool = True, flag_cut_glints: bool | None = None):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        if not isinstance(calibration, Calibration):
            raise ValueError(f"calibration must be a Calibration, got {type(calibration).__name__}")
        if method == "geometric" and not calibration.has_orbit:
            raise ValueError("geometric gaze needs a calibration with the eye centre and orbit")
        if method == "polynomial" and mapping not in calibration.mappings:
            raise ValueError(f"the calibration has no mapping {mapping!r} "
                             f"(has {sorted(calibration.mappings)})")
        self.setup, self.calibration, self.method, self.mapping = setup, calibration, method, mapping
        self.detection = detection
        fluxed = calibration.flags_cut_glints(setup.lights.count)
        if flag_cut_glints and not fluxed:
            raise ValueError(f"flag_cut_glints needs a calibration with glint_flux for the "
                             f"{setup.lights.count} lights (recalibrate)")
        self._flag_cut = fluxed if flag_cut_glints is None else bool(flag_cut_glints)
        # Detection reuses the sensor's noise model from frame to frame (measured again every
        # 30 frames, on a 5 % level drift, and after every reset of the stream).
        self._detector = GlintDetector(setup, detection)
        # Glints predicted from the calibrated geometry, not the nominal one: the lighting pose
        # of the prototype is off by millimetres (a pixel or more per glint).
        # One set of calibrated fit problems for the stream: the matcher's orbit fits and the
        # gaze fits of every band use them.
        self._problems = calibrated_problems(setup, calibration)
        self.matcher = GlintMatcher(setup, matching, calibration=calibration,
                                    problem=self._problems.orbit)
        self.n_lights = setup.lights.count
        self.prior = prior if calibration.has_orbit and matching.model == "orbit" else None
        self._orbit = self._problems.orbit if self.prior is not None else None
        self._map = None if method == "geometric" else calibration.mappings[mapping]
        self.follower = None
        if cheap and self.prior is not None and (self._map is None or self._map.n_features == 3):
            self.follower = BandFollower(self.matcher, FollowParams(min_matches=MIN_GLINTS))
        #: Dense bands identified by the cheap path, by the hypothesis search, and left to the
        #: prior unsearched (:meth:`_unfillable`); bands done again without cut glints.
        self.counts = {"cheap": 0, "search": 0, "unfillable": 0, "again": 0}
        self.reset()

    def reset(self) -> None:
        """Forget the previous sample (the next band is matched cold, and has no prior) and the
        noise model (a frame that failed as a whole often means the exposure changed)."""
        self._lose()
        self._state = None
        self._velocity = None
        self._detector.reset()

    def _lose(self) -> None:
        """A band failed: the next dense band is matched cold (the prior of sparse bands is
        kept; it grows with its age)."""
        self._prior_angles = None
        self._start = None

    def process(self, frame, frame_index: int, frame_start_s: float | None = None
                ) -> list[GazeSample]:
        """Samples of one frame: one per band the strobe lights visible rows of.

        Parameters
        ----------
        frame : (H, W) uint8, uint16 or float
            Sensor output (DN). ``None`` or an array of the wrong shape gives NaN samples
            (:data:`UNREADABLE_FRAME`, :data:`WRONG_FRAME_SIZE`).
        frame_index : int
        frame_start_s : float, optional
            Measured start t0_f of the frame (timing sidecar); default f Δt. Sample times are
            the banding model's strobe instants shifted by t0_f - f Δt.

        Returns
        -------
        list of GazeSample, in strobe order.
        """
        frame_index = int(frame_index)
        sensor, strobe = self.setup.sensor, self.setup.strobe
        shift = 0.0 if frame_start_s is None else float(frame_start_s) - frame_index * sensor.frame_period_s
        pulses, starts, first, last = band_rows(sensor, strobe, frame_index)
        bands = [(int(j), (int(a), int(b))) for j, a, b in zip(pulses, first, last)]
        times = (strobe_instant(starts, strobe.pulse_s) + shift).tolist()
        try:
            reason = self._check(frame)
            if reason is not None:
                self.reset()
                return [failed_sample(frame_index, j, t, reason) for (j, _), t in zip(bands, times)]
            det = self._detector(frame, frame_index)
            det = det.select(~det.has(NO_BAND))
            glints, strobes, flux = det.glints_px, det.strobe_index, det.intensity
            return [self._band(frame_index, self._of_strobe(glints, strobes, b[0]), b, t,
                               flux[strobes == b[0]] if self._flag_cut else None)
                    for b, t in zip(bands, times)]
        except Exception as exc:  # the stream must survive any one frame; the reason is logged
            # A bug, not bad input: logged with its traceback, counted by the run's summary.
            log.error("frame %d: internal error %s: %s; its samples are NaN (%s)", frame_index,
                      type(exc).__name__, exc, INTERNAL_ERROR, exc_info=True)
            self.reset()
            return [failed_sample(frame_index, j, t, f"{INTERNAL_ERROR}:{type(exc).__name__}")
                    for (j, _), t in zip(bands, times)]

    def _check(self, frame) -> str | None:
        if frame is None:
            return UNREADABLE_FRAME
        a = np.asarray(frame)
        if a.shape != (self.setup.camera.height_px, self.setup.camera.width_px):
            return WRONG_FRAME_SIZE
        full = 255 if a.dtype == np.uint8 else 2 ** self.setup.sensor.bit_depth - 1
        # The maximum first: a frame without a full-scale pixel (the common case) is not counted.
        if a.max() >= full and np.count_nonzero(a >= full) > SATURATED_FRAME_SHARE * a.size:
            return SATURATED_FRAME
        return None

    @staticmethod
    def _of_strobe(glints_px, strobes, j: int) -> np.ndarray:  # of_strobe's, 30 us cheaper
        return glints_px[strobes == j]

    def _band(self, f: int, g, band, time_s: float, flux=None) -> GazeSample:
        """Sample of a band of frame f: glints g (k, 2), band (pulse, (first row, last row)),
        the glints' flux (k,) where cut glints are flagged: a band with a flagged glint is
        done again, from the stream's state before it with the first pass's rotation as the
        prior of its identification, without the flagged detections
        (:func:`estimator.cut_glints.flagged`; the sample records their lights in
        ``flux_flagged``, a failure's reason is prefixed :data:`FLUX_CUT_GLINTS`)."""
        if flux is None:
            return self._sample(f, g, band, time_s)
        before = (self._prior_angles, self._start, self._state, self._velocity)
        counts = dict(self.counts)
        sample = self._sample(f, g, band, time_s)
        if not sample.ok:
            return sample
        bad = cut_glints.flagged(self.calibration, self.setup.camera,
                                 self._problems.center.lights_world_m, sample, g, flux,
                                 self.matcher.arrays)
        if not bad.any():
            return sample
        # The first pass's rotation seeds the second (the cheap path then identifies the band
        # from it instead of searching again); the rest of the state is the one before the band.
        first = self._prior_angles
        self._prior_angles, self._start, self._state, self._velocity = before
        if first is not None:
            self._prior_angles = first
        self.counts = counts  # the band counts once, by the path of its second pass
        self.counts["again"] += 1
        return self._without(f, g, band, time_s, sample, bad)

    def _without(self, f: int, g, band, time_s: float, sample: GazeSample, bad) -> GazeSample:
        """The band of ``sample`` done again without its glints ``bad`` (k,) bool."""
        again = self._sample(f, g[cut_glints.kept_detections(g, sample.glints_px[bad])], band,
                             time_s)
        lights = sample.light_index[bad]
        if again.ok:
            return replace(again, flux_flagged=lights)
        return replace(again, reason=f"{FLUX_CUT_GLINTS}_{again.reason}", flux_flagged=lights)

    def _sample(self, f: int, g, band, time_s: float) -> GazeSample:
        """:meth:`_band`'s sample of glints g, identified on their own or from the prior."""
        j, rows = band
        if g.shape[0] < MIN_GLINTS:
            sample = failed_sample(f, j, time_s, "match_too_few_glints", g)
        else:
            sample = self._dense(f, j, time_s, g, rows)
            if sample.ok or sample.reason not in IDENTITY_FAILURES:
                return self._keep(sample)
        self._lose()
        return self._keep(self._assisted(f, j, time_s, g, rows, sample))

    def _keep(self, sample: GazeSample) -> GazeSample:  # a failed band loses the stream
        if not sample.ok:
            self._lose()
        return sample

    def _dense(self, f, j, time_s, g, rows) -> GazeSample:
        """A band with enough glints, identified and fitted on its own: by the cheap path from
        a recent sample where it accepts the band, else by the hypothesis search."""
        if self.follower is not None:
            sample = self._cheap(f, j, time_s, g, rows)
            if sample is not None:
                self.counts["cheap"] += 1
                return sample
        if self.follower is not None and self._unfillable(time_s, rows, g):
            self.counts["unfillable"] += 1
            return failed_sample(f, j, time_s, OUT_OF_REACH, g)
        self.counts["search"] += 1
        match = self.matcher.match(g, rows=rows, prior_angles_rad=self._prior_angles)
        if not match.ok:
            return failed_sample(f, j, time_s, f"match_{match.reason}", g)
        used, lights = match.matched, match.light_index[match.matched]
        if lights.size < MIN_GLINTS:
            return failed_sample(f, j, time_s, "too_few_glints", g[used], lights)
        reason, xy, center, rms, resume = self._estimate(g[used], lights, match.cornea_center_m)
        if reason == "ok" and self._implausible(time_s, match.angles_rad):
            reason = IMPLAUSIBLE_JUMP
        if reason != "ok":
            return failed_sample(f, j, time_s, reason, g[used], lights)
        self._prior_angles = match.angles_rad
        self._start = resume.copy()
        if self._orbit is not None:
            mask = np.isfinite(self._glints(g[used], lights)[..., 0])
            cov = fit_covariance(self._orbit, match.angles_rad, mask, model="orbit",
                                 noise_px=self.prior.noise_px)[0]
            self._set_state(time_s, match.angles_rad, cov)
        return GazeSample(f, j, time_s, xy.copy(), center.copy(), g[used], lights, rms, "ok",
                          match.confidence[used].copy())

    def _estimate(self, g, lights, center_m):
        """(reason, screen point, centre, RMS, next start) of identified glints g (k, 2): the
        compiled small fit (estimates.searched_estimate), else the batched fits."""
        if self.follower is not None and match_kernels.ENABLED and not self.calibration.conic:
            quick = searched_estimate(self._problems, self.method, g, lights, self._start,
                                      center_m, self.follower.arrays, self._gaze_point,
                                      MAX_RESIDUAL_PX)
            if quick is not None:
                return ("ok", *quick)
        glints = self._glints(g, lights)
        if self.method == "polynomial":
            est = polynomial_gaze(self.setup, self.calibration, glints, mapping=self.mapping,
                                  start=self._start, problems=self._problems)
        else:
            est = geometric_gaze(self.setup, self.calibration, glints,
                                 start=(0.0, 0.0) if self._start is None else self._start,
                                 problems=self._problems)
        return (self._reason(est), est.screen_xy_m[0], est.cornea_center_m[0],
                float(est.rms_px[0]), est.resume_from)

    def _cheap(self, f, j, time_s, g, rows) -> GazeSample | None:
        """The cheap path's sample, or None where it declines (the search decides then). Its
        prior: the previous band's sample, or after bands without one the last sample up to
        :data:`JUMP_AGE_S` old (later the search runs cold). Every outcome but an accepted band
        with an estimate below :data:`MAX_RESIDUAL_PX` and no :data:`IMPLAUSIBLE_JUMP` goes to
        the search, which gives those failures their reasons."""
        fresh = self._prior_angles is not None
        if fresh:
            prior = self._prior_angles
        elif self._state is not None and 0 <= time_s - self._state[0] <= JUMP_AGE_S:
            # Carried on at the eye's last measured velocity: across the bands between two
            # frames' glints (~11 ms in paper_sim) a saccade moves the eye by degrees.
            t0, prior = self._state[:2]
            if self._velocity is not None:
                prior = prior + self._velocity * (time_s - t0)
        else:
            return None
        got = self.follower.follow(g, rows, prior, prior_term=fresh)
        if got is None and not fresh and self._velocity is not None:
            # The velocity of two bands 1 ms apart carries their estimation noise (tens of
            # deg/s in a fixation, degrees over the ~11 ms to the next frame's glints): the
            # last sample's own rotation, unextrapolated, is the second try.
            got = self.follower.follow(g, rows, self._state[1], prior_term=False)
        if got is None:
            return None
        match, orbit = got.match, got.fit
        used = match.matched
        lights = match.light_index[used]
        if self.calibration.conic:
            # The follower identifies on the sphere; the conic's estimate comes from the
            # batched fits of estimator.gaze, which know the cornea model.
            glints = self._glints(g[used], lights)
            if self.method == "polynomial":
                start = match.cornea_center_m if self._start is None else self._start
                est = polynomial_gaze(self.setup, self.calibration, glints, mapping=self.mapping,
                                      start=start, problems=self._problems)
            else:
                est = geometric_gaze(self.setup, self.calibration, glints, start=orbit.x,
                                     problems=self._problems)
            if self._reason(est) != "ok":
                return None
            xy, center = est.screen_xy_m[0], est.cornea_center_m[0]
            rms, resume = float(est.rms_px[0]), est.resume_from
        elif self.method == "polynomial":  # the free centre by the compiled small fit
            quick = searched_estimate(self._problems, "polynomial", g[used], lights, self._start,
                                      match.cornea_center_m, self.follower.arrays,
                                      self._gaze_point, MAX_RESIDUAL_PX)
            if quick is None:
                return None
            xy, center, rms, resume = quick
        else:
            center, rms, resume = match.cornea_center_m, orbit.rms_px, orbit.x
            xy = self._gaze_point(center, orbit.x)
        if not (np.isfinite(xy).all() and rms <= MAX_RESIDUAL_PX) or \
                self._implausible(time_s, match.angles_rad):
            return None
        self._prior_angles = match.angles_rad
        self._start = resume.copy()
        JtJ = orbit.JtJ
        inv = inverse_2x2(JtJ)
        cov = self.prior.noise_px ** 2 * inv if inv is not None else np.full((2, 2), np.inf)
        self._set_state(time_s, match.angles_rad, cov)
        return GazeSample(f, j, time_s, xy.copy(), center.copy(),
                          g[used], lights, float(rms), "ok", match.confidence[used].copy())

    def _assisted(self, f, j, time_s, g, rows, failed: GazeSample) -> GazeSample:
        """A sparse band (or one whose identification failed) with the previous sample's
        estimate as prior (:func:`estimator.assisted.assisted_sample`)."""
        return assisted_sample(self, f, j, time_s, g, rows, failed, max_residual_px=MAX_RESIDUAL_PX)

    def _gaze_point(self, center_m, angles_rad) -> np.ndarray:
        """The screen point (2,) of one estimate: the mapping of its cornea centre
        (polynomial), or where its optical axis from the calibrated eye centre meets the
        screen (geometric; NaN where it does not)."""
        if self.method == "polynomial":
            return np.array(self._map.predict_one(center_m))
        point, hits = screen_intersection(self.calibration.eye_center_m,
                                          gaze_direction(angles_rad[0], angles_rad[1])[None],
                                          self.setup.screen.z_m)
        return point[0, :2] if hits[0] else np.full(2, np.nan)

    def _set_state(self, time_s: float, angles_rad, cov) -> None:
        """Keep a sample's time, rotation and covariance (the prior of the next bands), and the
        eye's velocity where the sample before it is at most :data:`VELOCITY_AGE_S` older."""
        angles = np.array(angles_rad, dtype=np.float64)
        self._velocity = None
        if self._state is not None and 0 < time_s - self._state[0] <= VELOCITY_AGE_S:
            self._velocity = (angles - self._state[1]) / (time_s - self._state[0])
        self._state = (time_s, angles, cov)

    def _recent(self, time_s: float):
        """(mean, covariance, age, reach) of the previous sample where it is at most
        :data:`JUMP_AGE_S` old (reach: the furthest the eye turns since, v_max √2 Δt plus
        :data:`JUMP_SLACK_DEG`, rad), else None."""
        if self._state is None or self.prior is None:
            return None
        t0, mean, cov = self._state
        dt = time_s - t0
        if not 0 <= dt <= JUMP_AGE_S:
            return None
        reach = math.radians(self.prior.eye_speed_max_deg_s * math.sqrt(2.0) * dt + JUMP_SLACK_DEG)
        return mean, cov, dt, reach

    def _implausible(self, time_s: float, angles_rad) -> bool:
        """Whether the eye rotation ``angles_rad`` is further from the previous sample's than
        the eye turns in the time between them (see :data:`JUMP_AGE_S`)."""
        recent = self._recent(time_s)
        return recent is not None and math.hypot(float(angles_rad[0] - recent[0][0]),
                                                 float(angles_rad[1] - recent[0][1])) > recent[3]

    def _unfillable(self, time_s: float, rows, g) -> bool:
        """Whether no eye rotation :meth:`_implausible` accepts can have :data:`MIN_GLINTS` of
        the band's detections g matched (:data:`OUT_OF_REACH`)."""
        recent = self._recent(time_s)
        return recent is not None and \
            self.matcher.band_support(rows, recent[0], recent[3], g) < MIN_GLINTS

    def _glints(self, glints_px, lights) -> np.ndarray:
        out = np.full((1, self.n_lights, 2), np.nan)
        out[0, lights] = glints_px
        return out

    @staticmethod
    def _reason(est) -> str:
        reason = str(est.reason[0])
        if reason == "ok" and not est.rms_px[0] <= MAX_RESIDUAL_PX:
            reason = RESIDUAL_TOO_LARGE
        return reason
