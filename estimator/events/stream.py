"""The streaming form of :func:`estimator.events.detect_events`: events while samples arrive.

Samples are pushed as they come (a frame's bands at a time, say). Each push runs the detector
over the last ``history_s`` of samples and reports each event once, as soon as its offset is
:attr:`EventParams.settle_s` old (every velocity window and the amplitude window after it are
then full, and no event can start within the minimum intersaccadic interval and be merged into
it). So an event is reported ``duration + settle_s`` (plus the wait for the next push) after
its onset: 20 + 2 = 22 ms after the offset with the defaults, about 65 ms after the onset of
a 10-deg saccade (43 ms long). The velocity noise is estimated over the last
:data:`HISTORY_S`, refreshed every :data:`NOISE_EVERY` pushes; each push searches only the
last :data:`MAX_EVENT_S` plus twice the settle time, so its cost does not grow with the
history (``benchmarks/bench_events.py``).

Pushed with the tracker's ``n_glints``, ``prior`` and ``residual_px`` of each sample, the stream
leaves out what its ``gate`` leaves out (:mod:`estimator.events.quality`), the residual's
bound taken over the samples it holds (the last ``history_s``), as ``scet track --events``
does over the whole file.
"""

from __future__ import annotations

import numpy as np

from .detect import (EventParams, Events, check_samples, detect_events, empty_events, noise_sd,
                     scale_velocities)
from .quality import SampleGate, disagree_with_neighbours, poor_fits, residual_bound

#: Samples kept for the noise estimate (s): the median-based SD needs no more than a second
#: of fixations.
HISTORY_S = 1.0
#: Longest event the stream reports (s): a 40-deg saccade lasts ~110 ms (Carpenter 1988);
#: each push searches only the last MAX_EVENT_S + settle time of samples.
MAX_EVENT_S = 0.2
#: The noise estimate is refreshed every this many pushes (a frame each: ~0.17 s).
NOISE_EVERY = 10


class EventStream:
    """Events of a live gaze stream (module docstring).

    Parameters
    ----------
    params : EventParams
    history_s : float
        Samples kept for the noise estimate (s).
    early : bool
        Report each event :attr:`EventParams.early_settle_s` after its offset rather than
        :attr:`EventParams.settle_s` (module docstring).
    gate : SampleGate
        The poor fits left out of samples pushed with their quality (module docstring).
    """

    def __init__(self, params: EventParams = EventParams(), history_s: float = HISTORY_S, *,
                 early: bool = False, gate: SampleGate = SampleGate()):
        if not history_s > MAX_EVENT_S + 2 * params.settle_s:
            raise ValueError(f"history_s must exceed {MAX_EVENT_S + 2 * params.settle_s} s")
        self.params = params
        self.early = bool(early)
        self.wait_s = params.early_settle_s if self.early else params.settle_s
        self.history_s = float(history_s)
        self._t = np.zeros(0)
        self._x = np.zeros((0, 2))
        self._q = np.zeros((0, 3))  # n_glints, prior, residual_px (NaN: pushed without)
        self._bound = np.inf
        self.gate = gate
        self._last_offset = -np.inf
        self._sd = None
        self._pushes = 0
        self.reported_at_s: list[float] = []  # the latest sample time when each event was reported

    def push(self, time_s, position_deg, quality=None) -> Events:
        """Add samples (after every earlier one); returns the events completed by them.
        ``quality``: the samples' (n_glints, prior, residual_px), each (n,), to leave out the
        poor fits (module docstring); None: every sample as it is."""
        t, x = check_samples(time_s, position_deg, "pushed samples")
        if t.size == 0:
            return empty_events()
        if self._t.size and t[0] <= self._t[-1]:
            raise ValueError(f"pushed samples: time {float(t[0])!r} s is not after the last "
                             f"pushed sample's ({float(self._t[-1])!r} s)")
        q = np.full((t.size, 3), np.nan)
        if quality is not None:
            n_glints, prior, res = (np.asarray(v).reshape(-1) for v in quality)
            poor_fits(n_glints, prior, res, np.isfinite(x).all(axis=1), self.gate,
                      bound_px=np.inf, source="pushed samples")  # checks them
            q = np.column_stack([n_glints, prior, res]).astype(np.float64)
        self._t = np.r_[self._t, t]
        self._x = np.r_[self._x, x]
        self._q = np.r_[self._q, q]
        keep = self._t >= self._t[-1] - self.history_s
        self._t, self._x, self._q = self._t[keep], self._x[keep], self._q[keep]
        self._bound = residual_bound(self._q[:, 2], np.isfinite(self._x).all(axis=1), self.gate)
        now = float(self._t[-1])
        p = self.params
        young = now - float(self._t[0]) < 0.5 * self.history_s  # the estimate still settling
        if self._sd is None or young or self._pushes % NOISE_EVERY == 0:
            x_all = self._gated(np.ones(self._t.size, dtype=bool))
            ok = np.isfinite(x_all).all(axis=1)
            self._sd = noise_sd(scale_velocities(self._t[ok], x_all[ok], p), p)
        self._pushes += 1
        start = now - MAX_EVENT_S - 2 * p.settle_s
        recent = self._t >= start
        found = detect_events(self._t[recent], self._gated(recent), p, noise_sd_deg_s=self._sd)
        first = float(self._t[recent][0])
        done = ((found.offset_s + self.wait_s <= now) & (found.onset_s > self._last_offset)
                & (found.onset_s >= first + p.settle_s))
        # an event starting within the minimum interval after the last reported one continues
        # it (detect_events merges no event still under way: the data end inside it)
        cont = done & (found.onset_s - self._last_offset < p.min_interval_s)
        if cont.any():
            self._last_offset = max(self._last_offset, float(found.offset_s[cont].max()))
        done &= ~cont
        out = found.select(done)
        if out.count:
            self._last_offset = float(out.offset_s.max())
            self.reported_at_s.extend([now] * out.count)
        return out

    def _gated(self, sel) -> np.ndarray:
        """(k, 2) the gaze of the held samples ``sel`` (n,) bool, NaN where the gate leaves
        a sample pushed with its quality out (:func:`estimator.events.quality.left_out`,
        with the residual bound of every held sample)."""
        x, q = self._x[sel], self._q[sel]
        has = np.isfinite(q[:, 0])
        if not has.any():
            return x
        valid = np.isfinite(x).all(axis=1) & has
        out = poor_fits(np.where(has, q[:, 0], 0.0), q[:, 1] > 0, q[:, 2], valid, self.gate,
                        bound_px=self._bound, source="pushed samples")
        if self.gate.neighbour_check:
            out = disagree_with_neighbours(self._t[sel], x, out, self.gate)
        return np.where(out[:, None], np.nan, x)
