"""Scoring detected events against the trajectory's own saccades, with confidence intervals.

Truth: every saccade segment of the trajectory wholly inside the samples' span with
:data:`MARGIN_S` of room on each side; microsaccades are those below 1 deg. A true event is
matched to the detected event overlapping it most (one to one, in order), the true interval
widened by half the median sample spacing (a short event can fall between two samples).
Detected events matched to no true one are false. Intervals: Wilson's score interval for
rates, a seeded percentile bootstrap (:data:`BOOTSTRAP` resamples) for means, the exact
Poisson interval (Garwood) for the false events per minute; all at 95 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MARGIN_S = 0.05
BOOTSTRAP = 2000
Z95 = 1.959963984540054


#: The rendered comparison's third twin (:func:`scet_render.study.events_full.residuals_by_speed`).
TWIN_RESIDUALS = "simulated, the renders' valid bands and errors by eye speed"


@dataclass(frozen=True, slots=True)
class Truth:
    onset_s: np.ndarray
    offset_s: np.ndarray
    amplitude_deg: np.ndarray
    peak_velocity_deg_s: np.ndarray


def truth_events(traj, t0_s: float, t1_s: float) -> Truth:
    from scet_render.motion import SegmentKind

    kind = np.asarray(traj.kind)
    start = traj.start_s
    end = start + traj.segment_duration_s
    sel = (kind == SegmentKind.SACCADE) & (start >= t0_s + MARGIN_S) & (end <= t1_s - MARGIN_S)
    return Truth(start[sel].copy(), end[sel].copy(), np.degrees(traj.amplitude_rad[sel]),
                 np.degrees(traj.segment_peak_speed_rad_s[sel]))


@dataclass(frozen=True, slots=True)
class Matched:
    """True events (n,) with the index of their detected match (-1: missed), and the count of
    detected events, the false ones and the minutes scored."""

    truth: Truth
    match: np.ndarray
    onset_s: np.ndarray
    offset_s: np.ndarray
    amplitude_deg: np.ndarray
    peak_velocity_deg_s: np.ndarray
    n_detected: int
    n_false: int
    minutes: float


def match_events(onset_s, offset_s, amplitude_deg, peak_deg_s, truth: Truth, pad_s: float,
                 t0_s: float, t1_s: float) -> Matched:
    on = np.asarray(onset_s, float)
    off = np.asarray(offset_s, float)
    inside = (off >= t0_s + MARGIN_S) & (on <= t1_s - MARGIN_S)
    used = np.zeros(on.size, dtype=bool)
    match = np.full(truth.onset_s.size, -1, dtype=np.int64)
    for i in range(truth.onset_s.size):
        lo, hi = truth.onset_s[i] - pad_s, truth.offset_s[i] + pad_s
        overlap = np.minimum(off, hi) - np.maximum(on, lo)
        touch = (overlap >= 0) & ~used
        if touch.any():
            j = int(np.argmax(np.where(touch, overlap, -np.inf)))
            used[j] = True
            match[i] = j
    n_false = int((inside & ~used).sum())
    return Matched(truth, match, on, off, np.asarray(amplitude_deg, float),
                   np.asarray(peak_deg_s, float), int(inside.sum()), n_false,
                   (t1_s - t0_s - 2 * MARGIN_S) / 60.0)


def pool(matched) -> Matched:
    """One :class:`Matched` of several streams' (their true events, detections, false events
    and minutes together): the measures of :func:`summarise` over all of them."""
    ms = list(matched)
    truth = Truth(*(np.concatenate([getattr(m.truth, f) for m in ms]) for f in Truth.__slots__))
    shift = np.cumsum([0] + [m.onset_s.size for m in ms[:-1]])
    match = np.concatenate([np.where(m.match >= 0, m.match + k, -1) for m, k in zip(ms, shift)])
    cat = {f: np.concatenate([getattr(m, f) for m in ms])
           for f in ("onset_s", "offset_s", "amplitude_deg", "peak_velocity_deg_s")}
    return Matched(truth, match, n_detected=sum(m.n_detected for m in ms),
                   n_false=sum(m.n_false for m in ms), minutes=sum(m.minutes for m in ms), **cat)


def wilson(k: int, n: int) -> tuple[float, float, float]:
    """Rate and its 95 % Wilson score interval."""
    if n == 0:
        return math.nan, math.nan, math.nan
    p = k / n
    d = 1 + Z95 ** 2 / n
    c = (p + Z95 ** 2 / (2 * n)) / d
    h = Z95 * math.sqrt(p * (1 - p) / n + Z95 ** 2 / (4 * n * n)) / d
    return p, max(0.0, c - h), min(1.0, c + h)


def poisson_rate(k: int, exposure: float) -> tuple[float, float, float]:
    """Rate k / exposure and its exact (Garwood) 95 % interval."""
    from scipy.stats import chi2

    lo = 0.0 if k == 0 else chi2.ppf(0.025, 2 * k) / 2
    hi = chi2.ppf(0.975, 2 * k + 2) / 2
    return k / exposure, lo / exposure, hi / exposure


def mean_ci(values, seed: int = 0) -> tuple[float, float, float]:
    """Mean and its 95 % percentile-bootstrap interval."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return math.nan, math.nan, math.nan
    if v.size == 1:
        return float(v[0]), math.nan, math.nan
    rng = np.random.default_rng(seed)
    means = v[rng.integers(0, v.size, (BOOTSTRAP, v.size))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(v.mean()), float(lo), float(hi)


#: Measures of the goal table: name -> (what, unit).
MEASURES = {
    "detected_1deg": "saccades >= 1 deg detected (%)",
    "false_per_min": "false events per minute",
    "onset_mae_ms": "onset mean abs error, saccades >= 1 deg (ms)",
    "offset_mae_ms": "offset mean abs error, saccades >= 1 deg (ms)",
    "onset_bias_ms": "onset mean error (bias, ms)",
    "offset_bias_ms": "offset mean error (bias, ms)",
    "peak_rel_err_pct": "peak velocity mean abs error, saccades >= 2 deg (%)",
    "micro_detected": "microsaccades >= 0.3 deg detected (%)",
    "micro_onset_mae_ms": "microsaccade onset mean abs error (ms)",
}
GOALS = {"detected_1deg": (">=", 98.0), "false_per_min": ("<=", 1.0), "onset_mae_ms": ("<=", 1.0),
         "offset_mae_ms": ("<=", 1.0), "peak_rel_err_pct": ("<=", 5.0),
         "micro_detected": (">=", 80.0)}


def summarise(m: Matched, seed: int = 0) -> dict:
    """Measure -> (value, low, high) of :data:`MEASURES` (percentages in %)."""
    tr = m.truth
    hit = m.match >= 0
    j = m.match[hit]
    big = tr.amplitude_deg >= 1.0
    out = {}
    r = wilson(int((hit & big).sum()), int(big.sum()))
    out["detected_1deg"] = tuple(100 * x for x in r)
    out["false_per_min"] = poisson_rate(m.n_false, m.minutes)
    sel = hit & big
    jj = m.match[sel]
    d_on = 1e3 * (m.onset_s[jj] - tr.onset_s[sel])
    d_off = 1e3 * (m.offset_s[jj] - tr.offset_s[sel])
    out["onset_mae_ms"] = mean_ci(np.abs(d_on), seed)
    out["offset_mae_ms"] = mean_ci(np.abs(d_off), seed + 1)
    out["onset_bias_ms"] = mean_ci(d_on, seed + 2)
    out["offset_bias_ms"] = mean_ci(d_off, seed + 3)
    sel2 = hit & (tr.amplitude_deg >= 2.0)
    j2 = m.match[sel2]
    rel = 100 * np.abs(m.peak_velocity_deg_s[j2] / tr.peak_velocity_deg_s[sel2] - 1)
    out["peak_rel_err_pct"] = mean_ci(rel, seed + 4)
    micro = (tr.amplitude_deg >= 0.3) & (tr.amplitude_deg < 1.0)
    out["micro_detected"] = tuple(100 * x for x in wilson(int((hit & micro).sum()), int(micro.sum())))
    selm = hit & micro
    out["micro_onset_mae_ms"] = mean_ci(np.abs(1e3 * (m.onset_s[m.match[selm]] - tr.onset_s[selm])),
                                        seed + 5)
    del j
    return out
