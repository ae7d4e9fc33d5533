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
   in between is NaN (``implausible_jump``): clutter matched to a chain of lights.
5. Sparse bands (fewer than :data:`~estimator.tracking.MIN_GLINTS` glints, or whose identification failed) borrow
   from the previous sample when it is recent (:class:`~estimator.tracking.BandPrior`): its eye rotation, with a
   covariance grown by the motion model, is a Gaussian prior for identifying the few glints
   (:meth:`estimator.matching.GlintMatcher.match_near`) and for the orbit fit, which one glint
   then determines (the "ours + prior" rows of ``reports/paper-reproduction.md``). Such samples
   carry ``prior_assisted=True``. A band without any glint stays NaN: no sample is invented.

Each sample carries the strobe instant s_j + Δs / 2 of its pulse (Sec. 2.3 of the SCET paper:
the time of a band is its pulse's, not the frame's), shifted by the frame's measured start
when a timing sidecar gives one. A sample that cannot be estimated is NaN with a reason code;
any exception raised inside a frame becomes NaN samples with a reason and a log record: the
stream never stops half way.

The band steps themselves are :mod:`estimator.tracking.bands`; the stream's state between
bands is one immutable :class:`~estimator.tracking.StreamState`, which :attr:`Tracker.state`
holds. Folders of frames (rendered datasets, prototype captures) are read and tracked by
:mod:`estimator.folders`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

from ..banding import band_rows, strobe_instant
from ..calibration import Calibration
from ..gaze import calibrated_problems
from ..eye import EYE_SPEED_MAX_DEG_S
from ..glints import (NO_BAND, STRIP_PAD_PX, DetectionParams, GlintDetector, glint_px_per_deg,
                      undistort_points_px)
from ..lens import ideal_setup
from ..matching import BandFollower, FollowParams, GlintMatcher, MatchParams
from ..reasons import Reason, flux_cut_failure, internal_error
from ..setup import Setup
from .bands import band_sample
from .context import METHODS, MIN_GLINTS, BandContext
from .cut_glints import flagged, kept_detections
from .samples import BandPrior, GazeSample, failed_sample
from .state import JUMP_SLACK_DEG, StreamState

__all__ = ["Tracker", "SATURATED_FRAME_SHARE"]

log = logging.getLogger(__name__)

