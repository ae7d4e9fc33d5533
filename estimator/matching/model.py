"""What the matcher predicts from: the calibrated eye, the angle prior of a band and
the hypotheses of the search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..calibration import Calibration
from ..eye import Eye


@dataclass(frozen=True, slots=True)
class _Prior:
    """A prior on the eye rotation: mean (2,) rad, weight Σ⁻¹ (2, 2) in 1/rad² of the score,
    and optionally (mean, σ² Σ⁻¹) for the refits (:func:`estimator.cornea.fit_cornea`)."""

    mean: np.ndarray
    weight: np.ndarray
    fit: tuple | None = None

    def distance2(self, angles) -> float:
        d = np.asarray(angles, dtype=np.float64) - self.mean
        return float(d @ self.weight @ d)


@dataclass(frozen=True, slots=True)
class _Hypothesis:
    x: np.ndarray  # fit parameters: angles (2,) or centre (3,)
    assign: np.ndarray  # (k,) light per detection, -1 unmatched
    residual: np.ndarray  # (k,)
    pred: np.ndarray  # (n, 2) predicted glints at x
    cand: np.ndarray  # (n,) candidate (visible, in band)
    score: float
    iterations: int
    fit_ok: bool


def calibrated_eye(eye: Eye, calibration: Calibration | None) -> Eye:
    """The eye a calibration describes: its corneal radius r_c and, where it has them, its eye
    centre c_e and orbit radius r_co; the nominal ``eye``'s otherwise. The limbus depth scales
    with r_c, which keeps the cap's angular extent (the nominal eye's is the only one known)."""
    if calibration is None:
        return eye
    r_c = calibration.cornea_radius_m
    center, offset = eye.rotation_center_m, eye.cornea_offset_m
    if calibration.has_orbit:
        center, offset = calibration.eye_center_m, calibration.orbit_radius_m
    return Eye(center, r_c, offset, eye.limbus_depth_m * r_c / eye.cornea_radius_m,
               eye.refractive_index)
