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
   (:func:`estimator.gaze.polynomial_gaze` or :func:`estimator.gaze.geometric_gaze`).
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

Folders (rendered datasets, or prototype captures)::

    frames/NNNNNN.png   sensor output (8- or 16-bit grey), NNNNNN the frame index
    timing.json         {"format": "scet-timing", "version": 1,
                         "frames": {"<index>": <frame start t0_f, s>, ...},
                         optional "exposure_s" and "strobe" {pulses_per_frame, pulse_s,
                         period_s, phase_s}: the timing the frames were taken with, when it
                         differs from the scene's (single-pulse calibration frames)}
    manifest.json       a rendered dataset: without timing.json, t0_f = f Δt for its frames
    labels.jsonl        calibration folders: the fixated ``target_m`` of each frame

:func:`calibrate_from_folder` turns a folder of single-pulse calibration frames (every row lit
by the same pulse, i.e. the same instant) into a :class:`~estimator.calibration.Calibration`;
:func:`track_folder` writes ``samples.csv`` (format ``scet-samples``, version 2: version 1
plus the ``prior`` column) atomically; :func:`read_samples_csv` reads both versions.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import os
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from .banding import band_layout
from .calibration import Calibration, calibrate_joint
from .cornea import fit_covariance
from .gaze import (fit_cornea_centers, geometric_gaze, orbit_problem, polynomial_gaze,
                   posterior_covariance)
from .glints import NO_BAND, DetectionParams, GlintDetections, GlintDetector, detect_glints
from .mapping import fit_gaze_mapping
from .matching import GlintMatcher, MatchParams
from .setup import Setup

log = logging.getLogger(__name__)

TIMING_FORMAT, TIMING_VERSION = "scet-timing", 1
SAMPLES_FORMAT, SAMPLES_VERSION = "scet-samples", 2
#: Versions :func:`read_samples_csv` reads (version 1 has no ``prior`` column).
SAMPLES_READABLE = (1, 2)
TIMING_NAME, MANIFEST_NAME, LABELS_NAME, FRAMES_DIR = (
    "timing.json", "manifest.json", "labels.jsonl", "frames")
METHODS = ("polynomial", "geometric")

#: Reason codes of a :class:`GazeSample` beyond those of :mod:`estimator.gaze` ("ok",
#: "too_few_glints", "not_converged", "non_finite", "misses_screen") and of the matcher,
#: which are prefixed "match_" ("match_too_few_glints", "match_ambiguous", ...).
UNREADABLE_FRAME = "unreadable_frame"
WRONG_FRAME_SIZE = "wrong_frame_size"
SATURATED_FRAME = "saturated_frame"
MISSING_FRAME = "missing_frame"
INTERNAL_ERROR = "internal_error"
RESIDUAL_TOO_LARGE = "residual_too_large"
#: Prefix of the reason of a sparse band whose prior-assisted estimate failed too (e.g.
#: "prior_ambiguous", "prior_residual_too_large"): a prior was there, it did not suffice.
PRIOR_PREFIX = "prior_"

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

_FRAME_NAME = re.compile(r"^(\d+)\.png$")


@dataclass(frozen=True, slots=True)
class BandPrior:
    """Motion model of the prior a sparse band borrows from the previous sample.

    The previous sample's Fick angles θ_k (covariance Σ_k: its fit's, σ² (JᵀJ)⁻¹, or the
    posterior of its own prior-assisted fit) predict the eye rotation at time t as a Gaussian of
    mean θ_k and covariance Σ_k + (v_max (t - t_k))² I: the eye may have turned at up to
    ``eye_speed_max_deg_s`` on each axis since. The speed bound enters as one SD, so a saccade
    at full speed costs 1 in the squared Mahalanobis distance: the prior does not pull it back,
    it only tells identities apart (at 16 pulses per frame, 1.04 ms between bands, SD 0.62°,
    against the ~2° between neighbouring glints of an arc in ``paper_sim``).

    Attributes
    ----------
    eye_speed_max_deg_s : float
        Per-axis eye speed bound. Saccade peak speeds follow the main sequence up to ~500°/s
        (Baloh et al. 1975, the asymptote :mod:`scet_render.motion` renders) and reach
        600-700°/s in large saccades; 600°/s covers them.
    max_sd_deg : float
        A prior whose SD (largest axis) exceeds this is not used. The wider the prior, the
        likelier a sparse band's chain shifted by one light (~2° away) or a blob passes for the
        right identities: measured on 150 simulated bands of 1-3 glints with clutter
        (paper_sim), 99.6 % of the claimed identities were right at 0.62° SD, 98.5 % at 0.8°,
        97 % at 1.25°. In practice this is the prior's age limit: 1.25 ms at 600°/s, one band
        period at 16 pulses per frame (1.04 ms), not at 8 (2.08 ms).
    noise_px : float
        Glint noise σ (px per axis) that weighs the prior against the glints and sizes the
        samples' covariances: the matcher's (the upper end of the detector's error), which
        errs on the side of a wider posterior.
    """

    eye_speed_max_deg_s: float = 600.0
    max_sd_deg: float = 0.75
    noise_px: float = 0.5

    def __post_init__(self):
        for name in ("eye_speed_max_deg_s", "max_sd_deg", "noise_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"BandPrior.{name} must be positive, got {getattr(self, name)!r}")

    def predict(self, cov_rad2, elapsed_s: float):
        """Covariance (2, 2) rad² after ``elapsed_s``, or None when its SD exceeds the limit."""
        if not elapsed_s >= 0:
            return None
        grown = np.asarray(cov_rad2) + (math.radians(self.eye_speed_max_deg_s) * elapsed_s) ** 2 * np.eye(2)
        if not np.isfinite(grown).all() or np.linalg.eigvalsh(grown)[-1] > math.radians(self.max_sd_deg) ** 2:
            return None
        return grown


class TrackerInputError(ValueError):
    """A tracker input file (timing sidecar, calibration, frames folder) is missing or
    malformed; the message names the file (and key)."""


@dataclass(frozen=True, slots=True)
class GazeSample:
    """One gaze sample: one strobe pulse (one band) of one frame.

    Attributes
    ----------
    frame_index, strobe_index : int
    time_s : float
        Strobe instant s_j + Δs / 2 (s), on the sequence clock.
    screen_xy_m : (2,) float
        Gaze point on the screen plane (NaN when failed).
    cornea_center_m : (3,) float
    glints_px : (k, 2) float
        The band's detections that were identified and used.
    light_index : (k,) int
        Their lights.
    confidence : (k,) float
        The matcher's confidence in each identity (:class:`estimator.matching.GlintMatch`).
    residual_px : float
        RMS residual of the cornea fit (NaN when failed).
    reason : str
        "ok" or why the sample is NaN.
    prior_assisted : bool
        The band borrowed the previous sample's estimate as a prior (:class:`BandPrior`): its
        few glints were identified and fitted with it.
    """

    frame_index: int
    strobe_index: int
    time_s: float
    screen_xy_m: np.ndarray
    cornea_center_m: np.ndarray
    glints_px: np.ndarray
    light_index: np.ndarray
    residual_px: float
    reason: str
    confidence: np.ndarray
    prior_assisted: bool = False

    @property
    def ok(self) -> bool:
        return self.reason == "ok"

    @property
    def n_glints(self) -> int:
        return int(self.light_index.shape[0])


def _failed(frame_index: int, strobe_index: int, time_s: float, reason: str,
            glints_px=None, light_index=None) -> GazeSample:
    g = np.zeros((0, 2)) if glints_px is None else np.asarray(glints_px, dtype=np.float64)
    li = np.zeros(0, dtype=np.int64) if light_index is None else np.asarray(light_index, np.int64)
    return GazeSample(frame_index, strobe_index, time_s, np.full(2, np.nan), np.full(3, np.nan),
                      g, li, float("nan"), reason, np.zeros(li.shape[0]))


# --------------------------------------------------------------------------- the stream


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
    """

    def __init__(self, setup: Setup, calibration: Calibration, method: str = "polynomial", *,
                 mapping: str = "eq1_25", detection: DetectionParams = DetectionParams(),
                 matching: MatchParams = MatchParams(), prior: BandPrior | None = BandPrior()):
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
        # Detection reuses the sensor's noise model from frame to frame (measured again every
        # 30 frames, on a 5 % level drift, and after every reset of the stream).
        self._detector = GlintDetector(setup, detection)
        # Glints predicted from the calibrated geometry, not the nominal one: the lighting pose
        # of the prototype is off by millimetres (a pixel or more per glint).
        self.matcher = GlintMatcher(setup, matching, calibration=calibration)
        self.n_lights = setup.lights.count
        self.prior = prior if calibration.has_orbit and matching.model == "orbit" else None
        self._orbit = orbit_problem(setup, calibration) if self.prior is not None else None
        self.reset()

    def reset(self) -> None:
        """Forget the previous sample (the next band is matched cold, and has no prior) and the
        noise model (a frame that failed as a whole often means the exposure changed)."""
        self._lose()
        self._state = None
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
        bands = [b for b in band_layout(sensor, strobe, frame_index) if b.visible]
        times = [b.strobe_time_s + 0.5 * strobe.pulse_s + shift for b in bands]
        try:
            reason = self._check(frame)
            if reason is not None:
                self.reset()
                return [_failed(frame_index, b.pulse_index, t, reason) for b, t in zip(bands, times)]
            det = self._detector(frame, frame_index)
            det = det.select(~det.has(NO_BAND))
            return [self._band(det, b, t) for b, t in zip(bands, times)]
        except Exception as exc:  # the stream must survive any one frame; the reason is logged
            log.warning("frame %d: %s: %s", frame_index, type(exc).__name__, exc)
            self.reset()
            return [_failed(frame_index, b.pulse_index, t, f"{INTERNAL_ERROR}:{type(exc).__name__}")
                    for b, t in zip(bands, times)]

    def _check(self, frame) -> str | None:
        if frame is None:
            return UNREADABLE_FRAME
        a = np.asarray(frame)
        if a.shape != (self.setup.camera.height_px, self.setup.camera.width_px):
            return WRONG_FRAME_SIZE
        full = 255 if a.dtype == np.uint8 else 2 ** self.setup.sensor.bit_depth - 1
        if np.count_nonzero(a >= full) > SATURATED_FRAME_SHARE * a.size:
            return SATURATED_FRAME
        return None

    def _band(self, det: GlintDetections, band, time_s: float) -> GazeSample:
        f, j = det.frame_index, band.pulse_index
        g = det.of_strobe(j).glints_px
        rows = (band.first_row, band.last_row)
        if g.shape[0] < MIN_GLINTS:
            sample = _failed(f, j, time_s, "match_too_few_glints", g)
        else:
            sample = self._dense(f, j, time_s, g, rows)
            if sample.ok or sample.reason not in _IDENTITY_FAILURES:
                return self._keep(sample)
        self._lose()
        return self._keep(self._assisted(f, j, time_s, g, rows, sample))

    def _keep(self, sample: GazeSample) -> GazeSample:
        if not sample.ok:
            self._lose()
        return sample

    def _dense(self, f, j, time_s, g, rows) -> GazeSample:
        """A band with enough glints, identified and fitted on its own."""
        match = self.matcher.match(g, rows=rows, prior_angles_rad=self._prior_angles)
        if not match.ok:
            return _failed(f, j, time_s, f"match_{match.reason}", g)
        used = match.matched
        lights = match.light_index[used]
        if lights.size < MIN_GLINTS:
            return _failed(f, j, time_s, "too_few_glints", g[used], lights)
        glints = self._glints(g[used], lights)
        if self.method == "polynomial":
            est = polynomial_gaze(self.setup, self.calibration, glints, mapping=self.mapping,
                                  start=self._start)
        else:
            est = geometric_gaze(self.setup, self.calibration, glints,
                                 start=(0.0, 0.0) if self._start is None else self._start)
        reason = self._reason(est)
        if reason != "ok":
            return _failed(f, j, time_s, reason, g[used], lights)
        self._prior_angles = match.angles_rad
        self._start = est.resume_from
        if self._orbit is not None:
            mask = np.isfinite(glints[..., 0])
            cov = fit_covariance(self._orbit, match.angles_rad, mask, model="orbit",
                                 noise_px=self.prior.noise_px)[0]
            self._state = (time_s, match.angles_rad.copy(), cov)
        return GazeSample(f, j, time_s, est.screen_xy_m[0].copy(), est.cornea_center_m[0].copy(),
                          g[used], lights, float(est.rms_px[0]), "ok",
                          match.confidence[used].copy())

    def _assisted(self, f, j, time_s, g, rows, failed: GazeSample) -> GazeSample:
        """A sparse band (or one whose identification failed) with the previous sample's
        estimate as prior; ``failed`` when there is no usable prior or no glint."""
        if self._state is None or g.shape[0] == 0:
            return failed
        t0, mean, cov0 = self._state
        cov = self.prior.predict(cov0, time_s - t0)
        if cov is None:
            return failed
        match = self.matcher.match_near(g, mean, cov, rows=rows)
        if not match.ok:
            return replace(failed, reason=PRIOR_PREFIX + match.reason)
        used = match.matched
        lights = match.light_index[used]
        glints = self._glints(g[used], lights)
        prior = dict(prior_mean_rad=mean, prior_cov_rad2=cov, noise_px=self.prior.noise_px)
        if self.method == "polynomial":
            est = polynomial_gaze(self.setup, self.calibration, glints, mapping=self.mapping,
                                  **prior)
        else:
            est = geometric_gaze(self.setup, self.calibration, glints, **prior)
        reason = self._reason(est)
        if reason != "ok":
            return _failed(f, j, time_s, PRIOR_PREFIX + reason, g[used], lights)
        angles = est.angles_rad[0]
        post = posterior_covariance(self._orbit, angles, np.isfinite(glints[..., 0]), cov,
                                    self.prior.noise_px)[0]
        self._state = (time_s, angles.copy(), post)
        self._prior_angles = angles.copy()
        return GazeSample(f, j, time_s, est.screen_xy_m[0].copy(), est.cornea_center_m[0].copy(),
                          g[used], lights, float(est.rms_px[0]), "ok",
                          match.confidence[used].copy(), prior_assisted=True)

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


#: Failures of a band's own identification, after which the band may still be identified with
#: the prior (not a fit that failed on identified glints: those glints were the trouble).
_IDENTITY_FAILURES = frozenset({"match_too_few_glints", "match_ambiguous", "match_no_hypothesis",
                                "match_fit_failed", "too_few_glints"})


# --------------------------------------------------------------------------- folders


@dataclass(frozen=True, slots=True)
class FolderTiming:
    """A folder's timing sidecar.

    Attributes
    ----------
    frame_start_s : dict[int, float]
        Frame index -> frame start t0_f (s).
    exposure_s : float or None
    strobe : dict or None
        Strobe fields the frames were taken with (overriding the scene's).
    source : Path
        The file the timing was read from.
    """

    frame_start_s: dict
    exposure_s: float | None
    strobe: dict | None
    source: Path

    def apply(self, setup: Setup) -> Setup:
        """``setup`` with the sidecar's exposure and strobe, where it gives them."""
        sensor = setup.sensor if self.exposure_s is None else replace(setup.sensor,
                                                                      exposure_s=self.exposure_s)
        strobe = setup.strobe if self.strobe is None else replace(setup.strobe, **self.strobe)
        return replace(setup, sensor=sensor, strobe=strobe)


def timing_document(frame_start_s: dict, *, exposure_s: float | None = None,
                    strobe=None) -> str:
    """The text of a timing sidecar (``strobe``: a :class:`~estimator.setup.Strobe` or None)."""
    doc = {"format": TIMING_FORMAT, "version": TIMING_VERSION,
           "frames": {str(int(k)): float(v) for k, v in sorted(frame_start_s.items())}}
    if exposure_s is not None:
        doc["exposure_s"] = float(exposure_s)
    if strobe is not None:
        doc["strobe"] = {k: (int if k == "pulses_per_frame" else float)(getattr(strobe, k))
                         for k in ("pulses_per_frame", "pulse_s", "period_s", "phase_s")}
    return json.dumps(doc, indent=1) + "\n"


def read_timing(folder, setup: Setup) -> FolderTiming:
    """The timing of a frames folder: ``timing.json``, or a rendered dataset's manifest.

    Raises
    ------
    TrackerInputError
        Neither file, or a malformed one (the message names the file and key).
    """
    folder = Path(folder)
    path = folder / TIMING_NAME
    if path.is_file():
        return _parse_timing(path)
    manifest = folder / MANIFEST_NAME
    if manifest.is_file():
        data = _read_json(manifest)
        try:
            frames = int(data["frames"])
            width, height = int(data["image"]["width_px"]), int(data["image"]["height_px"])
        except (KeyError, TypeError, ValueError) as exc:
            raise TrackerInputError(f"{manifest}: malformed dataset manifest ({exc!r})") from None
        want = (setup.camera.width_px, setup.camera.height_px)
        if (width, height) != want:
            raise TrackerInputError(f"{manifest}: frames are {width}x{height} px, the setup's "
                                    f"camera is {want[0]}x{want[1]}")
        dt = setup.sensor.frame_period_s
        return FolderTiming({f: f * dt for f in range(frames)}, None, None, manifest)
    raise TrackerInputError(f"{folder}: no {TIMING_NAME} (frame index -> frame start time) and "
                            f"no {MANIFEST_NAME}; cannot time the frames")


def _read_json(path: Path):
    try:
        return json.loads(path.read_bytes().decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TrackerInputError(f"{path}: cannot read JSON ({exc})") from None


def _parse_timing(path: Path) -> FolderTiming:
    data = _read_json(path)
    if not isinstance(data, dict) or data.get("format") != TIMING_FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise TrackerInputError(f"{path}: format is {got!r}, expected {TIMING_FORMAT!r}")
    if data.get("version") != TIMING_VERSION:
        raise TrackerInputError(f"{path}: this SCET reads {TIMING_FORMAT} version {TIMING_VERSION},"
                                f" the file says {data.get('version')!r}")
    frames = data.get("frames")
    if not isinstance(frames, dict) or not frames:
        raise TrackerInputError(f"{path}: key 'frames' must be a non-empty object "
                                "{frame index: frame start time in s}")
    out = {}
    for k, v in frames.items():
        if not re.fullmatch(r"\d+", str(k)) or isinstance(v, bool) or not isinstance(v, (int, float)) \
                or not math.isfinite(v):
            raise TrackerInputError(f"{path}: key 'frames': entry {k!r}: {v!r} is not "
                                    "<frame index>: <finite time in s>")
        out[int(k)] = float(v)
    exposure = data.get("exposure_s")
    if exposure is not None and (isinstance(exposure, bool) or not isinstance(exposure, (int, float))
                                 or not exposure > 0):
        raise TrackerInputError(f"{path}: key 'exposure_s' must be a positive number, got {exposure!r}")
    strobe = data.get("strobe")
    if strobe is not None:
        keys = {"pulses_per_frame", "pulse_s", "period_s", "phase_s"}
        if not isinstance(strobe, dict) or not set(strobe) <= keys or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in strobe.values()):
            raise TrackerInputError(f"{path}: key 'strobe' must map some of {sorted(keys)} to numbers")
    return FolderTiming(out, None if exposure is None else float(exposure), strobe, path)


def frame_path(folder, frame_index: int) -> Path:
    """Where frame ``frame_index`` of a folder lives (``frames/`` if the folder has one)."""
    folder = Path(folder)
    sub = folder / FRAMES_DIR
    return (sub if sub.is_dir() else folder) / f"{int(frame_index):06d}.png"


def read_frame(path) -> np.ndarray:
    """A grey 8- or 16-bit PNG frame as (H, W) uint8 or uint16.

    Raises
    ------
    TrackerInputError
        Missing, corrupt or truncated file, or not a single-channel image.
    """
    path = Path(path)
    try:
        data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
    except OSError as exc:
        raise TrackerInputError(f"{path}: cannot read the frame ({exc.strerror})") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise TrackerInputError(f"{path}: not a readable PNG (corrupt or truncated)")
    if img.ndim != 2:
        raise TrackerInputError(f"{path}: expected a single-channel frame, got shape {img.shape}")
    return img


def iter_folder(folder, setup: Setup) -> Iterator[tuple[int, float, np.ndarray | None, str | None]]:
    """(frame index, frame start s, frame or None, error message or None) for every frame
    of the timing sidecar, in index order. A missing or unreadable frame yields None and why."""
    timing = read_timing(folder, setup)
    for f in sorted(timing.frame_start_s):
        path = frame_path(folder, f)
        if not path.is_file():
            yield f, timing.frame_start_s[f], None, f"{path}: missing"
            continue
        try:
            yield f, timing.frame_start_s[f], read_frame(path), None
        except TrackerInputError as exc:
            yield f, timing.frame_start_s[f], None, str(exc)


# --------------------------------------------------------------------------- calibration


def read_targets(folder) -> dict:
    """Frame index -> fixated target (3,) m, from a folder's ``labels.jsonl`` (``frame`` and
    ``target_m`` of each line)."""
    path = Path(folder) / LABELS_NAME
    out = {}
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackerInputError(f"{path}: cannot read the calibration targets ({exc})") from None
    for number, line in enumerate(lines, start=1):
        try:
            d = json.loads(line)
            t = np.asarray(d["target_m"], dtype=np.float64).reshape(3)
            out.setdefault(int(d["frame"]), t)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise TrackerInputError(f"{path}, line {number}: malformed label ({exc!r})") from None
    if not out:
        raise TrackerInputError(f"{path}: no calibration targets")
    return out


@dataclass(frozen=True, slots=True)
class CalibrationGlints:
    """Identified glints of the calibration frames: (m, n, 2) NaN where missing, targets
    (m, 3) m, and the frame indices used."""

    glints_px: np.ndarray
    targets_m: np.ndarray
    frames: tuple


def calibration_glints(folder, setup: Setup) -> tuple[Setup, CalibrationGlints]:
    """Detect and identify the glints of a folder of single-pulse calibration frames.

    Returns the setup with the sidecar's calibration timing, and the glints. Frames that cannot
    be read or matched are left out (logged)."""
    folder = Path(folder)
    timing = read_timing(folder, setup)
    cal_setup = timing.apply(setup)
    targets = read_targets(folder)
    matcher = GlintMatcher(cal_setup)
    n = cal_setup.lights.count
    rows, used_targets, frames = [], [], []
    for f, _, img, err in iter_folder(folder, cal_setup):
        if err is not None or f not in targets:
            log.warning("calibration frame %d left out: %s", f, err or "no target in labels")
            continue
        try:
            det = detect_glints(img, cal_setup, f)
        except ValueError as exc:
            log.warning("calibration frame %d left out: %s", f, exc)
            continue
        det = det.select(~det.has(NO_BAND))
        prior = np.array(cal_setup.eye.angles_toward(targets[f][None])).reshape(2)
        match = matcher.match(det.glints_px, prior_angles_rad=prior)
        if not match.ok or match.matched.sum() < MIN_GLINTS:
            log.warning("calibration frame %d left out: match %s", f, match.reason)
            continue
        g = np.full((n, 2), np.nan)
        g[match.light_index[match.matched]] = det.glints_px[match.matched]
        rows.append(g)
        used_targets.append(targets[f])
        frames.append(f)
    if len(rows) < 4:
        raise TrackerInputError(f"{folder}: only {len(rows)} usable calibration frames, need >= 4")
    return cal_setup, CalibrationGlints(np.array(rows), np.array(used_targets), tuple(frames))


def calibrate_from_folder(folder, setup: Setup) -> Calibration:
    """Calibrate from a folder of single-pulse calibration frames (targets in labels.jsonl).

    Lighting pose, corneal radius, eye centre and orbit radius are fitted at once
    (:func:`estimator.calibration.calibrate_joint`, optical axis through the targets); the
    mappings from the fitted cornea centres: ``eq1_<m>`` (Eq. (1)) and ``quadratic_<m>``
    (minimum-norm where the orbit makes it rank deficient), m the number of frames used.
    """
    cal_setup, cg = calibration_glints(folder, setup)
    mask = np.isfinite(cg.glints_px).all(axis=-1)
    lighting, orbit = calibrate_joint(cal_setup.camera, cal_setup.lights_world_m, cg.glints_px,
                                      cg.targets_m, mask,
                                      center0_m=cal_setup.eye.cornea_center(0.0, 0.0))
    cal = Calibration.from_fits(lighting, orbit)
    centers = fit_cornea_centers(cal_setup, cal, cg.glints_px, mask)
    ok = centers.ok
    m = int(ok.sum())
    maps = {f"eq1_{m}": fit_gaze_mapping(centers.center_m[ok], cg.targets_m[ok], "eq1",
                                         degenerate="min_norm"),
            f"quadratic_{m}": fit_gaze_mapping(centers.center_m[ok], cg.targets_m[ok],
                                               "quadratic", degenerate="min_norm")}
    return cal.with_mappings(**maps)


def save_calibration(calibration: Calibration, path) -> Path:
    """Write a calibration file (versioned JSON) atomically."""
    path = Path(path)
    _atomic_write(path, calibration.to_json().encode("utf-8"))
    return path


def load_calibration(path) -> Calibration:
    """Read and check a calibration file; errors name the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackerInputError(f"{path}: cannot read the calibration ({exc})") from None
    try:
        return Calibration.from_json(text)
    except ValueError as exc:
        raise TrackerInputError(f"{path}: {exc}") from None


# --------------------------------------------------------------------------- tracking a folder


SAMPLE_COLUMNS = ("frame", "strobe", "time_s", "screen_x_m", "screen_y_m", "cornea_x_m",
                  "cornea_y_m", "cornea_z_m", "n_glints", "lights", "residual_px", "reason",
                  "prior")


@dataclass(frozen=True, slots=True)
class TrackSummary:
    """What :func:`track_folder` did: the CSV written, and the samples."""

    path: Path
    samples: tuple
    frames: int

    @property
    def n_ok(self) -> int:
        return sum(s.ok for s in self.samples)


def track_folder(folder, setup: Setup, calibration, out_csv, *, method: str = "polynomial",
                 mapping: str | None = None,
                 progress: Callable[[int, int], None] | None = None) -> TrackSummary:
    """Track every frame of a folder and write ``samples.csv`` atomically.

    Parameters
    ----------
    folder : path
        Frames and timing sidecar (or a rendered dataset's manifest).
    setup : Setup
    calibration : Calibration or path
        A calibration, or the path of a calibration file.
    out_csv : path
        Written to ``<name>.partial`` and moved into place at the end: an existing file is
        replaced only by a complete one.
    method : {"polynomial", "geometric"}
    mapping : str, optional
        Polynomial mapping name; default the calibration's Eq. (1) mapping.
    progress : callable, optional
        ``progress(done, total)`` after every frame.
    """
    if not isinstance(calibration, Calibration):
        calibration = load_calibration(calibration)
    if mapping is None:
        eq1 = sorted(k for k in calibration.mappings if k.startswith("eq1"))
        mapping = eq1[-1] if eq1 else next(iter(calibration.mappings), "eq1_25")
    tracker = Tracker(setup, calibration, method, mapping=mapping)
    timing = read_timing(folder, setup)
    total = len(timing.frame_start_s)
    samples = []
    for done, (f, t0, img, err) in enumerate(iter_folder(folder, setup), start=1):
        if err is not None:
            log.warning("frame %d: %s", f, err)
            reason = MISSING_FRAME if err.endswith(": missing") else UNREADABLE_FRAME
            tracker.reset()
            out = tracker.process(None, f, t0)
            out = [replace(s, reason=reason) for s in out]
        else:
            out = tracker.process(img, f, t0)
        samples.extend(out)
        if progress is not None:
            progress(done, total)
    out_csv = Path(out_csv)
    _atomic_write(out_csv, samples_csv(samples).encode("utf-8"))
    return TrackSummary(out_csv, tuple(samples), total)


def samples_csv(samples) -> str:
    """CSV text of samples: a ``# scet-samples 2`` line, the header, one row per sample
    (``prior``: 1 for a prior-assisted sample, else 0)."""
    buf = io.StringIO()
    buf.write(f"# {SAMPLES_FORMAT} {SAMPLES_VERSION}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SAMPLE_COLUMNS)
    for s in samples:
        w.writerow([s.frame_index, s.strobe_index, repr(float(s.time_s)),
                    *(repr(float(v)) for v in s.screen_xy_m),
                    *(repr(float(v)) for v in s.cornea_center_m), s.n_glints,
                    ";".join(str(int(i)) for i in s.light_index), repr(float(s.residual_px)),
                    s.reason, int(s.prior_assisted)])
    return buf.getvalue()


def read_samples_csv(path) -> list[dict]:
    """Rows of a ``samples.csv`` (values as strings), after checking its format line.

    Reads versions 1 and 2 (:data:`SAMPLES_READABLE`); rows of version 1, written before prior
    assistance existed, get ``prior`` "0"."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    first, _, rest = text.partition("\n")
    known = {f"# {SAMPLES_FORMAT} {v}": v for v in SAMPLES_READABLE}
    version = known.get(first.strip())
    if version is None:
        raise TrackerInputError(f"{path}: expected first line '# {SAMPLES_FORMAT} <version>' "
                                f"with version in {SAMPLES_READABLE}, got {first[:60]!r}")
    rows = list(csv.DictReader(io.StringIO(rest)))
    if version == 1:
        for r in rows:
            r["prior"] = "0"
    return rows


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".partial")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
