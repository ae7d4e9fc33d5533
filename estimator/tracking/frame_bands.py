"""A frame's bands for the tracker, computed once per strobe phase: :class:`FrameBands`.

The tracker needs, per frame, every band that lights visible rows (its pulse, first and last
row: :func:`estimator.banding.band_rows`) and each band's strobe instant. Frame f sees pulse
j start at s_j - t0_f = (phase - f Δt) + j Δ_clk; writing phase - f Δt = δ + m Δ_clk with
δ in [0, Δ_clk), frame f looks like a frame of a strobe of phase δ whose pulse j' = j + m
(the detector's row tables are cached the same way, :mod:`estimator.glints.spots`). A strobe
locked to the frame (P Δ_clk = Δt, the prototype's 16 x 1039.75 us = 16.636 ms) has one δ
for the whole stream, so the layout is computed once and later frames only check it and
shift the pulse indices (measured on an idle x86 core: ``band_rows`` 54 us a frame, the
checked lookup ~30 us).

The cached rows are exactly what ``band_rows`` gives: it keeps a pulse by its integer first
and last rows alone (floor(k + ε) + 1 and ceil(k3 - ε) - 1 of the float edges
k = S (s_j - t0_f) / Δt of Eq. (4) and k3 = k + S (Δe + Δs) / Δt; its time test keeps every
pulse the row test keeps), so each frame computes those integers for the cached bands and
the pulses just before and after them and takes the cached layout only where all of them
are the cached ones; else ``band_rows`` runs for that frame. The strobe instants are
computed for every frame from the pulse indices with ``band_rows``' own arithmetic
(s_j = phase + j Δ_clk), so they are its bits (``tests/estimator/test_tracking_frames.py``).
"""

from __future__ import annotations

import math

import numpy as np

from ..banding import TIME_EPS_S, band_rows, first_lit_row, strobe_instant
from ..setup import Sensor, Strobe

__all__ = ["FrameBands", "PHASE_QUANTUM_S", "MAX_PHASES"]

#: The frame-local strobe phase δ is rounded to this (s) to key the cache (as the detector's
#: row tables are): a locked strobe then finds one entry despite the float rounding of
#: phase - f Δt (the rows are checked on every frame all the same).
PHASE_QUANTUM_S = 1e-10
#: Most phases kept (a strobe not locked to the frame has a new δ every frame: then nothing
#: is reused and the layout is computed per frame, as before).
MAX_PHASES = 64


class FrameBands:
    """The visible bands of each frame of a stream, cached per strobe phase.

    Parameters
    ----------
    sensor : Sensor
    strobe : Strobe

    Attributes
    ----------
    hits : int
        Frames whose layout came from the cache.
    """

    __slots__ = ("sensor", "strobe", "cache", "hits")

    def __init__(self, sensor: Sensor, strobe: Strobe):
        self.sensor, self.strobe = sensor, strobe
        #: δ key -> (pulses j' (B + 2,) int64 of the bands and their two neighbours, their
        #: first rows, their last rows (lists of int), the bands' [(first, last)] clipped)
        self.cache: dict[int, tuple] = {}
        self.hits = 0

    def phase(self, frame_index: int) -> tuple[int, int]:
        """(key of δ in units of :data:`PHASE_QUANTUM_S`, m) of frame ``frame_index``."""
        period = self.strobe.period_s
        local = self.strobe.phase_s - frame_index * self.sensor.frame_period_s
        m = math.floor(local / period)
        key = round((local - m * period) / PHASE_QUANTUM_S)
        if key * PHASE_QUANTUM_S >= period:
            key, m = key - round(period / PHASE_QUANTUM_S), m + 1
        return key, m

    def __call__(self, frame_index: int, frame_start_s: float | None = None
                 ) -> tuple[list, list]:
        """The bands of frame ``frame_index`` as [(pulse j, (first row, last row))], in
        pulse order, and their strobe instants s_j + Δs / 2 (s) shifted by the frame's
        measured start ``frame_start_s`` less f Δt (none: 0)."""
        sensor, strobe = self.sensor, self.strobe
        shift = 0.0 if frame_start_s is None else \
            float(frame_start_s) - frame_index * sensor.frame_period_s
        key, m = self.phase(frame_index)
        entry = self.cache.get(key)
        if entry is not None:
            span, first, last, rows = entry
            j = span - m
            s = strobe.phase_s + j * strobe.period_s  # pulse_times' s_j
            if self.rows(s, frame_index) == (first, last):
                self.hits += 1
                bands = list(zip(j[1:-1].tolist(), rows))
                return bands, (strobe_instant(s[1:-1], strobe.pulse_s) + shift).tolist()
        pulses, starts, first, last = band_rows(sensor, strobe, frame_index)
        bands = [(int(j), (int(a), int(b))) for j, a, b in zip(pulses, first, last)]
        if entry is None and pulses.size and len(self.cache) < MAX_PHASES:
            span = np.arange(pulses[0] - 1, pulses[-1] + 2, dtype=np.int64)
            if span.size == pulses.size + 2:  # consecutive pulses (always, for one strobe)
                s = strobe.phase_s + span * strobe.period_s
                self.cache[key] = (span + m, *self.rows(s, frame_index),
                                   [b[1] for b in bands])
        return bands, (strobe_instant(starts, strobe.pulse_s) + shift).tolist()

    def rows(self, pulse_start_s, frame_index: int) -> tuple[list, list]:
        """``band_rows``' unclipped first and last rows (lists of int) of the pulses that
        start at ``pulse_start_s`` (B,) s in frame ``frame_index``: floor(k + ε) + 1 and
        ceil(k3 - ε) - 1."""
        sensor = self.sensor
        k = first_lit_row(pulse_start_s, sensor, frame_index)
        k3 = k + sensor.total_lines * (sensor.exposure_s + self.strobe.pulse_s) \
            / sensor.frame_period_s
        eps = TIME_EPS_S / sensor.line_time_s
        return ((np.floor(k + eps).astype(np.int64) + 1).tolist(),
                (np.ceil(k3 - eps).astype(np.int64) - 1).tolist())
