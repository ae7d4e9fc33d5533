"""Blinks: the upper lid's closure over time (0 open, 1 shut on the lower lid).

A blink is a fast closing (down) phase and a slower opening (up) phase, each with a raised-
cosine speed profile (speed and acceleration zero at both ends, peak-to-mean speed ratio 2):

* closing: duration D_c = ``close_base_s`` + ``close_slope_s`` x A for a blink of amplitude A
  (the fraction of the full lid travel, 1 = a complete blink), so the peak closing speed
  2 A / D_c grows with amplitude and saturates, as the down phase's main sequence does
  (Evinger et al. 1991: down-phase peak velocity rises linearly with amplitude over most of the
  range; the down phase lasts roughly 50-100 ms);
* opening: ``open_ratio`` x D_c (the up phase is 2-3x slower than the down phase: Evinger et
  al. 1991; Caffier et al. 2003 measured reopening times about 2-3x the closing times);
* complete blinks hold shut for ``hold_s``.

With the defaults a blink lasts 186 ms (A = 0.1) to 300 ms (A = 1; closing 80 ms), inside the 100-400 ms
usually quoted for spontaneous blinks (Caffier et al. 2003; Schiffman 2001).

Blink times are a Poisson process of the given mean rate with a refractory gap (no blink
starts within ``refractory_s`` of the previous blink's end), seeded. Amplitudes: a fraction
``complete_fraction`` are complete (A = 1), the rest uniform in ``incomplete_range``.

References
----------
Evinger, C., Manning, K. A., Sibony, P. A. (1991). Eyelid movements. Mechanisms and normal data.
*Investigative Ophthalmology & Visual Science* 32, 387-400.
Caffier, P. P., Erdmann, U., Ullsperger, P. (2003). Experimental evaluation of eye-blink
parameters as a drowsiness measure. *European Journal of Applied Physiology* 89, 319-325.
Schiffman, H. R. (2001). *Sensation and Perception*, 5th ed. Wiley, New York.
Bentivoglio, A. R., et al. (1997). Analysis of blink rate patterns in normal subjects.
*Movement Disorders* 12, 1028-1034.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimator.eyelids import MAX_BLINK_RATE_PER_MIN

#: Reported range of a spontaneous blink's total duration (s): the check of the model.
BLINK_DURATION_RANGE_S = (0.100, 0.400)


@dataclass(frozen=True, slots=True)
class BlinkModel:
    """Blink kinematics and statistics (module docstring); times in seconds."""

    close_base_s: float = 0.050
    close_slope_s: float = 0.030
    open_ratio: float = 2.5
    hold_s: float = 0.020
    refractory_s: float = 0.5
    complete_fraction: float = 0.8
    incomplete_range: tuple[float, float] = (0.3, 0.9)

    def __post_init__(self):
        for name in ("close_base_s", "close_slope_s", "open_ratio", "hold_s", "refractory_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        if self.close_base_s <= 0 or self.open_ratio <= 0:
            raise ValueError("close_base_s and open_ratio must be > 0")
        lo, hi = self.incomplete_range
        if not (0 < lo <= hi <= 1 and 0 <= self.complete_fraction <= 1):
            raise ValueError("need 0 < incomplete_range[0] <= [1] <= 1 and complete_fraction "
                             "in [0, 1]")

    def phases_s(self, amplitude) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(closing, hold, opening) durations (s) of blinks of amplitudes in (0, 1]."""
        a = np.asarray(amplitude, dtype=np.float64)
        close = self.close_base_s + self.close_slope_s * a
        hold = np.where(a >= 1.0, self.hold_s, 0.0)
        return close, hold, self.open_ratio * close

    def duration_s(self, amplitude) -> np.ndarray:
        """Total duration (s) of blinks of amplitudes in (0, 1]."""
        return sum(self.phases_s(amplitude))

    def peak_closing_speed_per_s(self, amplitude) -> np.ndarray:
        """Peak closing speed (amplitude fractions per second): 2 A / D_c (raised cosine)."""
        a = np.asarray(amplitude, dtype=np.float64)
        return 2.0 * a / self.phases_s(a)[0]


