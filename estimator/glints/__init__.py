"""Glint detection in banded frames: sub-pixel centroids, the strobe and time of each
glint, flags.

Modules: ``params`` (:class:`DetectionParams`, :class:`GlintDetections`, flags), ``noise``
(the frame's noise model), ``spots`` (spot measurement and band timing), ``kernels`` (the
same steps compiled with Numba, optional), ``detector`` (:func:`detect_glints`), ``sequence``
(:class:`GlintDetector` over a stream).
"""

from .detector import detect_glints
from .params import (
    BLENDED,
    CUT_BY_BAND_EDGE,
    FLAG_NAMES,
    IMAGE_EDGE,
    NO_BAND,
    SATURATED,
    TWO_PULSES,
    DetectionParams,
    GlintDetections,
    undistort_points_px,
)
from .sequence import STRIP_PAD_PX, GlintDetector, glint_px_per_deg, window_margin_px

__all__ = [
    "detect_glints", "SATURATED", "CUT_BY_BAND_EDGE", "TWO_PULSES", "IMAGE_EDGE", "NO_BAND",
    "BLENDED", "FLAG_NAMES", "DetectionParams", "GlintDetections", "GlintDetector",
    "window_margin_px", "glint_px_per_deg", "STRIP_PAD_PX", "undistort_points_px"
]
