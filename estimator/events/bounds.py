"""Where an event starts and ends, for :func:`estimator.events.detect_events`: runs of fast
samples, threshold crossings between (or beside) the samples that bracket them, the bounds of
sparse samples from the speed of each interval, and the position model fitted across an edge
(steps 3 and 4 of :mod:`estimator.events.detect`). Times in s, gaze in deg.
"""

from __future__ import annotations

import math

import numpy as np

#: A crossing's bracket wider than this many median sample spacings is a gap: the crossing is
#: extrapolated from inside rather than interpolated across it (:func:`crossing`).
WIDE_BRACKET = 2.5


#: Powers of the edge model (:func:`edge_fit`): the speed jumping (1), rising linearly (2)
#: or rising from zero acceleration (3) at the onset.
EDGE_POWERS = (1.0, 2.0, 3.0)
#: Candidate onsets of the edge fit relative to the crossing (s), and their step: 3 ms before
#: (a 3-SD boundary is met up to ~2 ms into the 12-ms accelerations of 20-deg saccades) to
#: 1.5 ms after (the +-2 ms fits' response starts a spacing before the movement).
EDGE_SEARCH_S = (-0.003, 0.0015, 1e-4)


def runs(mask) -> list[tuple[int, int]]:
    """(first, last) index pairs of the runs of True in ``mask``."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


def split_at_gaps(runs, tv, max_gap_s) -> list[tuple[int, int]]:
    """The runs (first, last) cut wherever consecutive samples are more than ``max_gap_s``
    apart."""
    out = []
    for a, b in runs:
        cuts = np.flatnonzero(np.diff(tv[a:b + 1]) > max_gap_s) + a
        starts = [a, *(cuts + 1)]
        ends = [*cuts, b]
        out += [(int(x), int(y)) for x, y in zip(starts, ends)]
    return out


def crossing(tv, tt, r, i, step, level, wide_s, max_reach_s=math.inf) -> tuple[float, float]:
    """Walk from valid sample ``i`` (r > level) by ``step`` (-1, +1) to the first sample at or
    below ``level``; returns (time of the crossing, half the bracket). ``tv`` are the samples'
    instants (the bracket), ``tt`` where their speeds ``r`` belong (the fits' mean instants,
    or ``tv``). Within a bracket up to ``wide_s`` the crossing is interpolated linearly;
    across a wider one (a blanking gap, NaN bands) the speed's trend over the last two samples
    inside is extrapolated to the level, no further than the bracket's middle (a straight
    line across a gap puts the crossing at its far end) and no further than ``max_reach_s``
    from the last sample inside; the walk stops at a stretch without samples longer than
    twice ``max_reach_s`` (the speeds beyond it are of another movement).
    The start or end of the data is a crossing there, with an infinite uncertainty."""
    j = i
    while (0 <= j + step < r.size and np.isfinite(r[j + step]) and r[j + step] > level
           and abs(float(tv[j + step] - tv[j])) <= 2 * max_reach_s):
        j += step
    k = j + step
    if not (0 <= k < r.size) or not np.isfinite(r[k]):
        return float(tv[j]), math.inf
    half = 0.5 * abs(float(tv[k] - tv[j]))
    if not step * (tt[k] - tt[j]) > 0:  # the fits' instants out of order: use the samples'
        tt = tv
    if 2 * half <= wide_s:
        f = (r[j] - level) / (r[j] - r[k])  # r[j] > level >= r[k]
        return float(tt[j] + f * (tt[k] - tt[j])), half
    q = j - step  # the sample before j, further inside the event
    if 0 <= q < r.size and np.isfinite(r[q]) and r[q] > r[j] and step * (tt[j] - tt[q]) > 0:
        rate = (r[q] - r[j]) / abs(float(tt[q] - tt[j]))  # fall of r per second outwards
        # at most to the bracket's middle: a speed above the level just inside a gap says the
        # event began near it (the ramps take a few ms), and a flat trend says little
        reach = min((r[j] - level) / rate, abs(float(0.5 * (tv[j] + tv[k]) - tt[j])),
                    max_reach_s)
        return float(tt[j] + step * reach), half
    return float(tv[j] + step * min(half, max_reach_s)), half


def interval_bound(tv, ri, i, step, level) -> tuple[float, float]:
    """Onset (``step`` -1) or offset (+1) of an event found at sample ``i`` of sparse samples:
    from the intervals next to it, walk outwards while an interval's speed ``ri`` (between
    consecutive samples, in noise SDs) exceeds ``level``; the event starts (ends) inside the
    outermost such interval, whose middle is the estimate and half its length the
    uncertainty (the interval alone cannot place it better)."""
    n = ri.size
    k = i - 1 if step < 0 else i  # the interval on that side of sample i
    if not (0 <= k < n) or not np.isfinite(ri[k]):
        return float(tv[i]), math.inf
    if ri[k] <= level:  # nothing moved on that side: the bound is at the sample itself
        k2 = k + (1 if step < 0 else -1)
        if not (0 <= k2 < n):
            return float(tv[i]), math.inf
        k = k2
    while 0 <= k + step < n and np.isfinite(ri[k + step]) and ri[k + step] > level:
        k += step
    return float(0.5 * (tv[k] + tv[k + 1])), 0.5 * float(tv[k + 1] - tv[k])


def mean_near(tv, xv, t0, t1, nearest_before: bool):
    """Mean gaze of the valid samples in [t0, t1]; else the nearest sample outside it."""
    sel = (tv >= t0) & (tv <= t1)
    if sel.any():
        return xv[sel].mean(axis=0)
    i = np.searchsorted(tv, t0 if nearest_before else t1)
    i = i - 1 if nearest_before else i
    return xv[i] if 0 <= i < tv.size else np.full(2, np.nan)


def angle_deg(a, b) -> float:
    """Angle between the gaze directions of Fick angles ``a`` and ``b`` (deg)."""
    def direction(p):
        yaw, pitch = np.radians(p)
        return np.array([math.cos(pitch) * math.sin(yaw), math.sin(pitch),
                         -math.cos(pitch) * math.cos(yaw)])
    c = float(np.clip(direction(a) @ direction(b), -1.0, 1.0))
    return math.degrees(math.acos(c))


def edge_fit(tv, xv, speed, on, off, side, before_s: float, speed_fraction: float) -> float:
    """Onset (``side`` -1) or offset (+1) of the event [on, off] by a position model fitted
    across its edge; the crossing itself where the fit cannot be made.

    Along the event's direction u (the mean gaze over ``before_s`` outside each edge),
    y(t) = (x(t) - x_fix) . u is fitted over the valid samples from ``before_s``
    outside the edge to where ``speed`` first reaches ``speed_fraction`` of the
    event's peak as y = a + c max(0, tau - tau0)^k (tau: time into the event from the
    crossing, c > 0, k in :data:`EDGE_POWERS`); the (tau0, k) of least squares over the grid
    :data:`EDGE_SEARCH_S` gives the edge. A two-phase regression (Hinkley 1969) of the movement's
    start: every sample on both sides of the edge votes, where the crossing is decided by the
    two that bracket one level; irregular instants and NaN bands need nothing special."""
    edge = on if side < 0 else off
    inside = (tv >= on) & (tv <= off)
    if not inside.any():
        return edge
    peak = float(np.nanmax(speed[inside]))
    before = (tv >= on - before_s) & (tv < on)
    after = (tv > off) & (tv <= off + before_s)
    fix, other = (before, after) if side < 0 else (after, before)
    if fix.sum() < 2 or other.sum() < 2:
        return edge
    x_fix = xv[fix].mean(axis=0)
    u = xv[other].mean(axis=0) - x_fix
    norm = float(np.hypot(*u))
    if not norm > 0:
        return edge
    tau = side * (edge - tv)  # into the event, from the crossing
    fast = np.flatnonzero(inside & (speed >= speed_fraction * peak))
    if fast.size == 0:
        return edge
    lo, hi, step = EDGE_SEARCH_S
    end = max(float(np.min(tau[fast])), hi + step)
    w = (tau >= -before_s) & (tau <= end)
    if w.sum() < 5:
        return edge
    y = (xv[w] - x_fix) @ (u / norm)
    x = tau[w]
    t0 = np.arange(lo, min(hi, end - step) + 0.5 * step, step)
    powers = np.asarray(EDGE_POWERS)[:, None, None]
    h = np.maximum(0.0, x[None, None, :] - t0[None, :, None]) ** powers  # (powers, t0, samples)
    hc = h - h.mean(axis=2, keepdims=True)
    yc = y - y.mean()
    s_hh = (hc * hc).sum(axis=2)
    s_hy = (hc * yc).sum(axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = s_hy / s_hh
        sse = float(yc @ yc) - c * s_hy
    sse = np.where((s_hh > 0) & (c > 0), sse, np.inf)
    if not np.isfinite(sse).any():
        return edge
    k = np.unravel_index(int(np.argmin(sse)), sse.shape)
    return float(edge - side * t0[k[1]])  # tau = side (edge - t)


def half_bracket(tv, t) -> float:
    """Half the time between the valid samples that bracket instant ``t`` (s)."""
    i = int(np.searchsorted(tv, t))
    if i <= 0 or i >= tv.size:
        return math.inf
    return 0.5 * float(tv[i] - tv[i - 1])
