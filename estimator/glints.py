"""Glint detection in a banded rolling-shutter frame, with OpenCV.

A glint is the corneal reflection of one strobed point light: a small bright spot (1-4 px in
radius at 640x480) on an eye image whose sclera, iris, skin and eyelids sit at low to moderate
levels. Each strobe pulse lights only a band of rows (Sec. 2.3 of the SCET paper, Fig. 2), so
every glint also carries the instant of the pulse that lit it. The pipeline is lean (it runs on
a Raspberry Pi, one frame per 16.6 ms). Steps 2-6 after the top-hat run compiled with Numba
when it is installed (:mod:`estimator.glint_kernels`, one call per step), and otherwise as
numpy and OpenCV (:mod:`estimator.glint_spots`: components labelled by
``cv2.connectedComponents`` on the frame with the rows and columns that hold no pixel above
threshold squeezed out; small spots measured as one stack of equal patches with moments as
matrix products, large ones pixel by pixel with ``np.add.reduceat``), at about half the frame
rate; every path weighs the same pixels alike and gives the same detections (tested to
1e-9 px):

1. Background: a morphological white top-hat, the image minus its opening by a horizontal line
   of ``background_kernel_px`` pixels (OpenCV, on the frame's own 8/16-bit or float32 type,
   no float64 frame-sized temporary). The opening erases every bright structure narrower than
   the line (glints) and keeps everything wider: skin, sclera, iris, pupil and lid edges, linear
   gradients exactly, and the band structure. A horizontal line rather than a square because
   the bands are constant along rows: the V-shaped dips at band edges (Eq. (5)) cut the sclera
   and skin into bright horizontal ridges a few rows high wherever a dip runs near a lid or
   iris edge; a square does not fit in them and would leave them in the top-hat, a line does.
2. Threshold: the top-hat floor plus ``threshold_sigma`` robust standard deviations (1.4826
   MAD), both from a 1-in-64 pixel subsample (the glints are too sparse to move them), in 7
   bins of the local background level L (the opening) between quantiles of L, interpolated
   in L: noise grows with brightness (shot noise), and a single global σ set by the dark
   pupil or the dark gaps between bands would let the bright sclera's noise cross the
   threshold. The medians are counted (histograms) for integer frames and sorted for float
   ones, with the same result. Pixels above the lowest threshold are found word by word,
   then kept where the top-hat exceeds the threshold at their own level.
   The top-hat works along rows, so the subsample's top-hat is that of every 8th row alone.
   :class:`GlintDetector` measures this model only now and then over the frames of one
   sequence (it is the sensor's, not the scene's; see there when it is measured again), and
   between whole-frame searches searches only a window around the glints it found, with the
   same result for every glint inside it.
3. Connected components (8-connected) of the pixels above threshold, with each one's area
   and box.
4. Per component, over its box grown by ``centroid_margin_px``, the intensity-weighted
   centroid of the top-hat above its floor (pixel-centre convention: (0, 0)
   is the centre of the top-left pixel), with each row divided by the light it collected from
   the strobes, Σ_j w_j(y) of :func:`estimator.banding.row_pulse_weights`, clamped below at
   ``band_weight_floor``. A static glint is recorded as I(x, y) Σ_j w_j(y), so the division
   undoes the cut a band edge makes in the spot (uncorrected, a spot on the ramp of Eq. (5)
   moves toward the band's plateau by up to half a pixel).
5. Filters (a failing component is not a glint and is not returned): area, elongation of the
   intensity-weighted second moments, and the ratio of the brightest 4-neighbour to the peak
   (an optical spot is never a single pixel; a noise spike or hot pixel is). Elongated
   components with two or three clearly separated maxima (neighbouring glints whose skirts
   touch, common where the arc's glints crowd) are first split among their maxima and flagged
   :data:`BLENDED`. Thresholds and their reasons are in :class:`DetectionParams`.
6. Band and time: the light of a spot is shared among the pulses in proportion to
   Σ_pixels I(x, y) w_j(y); the largest share names the strobe, and the time stamp is that
   pulse's centre s_j + Δs / 2 (as in :func:`estimator.banding.row_strobe`). The row weights,
   and per pulse the running count of rows below its plateau (for :data:`CUT_BY_BAND_EDGE`),
   are computed once per strobe phase and cached.

Flags (bits of :attr:`GlintDetections.flags`): :data:`SATURATED` (a pixel of the spot reached
full scale: the centroid is that of the flat top and its skirt, the intensity a lower bound),
:data:`CUT_BY_BAND_EDGE` (the spot reaches a row where its pulse's weight falls below the
plateau: the centroid was corrected as above and is less certain), :data:`TWO_PULSES` (a second
pulse contributes a share of the spot's light: the spot may hold two images of the same glint,
Δ_clk apart; they are not split, the strobe and time are those of the larger share),
:data:`IMAGE_EDGE` (the spot's box touches the image border: the centroid may be truncated),
:data:`NO_BAND` (the spot lies on rows no pulse lights: not a strobe glint; strobe index
:data:`estimator.banding.NO_PULSE`, time NaN) and :data:`BLENDED` (split from a neighbour: the
centroid is pulled toward it by up to ~0.1 px). Flagged glints are kept: what to do with them
is the caller's decision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from . import glint_kernels, glint_spots
from .banding import NO_PULSE
from .eye import EYE_SPEED_MAX_DEG_S, gaze_direction
from .glint_noise import _NOISE_STEP, _flat_true, _line_kernel, _NoiseModel
from .glint_spots import (
    _Boxes,
    _deblend,
    _frame_timing,
    _gather,
    _Labels,
    _measure_patches,
    _measure_pixels,
    _Spots,
    _weights,
)
from .projection import project_glints
from .setup import Sensor, Setup

#: Flag bits of :attr:`GlintDetections.flags`.
SATURATED = 1
CUT_BY_BAND_EDGE = 2
TWO_PULSES = 4
IMAGE_EDGE = 8
NO_BAND = 16
BLENDED = 32
FLAG_NAMES = {SATURATED: "saturated", CUT_BY_BAND_EDGE: "cut_by_band_edge",
              TWO_PULSES: "two_pulses", IMAGE_EDGE: "image_edge", NO_BAND: "no_band",
              BLENDED: "blended"}

@dataclass(frozen=True, slots=True)
class DetectionParams:
    """Thresholds of :func:`detect_glints`, each with the reason for its default.

    Attributes
    ----------
    background_kernel_px : int
        Length of the horizontal line of the top-hat's opening (odd). Glints are at most 4 px
        in radius (9 px across); 11 px leaves a pixel of skirt on each side. Longer lets wider
        bright clutter through to the shape filters; shorter than a glint erodes its top.
    threshold_sigma : float
        Detection threshold above the top-hat floor, in robust noise standard deviations. The
        top-hat of noise has a heavier upper tail than a Gaussian (a pixel minus a local max
        of minima), and σ is estimated per level bin from a few hundred pixels (~5-10 %
        error). Measured on 200 frames of shot and read noise on an eye-like banded background
        (the tests' generator, half with dark gaps between bands), false glints per frame:
        8: none, 7.5: 0.005, 7: 0.015, 6: 0.2, 5: 1.7. This is also the peak-contrast test:
        a glint's peak stands 8 σ above the local background's top-hat floor.
    min_noise_dn : float
        Floor of the noise estimate (DN): a noiseless or coarsely quantised frame (MAD 0) would
        otherwise turn every quantisation step into a detection. 0.5 DN is the SD of a uniform
        quantisation error (0.29 DN) rounded up.
    min_area_px, max_area_px : int
        Pixels above threshold. A glint of radius 1-4 px covers ~1-50 px; a saturated one
        blooms further (σ = 2 px at 50x the threshold: radius 5.6 px, ~100 px), hence 150.
        Larger components are not glints (pupil-edge and tear-film highlights).
    max_elongation : float
        sqrt(λ_max / λ_min) of the intensity-weighted second moments of a component (after the
        band correction). A round glint gives 1, a Gaussian cut in half by the image border
        1.7, and glints of a 0.4 mm source near the limbus, seen obliquely, up to 2.2
        (measured on Mitsuba renders of paper_sim). Reflections off the sclera and the lid
        margin are streaks: 9 px long and 1.6 px wide already gives 3.4.
    blend_elongation : float
        Components longer than this (two touching glints of σ = 1.4 px 5.5 px apart give 2.2)
        are examined for two or three separated maxima and split among them; a single
        elongated glint has one maximum and stays whole.
    max_blend : int
        More maxima than this make a textured streak, not neighbouring glints.
    blend_saddle : float
        Two maxima are separate glints when the profile between them dips below this fraction
        of the lower one. Two glints of σ = 1.5 px 5.7 px apart (the closest pair of
        ``paper_sim``) dip to 0.33; the noise ripple on a streak (σ / peak ~ 0.05) does not
        reach 0.6.
    min_neighbour_ratio : float
        Brightest 4-neighbour of the peak pixel over the peak (above the floor). A Gaussian
        spot of σ >= 0.5 px (the sharpest a lens gives at VGA) centred on a pixel gives 0.23,
        more off centre; a noise spike or hot pixel only its neighbours' noise over its height.
        Saturated spots pass.
    centroid_margin_px : int
        Growth of each component's box for the centroid (px): the skirt below threshold holds
        a spot's tails (leaving them out pulls the centroid toward the peak pixel); wider
        margins add noise faster than signal (measured: 2 px doubles the centroid's spread).
        Pixels of other components are excluded.
    centroid_floor_sigma : float
        Pixels weigh their value above the floor minus this many noise SDs, clipped at zero:
        the skirt's zero-mean noise then adds little variance, at a bias below 0.02 px
        (measured: median error 0.043 px against 0.052 px without it).
    band_weight_floor : float
        Rows are divided by max(Σ_j w_j(y), floor). Rows lit by less than a quarter of a pulse
        hold little of the spot, and dividing them by less would amplify their noise more
        than 4x.
    cut_tolerance : float
        A spot is :data:`CUT_BY_BAND_EDGE` when its pulse's weight on any of its rows (±1)
        falls below (1 - tolerance) of that pulse's largest weight in the frame.
    two_pulse_share : float
        A spot is :data:`TWO_PULSES` when the second pulse carries at least this share of its
        light: 5 % moves the centroid of a glint that moved 1 px between the pulses by 0.05 px.
    saturation_dn : float, optional
        Full scale. Default: 255 for uint8 frames, 2**bit_depth - 1 of the sensor otherwise.
    """

    background_kernel_px: int = 11
    threshold_sigma: float = 8.0
    min_noise_dn: float = 0.5
    min_area_px: int = 1
    max_area_px: int = 150
    max_elongation: float = 3.0
    blend_elongation: float = 1.5
    max_blend: int = 3
    blend_saddle: float = 0.6
    min_neighbour_ratio: float = 0.12
    centroid_margin_px: int = 1
    centroid_floor_sigma: float = 1.0
    band_weight_floor: float = 0.25
    cut_tolerance: float = 0.02
    two_pulse_share: float = 0.05
    saturation_dn: float | None = None

    def __post_init__(self):
        k = self.background_kernel_px
        if not isinstance(k, (int, np.integer)) or k < 3 or k % 2 == 0:
            raise ValueError(f"background_kernel_px must be an odd integer >= 3, got {k!r}")
        if not (self.threshold_sigma > 0 and self.min_noise_dn > 0):
            raise ValueError("threshold_sigma and min_noise_dn must be positive")
        if not 1 <= self.min_area_px <= self.max_area_px:
            raise ValueError("need 1 <= min_area_px <= max_area_px")
        if not self.max_elongation >= 1:
            raise ValueError(f"max_elongation must be >= 1, got {self.max_elongation!r}")
        if not 0 < self.band_weight_floor <= 1:
            raise ValueError(f"band_weight_floor must be in (0, 1], got {self.band_weight_floor!r}")
        if self.centroid_margin_px < 0 or self.centroid_floor_sigma < 0:
            raise ValueError("centroid_margin_px and centroid_floor_sigma must be >= 0")


@dataclass(frozen=True, slots=True)
class GlintDetections:
    """The glints found in one frame (n of them), ordered by row.

    Attributes
    ----------
    u_px, v_px : (n,) float
        Intensity-weighted, band-corrected centroid (pixel-centre convention).
    intensity : (n,) float
        Flux of the spot above the background (DN summed over its pixels), divided by the
        light its rows collected: the flux a full pulse would have given.
    area_px : (n,) int
        Pixels above threshold.
    peak : (n,) float
        Brightest pixel of the spot above the black level (DN): its distance to full scale
        minus black is the headroom an exposure control needs.
    strobe_index : (n,) int64
        Global index j of the pulse that lit the glint (:data:`estimator.banding.NO_PULSE`
        for :data:`NO_BAND`).
    time_s : (n,) float
        That pulse's centre s_j + Δs / 2 (NaN for :data:`NO_BAND`).
    flags : (n,) int64
        OR of :data:`SATURATED`, :data:`CUT_BY_BAND_EDGE`, :data:`TWO_PULSES`,
        :data:`IMAGE_EDGE`, :data:`NO_BAND`, :data:`BLENDED`.
    frame_index : int
    noise_dn : float
        Robust noise SD of the top-hat image.
    threshold_dn : float
        Detection threshold on the top-hat image.
    """

    u_px: np.ndarray
    v_px: np.ndarray
    intensity: np.ndarray
    area_px: np.ndarray
    peak: np.ndarray
    strobe_index: np.ndarray
    time_s: np.ndarray
    flags: np.ndarray
    frame_index: int = 0
    noise_dn: float = float("nan")
    threshold_dn: float = float("nan")

    def __len__(self) -> int:
        return int(self.u_px.shape[0])

    @property
    def glints_px(self) -> np.ndarray:
        """(n, 2) centroids (u, v)."""
        return np.stack([self.u_px, self.v_px], axis=-1)

    def has(self, flag: int) -> np.ndarray:
        """(n,) bool: which glints carry ``flag``."""
        return (self.flags & flag) != 0

    def select(self, keep) -> "GlintDetections":
        """The detections at ``keep`` (bool mask or indices)."""
        return replace(self, **{name: getattr(self, name)[keep] for name in _ARRAY_FIELDS})

    def of_strobe(self, strobe_index: int) -> "GlintDetections":
        """The detections lit by one pulse: one band, one gaze sample."""
        return self.select(self.strobe_index == strobe_index)


_ARRAY_FIELDS = ("u_px", "v_px", "intensity", "area_px", "peak", "strobe_index", "time_s", "flags")


def _empty(frame_index: int, noise: float, thr: float) -> GlintDetections:
    f = np.zeros(0)
    i = np.zeros(0, dtype=np.int64)
    return GlintDetections(f, f.copy(), f.copy(), i, f.copy(), i.copy(), f.copy(), i.copy(),
                           frame_index, noise, thr)


# --------------------------------------------------------------------------- input checks


def _check_frame(frame, setup: Setup) -> np.ndarray:
    a = np.asarray(frame)
    if a.size == 0:
        raise ValueError(f"frame is empty (shape {a.shape})")
    want = (setup.camera.height_px, setup.camera.width_px)
    if a.ndim != 2 or a.shape != want:
        raise ValueError(f"frame must have shape {want} (height, width of setup {setup.name!r}'s "
                         f"camera), got {a.shape}")
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise ValueError(f"frame must be uint8, uint16 or float sensor DN, got dtype {a.dtype}")
    if a.dtype in (np.uint8, np.uint16):
        return np.ascontiguousarray(a)
    if np.issubdtype(a.dtype, np.floating) and not np.isfinite(a).all():
        raise ValueError("frame contains NaN or infinite values")
    return np.ascontiguousarray(a, dtype=np.float32)


# --------------------------------------------------------------------------- detection


def detect_glints(frame, setup: Setup, frame_index: int = 0,
                  params: DetectionParams = DetectionParams()) -> GlintDetections:
    """Find the glints in one banded frame and time-stamp each with its strobe.

    Parameters
    ----------
    frame : (H, W) uint8, uint16 or float
        Sensor output in DN (black level included), H x W the setup camera's size. uint8 is
        taken as 8-bit output (full scale 255, black level scaled by 2^(8 - bit depth)).
    setup : Setup
        Sensor and strobe timing (the bands), bit depth and black level.
    frame_index : int
        Frame f of the sequence; its row 0 is read at f Δt (Eq. (2)).
    params : DetectionParams

    Returns
    -------
    GlintDetections
        Empty arrays when the frame holds no glint.

    Raises
    ------
    ValueError
        Empty frame, wrong shape or dtype, NaN or infinite values, non-integer frame index.
    """
    img, frame_index = _prepare(frame, setup, frame_index)
    return _detect(img, setup, frame_index, params, None)[0]


def _prepare(frame, setup: Setup, frame_index) -> tuple[np.ndarray, int]:
    """The checked frame (uint8, uint16 or float32, C-contiguous) and frame index."""
    if isinstance(frame_index, bool) or not isinstance(frame_index, (int, np.integer)):
        raise ValueError(f"frame_index must be an integer, got {frame_index!r}")
    img = _check_frame(frame, setup)
    if setup.sensor.visible_lines != img.shape[0]:
        raise ValueError(f"setup {setup.name!r}: sensor.visible_lines = "
                         f"{setup.sensor.visible_lines} but its camera image has "
                         f"{img.shape[0]} rows")
    return img, int(frame_index)


def _full_scale_and_black(img: np.ndarray, sensor: Sensor, params: DetectionParams):
    """Full scale and black level (DN) of a checked frame."""
    if img.dtype == np.uint8:
        full_scale, black = 255.0, sensor.black_level_dn * 2.0 ** (8 - sensor.bit_depth)
    else:
        full_scale, black = float(2 ** sensor.bit_depth - 1), float(sensor.black_level_dn)
    if params.saturation_dn is not None:
        full_scale = float(params.saturation_dn)
    return full_scale, black


class GlintDetector:
    """:func:`detect_glints` over the frames of one sequence: the noise model of step 2 is
    measured only now and then, and the search follows the glints in a window.

    **Noise model.** The model is the top-hat's floor and σ as functions of the background
    level L, a property of the sensor (read noise, conversion gain, quantisation) and of the
    top-hat operator, not of where the eye looks: a frame's model serves the frames after it.
    It is measured again

    - when the frame's mean level (on the model's 1-in-64 subsample, glints included) has moved
      by more than ``level_drift`` of the mean above black since the model was measured, or by
      1 DN on a frame near black: exposure, analog gain or illumination changes rescale every
      level and σ(L) with them; 5 % rescales σ by at most 5 %, which moves the 8 σ threshold
      by 0.4 σ (measured false glints per frame: 0.005 at 7.5 σ,
      :attr:`DetectionParams.threshold_sigma`). A blink, the eye leaving the frame or a
      strobe that fails moves the mean by far more. The mean of 4,800 pixels wanders by
      ~σ / 70 from frame to frame: far below either bound.
    - every ``refresh_frames`` frames (default 30, 0.5 s at 60 fps) in any case: slow changes
      the mean does not see (sensor warm-up raising the dark noise, the level histogram
      reshaping as the eye turns, which moves the model's bins) last at most that long;
    - when the frame's dtype changes (8-bit and 10-bit output have different models), and
      after :meth:`reset`.

    **Window** (``track_roi``, on by default). The glints of one eye cover a small part of
    the frame (paper_sim: ~250 x 220 of 640 x 480 px over the whole screen), and steps 1-3 cost
    in proportion to the pixels searched. A frame that measures a noise model is searched
    whole; the frames after it only inside the bounding box of every glint found since that
    frame, grown by ``roi_margin_px`` on each side. The window's glints are exactly those the
    whole frame gives for them (see :func:`_detect`); the whole frame is searched again at
    once when a component touches the window's inner edge (a glint moving out of it, or
    anything larger cut by it) or when the window holds no glint (a blink, a lost eye). A
    glint that appears wholly outside the window (a light that was hidden, a jump larger than
    the margin) is found at the next whole-frame search, at most ``refresh_frames`` frames
    later. The default margin is how far any glint moves in one frame period at
    ``eye_speed_deg_s``: the largest displacement per degree of eye rotation, in any direction,
    of the setup's glints at primary gaze (the closed-form projection, :func:`window_margin_px`).

    The detections carry the model's ``noise_dn`` and ``threshold_dn``: those of the frame it
    was measured on. :attr:`window` is the window the last frame was searched in (None: the
    whole frame); :attr:`frames`, :attr:`windowed` and :attr:`retried` count the frames, those
    searched in a window alone, and windows voided and searched again whole.

    Parameters
    ----------
    setup : Setup
    params : DetectionParams
    refresh_frames : int
        Frames per model and per whole-frame search, >= 1 (1: every frame is measured and
        searched whole, as :func:`detect_glints`).
    level_drift : float
        Relative change of the mean level above black that forces a new model, > 0.
    track_roi : bool
        Search a window around the glints between whole-frame searches.
    roi_margin_px : int, optional
        Growth of the window beyond the glints found (px, >= 0). Default:
        :func:`window_margin_px` of the setup at ``eye_speed_deg_s``.
    eye_speed_deg_s : float
        Eye rotation speed the default margin allows for
        (:data:`estimator.eye.EYE_SPEED_MAX_DEG_S`, 600°/s).
    """

    def __init__(self, setup: Setup, params: DetectionParams = DetectionParams(), *,
                 refresh_frames: int = 30, level_drift: float = 0.05, track_roi: bool = True,
                 roi_margin_px: int | None = None,
                 eye_speed_deg_s: float = EYE_SPEED_MAX_DEG_S):
        if isinstance(refresh_frames, bool) or not isinstance(refresh_frames, (int, np.integer)) \
                or refresh_frames < 1:
            raise ValueError(f"refresh_frames must be an integer >= 1, got {refresh_frames!r}")
        if not level_drift > 0:
            raise ValueError(f"level_drift must be positive, got {level_drift!r}")
        if roi_margin_px is None:
            roi_margin_px = window_margin_px(setup, eye_speed_deg_s)
        if isinstance(roi_margin_px, bool) or not isinstance(roi_margin_px, (int, np.integer)) \
                or roi_margin_px < 0:
            raise ValueError(f"roi_margin_px must be an integer >= 0, got {roi_margin_px!r}")
        self.setup, self.params = setup, params
        self.refresh_frames, self.level_drift = int(refresh_frames), float(level_drift)
        self.track_roi, self.roi_margin_px = bool(track_roi), int(roi_margin_px)
        self.measured_at: int | None = None  # frame index of the model in use
        self.measurements = 0  # models measured so far
        self.window: tuple[int, int, int, int] | None = None  # (y0, y1, x0, x1) of the last frame
        self.frames = self.windowed = self.retried = 0
        self._noise: _NoiseModel | None = None
        self._mean = 0.0
        self._dtype = None
        self._age = 0
        self._box: tuple | None = None  # (v min, v max, u min, u max) of the glints found

    def reset(self) -> None:
        """Forget the noise model and the glints: the next frame measures its own model and
        is searched whole."""
        self._noise, self.measured_at, self._box = None, None, None

    def __call__(self, frame, frame_index: int) -> GlintDetections:
        """The glints of the next frame of the sequence (as :func:`detect_glints`)."""
        img, frame_index = _prepare(frame, self.setup, frame_index)
        sample = img[::_NOISE_STEP, ::_NOISE_STEP]
        mean = float(sample.sum(dtype=np.float64)) / sample.size  # 3x faster than .mean()
        noise = self._noise
        if noise is not None:
            black = _full_scale_and_black(img, self.setup.sensor, self.params)[1]
            if (self._age >= self.refresh_frames or img.dtype != self._dtype
                    or abs(mean - self._mean) > max(self.level_drift * (self._mean - black), 1.0)):
                noise = None
        window = self._window(img.shape) if noise is not None else None
        det = None
        if window is not None:
            det, _ = _detect(img, self.setup, frame_index, self.params, noise, window)
            if det is None or len(det) == 0:
                det, window = None, None
                self.retried += 1
        if det is None:
            det, model = _detect(img, self.setup, frame_index, self.params, noise)
            if noise is None:
                self._noise, self._mean, self._dtype, self._age = model, mean, img.dtype, 0
                self.measured_at = frame_index
                self.measurements += 1
        self._age += 1
        self.frames += 1
        self.windowed += window is not None
        self.window = window
        self._grow(det, whole=window is None)
        return det

    def _window(self, shape) -> tuple[int, int, int, int] | None:
        if not self.track_roi or self._box is None:
            return None
        m = self.roi_margin_px
        v0, v1, u0, u1 = self._box
        y0, x0 = max(int(v0) - m, 0), max(int(u0) - m, 0)  # the centroids' pixels (v, u >= -0.5)
        y1, x1 = min(int(v1) + m + 2, shape[0]), min(int(u1) + m + 2, shape[1])
        if (y1 - y0) * (x1 - x0) > 0.8 * shape[0] * shape[1]:
            return None  # hardly smaller than the frame: the copies would cost more
        return y0, y1, x0, x1

    def _grow(self, det: GlintDetections, whole: bool) -> None:
        """The box of the glints since the last whole-frame search (reset by one)."""
        if len(det) == 0:
            if whole:
                self._box = None
            return
        v, u = det.v_px, det.u_px  # ordered by row
        box = (float(v[0]), float(v[-1]), float(u.min()), float(u.max()))
        if not whole and self._box is not None:
            old = self._box
            box = (min(box[0], old[0]), max(box[1], old[1]), min(box[2], old[2]),
                   max(box[3], old[3]))
        self._box = box


def window_margin_px(setup: Setup, eye_speed_deg_s: float = EYE_SPEED_MAX_DEG_S) -> int:
    """How far (px, rounded up) any glint of ``setup`` moves in one frame period while the
    eye turns at ``eye_speed_deg_s`` in any direction: the largest singular value of each
    glint's 2 x 2 Jacobian in the Fick angles, by central differences of the closed-form
    projection (±0.5°) at primary gaze, the largest over the glints, times the angle turned
    in one frame. paper_sim: 3.6 px per degree, 10° per frame at 60 fps, 36 px."""
    if not eye_speed_deg_s > 0:
        raise ValueError(f"eye_speed_deg_s must be positive, got {eye_speed_deg_s!r}")
    eye, h = setup.eye, math.radians(0.5)
    yaw = np.array([h, -h, 0.0, 0.0])
    pitch = np.array([0.0, 0.0, h, -h])
    g, visible = project_glints(setup.camera, eye.cornea_center(yaw, pitch), eye.cornea_radius_m,
                                setup.lights_world_m, cornea_axis=gaze_direction(yaw, pitch),
                                cap_cos_min=eye.cap_cos_min)
    seen = visible.all(axis=0)
    if not seen.any():
        raise ValueError(f"setup {setup.name!r}: no glint is visible at primary gaze")
    jac = np.stack([g[0] - g[1], g[2] - g[3]], axis=-1)[seen] / (2 * math.degrees(h))  # px/deg
    per_deg = float(np.linalg.norm(jac, ord=2, axis=(1, 2)).max())
    return math.ceil(per_deg * eye_speed_deg_s * setup.sensor.frame_period_s)


def _detect(img: np.ndarray, setup: Setup, frame_index: int, params: DetectionParams,
            noise: _NoiseModel | None, roi: tuple[int, int, int, int] | None = None
            ) -> tuple[GlintDetections | None, _NoiseModel]:
    """:func:`detect_glints` on a checked frame, with ``noise`` as its noise model (measured
    on the frame when None). Returns the detections and the model used.

    With ``roi`` = (y0, y1, x0, x1), only the window of rows y0 .. y1 - 1 and columns
    x0 .. x1 - 1 is searched, and every glint found is exactly what the whole frame gives
    for it: the top-hat is taken over the window widened by the line kernel's reach (it works
    along rows only), the noise model (when measured) on the whole frame, the band timing on
    the window's rows, and a component whose grown box touches a side of the window that is
    not the frame's border (it may reach beyond, or join another there) voids the window:
    the detections are then None."""
    sensor = setup.sensor
    full_scale, black = _full_scale_and_black(img, sensor, params)
    kernel = _line_kernel(params.background_kernel_px)
    if noise is None:
        noise = _NoiseModel.of_frame(img, params)

    # 1-2: background and threshold (shot noise: the threshold rises with the background).
    if roi is None:
        y0 = x0 = 0
        top = cv2.morphologyEx(img, cv2.MORPH_TOPHAT, kernel)
    else:
        y0, y1, x0, x1 = roi
        reach = params.background_kernel_px - 1  # the opening at x reads x ± (length - 1)
        wx0, wx1 = max(x0 - reach, 0), min(x1 + reach, img.shape[1])
        top = cv2.morphologyEx(img[y0:y1, wx0:wx1], cv2.MORPH_TOPHAT, kernel)
        top, frame_shape, img = top[:, x0 - wx0:x1 - wx0], img.shape, img[y0:y1, x0:x1]
        if not glint_kernels.ENABLED:  # the numpy path reads the window by flat indices
            top, img = np.ascontiguousarray(top), np.ascontiguousarray(img)
    height, width = img.shape
    found = _components(top, img, noise, params)
    if found is None:
        return _empty(frame_index, noise.typical_sigma, noise.typical_threshold), noise
    labels, area, box_y0, box_y1, box_x0, box_x1 = found
    if roi is not None and _touches_inner_side(box_y0, box_y1, box_x0, box_x1,
                                               params.centroid_margin_px, roi, frame_shape):
        return None, noise
    comp = np.flatnonzero((area >= params.min_area_px) & (area <= params.max_area_px))
    if comp.size == 0:
        return _empty(frame_index, noise.typical_sigma, noise.typical_threshold), noise

    # 4: centroid, shape and light of every component over its box grown by the margin.
    table, m_off = _frame_timing(sensor, setup.strobe, frame_index, params.cut_tolerance,
                                 params.band_weight_floor)
    if roi is not None:
        table = table.rows(y0, y0 + height)
    if comp.size < area.size:
        box_y0, box_y1, box_x0, box_x1 = box_y0[comp], box_y1[comp], box_x0[comp], box_x1[comp]
    box = _Boxes.grown(comp + 1, box_y0, box_y1, box_x0, box_x1, params.centroid_margin_px,
                       height, width)
    spots = _measure(box, img, top, labels, noise, table, params)

    # 5: split blended neighbours, then filter.
    area_out, row0, row1, edge = area[comp], box.y0, box.y1, box.edge
    blended = np.zeros(comp.size, dtype=bool)
    replaced = np.zeros(comp.size, dtype=bool)
    elongated = np.flatnonzero(spots.elong > params.blend_elongation)
    if elongated.size:
        px = _gather(box.take(elongated), labels)
        value = _weights(px, img, top, noise, table, params)[1]
        px2, split = _deblend(px, value, np.arange(px.n), top, params)
        if px2 is not None:
            replaced[elongated[split]] = True
            spots = _Spots.concat([spots, _measure_pixels(px2, img, top, noise, table,
                                                          params)[0]])
            replaced = np.concatenate([replaced, np.zeros(px2.n, dtype=bool)])
            blended = np.concatenate([blended, np.ones(px2.n, dtype=bool)])
            area_out = np.concatenate([area_out, np.bincount(px2.seg, px2.own, px2.n)
                                       .astype(np.int64)])
            row0, row1, edge = (np.concatenate([a, b]) for a, b in (
                (row0, px2.row0), (row1, px2.row1), (edge, px2.edge)))
    finish = glint_kernels.finish if glint_kernels.ENABLED else _finish
    u, v, flux, area_out, peak, j_global, time_s, flags = finish(
        spots, area_out, row0, row1, edge, blended, replaced, table, m_off, setup.strobe,
        full_scale, params)
    if u.size == 0:
        return _empty(frame_index, noise.typical_sigma, noise.typical_threshold), noise
    return GlintDetections(
        u_px=u + x0, v_px=v + y0, intensity=flux, area_px=area_out, peak=peak - black,
        strobe_index=j_global, time_s=time_s, flags=flags, frame_index=frame_index,
        noise_dn=noise.typical_sigma, threshold_dn=noise.typical_threshold), noise


def _finish(spots: _Spots, area, row0, row1, edge, blended, replaced, table, m_off: int,
            strobe, full_scale: float, params: DetectionParams):
    """The end of step 5 and step 6 (numpy; :func:`estimator.glint_kernels.finish` when
    compiled): the spots that pass the filters, ordered by row, as (u, v, flux, area, peak,
    strobe index, time, flags), the peak with the black level."""
    saturated = spots.raw_peak.astype(np.float64) >= full_scale
    good = (~replaced & (spots.flux > 0) & (spots.elong <= params.max_elongation)
            & ((spots.neighbour >= params.min_neighbour_ratio) | saturated))
    sel = np.flatnonzero(good)
    sel = sel[np.argsort(spots.v[sel], kind="stable")]
    spots = spots.take(sel)
    # 6: band and time, from the pulse at the centroid row and its two neighbours (the only
    # ones a spot a few rows high can see): spots.light holds each spot's light and its
    # sums weighted by those three pulses' row weights.
    shares = spots.light[1:] / np.where(spots.light[0] > 0, spots.light[0], 1.0)  # (3, n)
    ranked = np.sort(shares, axis=0)
    lit = ranked[2] > 0
    col = spots.dom + np.argmax(shares, axis=0) - 1  # the table column of the largest share
    j_global = np.where(lit, table.local_index[np.where(lit, col - 1, 0)] - m_off, NO_PULSE)
    time_s = np.where(lit, strobe.phase_s + j_global * strobe.period_s + 0.5 * strobe.pulse_s,
                      np.nan)
    # Cut by a band edge: the pulse's weight on a row of the spot (±1) is below its plateau.
    below = table.below_plateau
    cut = lit & (below[row1[sel] + 3, col] > below[row0[sel], col])
    flags = (saturated[sel] * SATURATED | cut * CUT_BY_BAND_EDGE
             | (lit & (ranked[1] >= params.two_pulse_share)) * TWO_PULSES
             | edge[sel] * IMAGE_EDGE | ~lit * NO_BAND | blended[sel] * BLENDED)
    return (spots.u, spots.v, spots.flux, area[sel], spots.raw_peak.astype(np.float64),
            j_global.astype(np.int64), time_s, flags.astype(np.int64))


def _components(top, img, noise: _NoiseModel, params: DetectionParams):
    """Steps 2-3 on the top-hat ``top`` of ``img``: the components of the pixels above
    threshold as (labels, area, y0, y1, x0, x1), the boxes inclusive and labels 1, 2, ...
    the components in order; None when no pixel is above threshold. Compiled when
    :data:`estimator.glint_kernels.ENABLED`, else numpy and OpenCV (C-contiguous frames)."""
    height, width = img.shape
    # Compare in the image's own type: a Python float would cast the whole frame to float64.
    low = noise.lowest_threshold
    idx = _flat_true(top > (math.floor(low) if top.dtype.kind == "u" else np.float32(low)))
    if idx.size == 0:
        return None
    if glint_kernels.ENABLED:
        image, *found = glint_kernels.components(idx, top, img, noise, params)
        return (_Labels.whole(image, found[0].size + 1), *found) if found[0].size else None
    if top.dtype.kind == "u":
        t = top.ravel().take(idx)
        level = img.ravel().take(idx) - t  # the opening
        idx = idx[t > noise.tables(int(level.max()), params.centroid_floor_sigma)[2].take(level)]
    else:
        t = top.ravel()[idx].astype(np.float64)
        idx = idx[t > noise.threshold(img.ravel()[idx] - t)]  # level: the opening
    if idx.size == 0:
        return None
    # Labelled with the empty rows and columns between them squeezed to one (8-connectivity
    # is unchanged; ~4x fewer pixels to label than their bounding rectangle); the boxes from
    # the labels of those pixels (OpenCV's per-component statistics cost 4x the labelling).
    rows, cols = np.divmod(idx, width)
    labels = _Labels.of(rows, cols, height, width)
    lab = labels.at(rows, cols)
    area = np.bincount(lab, minlength=labels.n)[1:]
    order = np.argsort(lab, kind="stable")  # rows ascend within a component
    first = np.cumsum(area) - area
    rows, cols = rows[order], cols[order]
    return (labels, area, rows[first], rows[first + area - 1],
            np.minimum.reduceat(cols, first), np.maximum.reduceat(cols, first))


def _measure(box: _Boxes, img, top, labels: _Labels, noise: _NoiseModel, table,
             params: DetectionParams) -> _Spots:
    """Step 4 on the components of ``box``: compiled when
    :data:`estimator.glint_kernels.ENABLED`; else small boxes as one stack of equal patches,
    the rare large ones pixel by pixel."""
    if glint_kernels.ENABLED:
        return glint_kernels.measure(box, img, top, labels.image, noise, table, params)
    small = ((box.gy1 - box.gy0 <= glint_spots._PATCH_PX)
             & (box.gx1 - box.gx0 <= glint_spots._PATCH_PX))
    if small.all():
        return _measure_patches(box, img, top, labels, noise, table, params)
    patch, pixel = np.flatnonzero(small), np.flatnonzero(~small)
    parts = [_measure_pixels(_gather(box.take(pixel), labels), img, top, noise, table,
                             params)[0]]
    if patch.size:
        parts.insert(0, _measure_patches(box.take(patch), img, top, labels, noise, table,
                                         params))
    return _Spots.concat(parts).take(np.argsort(np.concatenate([patch, pixel])))


def _touches_inner_side(y0, y1, x0, x1, margin: int, roi, frame_shape) -> bool:
    """Whether any of the boxes (window coordinates, inclusive ends), grown by ``margin``,
    reaches a side of the window ``roi`` that is not the frame's border."""
    r0, r1, c0, c1 = roi
    height, width = frame_shape
    return bool((r0 > 0 and (y0 <= margin).any())
                or (r1 < height and (y1 + margin >= r1 - r0 - 1).any())
                or (c0 > 0 and (x0 <= margin).any())
                or (c1 < width and (x1 + margin >= c1 - c0 - 1).any()))
