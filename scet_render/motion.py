"""Eye motion over time: fixations, main-sequence saccades and smooth pursuit.

The renderer samples the eye pose at every strobe instant s_j (about 1 kHz), so a
:class:`Trajectory` answers "where does the eye look at time t" for any array of times, without a
Python loop over samples. A trajectory is a list of segments laid end to end from t = 0:

* **fixation**: the optical axis holds the direction of a target, optionally with a small seeded
  fixational drift and tremor (:class:`FixationalNoise`, off unless asked for);
* **saccade**: a rotation along the great circle between two gaze directions, with duration and
  peak angular speed from the main sequence (:func:`main_sequence`);
* **pursuit**: a rotation along the great circle at constant angular speed.

Every direction is a unit vector from the eyeball rotation centre; poses are reported as the
Fick angles of :mod:`estimator.eye` (radians). Angular speeds are in rad/s, times in seconds.

Saccade profile
---------------
Carpenter's duration and Baloh's peak velocity fix the peak-to-mean speed ratio
Q = V_p D / A of each saccade. The position profile is a *plateau profile*: the normalised speed
rises as a half cosine over a fraction ``a`` of the duration, stays at its peak, then falls as a
half cosine over a fraction ``d``. Speed and acceleration are zero at both ends, the position is
monotone, reaches the amplitude exactly at D, and Q = 2 / (2 - (a + d)); solving for
a + d matches any Q in (1, 2]. ``acceleration_share`` = a / (a + d) skews the profile (real
saccades accelerate faster than they brake, Van Opstal & Van Gisbergen 1987); it does not
change Q. With the default constants Q is 0.78-1.29 (below the 1.6-2 usually measured, because
the two cited fits come from different studies), and below about 8 deg it is under 1, which no
profile that starts at rest can reach: the ramps are then clamped at ``min_ramp_fraction``,
the duration is kept and the peak speed comes out above the main-sequence value
(:attr:`Trajectory.segment_peak_speed_rad_s` reports the speed actually used).

References
----------
Carpenter, R. H. S. (1988). *Movements of the Eyes*, 2nd ed. Pion, London.
Baloh, R. W., Sills, A. W., Kumley, W. E., Honrubia, V. (1975). Quantitative measurement of
saccade amplitude, duration and velocity. *Neurology* 25, 1065-1070.
Van Opstal, A. J., Van Gisbergen, J. A. M. (1987). Skewness of saccadic velocity profiles.
*Vision Research* 27, 731-745.
Martinez-Conde, S., Macknik, S. L., Hubel, D. H. (2004). The role of fixational eye movements
in visual perception. *Nature Reviews Neuroscience* 5, 229-240.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from estimator.eye import Eye, fick_angles, gaze_direction
from estimator.setup import Screen

#: Carpenter (1988): saccade duration D = slope * A + intercept.
CARPENTER_SLOPE_S_PER_DEG = 2.2e-3
CARPENTER_INTERCEPT_S = 21e-3
#: Baloh et al. (1975): peak velocity V_p = V_max (1 - exp(-A / C)).
BALOH_V_MAX_DEG_S = 500.0
BALOH_C_DEG = 14.0

#: Two gaze directions closer than this are the same: no saccade is inserted between them.
SAME_DIRECTION_RAD = 1e-9
#: Sinusoids per axis in the fixational noise of one fixation: half drift, half tremor.
NOISE_COMPONENTS = 8


class SegmentKind(IntEnum):
    """Kind of a trajectory segment, as returned by :meth:`Trajectory.segment_at`."""

    FIXATION = 0
    SACCADE = 1
    PURSUIT = 2


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


@dataclass(frozen=True, slots=True, eq=False)
class Trajectory:
    """Eye motion as segments laid end to end from t = 0 (build it with the functions below).

    Segment i starts at ``start_s[i]`` and lasts ``segment_duration_s[i]``. Its deterministic
    gaze direction at normalised time u in [0, 1] is
    ``cos(theta) * start_direction[i] + sin(theta) * plane_direction[i]`` with
    ``theta = amplitude_rad[i] * progress(u)``: a great-circle arc, ``progress`` being the
    plateau profile with ``ramp_fraction[i]`` (zero ramps: linear, i.e. constant speed).
    Fixations have zero amplitude. Arrays are read-only copies.

    Attributes
    ----------
    kind : (n,) int8
        :class:`SegmentKind` of each segment.
    segment_duration_s : (n,) float
        Positive durations.
    start_direction, plane_direction : (n, 3) float
        Unit gaze direction at the segment start and the unit tangent it rotates toward
        (orthogonal to it; zeros for fixations).
    amplitude_rad : (n,) float
        Angle swept by the segment.
    ramp_fraction : (n, 2) float
        Acceleration and braking fractions of the saccade profile (zero otherwise).
    from_target_m, to_target_m : (n, 3) float
        World targets the segment starts and ends at (equal for fixations).
    eye_center_m : (3,) float
        Eyeball rotation centre the directions are taken from.
    noise_amplitude_rad, noise_frequency_hz, noise_phase_rad : (n, k, 2) float
        Fixational noise sinusoids per segment and axis (yaw, pitch); zeros for none.
    start_s : (n,) float
        Segment start times (derived).
    """

    kind: np.ndarray
    segment_duration_s: np.ndarray
    start_direction: np.ndarray
    plane_direction: np.ndarray
    amplitude_rad: np.ndarray
    ramp_fraction: np.ndarray
    from_target_m: np.ndarray
    to_target_m: np.ndarray
    eye_center_m: np.ndarray
    noise_amplitude_rad: np.ndarray | None = None
    noise_frequency_hz: np.ndarray | None = None
    noise_phase_rad: np.ndarray | None = None
    start_s: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        kind = np.asarray(self.kind)
        n = kind.shape[0] if kind.ndim == 1 else -1
        if n < 1 or not np.all(np.isin(kind, list(SegmentKind))):
            raise ValueError(f"kind must be a non-empty (n,) array of SegmentKind, got {kind!r}")
        shapes = {"segment_duration_s": (n,), "start_direction": (n, 3), "plane_direction": (n, 3),
                  "amplitude_rad": (n,), "ramp_fraction": (n, 2), "from_target_m": (n, 3),
                  "to_target_m": (n, 3), "eye_center_m": (3,)}
        noise_amp = self.noise_amplitude_rad
        noise_shape = (n, 0, 2) if noise_amp is None else np.shape(noise_amp)
        for name in ("noise_amplitude_rad", "noise_frequency_hz", "noise_phase_rad"):
            shapes[name] = noise_shape
        if len(noise_shape) != 3 or noise_shape[0] != n or noise_shape[2] != 2:
            raise ValueError(f"noise arrays must have shape ({n}, k, 2), got {noise_shape}")
        values = {"kind": kind.astype(np.int8)}
        for name, shape in shapes.items():
            v = getattr(self, name)
            a = np.zeros(shape) if v is None else np.array(v, dtype=np.float64)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise ValueError(f"{name} must be a finite array of shape {shape}, got {a.shape}")
            values[name] = a
        if np.any(values["segment_duration_s"] <= 0):
            raise ValueError("segment_duration_s must be > 0")
        if np.any(values["amplitude_rad"] < 0) or np.any(values["amplitude_rad"] >= np.pi):
            raise ValueError("amplitude_rad must lie in [0, pi)")
        ramp = values["ramp_fraction"]
        if np.any(ramp < 0) or np.any(ramp.sum(axis=1) > 1.0 + 1e-12):
            raise ValueError("ramp_fraction must be >= 0 with a row sum <= 1")
        if np.any(np.abs(np.linalg.norm(values["start_direction"], axis=1) - 1.0) > 1e-9):
            raise ValueError("start_direction must hold unit vectors")
        end = np.cumsum(values["segment_duration_s"])
        values["start_s"] = np.concatenate([[0.0], end[:-1]])
        for name, a in values.items():
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    # -- whole-trajectory properties ---------------------------------------------------------

    @property
    def duration_s(self) -> float:
        """Total duration: the end of the last segment."""
        return float(self.start_s[-1] + self.segment_duration_s[-1])

    @property
    def segment_count(self) -> int:
        return int(self.kind.shape[0])

    @property
    def segment_peak_speed_rad_s(self) -> np.ndarray:
        """(n,) peak angular speed of each segment's deterministic motion (0 for fixations)."""
        lo = 1.0 - 0.5 * self.ramp_fraction.sum(axis=1)
        return self.amplitude_rad / self.segment_duration_s / lo

    @property
    def initial_direction(self) -> np.ndarray:
        """(3,) gaze direction at t = 0 (without fixational noise)."""
        return self.start_direction[0].copy()

    @property
    def final_direction(self) -> np.ndarray:
        """(3,) gaze direction at t = duration (without fixational noise)."""
        a = self.amplitude_rad[-1]
        d = np.cos(a) * self.start_direction[-1] + np.sin(a) * self.plane_direction[-1]
        return d / np.linalg.norm(d)

    # -- sampling ----------------------------------------------------------------------------

    def segment_index_at(self, t_s) -> np.ndarray:
        """(...) int index of the segment each time falls in (times clamp to [0, duration])."""
        return self._locate(t_s)[0]

    def segment_at(self, t_s) -> np.ndarray:
        """(...) int8 :class:`SegmentKind` at each time (0 fixation, 1 saccade, 2 pursuit)."""
        return self.kind[self._locate(t_s)[0]]

    def angles_at(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Fick angles (yaw_rad, pitch_rad), each shaped like ``t_s``, at times in seconds.

        A time on a segment boundary belongs to the later segment; times outside
        [0, duration] clamp to the ends.
        """
        i, tau, u = self._locate(t_s)
        yaw, pitch = fick_angles(self._direction(i, u))
        yaw, pitch = np.asarray(yaw), np.asarray(pitch)
        noisy = self._noisy(i)
        if noisy.any():
            offset, _ = self._noise(i[noisy], tau[noisy])
            yaw[noisy] += offset[:, 0]
            pitch[noisy] += offset[:, 1]
        return yaw, pitch

    def direction_at(self, t_s) -> np.ndarray:
        """(..., 3) unit gaze directions (optical axis, world frame) at times ``t_s``."""
        return gaze_direction(*self.angles_at(t_s))

    def velocity_at(self, t_s) -> np.ndarray:
        """(...) angular speed of the gaze direction in rad/s (analytic, not differenced)."""
        i, tau, u = self._locate(t_s)
        speed = self.amplitude_rad[i] / self.segment_duration_s[i] * _progress_rate(
            u, self.ramp_fraction[i, 0], self.ramp_fraction[i, 1])
        noisy = self._noisy(i)
        if noisy.any():
            offset, rate = self._noise(i[noisy], tau[noisy])
            _, pitch0 = fick_angles(self.start_direction[i[noisy]])
            pitch = pitch0 + offset[:, 1]
            # |d gaze_direction / dt|^2 = cos^2(pitch) yaw'^2 + pitch'^2 for Fick angles.
            speed[noisy] = np.hypot(np.cos(pitch) * rate[:, 0], rate[:, 1])
        return speed

    def target_at(self, t_s) -> np.ndarray:
        """(..., 3) world point the eye fixates, heads for (saccade) or pursues, at ``t_s``.

        For pursuit this is the point of the straight line between the two pursuit targets
        that the deterministic gaze ray passes through.
        """
        i, _, u = self._locate(t_s)
        out = self.to_target_m[i].copy()
        chase = self.kind[i] == SegmentKind.PURSUIT
        if chase.any():
            ic = i[chase]
            d = self._direction(ic, u[chase])
            a = self.from_target_m[ic] - self.eye_center_m
            b = self.to_target_m[ic] - self.from_target_m[ic]
            # The ray c + s d meets the line a + lam b where (a + lam b) x d = 0; all three vectors
            # lie in one plane, so project the cross products on its normal.
            m = np.cross(a, b)
            lam = -np.sum(np.cross(a, d) * m, axis=-1) / np.sum(np.cross(b, d) * m, axis=-1)
            out[chase] = self.from_target_m[ic] + lam[:, None] * b
        return out

    # -- internals ---------------------------------------------------------------------------

    def _locate(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)
        if not np.all(np.isfinite(t)):
            raise ValueError("t_s must be finite")
        t = np.clip(t, 0.0, self.duration_s)
        i = np.clip(np.searchsorted(self.start_s, t, side="right") - 1, 0, self.segment_count - 1)
        tau = t - self.start_s[i]
        u = np.clip(tau / self.segment_duration_s[i], 0.0, 1.0)
        return i, tau, u

    def _direction(self, i, u):
        ramp = self.ramp_fraction[i]
        theta = self.amplitude_rad[i] * _progress(u, ramp[..., 0], ramp[..., 1])
        return (np.cos(theta)[..., None] * self.start_direction[i]
                + np.sin(theta)[..., None] * self.plane_direction[i])

    def _noisy(self, i):
        has = np.any(self.noise_amplitude_rad != 0, axis=(1, 2))
        return has[i]

    def _noise(self, i, tau):
        """Offsets (m, 2) added to (yaw, pitch) and their time derivatives (m, 2)."""
        amp = self.noise_amplitude_rad[i]
        omega = 2.0 * np.pi * self.noise_frequency_hz[i]
        phase = self.noise_phase_rad[i]
        duration = self.segment_duration_s[i][:, None]
        arg = omega * tau[:, None, None] + phase
        s = np.sum(amp * np.sin(arg), axis=1)
        ds = np.sum(amp * omega * np.cos(arg), axis=1)
        s0 = np.sum(amp * np.sin(phase), axis=1)
        slope = (np.sum(amp * np.sin(omega * duration[..., None] + phase), axis=1) - s0) / duration
        # Bridge: pinned to zero at tau = 0 and tau = T.
        return s - s0 - tau[:, None] * slope, ds - slope


# -- profile ---------------------------------------------------------------------------------


def _progress(u, a, d):
    """Plateau profile position in [0, 1] at normalised time u; a, d are the ramp fractions."""
    m = 1.0 - 0.5 * (a + d)
    sa = np.where(a > 0, a, 1.0)
    sd = np.where(d > 0, d, 1.0)
    r = 1.0 - u
    rise = 0.5 * u - sa / (2.0 * np.pi) * np.sin(np.pi * u / sa)
    fall = 0.5 * r - sd / (2.0 * np.pi) * np.sin(np.pi * r / sd)
    # Writing the braking branch as 1 - remaining makes the end land on exactly 1.
    return np.where(u < a, rise / m, np.where(r < d, 1.0 - fall / m, (u - 0.5 * a) / m))


def _progress_rate(u, a, d):
    """d progress / du of :func:`_progress` (its peak is 2 / (2 - a - d))."""
    m = 1.0 - 0.5 * (a + d)
    sa = np.where(a > 0, a, 1.0)
    sd = np.where(d > 0, d, 1.0)
    r = 1.0 - u
    rise = 0.5 * (1.0 - np.cos(np.pi * u / sa))
    fall = 0.5 * (1.0 - np.cos(np.pi * r / sd))
    return np.where(u < a, rise, np.where(r < d, fall, 1.0)) / m


# -- builders --------------------------------------------------------------------------------


def fixation_sequence(
    eye: Eye,
    targets_m,
    fixation_s,
    rng=None,
    *,
    noise: FixationalNoise | None = None,
    saccades: SaccadeModel = SaccadeModel(),
) -> Trajectory:
    """Fixations on each target in turn, joined by main-sequence saccades.

    Parameters
    ----------
    eye : Eye
        Gaze directions are taken from ``eye.rotation_center_m``.
    targets_m : (n, 3) float
        World targets, in front of the eye (direction with a negative z component).
    fixation_s : float or (n,) float
        Positive fixation durations in seconds.
    rng : numpy.random.Generator or int, optional
        Seed for the fixational noise; required when ``noise`` is given.
    noise : FixationalNoise, optional
        Fixational drift and tremor; None (the default) holds every target exactly.
    saccades : SaccadeModel
        Main-sequence constants and profile shape.

    Returns
    -------
    Trajectory
        Starts with the first fixation at t = 0 and ends with the last; repeated directions
        (closer than ``SAME_DIRECTION_RAD``) follow one another without a saccade.
    """
    c = eye.rotation_center_m
    targets, dirs = _targets(targets_m, c, "targets_m")
    n = targets.shape[0]
    fix_s = _durations(fixation_s, n, "fixation_s")
    gen = _noise_generator(rng, noise)

    pair_amp = _angle(dirs[:-1], dirs[1:])
    sac_dur, sac_ramp, _ = saccades.kinematics(np.where(pair_amp > 0, pair_amp, 1.0))
    rows = {
        "kind": np.full(2 * n - 1, SegmentKind.SACCADE, dtype=np.int8),
        "segment_duration_s": _interleave(fix_s, sac_dur),
        "start_direction": _interleave(dirs, dirs[:-1]),
        "plane_direction": _interleave(np.zeros_like(dirs), _tangent(dirs[:-1], dirs[1:])),
        "amplitude_rad": _interleave(np.zeros(n), pair_amp),
        "ramp_fraction": _interleave(np.zeros((n, 2)), sac_ramp),
        "from_target_m": _interleave(targets, targets[:-1]),
        "to_target_m": _interleave(targets, targets[1:]),
    }
    rows["kind"][0::2] = SegmentKind.FIXATION
    keep = np.ones(2 * n - 1, dtype=bool)
    keep[1::2] = pair_amp >= SAME_DIRECTION_RAD
    rows = {k: v[keep] for k, v in rows.items()}
    rows.update(_noise_rows(rows["kind"], gen, noise))
    return Trajectory(eye_center_m=c, **rows)


def saccade_sequence(
    eye: Eye,
    targets_m,
    rng,
    fixation_range_s: tuple[float, float] = (0.15, 0.4),
    *,
    noise: FixationalNoise | None = None,
    saccades: SaccadeModel = SaccadeModel(),
) -> Trajectory:
    """Fixations of uniformly random duration in ``fixation_range_s`` joined by saccades.

    ``rng`` (a ``numpy.random.Generator`` or an int seed) draws the durations first, then the
    fixational noise; the same seed gives identical trajectories. Other parameters as in
    :func:`fixation_sequence`.
    """
    lo, hi = (float(x) for x in fixation_range_s)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(
            f"fixation_range_s must be (lo, hi) with 0 < lo <= hi, got {fixation_range_s}")
    gen = _as_generator(rng)
    if gen is None:
        raise ValueError("saccade_sequence needs rng (a numpy.random.Generator or an int seed)")
    n = _targets(targets_m, eye.rotation_center_m, "targets_m")[0].shape[0]
    fix_s = gen.uniform(lo, hi, n)
    return fixation_sequence(eye, targets_m, fix_s, gen, noise=noise, saccades=saccades)


def grid_sequence(
    eye: Eye,
    screen: Screen,
    cols: int,
    rows: int,
    fixation_s,
    rng=None,
    *,
    margin: float = 0.5,
    noise: FixationalNoise | None = None,
    saccades: SaccadeModel = SaccadeModel(),
) -> Trajectory:
    """Fixations on ``screen.grid(cols, rows, margin)`` in its row-major order (top left first).

    ``fixation_s`` is a scalar or a (rows * cols,) array; the rest as in
    :func:`fixation_sequence`.
    """
    targets = screen.grid(cols, rows, margin)
    return fixation_sequence(eye, targets, fixation_s, rng, noise=noise, saccades=saccades)


def pursuit(eye: Eye, start_m, end_m, speed_deg_s: float) -> Trajectory:
    """Smooth pursuit from ``start_m`` to ``end_m`` (world points, (3,)) at constant speed.

    The gaze turns along the great circle between the two directions at ``speed_deg_s``
    (deg/s, > 0) from t = 0 to A / speed; there is no initiation ramp or catch-up saccade.
    :meth:`Trajectory.target_at` follows the point of the straight line from ``start_m`` to
    ``end_m`` under the gaze. Join it to fixations with :func:`concatenate`.
    """
    c = eye.rotation_center_m
    pts, dirs = _targets(np.stack([_point(start_m, "start_m"), _point(end_m, "end_m")]), c,
                         "start_m/end_m")
    speed = float(speed_deg_s)
    if not np.isfinite(speed) or speed <= 0:
        raise ValueError(f"speed_deg_s must be finite and > 0, got {speed_deg_s}")
    amp = float(_angle(dirs[0], dirs[1]))
    if amp < SAME_DIRECTION_RAD:
        raise ValueError("pursuit needs start_m and end_m in different directions from the eye")
    return Trajectory(
        kind=np.array([SegmentKind.PURSUIT]),
        segment_duration_s=np.array([amp / np.deg2rad(speed)]),
        start_direction=dirs[:1],
        plane_direction=_tangent(dirs[:1], dirs[1:]),
        amplitude_rad=np.array([amp]),
        ramp_fraction=np.zeros((1, 2)),
        from_target_m=pts[:1],
        to_target_m=pts[1:],
        eye_center_m=c,
    )


def concatenate(trajectories, *, saccades: SaccadeModel = SaccadeModel()) -> Trajectory:
    """Play trajectories one after the other.

    Where one ends looking elsewhere than the next starts, a main-sequence saccade joins them
    (from the last target of one to the first of the next). All must share one eye centre.
    """
    trajs = list(trajectories)
    if not trajs or not all(isinstance(t, Trajectory) for t in trajs):
        raise ValueError("concatenate needs a non-empty sequence of Trajectory")
    c = trajs[0].eye_center_m
    if any(not np.array_equal(t.eye_center_m, c) for t in trajs):
        raise ValueError("concatenate needs trajectories of the same eye (eye_center_m differs)")
    k = max(t.noise_amplitude_rad.shape[1] for t in trajs)
    parts = [_rows(trajs[0], k)]
    for prev, nxt in zip(trajs[:-1], trajs[1:]):
        d0, d1 = prev.final_direction, nxt.initial_direction
        amp = _angle(d0, d1)
        if amp >= SAME_DIRECTION_RAD:
            dur, ramp, _ = saccades.kinematics(np.array([amp]))
            parts.append({
                "kind": np.array([SegmentKind.SACCADE], dtype=np.int8),
                "segment_duration_s": dur,
                "start_direction": d0[None],
                "plane_direction": _tangent(d0[None], d1[None]),
                "amplitude_rad": np.array([amp]),
                "ramp_fraction": ramp,
                "from_target_m": prev.to_target_m[-1:],
                "to_target_m": nxt.from_target_m[:1],
                **_noise_rows(np.array([SegmentKind.SACCADE]), None, None, k),
            })
        parts.append(_rows(nxt, k))
    rows = {name: np.concatenate([p[name] for p in parts]) for name in parts[0]}
    return Trajectory(eye_center_m=c, **rows)


# -- helpers ---------------------------------------------------------------------------------


def _as_generator(rng) -> np.random.Generator | None:
    if rng is None or isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise TypeError(
        f"rng must be a numpy.random.Generator, an int seed or None, got {type(rng).__name__}")


def _noise_generator(rng, noise):
    gen = _as_generator(rng)
    if noise is not None and gen is None:
        raise ValueError("fixational noise needs rng (a numpy.random.Generator or an int seed)")
    return gen


def _point(x, name):
    p = np.asarray(x, dtype=np.float64)
    if p.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {p.shape}")
    return p


def _targets(targets_m, center_m, name):
    """(n, 3) targets and their unit directions from the eye; rejects bad or rear targets."""
    t = np.asarray(targets_m, dtype=np.float64)
    if t.ndim != 2 or t.shape[1] != 3 or t.shape[0] < 1:
        raise ValueError(f"{name} must have shape (n, 3) with n >= 1, got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{name} must be finite")
    v = t - center_m
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    behind = (v[:, 2] >= 0) | (norm[:, 0] == 0)
    if behind.any():
        bad = np.flatnonzero(behind).tolist()
        raise ValueError(f"{name}: targets {bad} are not in front of the "
                         "eye (the eye looks along -z, so a target needs z < the eye centre's z)")
    return t, v / norm


def _durations(x, n, name):
    d = np.asarray(x, dtype=np.float64)
    if d.shape not in ((), (n,)):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {d.shape}")
    d = np.broadcast_to(d, (n,)).copy()
    if not np.all(np.isfinite(d)) or np.any(d <= 0):
        raise ValueError(f"{name} must be finite and > 0, got {d}")
    return d


def _angle(a, b):
    """Angle in radians between unit vectors (..., 3), accurate for small and large angles."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _tangent(d0, d1):
    """(m, 3) unit vectors orthogonal to d0 in the plane of d0 and d1 (zeros if parallel)."""
    e = d1 - np.sum(d0 * d1, axis=-1, keepdims=True) * d0
    n = np.linalg.norm(e, axis=-1, keepdims=True)
    return np.divide(e, n, out=np.zeros_like(e), where=n > 0)


def _interleave(even, odd):
    out = np.empty((even.shape[0] + odd.shape[0],) + even.shape[1:], dtype=np.float64)
    out[0::2] = even
    out[1::2] = odd
    return out


def _rows(traj: Trajectory, k: int) -> dict:
    names = ("kind", "segment_duration_s", "start_direction", "plane_direction", "amplitude_rad",
             "ramp_fraction", "from_target_m", "to_target_m")
    rows = {name: getattr(traj, name) for name in names}
    pad = ((0, 0), (0, k - traj.noise_amplitude_rad.shape[1]), (0, 0))
    for name in ("noise_amplitude_rad", "noise_frequency_hz", "noise_phase_rad"):
        rows[name] = np.pad(getattr(traj, name), pad)
    return rows


def _noise_rows(kind, gen, noise, k: int = NOISE_COMPONENTS) -> dict:
    """Noise arrays for segments: sinusoids for fixations when ``noise`` is set, else zeros."""
    n = kind.shape[0]
    amp, freq, phase = np.zeros((n, k, 2)), np.zeros((n, k, 2)), np.zeros((n, k, 2))
    if noise is not None:
        fix = np.flatnonzero(kind == SegmentKind.FIXATION)
        m, kd = fix.size, k // 2
        lo, hi = np.log(noise.drift_band_hz[0]), np.log(noise.drift_band_hz[1])
        f_drift = np.exp(gen.uniform(lo, hi, (m, kd, 2)))
        f_tremor = gen.uniform(*noise.tremor_band_hz, (m, k - kd, 2))
        phase[fix] = gen.uniform(0.0, 2.0 * np.pi, (m, k, 2))
        freq[fix] = np.concatenate([f_drift, f_tremor], axis=1)
        a_drift, a_tremor = 1.0 / f_drift, np.ones_like(f_tremor)
        # A sum of sinusoids with amplitudes a_k has RMS sqrt(sum a_k^2 / 2).
        a_drift *= noise.drift_rms_rad / np.sqrt(0.5 * np.sum(a_drift**2, axis=1, keepdims=True))
        a_tremor *= noise.tremor_rms_rad / np.sqrt(0.5 * np.sum(a_tremor**2, axis=1, keepdims=True))
        amp[fix] = np.concatenate([a_drift, a_tremor], axis=1)
    return {"noise_amplitude_rad": amp, "noise_frequency_hz": freq, "noise_phase_rad": phase}
