"""Eye-movement events from gaze samples, against the motion model's ground truth.

The detectors are pymovements' own (optional extra ``events``): the velocity threshold I-VT
and the dispersion threshold I-DT of Salvucci and Goldberg (2000), both of which find
fixations; a saccade is the run of samples between two consecutive fixations. Velocities come
from pymovements' ``pos2vel``. Nothing here re-implements a detector.

The samples of a SCET stream are not evenly spaced: each band is a strobe instant, and the
invisible lines of every frame leave a gap (about 6 ms at 16 pulses per frame in
``paper_sim``). :func:`uniform_series` puts the samples on the strobe's own clock (one slot
per pulse, or per frame at 60 Hz) and bridges gaps of at most :data:`MAX_GAP_S` linearly
(the interpolation the SCET paper suggests for such gaps, Sec. 5.1); longer gaps stay NaN and
break fixations.

Conventions, the same at every rate: positions are the Fick angles of the optical axis in
degrees (yaw, pitch); a detected saccade starts half a sample after the last sample of the
fixation before it and ends half a sample before the first sample of the fixation after it;
its peak velocity is the largest speed of the samples in between (and the two fixation
samples that bound them); its amplitude the angle between those two fixation samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Gaps between valid samples up to this long are bridged by linear interpolation: more than
#: the invisible-lines gap of a SCET frame (6-7 ms at 8-16 pulses), less than two 60 Hz
#: frame periods (33 ms), so a lost 60 Hz sample stays lost.
MAX_GAP_S = 0.020
#: I-VT threshold (deg/s): a common choice for saccades (Salvucci and Goldberg use 20; 30
#: keeps fixational drift and estimation noise of ~0.1 deg per sample out).
IVT_THRESHOLD_DEG_S = 30.0
#: I-DT dispersion threshold (deg): pymovements' default, about the fovea.
IDT_DISPERSION_DEG = 1.0
#: Shortest fixation of both detectors (s): shorter than the shortest fixation of the
#: "saccades" trajectory (100 ms), longer than any saccade.
MIN_FIXATION_S = 0.05
#: Velocity filter: a Savitzky-Golay window of about this length (s), at least 3 samples
#: (at 60 Hz that is the central difference), fitted with a quadratic where it has 5 or more.
VELOCITY_WINDOW_S = 0.010
DETECTORS = ("ivt", "idt")


def _pymovements():
    try:
        import pymovements  # noqa: F401
        from pymovements.events import idt, ivt
        from pymovements.transforms.numpy import pos2vel
    except ImportError as exc:  # pragma: no cover - the extra is part of 'all'
        raise ImportError("event detection needs pymovements: pip install 'scet[events]'"
                          f" ({exc})") from None
    return ivt, idt, pos2vel


@dataclass(frozen=True, slots=True)
class Series:
    """Gaze on an even clock: times (n,) s, positions (n, 2) deg (NaN: missing)."""

    time_s: np.ndarray
    position_deg: np.ndarray
    period_s: float

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.period_s


def uniform_series(time_s, position_deg, period_s: float, *, origin_s: float | None = None,
                   max_gap_s: float = MAX_GAP_S) -> Series:
    """Samples on the clock ``origin_s + k period_s`` (each sample to its nearest slot), gaps
    up to ``max_gap_s`` between valid samples interpolated linearly."""
    t = np.asarray(time_s, dtype=np.float64)
    x = np.asarray(position_deg, dtype=np.float64).reshape(-1, 2)
    if t.shape != (x.shape[0],):
        raise ValueError(f"time_s {t.shape} and position_deg {x.shape} must have one row per sample")
    if not (math.isfinite(period_s) and period_s > 0):
        raise ValueError(f"period_s must be positive, got {period_s!r}")
    ok = np.isfinite(x).all(axis=1) & np.isfinite(t)
    if not ok.any():
        raise ValueError("no valid gaze sample to build a series from")
    origin = float(t[np.isfinite(t)].min()) if origin_s is None else float(origin_s)
    k = np.round((t - origin) / period_s).astype(np.int64)
    n = int(k[np.isfinite(t)].max()) + 1
    out = np.full((n, 2), np.nan)
    out[k[ok]] = x[ok]
    slots = np.flatnonzero(np.isfinite(out[:, 0]))
    for a, b in zip(slots[:-1], slots[1:]):
        if 1 < b - a and (b - a) * period_s <= max_gap_s + 1e-12:
            w = (np.arange(a + 1, b) - a) / (b - a)
            out[a + 1:b] = out[a] + w[:, None] * (out[b] - out[a])
    return Series(origin + period_s * np.arange(n), out, float(period_s))


@dataclass(frozen=True, slots=True)
class Saccades:
    """Saccades (m,) of a series: onset/offset (s), peak speed (deg/s), amplitude (deg)."""

    onset_s: np.ndarray
    offset_s: np.ndarray
    peak_velocity_deg_s: np.ndarray
    amplitude_deg: np.ndarray

    @property
    def count(self) -> int:
        return int(self.onset_s.shape[0])

    @property
    def duration_s(self) -> np.ndarray:
        return self.offset_s - self.onset_s


def _angle_deg(a, b) -> np.ndarray:
    from estimator.eye import gaze_direction

    da = gaze_direction(*np.radians(a).T)
    db = gaze_direction(*np.radians(b).T)
    return np.degrees(np.arccos(np.clip(np.sum(da * db, axis=-1), -1.0, 1.0)))


def velocity(series: Series) -> np.ndarray:
    """(n, 2) deg/s from pymovements' ``pos2vel`` (Savitzky-Golay, :data:`VELOCITY_WINDOW_S`)."""
    _, _, pos2vel = _pymovements()
    n = max(3, int(round(VELOCITY_WINDOW_S / series.period_s)))
    n += 1 - n % 2
    degree = 2 if n >= 5 else 1
    x = series.position_deg
    if x.shape[0] < n:
        raise ValueError(f"a series of {x.shape[0]} samples is shorter than the velocity window "
                         f"({n} samples)")
    return pos2vel(x, sampling_rate=series.rate_hz, method="savitzky_golay", window_length=n,
                   polyorder=degree, mode="nearest")