#: A frame with more than this share of its pixels at full scale is not an eye image the
#: detector can read (a lamp in view, a failed exposure): its samples fail with
#: ``saturated_frame`` rather than with whatever the clutter makes of them.
SATURATED_FRAME_SHARE = 0.25


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
        first band, after a sample older than :data:`~estimator.tracking.JUMP_AGE_S`, and
        wherever its checks fail. ``False`` runs the search on every band (the reference it is
        compared with). Needs the calibration's eye centre and orbit radius and the
        ``"orbit"`` model.
    flag_cut_glints : bool or None
        Drop glints whose flux says a lash cuts them and do the band again without them
        (:meth:`band`, :mod:`estimator.tracking.cut_glints`; docs/guide/rendering.md, "Moving lids, blinks and
        lashes"). It needs the calibration's ``glint_flux`` for the rig's lights: ``True``
        refuses a calibration without it, ``None`` (the default) flags where the calibration
        has it (a calibration from images, spherical or conic), ``False`` never flags.
    focus_detection : bool
        Search each frame for glints only around the glints its last frame's accepted samples
        used and those predicted at the last eye rotation (:meth:`focus_points`,
        :class:`estimator.glints.GlintDetector` ``focus``), grown by how far a glint moves
        while the eye turns by the plausibility check's reach over one frame period; a
        whole-frame search every 30 frames, after a frame without an accepted sample or a
        dropped one, and where the window holds nothing. With its fallback
        (:meth:`focused_bands`, :attr:`focus_fallback`): a band where the last sample expects
        glints beyond the window's edge, or that has no recent sample to bound the eye,
        takes its rows' detections across the whole width. Clutter far from the eye is not
        detected. Off by default: bands of clutter alone then fail as
        ``match_too_few_glints`` rather than ``band_out_of_reach`` or
        ``prior_no_hypothesis``; the accepted samples were the whole frame's (same bands and
        lights, estimates within 1.3e-8 m on the screen: the window's centroids differ in the
        last bits) on every rendered dataset measured (``benchmarks/bench_focus.py``,
        ``docs/results/benchmarks.md``, issue 31's fifth pass).

    Attributes
    ----------
    context : BandContext
        What every band step shares (setup, calibration, fit problems, matcher, follower). Its
        setup's camera is the ideal pinhole of the given one (:func:`estimator.lens.ideal_setup`):
        detections are undistorted through :attr:`lens_camera` before anything else sees them.
    lens_camera : Camera
        The given setup's camera, lens distortion included.
    state : StreamState
        The stream's state after the last band (immutable; each band step returns the next).
    detector : GlintDetector
    flags_cut_glints : bool
        Whether bands are checked for glints cut by a lash.
    last_frame_index : int or None
        The last frame taken.
    counts : dict
        Dense bands identified by the cheap path ("cheap"), by the hypothesis search
        ("search"), left to the prior unsearched ("unfillable"); bands done again without cut
        glints ("again").
    focus_fallback : bool
        With ``focus_detection``: whether the fallback runs (True; False measures the window
        alone, ``benchmarks/bench_focus.py``).
    refocused : int
        Bands that took their strip's detections (the fallback).
    """

    def __init__(self, setup: Setup, calibration: Calibration, method: str = "polynomial", *,
                 mapping: str = "eq1_25", detection: DetectionParams = DetectionParams(),
                 matching: MatchParams = MatchParams(), prior: BandPrior | None = BandPrior(),
                 cheap: bool = True, flag_cut_glints: bool | None = None,
                 focus_detection: bool = False):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        if not isinstance(calibration, Calibration):
            raise ValueError(f"calibration must be a Calibration, got {type(calibration).__name__}")
        if method == "geometric" and not calibration.has_orbit:
            raise ValueError("geometric gaze needs a calibration with the eye centre and orbit")
        if method == "polynomial" and mapping not in calibration.mappings:
            raise ValueError(f"the calibration has no mapping {mapping!r} "
                             f"(has {sorted(calibration.mappings)})")
        fluxed = calibration.flags_cut_glints(setup.lights.count)
        if flag_cut_glints and not fluxed:
            raise ValueError(f"flag_cut_glints needs a calibration with glint_flux for the "
                             f"{setup.lights.count} lights (recalibrate)")
        self.flags_cut_glints = fluxed if flag_cut_glints is None else bool(flag_cut_glints)
        # A camera with lens distortion: detections are undistorted (process) and everything
        # after them works in the ideal pinhole image of the same intrinsics.
        self.lens_camera = setup.camera
        setup = ideal_setup(setup)
        # Detection reuses the sensor's noise model from frame to frame (measured again every
        # 30 frames, on a 5 % level drift, and after every reset of the stream).
        # Focused: the window's margin is how far a glint moves while the eye turns by the
        # plausibility check's reach over one frame period (expects_glints' bound), so a band
        # of the next frame finds its glints inside it.
        margin = None
        if focus_detection:
            speed = EYE_SPEED_MAX_DEG_S if prior is None else prior.eye_speed_max_deg_s
            turn = speed * math.sqrt(2.0) * setup.sensor.frame_period_s + JUMP_SLACK_DEG
            margin = math.ceil(glint_px_per_deg(setup) * turn) + STRIP_PAD_PX
        self.detector = GlintDetector(setup, detection, focus=focus_detection,
                                      roi_margin_px=margin)
        # Glints predicted from the calibrated geometry, not the nominal one: the lighting pose
        # of the prototype is off by millimetres (a pixel or more per glint). One set of
        # calibrated fit problems for the stream: the matcher's orbit fits and the gaze fits of
        # every band use them.
        problems = calibrated_problems(setup, calibration)
        matcher = GlintMatcher(setup, matching, calibration=calibration, problem=problems.orbit)
        prior = prior if calibration.has_orbit and matching.model == "orbit" else None
        gaze_map = None if method == "geometric" else calibration.mappings[mapping]
        follower = None
        if cheap and prior is not None and (gaze_map is None or gaze_map.n_features == 3):
            follower = BandFollower(matcher, FollowParams(min_matches=MIN_GLINTS))
        self.context = BandContext(setup, calibration, method, mapping, gaze_map, problems,
                                   matcher, follower, prior).with_kernel()
        self.counts = {"cheap": 0, "search": 0, "unfillable": 0, "again": 0}
        #: The last frame index taken (a frame not after it is ``frame_out_of_order``).
        self.last_frame_index: int | None = None
        self.focus_fallback = True
        self.refocused = 0
        self._predicted = (None, None, None)  # (last estimate, u, v) of expects_glints
        self._focus_angles = None  # the rotation focus_points predicted the window's glints at
        self.reset()

    # The context's parts under their old names (read-only).
    setup = property(lambda self: self.context.setup)
    calibration = property(lambda self: self.context.calibration)
    method = property(lambda self: self.context.method)
    mapping = property(lambda self: self.context.mapping)
    matcher = property(lambda self: self.context.matcher)
    follower = property(lambda self: self.context.follower)
    prior = property(lambda self: self.context.prior)

    def reset(self) -> None:
        """Forget the previous sample (the next band is matched cold, and has no prior) and the
        noise model (a frame that failed as a whole often means the exposure changed)."""
        self.state = StreamState()
        self.detector.reset()

    def process(self, frame, frame_index: int, frame_start_s: float | None = None
                ) -> list[GazeSample]:
        """Samples of one frame: one per band the strobe lights visible rows of.

        Parameters
        ----------
        frame : (H, W) uint8, uint16 or float
            Sensor output (DN). ``None`` or an array of the wrong shape gives NaN samples
            (``unreadable_frame``, ``wrong_frame_size``).
        frame_index : int
            Frames come in increasing order; gaps (dropped frames) are fine, the prior ages
            over them. A frame not after the last one taken gives NaN samples
            (``frame_out_of_order``) and leaves the stream as it was.
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
        if self.last_frame_index is not None and frame_index <= self.last_frame_index:
            # The stream's state is the newer frame's: an older one cannot be followed from
            # it (its bands would precede the prior), nor may it undo it.
            log.warning("frame %d after frame %d: out of order, its samples are NaN (%s)",
                        frame_index, self.last_frame_index, Reason.FRAME_OUT_OF_ORDER)
            return [failed_sample(frame_index, j, t, Reason.FRAME_OUT_OF_ORDER)
                    for (j, _), t in zip(bands, times)]
        dropped = self.last_frame_index is not None and frame_index > self.last_frame_index + 1
        self.last_frame_index = frame_index
        if dropped:
            # The focused window allows for one frame of eye motion: after a gap the whole
            # frame is searched.
            self.detector.focus_on(None)
        try:
            reason = self.frame_check(frame)
            if reason is not None:
                self.reset()
                return [failed_sample(frame_index, j, t, reason) for (j, _), t in zip(bands, times)]
            det = self.detector(frame, frame_index)
            # The one place detections enter the tracker's geometry (group): those a band lit,
            # through the lens into the ideal pinhole image (a pinhole camera passes them on
            # untouched).
            spans, glints, flux = self.group(det, bands, self.lens_camera)
            flag = self.flags_cut_glints
            samples = [self.band(frame_index, glints[a:b], band, t, flux[a:b] if flag else None)
                       for (a, b), band, t in zip(spans, bands, times)] \
                if self.detector.window is None or not self.detector.focus else \
                self.focused_bands(frame_index, spans, glints, flux, bands, times)
            if self.detector.focus:
                self.detector.focus_on(self.focus_points(samples))
            return samples
        except Exception as exc:  # the stream must survive any one frame; the reason is logged
            # A bug, not bad input: logged with its traceback, counted by the run's summary.
            log.error("frame %d: internal error %s: %s; its samples are NaN (%s)", frame_index,
                      type(exc).__name__, exc, Reason.INTERNAL_ERROR, exc_info=True)
            self.reset()
            return [failed_sample(frame_index, j, t, internal_error(exc))
                    for (j, _), t in zip(bands, times)]

    def focused_bands(self, f: int, spans, glints, flux, bands, times) -> list[GazeSample]:
        """The samples of frame f from the detections of a focused window (grouped:
        ``spans``, ``glints``, ``flux`` as :meth:`group` gives them), with the fallback: a band
        where the last sample expects glints beyond the window's edge (:meth:`expects_glints`,
        decided from the stream's state before the band) takes instead its rows' detections
        across the frame's whole width (:meth:`GlintDetector.rows_of
        <estimator.glints.GlintDetector.rows_of>`: the whole frame's detections of the band):
        a band whose glints the window cut might otherwise fail, or be accepted
        prior-assisted from the few left; :attr:`refocused` counts those bands."""
        flag, samples = self.flags_cut_glints, []
        for (a, b), band, t in zip(spans, bands, times):
            g, w = glints, flux
            if self.focus_fallback and self.expects_glints(self.state, band, t):
                strip, g, w = self.group(self.detector.rows_of(*band[1]), [band],
                                         self.lens_camera)
                (a, b), = strip  # the band's strobe of the strip's detections
                self.refocused += 1
            samples.append(self.band(f, g[a:b], band, t, w[a:b] if flag else None))
        return samples

    def expects_glints(self, state: StreamState, band, time_s: float) -> bool:
        """Whether a focused band (pulse j, (first row, last row)) at ``time_s`` may hold
        glints the window (:attr:`GlintDetector.window <estimator.glints.GlintDetector>`)
        left out: the stream has no sample recent enough to bound the eye
        (:meth:`BandContext.recent <estimator.tracking.BandContext.recent>`), or a visible
        light's glint predicted at the last sample's rotation comes within reach of the
        band's rows and there within reach of the window's edge. Reach: as far as a glint
        moves while the eye turns by that sample's reach (the detector's ``px_per_deg`` times
        the furthest the eye turns since, with the plausibility check's slack), plus a glint's
        radius (:data:`STRIP_PAD_PX`). Where the last rotation is close enough to the one
        the window's glints were predicted at (:meth:`focus_points`) that the window's margin
        holds that reach, the answer is no without a prediction (a light that comes into view
        since, away from the others, is then not looked for: it waits, as in the plain
        window, for the next whole-frame search)."""
        recent = self.context.recent(state, time_s)
        if recent is None or self.follower is None:
            return True
        m = self.detector.px_per_deg * math.degrees(recent[3]) + STRIP_PAD_PX
        r0 = self._focus_angles
        if r0 is not None and self.detector.px_per_deg * math.degrees(math.hypot(
                recent[0][0] - r0[0], recent[0][1] - r0[1])) + m <= self.detector.roi_margin_px:
            # The window holds every glint predicted at r0 grown by its margin: those at the
            # last rotation lie within px_per_deg |r - r0| of them (no prediction needed).
            return False
        if self._predicted[0] is not state.last:  # one prediction per accepted sample
            pred, visible = self.follower.predict(recent[0])
            pred = self.lens_camera.distort_px(pred[visible])  # the window's (raw) pixels
            self._predicted = (state.last, pred[:, 0], pred[:, 1])
        u, v = self._predicted[1], self._predicted[2]
        (first, last), (y0, y1, x0, x1) = band[1], self.detector.window
        cam = self.setup.camera  # a window's side on the frame's border holds all beyond it
        x0, y0 = (x0 if x0 > 0 else -math.inf), (y0 if y0 > 0 else -math.inf)
        x1 = x1 - 1 if x1 < cam.width_px else math.inf
        y1 = y1 - 1 if y1 < cam.height_px else math.inf
        near = (v >= first - m) & (v <= last + m)
        inside = (u - m >= x0) & (u + m <= x1) & (v - m >= y0) & (v + m <= y1)
        return bool(np.any(near & ~inside))

    def focus_points(self, samples) -> np.ndarray | None:
        """Where the next frame's glints are sought with ``focus_detection`` (k, 2, the
        frame's pixels through the lens): the detections the accepted ``samples`` of this
        frame used, and every visible light's glint predicted at the stream's last eye rotation
        (a light that comes into view next to the others); None without an accepted sample
        (the next frame is searched whole)."""
        used = [s.glints_px for s in samples if s.ok]
        if not used:
            return None
        last = self.state.last
        self._focus_angles = None
        if self.follower is not None and last is not None:
            pred, visible = self.follower.predict(last.angles_rad)
            used.append(pred[visible & np.isfinite(pred).all(axis=1)])
            self._focus_angles = last.angles_rad
        # The samples' glints and the predictions are ideal (pinhole) pixels; the detector's
        # window is in the frame's own, through the lens (the identity for a pinhole).
        return self.lens_camera.distort_px(np.concatenate(used))

    @staticmethod
    def group(det, bands, camera=None) -> tuple[list, np.ndarray, np.ndarray]:
        """The detections ``det`` of a frame that a band lit (those flagged ``NO_BAND`` left
        out), grouped by strobe once for all its ``bands`` ([(pulse j, rows)]): ([(start,
        stop)] of each band's rows in the glints and fluxes, glints (m, 2), fluxes (m,)), the
        detections in the order of their strobes, each strobe's in the detector's order (a
        stable sort: each band's slice is the rows ``glints_px[strobe_index == j]`` of the
        frame's detections). With a ``camera`` whose lens distorts, the glints are
        :meth:`~estimator.glints.GlintDetections.undistorted` through it (before the sort,
        as that method does on the kept detections). The same arrays as
        ``det.select(~det.has(NO_BAND)).undistorted(camera)`` grouped, without the
        intermediate detections (8 arrays and a dataclass a frame)."""
        keep = np.flatnonzero((det.flags & NO_BAND) == 0)
        u, v = det.u_px[keep], det.v_px[keep]
        if camera is not None and camera.has_distortion and keep.size:
            uv = undistort_points_px(camera, np.stack([u, v], axis=-1))
            u, v = uv[:, 0], uv[:, 1]
        strobes = det.strobe_index[keep]
        order = np.argsort(strobes, kind="stable")
        ranked = strobes[order]
        pulses = np.fromiter((b[0] for b in bands), dtype=np.int64, count=len(bands))
        lo = np.searchsorted(ranked, pulses, side="left").tolist()
        hi = np.searchsorted(ranked, pulses, side="right").tolist()
        glints = np.stack([u, v], axis=-1)[order]
        return list(zip(lo, hi)), glints, det.intensity[keep][order]

    def frame_check(self, frame) -> str | None:
        """Why ``frame`` cannot be tracked (a :class:`~estimator.reasons.Reason`), or None."""
        if frame is None:
            return Reason.UNREADABLE_FRAME
        a = np.asarray(frame)
        if a.shape != (self.setup.camera.height_px, self.setup.camera.width_px):
            return Reason.WRONG_FRAME_SIZE
        full = 255 if a.dtype == np.uint8 else 2 ** self.setup.sensor.bit_depth - 1
        # The maximum first: a frame without a full-scale pixel (the common case) is not counted.
        if a.max() >= full and np.count_nonzero(a >= full) > SATURATED_FRAME_SHARE * a.size:
            return Reason.SATURATED_FRAME
        return None

    def band(self, f: int, g, band, time_s: float, flux=None) -> GazeSample:
        """Sample of a band of frame f from its detections g (k, 2); band (pulse, (first row,
        last row)); advances :attr:`state`. With the detections' flux (k,) (where cut glints
        are flagged) a band with a flagged glint is done again, from the stream's state before
        it with the first pass's rotation as the prior of its identification, without the
        flagged detections (:func:`estimator.tracking.cut_glints.flagged`; the sample records
        their lights in ``flux_flagged``, a failure's reason is prefixed
        ``flux_cut_glints_``)."""
        before = self.state
        if flux is None:
            sample, self.state = band_sample(self.context, before, f, g, band, time_s,
                                             self.counts)
            return sample
        counts = dict(self.counts)
        sample, after = band_sample(self.context, before, f, g, band, time_s, self.counts)
        self.state = after
        if not sample.ok:
            return sample
        ctx = self.context
        bad = flagged(ctx.calibration, ctx.setup.camera, ctx.problems.center.lights_world_m,
                      sample, g, flux, ctx.matcher.arrays)
        if not bad.any():
            return sample
        # The first pass's rotation seeds the second (the cheap path then identifies the band
        # from it instead of searching again); the rest of the state is the one before the band.
        if after.prior_angles_rad is not None:
            before = replace(before, prior_angles_rad=after.prior_angles_rad)
        self.counts.clear()
        self.counts.update(counts)  # the band counts once, by the path of its second pass
        self.counts["again"] += 1
        return self.without(f, g, band, time_s, sample, bad, before)

    def without(self, f: int, g, band, time_s: float, sample: GazeSample, bad,
                state: StreamState) -> GazeSample:
        """The band of ``sample`` done again from ``state`` without its glints ``bad`` (k,)
        bool; advances :attr:`state`."""
        kept = g[kept_detections(g, sample.glints_px[bad])]
        again, self.state = band_sample(self.context, state, f, kept, band, time_s, self.counts)
        lights = sample.light_index[bad]
        if again.ok:
            return replace(again, flux_flagged=lights)
        return replace(again, reason=flux_cut_failure(again.reason), flux_flagged=lights)
