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

import dataclasses
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from estimator.eye import fick_angles, gaze_direction

from .blinks import Blinks
from .pupil import PupilTrace

#: Two gaze directions closer than this are the same: no saccade is inserted between them.
SAME_DIRECTION_RAD = 1e-9
#: Sinusoids per axis in the fixational noise of one fixation: half drift, half tremor.
NOISE_COMPONENTS = 8


class SegmentKind(IntEnum):
    """Kind of a trajectory segment, as returned by :meth:`Trajectory.segment_at`."""

    FIXATION = 0
    SACCADE = 1
    PURSUIT = 2


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
    blinks : Blinks, optional
        Blinks of the upper lid over the same time axis (:mod:`scet_render.motion.blinks`);
        None: the lids never blink. :func:`with_blinks` adds them to a trajectory.
    pupil : PupilTrace, optional
        The pupil's size over the same time axis (:mod:`scet_render.motion.pupil`); None:
        the scene's size throughout. :func:`with_pupil` adds it.
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
    blinks: Blinks | None = None
    pupil: PupilTrace | None = None

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

    def lid_closure_at(self, t_s) -> np.ndarray:
        """(...) upper lid closure of the blinks (0 open .. 1 shut) at times ``t_s``."""
        t = np.clip(np.asarray(t_s, dtype=np.float64), 0.0, self.duration_s)
        return np.zeros(t.shape) if self.blinks is None else self.blinks.closure_at(t)

    def pupil_diameter_at(self, t_s, default_m: float) -> np.ndarray:
        """(...) pupil diameter (m) at times ``t_s``: the ``pupil`` trace's, or ``default_m``
        (the scene's ``eye.pupil_diameter_m``) where the trajectory has none."""
        t = np.clip(np.asarray(t_s, dtype=np.float64), 0.0, self.duration_s)
        if self.pupil is None:
            return np.full(t.shape, float(default_m))
        return self.pupil.diameter_at(t)

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


def with_blinks(trajectory: Trajectory, blinks: Blinks | None) -> Trajectory:
    """The trajectory with the upper lid blinking as ``blinks`` says (None: no blinks)."""
    return dataclasses.replace(trajectory, blinks=blinks)


def with_pupil(trajectory: Trajectory, pupil: PupilTrace | None) -> Trajectory:
    """The trajectory with the pupil's size following ``pupil`` (None: the scene's size)."""
    return dataclasses.replace(trajectory, pupil=pupil)


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
