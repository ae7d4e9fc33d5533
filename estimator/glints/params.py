"""The detector's value types: :class:`DetectionParams` (every threshold with the
measurement that chose it), :class:`GlintDetections` (one frame's glints) and the flag bits.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

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


#: Undistortion: OpenCV's iteration stops at a reprojection error below 1e-10 px or after 50
#: steps; any point whose round trip through the lens is then off by more than
#: :data:`UNDISTORT_CHECK_PX` is solved again by the camera's Newton inversion. Measured on 40
#: glints of paper_sim with k1 = -0.35: 67 us a frame with the check (OpenCV's step alone
#: 13.5 us) against 517 us for the Newton inversion (Camera.undistort_px); they agree to 1e-10 px.
UNDISTORT_CRITERIA = (3, 50, 1e-10)  # cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS
UNDISTORT_CHECK_PX = 1e-6


def undistort_points_px(camera, points_px) -> np.ndarray:
    """(k, 2) distorted pixel positions -> (k, 2) ideal (pinhole) ones through ``camera``'s
    lens: ``cv2.undistortPoints`` into the same intrinsics, checked by the round trip through
    ``cv2.projectPoints`` (:data:`UNDISTORT_CRITERIA`);
    :meth:`estimator.geometry.Camera.undistort_px` where that
    fails (NaN where the lens cannot be inverted)."""
    import cv2

    px = np.ascontiguousarray(points_px, dtype=np.float64).reshape(-1, 2)
    K = camera.K
    uv = cv2.undistortPoints(px.reshape(-1, 1, 2), K, camera.distortion, P=K,
                             criteria=UNDISTORT_CRITERIA).reshape(-1, 2)
    xy1 = np.column_stack([(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1],
                           np.ones(len(uv))])
    back = cv2.projectPoints(xy1, np.zeros(3), np.zeros(3), K, camera.distortion)[0]
    bad = ~(np.abs(back.reshape(-1, 2) - px).max(axis=1) <= UNDISTORT_CHECK_PX)
    if bad.any():
        uv[bad] = camera.undistort_px(px[bad])
    return uv


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

    def undistorted(self, camera) -> "GlintDetections":
        """The detections with their centroids moved through ``camera``'s lens into the ideal
        (pinhole) image that the estimator's geometry works in
        (:meth:`estimator.geometry.Camera.undistort_px`); ``self`` for a pinhole (no copy, no
        cost, byte-identical). Strobes, times and flags stay those of the detected rows: a
        glint was read out where the lens put it."""
        if not camera.has_distortion or not len(self):
            return self
        uv = undistort_points_px(camera, self.glints_px)
        return replace(self, u_px=np.ascontiguousarray(uv[:, 0]),
                       v_px=np.ascontiguousarray(uv[:, 1]))

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