def _raised_cosine_position(u):
    """Position 0..1 of a raised-cosine speed profile at normalised time u in [0, 1]."""
    return 0.5 * (1.0 - np.cos(np.pi * np.clip(u, 0.0, 1.0)))


@dataclass(frozen=True, slots=True, eq=False)
class Blinks:
    """A sequence of blinks: start times and amplitudes, the model giving their shape.

    Attributes
    ----------
    start_s : (n,) float
        Blink onsets, increasing; blinks do not overlap.
    amplitude : (n,) float
        In (0, 1]: the fraction of the full lid travel.
    model : BlinkModel
    """

    start_s: np.ndarray
    amplitude: np.ndarray
    model: BlinkModel = BlinkModel()

    def __post_init__(self):
        t = np.array(self.start_s, dtype=np.float64).reshape(-1)
        a = np.array(self.amplitude, dtype=np.float64).reshape(-1)
        if t.shape != a.shape or not (np.all(np.isfinite(t)) and np.all(np.isfinite(a))):
            raise ValueError("start_s and amplitude must be finite arrays of one length")
        if np.any(a <= 0) or np.any(a > 1):
            raise ValueError("blink amplitudes must lie in (0, 1]")
        ends = t + self.model.duration_s(a)
        if np.any(t[1:] < ends[:-1]):
            raise ValueError("blinks overlap: each must start after the previous one ends")
        for name, v in (("start_s", t), ("amplitude", a)):
            v.setflags(write=False)
            object.__setattr__(self, name, v)

    @property
    def end_s(self) -> np.ndarray:
        return self.start_s + self.model.duration_s(self.amplitude)

    def closure_at(self, t_s) -> np.ndarray:
        """Upper lid closure (0 open .. 1 shut) at times ``t_s`` (any shape)."""
        t = np.asarray(t_s, dtype=np.float64)
        out = np.zeros(t.shape)
        if self.start_s.size == 0:
            return out
        i = np.clip(np.searchsorted(self.start_s, t, side="right") - 1, 0, self.start_s.size - 1)
        tau = t - self.start_s[i]
        a = self.amplitude[i]
        close, hold, opening = self.model.phases_s(a)
        rising = _raised_cosine_position(tau / close)
        falling = 1.0 - _raised_cosine_position((tau - close - hold) / opening)
        shape = np.where(tau < close, rising, np.where(tau < close + hold, 1.0, falling))
        inside = (tau >= 0) & (tau <= close + hold + opening)
        return np.where(inside, a * shape, 0.0)


def blink_schedule(duration_s: float, rate_per_min: float, rng,
                   model: BlinkModel = BlinkModel()) -> Blinks:
    """Random blinks over [0, duration_s] at a mean rate (per minute), seeded (module docstring).

    Raises
    ------
    ValueError
        A rate outside [0, :data:`estimator.eyelids.MAX_BLINK_RATE_PER_MIN`] (named), or a
        negative duration.
    """
    if not (math.isfinite(rate_per_min) and 0.0 <= rate_per_min <= MAX_BLINK_RATE_PER_MIN):
        raise ValueError(f"rate_per_min must lie in [0, {MAX_BLINK_RATE_PER_MIN:g}] (the "
                         f"physiological maximum), got {rate_per_min!r}")
    if not (math.isfinite(duration_s) and duration_s >= 0):
        raise ValueError(f"duration_s must be finite and >= 0, got {duration_s!r}")
    gen = np.random.default_rng(rng)
    starts, amps = [], []
    if rate_per_min > 0:
        mean_gap = 60.0 / rate_per_min
        t = float(gen.exponential(mean_gap))
        while t < duration_s:
            complete = gen.uniform() < model.complete_fraction
            a = 1.0 if complete else float(gen.uniform(*model.incomplete_range))
            starts.append(t)
            amps.append(a)
            # A dead time (the blink and the refractory gap), then an exponential wait whose
            # mean makes the onsets' mean spacing 60 / rate.
            dead = float(model.duration_s(a)) + model.refractory_s
            t += dead + float(gen.exponential(max(mean_gap - dead, 1e-3)))
    return Blinks(np.array(starts), np.array(amps), model)
