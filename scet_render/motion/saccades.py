"""Saccade and fixation models: the main sequence (Carpenter 1988, Baloh et al.
1975), :class:`SaccadeModel` and the fixational drift and tremor of :class:`FixationalNoise`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Carpenter (1988): saccade duration D = slope * A + intercept.
CARPENTER_SLOPE_S_PER_DEG = 2.2e-3
CARPENTER_INTERCEPT_S = 21e-3
#: Baloh et al. (1975): peak velocity V_p = V_max (1 - exp(-A / C)).
BALOH_V_MAX_DEG_S = 500.0
BALOH_C_DEG = 14.0


def _check_positive(**values):
    for name, v in values.items():
        if not np.isfinite(v) or v <= 0:
            raise ValueError(f"{name} must be finite and > 0, got {v}")


def main_sequence(
    amplitude_deg,
    *,
    slope_s_per_deg: float = CARPENTER_SLOPE_S_PER_DEG,
    intercept_s: float = CARPENTER_INTERCEPT_S,
    v_max_deg_s: float = BALOH_V_MAX_DEG_S,
    c_deg: float = BALOH_C_DEG,
) -> tuple[np.ndarray, np.ndarray]:
    """Duration and peak velocity of saccades of the given amplitudes.

    D = slope * A + intercept (Carpenter 1988: 2.2 ms/deg and 21 ms) and
    V_p = V_max (1 - exp(-A / C)) (Baloh et al. 1975: V_max = 500 deg/s, C = 14 deg).

    Parameters
    ----------
    amplitude_deg : (...) float
        Saccade amplitudes in degrees, finite and non-negative.

    Returns
    -------
    duration_s : (...) float
        Durations in seconds.
    peak_velocity_deg_s : (...) float
        Peak angular velocities in deg/s.
    """
    a = np.asarray(amplitude_deg, dtype=np.float64)
    if not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ValueError(f"amplitude_deg must be finite and >= 0, got {a}")
    _check_positive(slope_s_per_deg=slope_s_per_deg, v_max_deg_s=v_max_deg_s, c_deg=c_deg)
    if not np.isfinite(intercept_s) or intercept_s < 0:
        raise ValueError(f"intercept_s must be finite and >= 0, got {intercept_s}")
    return slope_s_per_deg * a + intercept_s, v_max_deg_s * -np.expm1(-a / c_deg)


@dataclass(frozen=True, slots=True)
class SaccadeModel:
    """Main-sequence constants and profile shape of saccades (see the module docstring).

    ``acceleration_share`` is the part of the ramp time spent accelerating (0.5: symmetric).
    ``min_ramp_fraction`` is the smallest part of the duration spent accelerating plus braking;
    it bounds the peak acceleration and sets the smallest reachable peak-to-mean speed ratio,
    2 / (2 - min_ramp_fraction). The largest is 2 (a raised-cosine speed profile).
    """

    slope_s_per_deg: float = CARPENTER_SLOPE_S_PER_DEG
    intercept_s: float = CARPENTER_INTERCEPT_S
    v_max_deg_s: float = BALOH_V_MAX_DEG_S
    c_deg: float = BALOH_C_DEG
    acceleration_share: float = 0.5
    min_ramp_fraction: float = 0.1

    def __post_init__(self):
        main_sequence(0.0, slope_s_per_deg=self.slope_s_per_deg, intercept_s=self.intercept_s,
                      v_max_deg_s=self.v_max_deg_s, c_deg=self.c_deg)
        if not 0.0 < self.acceleration_share < 1.0:
            raise ValueError(
                f"acceleration_share must lie in (0, 1), got {self.acceleration_share}")
        if not 0.0 < self.min_ramp_fraction <= 1.0:
            raise ValueError(f"min_ramp_fraction must lie in (0, 1], got {self.min_ramp_fraction}")

    @property
    def peak_to_mean_range(self) -> tuple[float, float]:
        """Smallest and largest peak-to-mean speed ratio V_p D / A the profile can reach."""
        return 2.0 / (2.0 - self.min_ramp_fraction), 2.0

    def kinematics(self, amplitude_rad) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Duration, ramp fractions and peak angular speed of saccades.

        Parameters
        ----------
        amplitude_rad : (m,) float
            Amplitudes in radians (> 0).

        Returns
        -------
        duration_s : (m,) float
        ramp_fraction : (m, 2) float
            Fractions of the duration spent accelerating and braking.
        peak_speed_rad_s : (m,) float
            Peak angular speed of the profile actually used; it differs from the main-sequence
            value where the ratio V_p D / A had to be clamped.
        """
        amp = np.asarray(amplitude_rad, dtype=np.float64)
        duration_s, v_peak_deg_s = main_sequence(
            np.rad2deg(amp), slope_s_per_deg=self.slope_s_per_deg, intercept_s=self.intercept_s,
            v_max_deg_s=self.v_max_deg_s, c_deg=self.c_deg)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.deg2rad(v_peak_deg_s) * duration_s / amp
        q_lo, q_hi = self.peak_to_mean_range
        q = np.clip(np.nan_to_num(q, nan=q_lo), q_lo, q_hi)
        ramp = 2.0 - 2.0 / q
        share = self.acceleration_share
        ramp_fraction = np.stack([share * ramp, (1.0 - share) * ramp], axis=-1)
        return duration_s, ramp_fraction, amp * q / duration_s


@dataclass(frozen=True, slots=True)
class FixationalNoise:
    """Seeded fixational drift and tremor, added to the Fick angles during fixations.

    Each axis (yaw, pitch) gets a sum of sinusoids with random phases: drift components with
    log-uniform frequencies in ``drift_band_hz`` and 1/f amplitudes (a random-walk-like
    spectrum), tremor components with uniform frequencies in ``tremor_band_hz``, each group
    scaled to its RMS. The sum S(tau) is pinned to zero at both ends of a fixation of duration T
    like a Brownian bridge, S(tau) - S(0) - (tau / T) (S(T) - S(0)), so gaze stays continuous
    into the saccades (the tremor's speed is not pinned: it may jump by a few deg/s there). The
    defaults have the orders of magnitude reviewed by Martinez-Conde et al. (2004): drift of a
    few arcmin at well under 1 deg/s, tremor of some arcsec near 90 Hz. Microsaccades are not
    modelled.
    """

    drift_rms_rad: float = float(np.deg2rad(2.0 / 60.0))
    drift_band_hz: tuple[float, float] = (0.5, 5.0)
    tremor_rms_rad: float = float(np.deg2rad(10.0 / 3600.0))
    tremor_band_hz: tuple[float, float] = (60.0, 100.0)

    def __post_init__(self):
        for name in ("drift_rms_rad", "tremor_rms_rad"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {v}")
        for name in ("drift_band_hz", "tremor_band_hz"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
                raise ValueError(f"{name} must be (lo, hi) with 0 < lo <= hi, got {(lo, hi)}")