def detect_saccades(series: Series, detector: str = "ivt") -> Saccades:
    """Saccades between the fixations pymovements' I-VT or I-DT finds (module docstring)."""
    if detector not in DETECTORS:
        raise ValueError(f"detector must be one of {DETECTORS}, got {detector!r}")
    ivt, idt, _ = _pymovements()
    T = series.period_s
    steps = np.arange(series.time_s.shape[0], dtype=np.int64)  # slots: duration in samples
    min_dur = max(1, int(round(MIN_FIXATION_S / T)))
    vel = velocity(series)
    if detector == "ivt":
        events = ivt(vel, timesteps=steps, minimum_duration=min_dur,
                     velocity_threshold=IVT_THRESHOLD_DEG_S)
    else:
        events = idt(series.position_deg, timesteps=steps, minimum_duration=min_dur,
                     dispersion_threshold=IDT_DISPERSION_DEG)
    frame = events.frame if hasattr(events, "frame") else events
    on = np.asarray(frame["onset"], dtype=np.int64)
    off = np.asarray(frame["offset"], dtype=np.int64)
    order = np.argsort(on)
    on, off = on[order], off[order]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    rows = []
    for a, b in zip(off[:-1], on[1:]):  # last sample of one fixation, first of the next
        if b <= a:
            continue
        gap = series.position_deg[a:b + 1]
        if not np.isfinite(gap).all():
            continue  # data lost between them: no saccade can be measured
        rows.append((series.time_s[a] + 0.5 * T, series.time_s[b] - 0.5 * T,
                     float(np.nanmax(speed[a:b + 1])),
                     float(_angle_deg(series.position_deg[a][None], series.position_deg[b][None])[0])))
    arr = np.array(rows, dtype=np.float64).reshape(-1, 4)
    return Saccades(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3])


def true_saccades(trajectory, t0_s: float, t1_s: float) -> Saccades:
    """The trajectory's saccades that lie wholly inside [t0_s, t1_s] with room for a
    fixation of :data:`MIN_FIXATION_S` on both sides (a detector needs one there)."""
    from scet_render.motion import SegmentKind

    kind = np.asarray(trajectory.kind)
    start = trajectory.start_s
    end = start + trajectory.segment_duration_s
    sel = ((kind == SegmentKind.SACCADE) & (start >= t0_s + MIN_FIXATION_S)
           & (end <= t1_s - MIN_FIXATION_S))
    return Saccades(start[sel].copy(), end[sel].copy(),
                    np.degrees(trajectory.segment_peak_speed_rad_s[sel]),
                    np.degrees(trajectory.amplitude_rad[sel]))


@dataclass(frozen=True, slots=True)
class EventScores:
    """Detected against true saccades (errors: detected minus true, over matched ones)."""

    n_true: int
    n_detected: int
    n_matched: int
    onset_ms: np.ndarray
    offset_ms: np.ndarray
    duration_ms: np.ndarray
    peak_velocity_deg_s: np.ndarray
    amplitude_deg: np.ndarray

    @property
    def detection_rate(self) -> float:
        return self.n_matched / self.n_true if self.n_true else math.nan

    @property
    def false_detections(self) -> int:
        return self.n_detected - self.n_matched


def score_saccades(detected: Saccades, truth: Saccades, period_s: float) -> EventScores:
    """Match each true saccade to the detected one overlapping it most (one to one, true
    saccades in order), the true interval widened by half a sample on each side (a saccade
    shorter than a sample period can fall between two samples)."""
    used = np.zeros(detected.count, dtype=bool)
    pairs = []
    pad = 0.5 * period_s
    for i in range(truth.count):
        lo, hi = truth.onset_s[i] - pad, truth.offset_s[i] + pad
        overlap = np.minimum(detected.offset_s, hi) - np.maximum(detected.onset_s, lo)
        touch = (overlap >= 0) & ~used
        if touch.any():
            j = int(np.argmax(np.where(touch, overlap, -np.inf)))
            used[j] = True
            pairs.append((i, j))
    ti = np.array([p[0] for p in pairs], dtype=np.int64)
    dj = np.array([p[1] for p in pairs], dtype=np.int64)
    return EventScores(
        truth.count, detected.count, len(pairs),
        1e3 * (detected.onset_s[dj] - truth.onset_s[ti]),
        1e3 * (detected.offset_s[dj] - truth.offset_s[ti]),
        1e3 * (detected.duration_s[dj] - truth.duration_s[ti]),
        detected.peak_velocity_deg_s[dj] - truth.peak_velocity_deg_s[ti],
        detected.amplitude_deg[dj] - truth.amplitude_deg[ti])
