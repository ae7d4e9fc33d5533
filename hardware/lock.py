"""Software phase lock of the free-running strobe (issue 13, part 2): the control law behind
``scet strobe lock``, and a simulated closed loop to show it.

Without a frame-sync line the strobe's train drifts across the frame by δ = M p - S rows a
frame (``estimator.capture.timing``). From the measured phases φ_n (s, delay from each frame's
first readout to its first band) of a window of frames the law takes

* the strobe period on the Pi's clock, Δclk = Δt (1 + δ/S) / M, and so the true length of one
  firmware tick for the current setting c = PERIOD + TRIM/256 ticks: τ = Δclk / c;
* the setting that makes M periods one frame, c' = Δt / (M τ), split into PERIOD (integer) and
  TRIM (1/256 tick, -255..255) as the firmware adds them (a Bresenham accumulator: TRIM/256 of
  a tick on average per period, ``hardware/firmware/strobe.c``, next_top);
* the phase error φ - φ* (wrapped to half a period), undone by one ``PHASE`` shift of
  -round(error / τ) ticks, taking out also the drift the window's delay will add.

:class:`FirmwareTrain` replays the firmware's arithmetic (integer ticks per period, the trim
accumulator, a pending phase shift applied in one period) on a tick of the true length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["F_CPU_HZ", "LockCommand", "lock_command", "FirmwareTrain", "simulate_lock"]

F_CPU_HZ = 16_000_000
TRIM_MAX = 255
GAP_MIN = 128  # strobe.c GAP_MIN: fewest ticks from a pulse's end to the next period


@dataclass(frozen=True, slots=True)
class LockCommand:
    """What to send: ``SET PERIOD``, ``SET TRIM`` and ``PHASE`` (ticks)."""

    period_ticks: int
    trim_256th: int
    phase_ticks: int


def split_period(ticks: float) -> tuple[int, int]:
    """A period in (fractional) ticks as the firmware's PERIOD and TRIM (1/256 tick)."""
    whole = math.floor(ticks)
    trim = int(round((ticks - whole) * 256))
    if trim > TRIM_MAX:
        whole, trim = whole + 1, trim - 256
    return int(whole), trim


def lock_command(phases_s, frame_indices, *, frame_period_s: float, total_lines: float,
                 periods_per_frame: int, period_ticks: int, trim_256th: int,
                 target_phase_s: float, next_frame: int) -> LockCommand:
    """The period, trim and phase shift that hold the bands still at ``target_phase_s``.

    ``phases_s`` of ``frame_indices`` are measured under the current setting; the shift is
    aimed at ``next_frame`` (the first frame the command can act on).
    """
    n = np.asarray(frame_indices, dtype=np.float64)
    c = period_ticks + trim_256th / 256
    tau0 = frame_period_s / (periods_per_frame * c)  # the tick if the clock were right
    per0 = c * tau0
    ph = np.unwrap(np.asarray(phases_s, dtype=np.float64) * 2 * np.pi / per0) * per0 / (2 * np.pi)
    slope, icpt = np.polyfit(n, ph, 1) if n.size > 1 else (0.0, ph[0])
    # slope = M Δclk - Δt (s of phase per frame), so Δclk = (Δt + slope) / M
    clk = (frame_period_s + slope) / periods_per_frame
    tau = clk / c
    period, trim = split_period(frame_period_s / (periods_per_frame * tau))
    predicted = icpt + slope * next_frame
    err = (predicted - target_phase_s + clk / 2) % clk - clk / 2
    return LockCommand(period, trim, -int(round(err / tau)))


class FirmwareTrain:
    """Pulse start times (Pi seconds) of the firmware's train on a clock off by ``ppm``."""

    def __init__(self, period_ticks: int, trim_256th: int, ppm: float, start_s: float = 0.0,
                 width_ticks: int = 560):
        self.period, self.trim, self.acc, self.pending = period_ticks, trim_256th, 0, 0
        self.width = width_ticks
        self.tick_s = (1 + ppm * 1e-6) / F_CPU_HZ
        self.t = start_s

    def next_period_ticks(self) -> int:
        top = self.period - 1  # next_top (TOP = ticks - 1): PERIOD ticks, the trim accumulator, the pending shift
        self.acc += self.trim
        if self.acc >= 256:
            self.acc, top = self.acc - 256, top + 1
        elif self.acc <= -256:
            self.acc, top = self.acc + 256, top - 1
        if self.pending:
            step = max(min(self.pending, 65535 - top), self.width + GAP_MIN - 1 - top)
            top, self.pending = top + step, self.pending - step
        return top + 1

    def pulses_until(self, t_end_s: float) -> list[float]:
        out = []
        while self.t < t_end_s:
            out.append(self.t)
            self.t += self.next_period_ticks() * self.tick_s
        return out


def simulate_lock(*, ppm: float, total_lines: int = 524, frame_period_s: float = 1 / 60,
                  periods_per_frame: int = 16, seconds: float = 12.0, window: int = 10,
                  target_phase_s: float = 3e-4, noise_rows: float = 0.05, seed: int = 0):
    """Closed loop: the train, band onsets in rows (Eq. (4)), measured phases with noise, a
    command after every ``window`` frames measured under the same setting (acting two frames
    later). Returns (frames, the
    first band's offset from the target in rows per frame)."""
    rng = np.random.default_rng(seed)
    period, trim = split_period(frame_period_s / periods_per_frame * F_CPU_HZ)
    train = FirmwareTrain(period, trim, ppm, start_s=1e-3)
    line = frame_period_s / total_lines
    pulses: list[float] = []
    frames = int(round(seconds / frame_period_s))
    offsets, seen, idx, queued, settled = [], [], [], None, 0
    for f in range(frames):
        t0 = f * frame_period_s
        if queued is not None and queued[0] == f:
            cmd = queued[1]
            train.period, train.trim, train.pending = cmd.period_ticks, cmd.trim_256th, \
                train.pending + cmd.phase_ticks
            queued, seen, idx = None, [], []  # measure under the new setting only: this
            settled = f + 1  # frame's first pulse was timed by the old one
        pulses += train.pulses_until(t0 + frame_period_s)
        clk = train.period * train.tick_s
        after = [s - t0 for s in pulses[-3 * periods_per_frame:] if s >= t0]
        phase = after[0] if after else math.nan
        off = ((phase - target_phase_s + clk / 2) % clk - clk / 2) / line
        offsets.append(off)
        if f >= settled:
            seen.append(phase + rng.normal(0, noise_rows) * line)
            idx.append(f)
        if len(seen) >= window and queued is None:
            cmd = lock_command(seen, idx, frame_period_s=frame_period_s,
                               total_lines=total_lines, periods_per_frame=periods_per_frame,
                               period_ticks=train.period, trim_256th=train.trim,
                               target_phase_s=target_phase_s, next_frame=f + 2)
            queued = (f + 2, cmd)
            seen, idx = [], []
    return np.arange(frames), np.asarray(offsets)
