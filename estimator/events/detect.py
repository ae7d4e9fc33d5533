"""Saccades and microsaccades from band samples at their strobe instants.

The algorithm, on samples as the tracker gives them (irregular instants, the blanking gap,
NaN bands):

1. Velocities from local line fits over irregular time stamps
   (:func:`estimator.events.velocity.local_velocity`) at three scales: ``timing_window_s`` to
   place onsets and offsets, ``peak_window_s`` to measure the peak velocity, and
   ``small_window_s`` to find microsaccades, whose speeds are near the noise of the short
   windows.
2. The noise of each velocity scale from the data: the median-based standard deviation of
   each axis, sigma = sqrt(median(v^2) - median(v)^2) (Engbert and Kliegl 2003, robust to the
   saccades themselves), taken of each velocity divided by its own fit's standard-error gain
   (:func:`estimator.events.velocity.local_velocity`): a fit that NaN bands or the blanking
   gap thin is noisier, and its speed is read against its own noise, r = |v / (g sigma)|.
3. A saccade is a run of samples with r > ``detect_sd`` at the timing scale (a microsaccade: at
   the small scale, where no saccade was found); its boundaries are first where r crosses
   ``bound_sd``, interpolated linearly between the two samples that bracket the crossing, at
   the instants where their fits' slopes belong (each fit's mean instant). An event that
   starts less than ``min_interval_s`` (20 ms) after the previous one ends is merged into it
   (the minimum intersaccadic interval of microsaccade studies, Troncoso et al. 2008: an
   overshoot correction, or a slow microsaccade whose plateau speed dips where NaN bands thin
   the fits, is one movement).
4. Each onset and offset is then placed by a position model fitted across the edge
   (:func:`estimator.events.bounds.edge_fit`): the fixation level, then a power-law rise
   along the event's direction, fitted over 8 ms of fixation and the event's samples up to
   half its peak speed; every sample on both sides votes, where the crossing rests on the two
   around one level, and a 3-SD level is met up to ~2 ms into the 12-ms acceleration of a
   20-deg saccade. The uncertainty of each is half the bracket of the samples around it: at
   16 pulses per frame and S = 524 about 0.5 ms, but 3.3 ms where the blanking gap of S = 786
   (6.5 ms) hides it, and more across NaN bands. An event ends at a stretch without valid
   samples longer than ``max_gap_s``, its bound at most half of that beyond its last sample.
5. Main-sequence checks reject what noise and glitches make (amplitude and peak velocity per
   amplitude each event before merging too, so that a glitch near a saccade is not merged
   into it; not the duration: the pieces of a microsaccade split where its speed dips are
   short): the amplitude (between the mean
   gaze over ``amplitude_window_s`` before the onset and after the offset) must reach
   ``min_amplitude_deg``, the duration ``min_duration_s``, and the peak velocity must not exceed
   ``max_peak_per_amplitude_hz`` times the amplitude (a one-band glitch has a large speed and
   no amplitude; real saccades have V_p / A below ~70 /s even at 0.1 deg: Carpenter's and
   Baloh's main sequence gives 20-50 /s, microsaccades reach 30-70 /s, Martinez-Conde et al.
   2004).

:data:`FIRST_ROUND` is the detector before steps 2's local noise, 3's mean instants and
merging, and 4 (the first full-size study); ``scet study events`` measures each against it.

Everything is in degrees (the Fick angles of the gaze, :func:`gaze_angles_deg`) and seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .bounds import (WIDE_BRACKET, angle_deg, crossing, edge_fit, half_bracket, interval_bound,
                     mean_near, runs, split_at_gaps)
from .velocity import local_velocity

SACCADE = "saccade"
MICROSACCADE = "microsaccade"
#: Events below this amplitude are called microsaccades (deg): the usual upper bound
#: (Martinez-Conde et al. 2004; issue 34 asks for 0.1-1 deg).
MICROSACCADE_MAX_DEG = 1.0
@dataclass(frozen=True, slots=True)
class EventParams:
    """Settings of :func:`detect_events` (every default with its reason).

    Attributes
    ----------
    timing_window_s : float
        Half window of the velocity that places onsets and offsets (s): 2 ms spans ~5 bands at
        16 pulses per frame, short against the 2-12 ms acceleration of a main-sequence saccade.
    peak_window_s : float
        Half window of the peak velocity (s): 5 ms is inside the constant-speed part of every
        saccade of 2 deg or more (ramps take at most 20 % of their 25-65 ms) and averages 10
        bands of noise.
    small_window_s : float
        Half window of the microsaccade search (s): 8 ms, half of a 0.3-deg microsaccade's
        ~22 ms, brings the velocity noise down ~6x against the timing window.
    detect_sd, bound_sd : float
        Detection and boundary thresholds in noise SDs: 6 as Engbert and Kliegl (2003); 3 for
        the boundaries, so onsets sit low on the acceleration.
    min_detect_deg_s : float
        Floor of the detection threshold (deg/s): above the fixational tremor's ~2 deg/s,
        where the estimate is so clean that 6 SD would be less.
    min_amplitude_deg, min_duration_s, max_peak_per_amplitude_hz : float
        Main-sequence checks (module docstring).
    amplitude_window_s : float
        Gaze averaged before the onset and after the offset for the amplitude (s).
    max_gap_s : float
        Longest stretch without a valid sample that velocities bridge (s): the blanking gap
        (6.5 ms) and a 60 Hz period (16.6 ms) pass, a blink or lost tracking does not.
    min_interval_s : float
        Minimum intersaccadic interval (s): an event that starts less than this after the
        previous one ends is the same movement (a speed dip of a slow microsaccade's plateau
        where NaN bands thin its velocity fits, an overshoot correction) and the two are
        merged. 20 ms, the interval microsaccade studies impose so that overshoot corrections
        are not counted as new saccades (Moller et al. 2002; Troncoso, Macknik and
        Martinez-Conde 2008); 0 merges nothing (the detector before issue 34's second round).
    local_noise : bool
        Each velocity in noise units of its own fit (module docstring, step 2): a window that
        NaN bands or the blanking gap thin is noisier, and its speed is read against its own
        standard error rather than the median window's. False: every velocity against the
        scale's one median-based SD (the detector before issue 34's second round).
    edge_fit : bool
        Onsets and offsets placed by fitting the position across the edge (module docstring,
        step 4) rather than at the boundary crossing. False: at the crossing (the earlier
        detector).
    edge_before_s : float
        Fixation before the onset (after the offset) that the edge fit takes (s): the
        amplitude window's 8 ms, ~8 bands at 16 pulses.
    edge_speed_fraction : float
        The edge fit runs into the event until the speed first reaches this share of the
        event's peak: 0.5, the steepest part of a symmetric acceleration, chosen before
        measuring (tried after, in a draft: on the study's goal stream 0.3 was 0.15 ms worse
        in onset mean abs error, 0.7 0.02 ms worse; on its held-out trajectories 0.7 was
        0.02 ms better; not adopted).
    bounded_gap_reach : bool
        An event ends at a stretch without valid samples longer than ``max_gap_s`` (the
        velocities bridge no such stretch, and the speeds beyond it belong to another
        movement), and a crossing hidden in any stretch is placed at most half of
        ``max_gap_s`` (12.5 ms) beyond the last sample inside the event; its uncertainty
        stays half the stretch. False: the earlier detector, whose bounds walked on across
        such stretches (an offset found 1.4 s late, past 1.3 s of NaN bands, on a held-out
        trajectory of the study).
    centroid_timing : bool
        Crossings interpolated between the instants where the two bracketing fits' slopes
        belong (the mean instant of each fit's samples, :func:`local_velocity`) rather than
        the samples' own instants. False: the samples' own (the earlier detector).
    glitches_before_merge : bool
        The checks of step 5 of amplitude and peak velocity per amplitude also reject each
        event before merging (step 3), so that a glitch (one or two bands of a poor fit,
        about a tenth of a degree off: a speed spike with no amplitude) within
        ``min_interval_s`` of a saccade is dropped rather than merged into it, which moved
        that saccade's onset or offset by up to 23 ms (seven of the 36 saccades of the
        events study's rendered sub-sequence). Not the duration: a microsaccade split where
        its speed dips has pieces of 2-6 ms (checked for duration too, 88 % of the study's
        microsaccades >= 0.3 deg were found instead of 99 %). A glitch of 0.3 deg still
        merges: its microsaccade-scale piece reaches the minimum amplitude. False: checked
        only after merging (the detector before issue 34's fifth round).
    """

    timing_window_s: float = 0.002
    peak_window_s: float = 0.005
    small_window_s: float = 0.008
    detect_sd: float = 6.0
    bound_sd: float = 3.0
    min_detect_deg_s: float = 5.0
    min_amplitude_deg: float = 0.05
    min_duration_s: float = 0.006
    max_peak_per_amplitude_hz: float = 150.0
    amplitude_window_s: float = 0.008
    max_gap_s: float = 0.025
    min_interval_s: float = 0.020
    edge_before_s: float = 0.008
    edge_speed_fraction: float = 0.5
    edge_fit: bool = True
    local_noise: bool = True
    centroid_timing: bool = True
    bounded_gap_reach: bool = True
    glitches_before_merge: bool = True

    def __post_init__(self):
        for name in self.__slots__:
            v = getattr(self, name)
            if isinstance(v, bool):
                continue
            ok = math.isfinite(v) and (v >= 0 if name == "min_interval_s" else v > 0)
            if not ok:
                raise ValueError(f"EventParams.{name} must be finite and "
                                 f"{'>= 0' if name == 'min_interval_s' else '> 0'}, got {v!r}")
        if self.bound_sd > self.detect_sd:
            raise ValueError(f"EventParams.bound_sd ({self.bound_sd}) must not exceed detect_sd "
                             f"({self.detect_sd})")

    @property
    def settle_s(self) -> float:
        """Time after an offset before every velocity and the amplitude near it are final:
        what the streaming form waits (s)."""
        windows = max(self.small_window_s, self.peak_window_s, self.timing_window_s)
        # an event starting within min_interval_s of the offset would be merged into it
        return max(windows + self.amplitude_window_s, self.min_interval_s + self.timing_window_s)

    @property
    def early_settle_s(self) -> float:
        """Time after an offset before the event's own values are final, without waiting out
        the minimum intersaccadic interval (s): the offset is a crossing at a sample whose
        fit reaches ``timing_window_s`` (``small_window_s`` for a microsaccade) beyond it,
        and the edge fit and the amplitude take ``edge_before_s`` and
        ``amplitude_window_s`` of samples after it; 10 ms with the defaults. What the
        streaming form waits with ``early`` (:class:`estimator.events.EventStream`)."""
        after = max(self.small_window_s, self.amplitude_window_s, self.edge_before_s)
        return after + self.timing_window_s


#: The detector of the first full-size study (reports/events.md before issue 34's second
#: round): one noise SD per scale, crossings at the samples' own instants, no merging. Kept
#: so that the study measures each change against it on the same samples.
FIRST_ROUND = EventParams(min_interval_s=0.0, local_noise=False, centroid_timing=False,
                          edge_fit=False, bounded_gap_reach=False)
@dataclass(frozen=True, slots=True)
class Events:
    """Detected events, (m,) arrays in onset order.

    Attributes
    ----------
    onset_s, offset_s : (m,) float
        Onsets and offsets (s): the edge fits, or the threshold crossings without them.
    onset_uncertainty_s, offset_uncertainty_s : (m,) float
        Half the time between the two valid samples that bracket each (s).
    amplitude_deg : (m,) float
    peak_velocity_deg_s : (m,) float
    kind : (m,) str
        :data:`SACCADE` or :data:`MICROSACCADE` (amplitude below :data:`MICROSACCADE_MAX_DEG`).
    """

    onset_s: np.ndarray
    offset_s: np.ndarray
    onset_uncertainty_s: np.ndarray
    offset_uncertainty_s: np.ndarray
    amplitude_deg: np.ndarray
    peak_velocity_deg_s: np.ndarray
    kind: np.ndarray

    @property
    def count(self) -> int:
        return int(self.onset_s.shape[0])

    @property
    def duration_s(self) -> np.ndarray:
        return self.offset_s - self.onset_s

    def select(self, mask) -> "Events":
        """The events where ``mask`` (m,) bool is true."""
        m = np.asarray(mask, dtype=bool)
        return Events(*(getattr(self, f)[m] for f in self.__slots__))


def empty_events() -> Events:
    z = np.zeros(0)
    return Events(z, z, z, z, z, z, np.zeros(0, dtype="<U12"))


def check_samples(time_s, position_deg, source: str = "samples"):
    """Coerce and check (n,) times and (n, 2) positions; raises ``ValueError`` naming the row
    of the first time that is not finite or not after the one before it."""
    t = np.asarray(time_s, dtype=np.float64)
    x = np.asarray(position_deg, dtype=np.float64)
    if t.ndim != 1 or x.shape != (t.shape[0], 2):
        raise ValueError(f"{source}: expected time_s (n,) and position_deg (n, 2), got "
                         f"{t.shape} and {x.shape}")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise ValueError(f"{source}: sample {bad[0]} has no finite time stamp ({t[bad[0]]!r})")
    step = np.diff(t)
    back = np.flatnonzero(step <= 0)
    if back.size:
        i = int(back[0]) + 1
        what = "repeats" if step[back[0]] == 0 else "is before"
        raise ValueError(f"{source}: sample {i} time {float(t[i])!r} s {what} sample {i - 1}'s "
                         f"({float(t[i - 1])!r} s): samples must be in strictly increasing "
                         "time order")
    return t, x


def _noise_sd(v) -> np.ndarray:
    """Per-axis median-based SD of velocities (Engbert and Kliegl 2003), (2,)."""
    ok = np.isfinite(v).all(axis=1)
    if ok.sum() < 3:
        return np.full(2, np.nan)
    vv = v[ok]
    return np.sqrt(np.maximum(np.median(vv * vv, axis=0) - np.median(vv, axis=0) ** 2, 1e-12))


@dataclass(frozen=True, slots=True)
class ScaleFit:
    """Velocities of the valid samples at one scale.

    Attributes
    ----------
    velocity_deg_s : (n, 2) float
        The yaw rate times cos(pitch), and the pitch rate (deg/s): their norm is the angular
        speed of the gaze direction (for Fick angles |d direction / dt|^2 = cos^2(pitch) yaw'^2
        + pitch'^2).
    centroid_s : (n,) float
        Mean instant of each fit's samples (s), where its slope belongs.
    noise_gain_per_s : (n,) float
        Standard error of each slope per unit of position noise (1/s).
    """

    velocity_deg_s: np.ndarray
    centroid_s: np.ndarray
    noise_gain_per_s: np.ndarray

    def noise_units(self, local: bool) -> np.ndarray:
        """(n, 2) velocities divided by their own standard-error gain (``local``: deg, a
        position noise) or as they are (deg/s); what :func:`noise_sd` is taken of."""
        if not local:
            return self.velocity_deg_s
        return self.velocity_deg_s / self.noise_gain_per_s[:, None]


def scale_velocities(tv, xv, p: EventParams) -> dict:
    """:class:`ScaleFit` of the valid samples at the three scales ("timing", "peak",
    "small")."""
    c = np.cos(np.radians(xv[:, 1]))
    out = {}
    for name, h in (("timing", p.timing_window_s), ("peak", p.peak_window_s),
                    ("small", p.small_window_s)):
        v, cen, gain = local_velocity(tv, xv, h, max_gap_s=p.max_gap_s, full=True)
        v[:, 0] *= c
        out[name] = ScaleFit(v, cen, gain)
    return out


def noise_sd(fits: dict, p: EventParams) -> dict:
    """Per scale the (2,) median-based SD (Engbert and Kliegl 2003) of the velocities in the
    units :meth:`ScaleFit.noise_units` gives for ``p.local_noise``."""
    return {k: _noise_sd(f.noise_units(p.local_noise)) for k, f in fits.items()}


def _main_sequence(amplitude_deg, peak_deg_s, p: EventParams):
    """Whether events of these amplitudes and peak speeds pass step 5's main-sequence checks
    (a finite amplitude of at least ``min_amplitude_deg``, a peak speed at most
    ``max_peak_per_amplitude_hz`` times it)."""
    a = np.asarray(amplitude_deg, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return (np.isfinite(a) & (a >= p.min_amplitude_deg)
                & (np.asarray(peak_deg_s, dtype=np.float64) <= p.max_peak_per_amplitude_hz * a))


def _merge(rows, p: EventParams) -> list:
    """Rows (onset, offset, onset unc., offset unc., amplitude, peak, pre (2,), post (2,)) in
    onset order, each event starting less than ``p.min_interval_s`` after the previous one's
    offset merged into it (the first's onset and gaze before, the last's offset and gaze
    after, the larger peak)."""
    out = []
    for row in sorted(rows, key=lambda r: r[0]):
        if out and row[0] - out[-1][1] < p.min_interval_s:
            prev = out[-1]
            pre, post = prev[6], row[7]
            amp = angle_deg(pre, post) if np.isfinite(pre).all() and np.isfinite(post).all() \
                else math.nan
            if row[1] >= prev[1]:
                out[-1] = (prev[0], row[1], prev[2], row[3], amp, max(prev[5], row[5]), pre, post)
            continue
        out.append(row)
    return out


def detect_events(time_s, position_deg, params: EventParams = EventParams(), *,
                  noise_sd_deg_s=None, source: str = "samples") -> Events:
    """Saccades and microsaccades of a gaze stream (module docstring).

    Parameters
    ----------
    time_s : (n,) float
        Sample instants (the strobe instants), strictly increasing (s).
    position_deg : (n, 2) float
        Gaze Fick angles (yaw, pitch) in degrees; NaN rows are missing bands.
    params : EventParams
    noise_sd_deg_s : dict, optional
        Velocity noise per scale ("timing", "peak", "small": (2,), in the units of
        :func:`noise_sd` for these params) to use instead of the estimate from these samples
        (the streaming form passes its running estimate).
    source : str
        Names the input in error messages.

    Returns
    -------
    Events
    """
    t, x = check_samples(time_s, position_deg, source)
    ok = np.isfinite(x).all(axis=1)
    if ok.sum() < 3:
        return empty_events()
    tv, xv = t[ok], x[ok]
    p = params
    fits = scale_velocities(tv, xv, p)
    sd = noise_sd_deg_s or noise_sd(fits, p)
    rows = []
    taken = np.zeros(tv.size, dtype=bool)
    spacing = float(np.median(np.diff(tv)))
    wide = WIDE_BRACKET * spacing
    # Sparse samples (60 Hz, 4 pulses a frame): no timing window holds three of them, and a
    # fit over the neighbours on both sides smears each event by a sample period on each
    # side; bounds then come from the speed of each interval between consecutive samples.
    sparse = spacing > p.timing_window_s
    if sparse:
        dtv = np.diff(tv)
        vi = np.diff(xv, axis=0) / dtv[:, None]
        vi[:, 0] *= np.cos(np.radians(0.5 * (xv[1:, 1] + xv[:-1, 1])))
        vi[dtv > p.max_gap_s] = np.nan
        si = _noise_sd(vi)
        ri = np.hypot(vi[:, 0] / si[0], vi[:, 1] / si[1])  # ri[i]: interval (i, i + 1)
    for scale in ("timing", "small"):
        fit = fits[scale]
        v, s = fit.velocity_deg_s, np.asarray(sd[scale], dtype=np.float64)
        if not np.isfinite(s).all():
            continue
        gain = fit.noise_gain_per_s if p.local_noise else np.ones(tv.size)
        r = np.hypot(v[:, 0] / s[0], v[:, 1] / s[1]) / gain
        speed = np.hypot(v[:, 0], v[:, 1])
        # the floor in noise units: each sample's own SD (deg/s) with local noise
        sd_deg_s = float(np.hypot(*s) / math.sqrt(2)) * gain
        with np.errstate(divide="ignore", invalid="ignore"):
            level_sd = np.maximum(p.detect_sd, p.min_detect_deg_s / sd_deg_s)
        hot = np.where(np.isfinite(r), r > level_sd, False) & np.isfinite(speed)
        tt = fit.centroid_s if p.centroid_timing else tv
        spans = runs(hot)
        if p.bounded_gap_reach:  # a run never spans a stretch the velocities do not bridge
            spans = split_at_gaps(spans, tv, p.max_gap_s)
        for a, b in spans:
            if taken[a:b + 1].any():
                continue
            if sparse:
                on, on_u = interval_bound(tv, ri, a, -1, p.bound_sd)
                off, off_u = interval_bound(tv, ri, b, +1, p.bound_sd)
            else:
                reach = 0.5 * p.max_gap_s if p.bounded_gap_reach else math.inf
                on, on_u = crossing(tv, tt, r, a, -1, p.bound_sd, wide, reach)
                off, off_u = crossing(tv, tt, r, b, +1, p.bound_sd, wide, reach)
            if not (math.isfinite(on_u) and math.isfinite(off_u)):
                continue  # the data start or end inside it: not measurable
            if any(on < f1 and off > f0 for f0, f1, *_ in rows):
                # it reaches into an event found already (a microsaccade-scale run walking
                # through a stretch of invalid bands into a saccade): that event stands
                continue
            span = (tv >= on) & (tv <= off)
            taken |= span | ((np.arange(tv.size) >= a) & (np.arange(tv.size) <= b))
            pre = mean_near(tv, xv, on - p.amplitude_window_s, on, True)
            post = mean_near(tv, xv, off, off + p.amplitude_window_s, False)
            amp = angle_deg(pre, post) if np.isfinite(pre).all() and np.isfinite(post).all() \
                else math.nan
            pv = fits["peak"].velocity_deg_s if scale == "timing" else v
            inside = span | ((np.arange(tv.size) >= a) & (np.arange(tv.size) <= b))
            peak = float(np.nanmax(np.hypot(pv[inside, 0], pv[inside, 1])))
            rows.append((on, off, on_u, off_u, amp, peak, pre, post))
    if p.glitches_before_merge:
        rows = [r for r in rows if _main_sequence(r[4], r[5], p)]
    rows = _merge(rows, p)
    if not rows:
        return empty_events()
    if p.edge_fit and not sparse:
        speed = np.hypot(*fits["timing"].velocity_deg_s.T)
        for n, row in enumerate(rows):
            on, off = (edge_fit(tv, xv, speed, row[0], row[1], side, p.edge_before_s,
                                p.edge_speed_fraction) for side in (-1, +1))
            if off > on:  # each uncertainty: half the bracket of the fitted edge
                rows[n] = (on, off, half_bracket(tv, on), half_bracket(tv, off), *row[4:])
    arr = np.array([r[:6] for r in rows], dtype=np.float64)
    keep = _main_sequence(arr[:, 4], arr[:, 5], p) & (arr[:, 1] - arr[:, 0] >= p.min_duration_s)
    arr = arr[keep]
    kind = np.where(arr[:, 4] < MICROSACCADE_MAX_DEG, MICROSACCADE, SACCADE).astype("<U12")
    return Events(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3], arr[:, 4], arr[:, 5], kind)


def gaze_angles_deg(screen_xy_m, eye_center_m, screen_z_m: float) -> np.ndarray:
    """(n, 2) Fick angles (deg) of the gaze from the eye's rotation centre (3,) m to the
    screen points (n, 2) m in the plane z = ``screen_z_m``."""
    from ..eye import fick_angles

    xy = np.asarray(screen_xy_m, dtype=np.float64).reshape(-1, 2)
    p = np.column_stack([xy, np.full(xy.shape[0], float(screen_z_m))])
    yaw, pitch = fick_angles(p - np.asarray(eye_center_m, dtype=np.float64))
    return np.degrees(np.column_stack([yaw, pitch]))
