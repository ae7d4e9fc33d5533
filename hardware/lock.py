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
import time
from dataclasses import dataclass

import logging

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["F_CPU_HZ", "LockCommand", "lock_command", "FirmwareTrain", "simulate_lock",
           "band_phase_rows", "PhaseLockLoop", "LockFeed", "single_pulse_rows",
           "single_pulse_shift_rows", "acquire_single"]

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


def band_phase_rows(image_dn: np.ndarray, black_dn: float, pitch_rows: float) -> float:
    """The bands' phase in one frame (rows, modulo the pitch): the phase of the row profile's
    fundamental at the known band pitch, i.e. the band centres' offset from row 0.

    The row profile (glints clipped as :func:`estimator.capture.timing.measure_frame` does,
    divided by its running mean over one pitch to remove the scene's brightness) is a
    periodic train of bands; its Fourier coefficient at 1/pitch has the phase
    -2π c/pitch for bands centred at rows c + j pitch. O(rows): cheap enough for every frame
    on a Pi, where the full fit of measure_frame is not. NaN for a frame without light.

    Parameters
    ----------
    image_dn : (H, W) float
    pitch_rows : float
        S Δclk / Δt (Eq. (1) of estimator.capture.timing), from the plan.
    """
    img = np.asarray(image_dn, dtype=np.float64)
    p95 = float(np.percentile(img[::4, ::4], 95))
    clip = black_dn + 3.0 * max(p95 - black_dn, 2.0)
    r = np.minimum(img, clip).mean(axis=1) - black_dn
    if not r.max() > 2.0:
        return math.nan
    w = max(int(round(pitch_rows)), 2)
    env = np.convolve(r, np.ones(w) / w, mode="same")
    h = w // 2 + 1
    y = np.arange(h, r.size - h, dtype=np.float64)
    q = r[h:r.size - h] / np.maximum(env[h:r.size - h], 1e-9) - 1.0
    c = np.sum(q * np.exp(-2j * np.pi * y / pitch_rows))
    if abs(c) < 1e-6 * y.size:
        return math.nan
    return float((-np.angle(c) / (2 * np.pi) * pitch_rows) % pitch_rows)


class PhaseLockLoop:
    """The software phase lock inside the capture loop: every frame's band phase
    (:func:`band_phase_rows`) in, every ``window`` frames measured under one setting a
    :func:`lock_command` out to the board (``SET PERIOD``, ``SET TRIM``, ``PHASE``).

    The phase held is the band centres' (rows modulo the pitch) at ``target_rows``, default
    the first measured frame's. The measurement runs behind the camera (on its own thread,
    skipping frames when busy), so a command is timed by the newest frame the camera has
    delivered when it is sent (:meth:`seen`, called from the capture loop): it acts within
    the frame after that one, so frames up to ``delay_frames`` after it are not used for the
    next window, and its phase shift is aimed at that frame. After a board reset
    (:meth:`restart`) the window starts over: the train's phase is a new random one, the
    period and trim come back from the settings file.

    Parameters
    ----------
    link : StrobeLink
    frame_period_s, total_lines, periods_per_frame
        Δt, S and M of the plan (the pitch S Δclk / Δt with Δclk = Δt / M).
    tolerance_rows : float
        :attr:`locked` when the last ``window`` measured phases lie this close to the target.
    """

    def __init__(self, link, *, frame_period_s: float, total_lines: float,
                 periods_per_frame: int, black_dn: float = 16.0, target_rows: float | None = None,
                 window: int = 10, delay_frames: int = 2, tolerance_rows: float = 1.0):
        self.link = link
        self.dt, self.S, self.M = float(frame_period_s), float(total_lines), int(periods_per_frame)
        self.pitch_rows = self.S / self.M
        self.line_s = self.dt / self.S
        self.black_dn = float(black_dn)
        self.target_rows = target_rows
        self.window, self.delay, self.tolerance = int(window), int(delay_frames), float(tolerance_rows)
        self.history: list[tuple[int, float, float]] = []   # (frame, phase rows, offset rows)
        self.commands: list[tuple[int, LockCommand]] = []
        self._seen, self._idx = [], []
        self._settled = 0
        self._epoch = 0
        self.latest_index = 0

    def seen(self, index: int) -> None:
        """The camera has delivered frame ``index`` (the capture loop's thread)."""
        self.latest_index = max(self.latest_index, int(index))

    def restart(self) -> None:
        """The board reset: its phase is new; measure afresh."""
        self._seen, self._idx = [], []
        self._settled = self.latest_index + 1
        self._epoch += 1

    def offset_rows(self, phase_rows: float) -> float:
        p = self.pitch_rows
        return (phase_rows - self.target_rows + p / 2) % p - p / 2

    @property
    def locked(self) -> bool:
        last = [o for _, _, o in self.history[-self.window:]]
        return len(last) == self.window and max(abs(o) for o in last) <= self.tolerance

    def frame(self, index: int, image_dn: np.ndarray) -> float:
        """Measure one frame and act when a window is full; the phase in rows (NaN: none)."""
        phase = band_phase_rows(image_dn, self.black_dn, self.pitch_rows)
        if math.isfinite(phase):
            self.observe(index, phase)
        return phase

    def observe(self, index: int, phase_rows: float) -> LockCommand | None:
        if self.target_rows is None:
            self.target_rows = phase_rows
        self.history.append((index, phase_rows, self.offset_rows(phase_rows)))
        if index < self._settled:
            return None
        self._seen.append(phase_rows * self.line_s)
        self._idx.append(index)
        if len(self._seen) < self.window:
            return None
        # A frame measured wrong (a glint row, a frame the camera tore) would steer the whole
        # window: phases more than one row off the window's line are left out, and a window
        # with fewer than half its frames left gives no command.
        idx = np.asarray(self._idx, dtype=np.float64)
        ph = np.unwrap(np.asarray(self._seen) * 2 * np.pi / (self.pitch_rows * self.line_s))
        ph *= self.pitch_rows / (2 * np.pi)
        res = ph - np.polyval(np.polyfit(idx, ph, 1), idx)
        keep = np.abs(res) <= 1.0
        if keep.sum() < self.window // 2:
            self._seen, self._idx = [], []
            return None
        seen = [v for v, k in zip(self._seen, keep) if k]
        idxs = [v for v, k in zip(self._idx, keep) if k]
        epoch = self._epoch
        s = self.link.get()          # may find the board reset: restart() runs inside it
        if epoch != self._epoch:
            return None
        now = max(self.latest_index, index)
        cmd = lock_command(seen, idxs, frame_period_s=self.dt, total_lines=self.S,
                           periods_per_frame=self.M, period_ticks=s.period_ticks,
                           trim_256th=s.trim_256th, target_phase_s=self.target_rows * self.line_s,
                           next_frame=now + self.delay)
        self.link.apply(period_ticks=cmd.period_ticks, trim_256th=cmd.trim_256th)
        if cmd.phase_ticks:
            self.link.shift_phase(cmd.phase_ticks)
        self.commands.append((index, cmd))
        self._seen, self._idx = [], []
        # The newest frame may have advanced while the commands were on the wire.
        self._settled = max(self.latest_index, now) + self.delay + 1
        return cmd


class LockFeed:
    """The capture loop's side of :class:`PhaseLockLoop`: ``feed(rows, metadata)`` for every
    frame (cheap: the frame index from its time stamp, then the rows handed to the lock's own
    thread unless it is busy). The index counts frame periods from the first frame fed, so
    dropped frames keep their place. :meth:`close` stops the thread and re-raises its error."""

    def __init__(self, lock: PhaseLockLoop, raw_format: str, width_px: int):
        from estimator.capture import decode_raw, parse_raw_format

        from .capture.stream import Worker

        fmt = parse_raw_format(raw_format)
        self.lock = lock
        self._first = None
        self.worker = Worker(lambda item: lock.frame(
            item[0], decode_raw(item[1], fmt, width_px).astype(np.float64)), "phase-lock")

    def __call__(self, rows, metadata: dict) -> int:
        ts = int(metadata["SensorTimestamp"])
        if self._first is None:
            self._first = ts
        f = int(round((ts - self._first) * 1e-9 / self.lock.dt))
        self.lock.seen(f)
        self.worker.offer((f, rows))
        return f

    def close(self) -> None:
        self.worker.close()
        if self.worker.error is not None:
            raise self.worker.error


def single_pulse_rows(image_dn: np.ndarray, black_dn: float, lit_share: float = 0.9):
    """The rows of a single-pulse frame not wholly lit, as (first, last): below ``lit_share``
    of the brightest row's level (a row the pulse only partly overlaps counts too); None
    when every row is lit, or "dark" for a frame without light."""
    img = np.asarray(image_dn, dtype=np.float64)
    r = np.median(img[:, ::4], axis=1) - black_dn
    if not r.max() > 2.0:
        return "dark"
    dark = np.flatnonzero(r < lit_share * r.max())
    return None if dark.size == 0 else (int(dark[0]), int(dark[-1]))


def single_pulse_shift_rows(dark, *, visible_rows: int, total_lines: float,
                            exposure_rows: float) -> float:
    """How far (rows, + later) to move a single pulse, one a frame, so that it lands in the
    middle of the window every visible row shares, [R(N-1) - Δe, R(0)] (Eqs. (2)-(3)).

    Row y integrates [R(y) - Δe, R(y)]: a pulse at row time y_s ((s - t_0) / line) lights
    rows y_s .. y_s + E (E = Δe / line) and, one frame earlier, y_s - S .. y_s - S + E; the
    rows between, (y_s - (S - E), y_s), are dark. Every visible row is lit when that gap lies
    outside 0 .. N-1, i.e. y_s in [N - 1 - E, 0]; its middle is (N - 1 - E) / 2. From the
    dark rows seen (:func:`single_pulse_rows`) y_s is their end + 1, or, when they run off
    the bottom of the frame, their start + (S - E).
    """
    n, S, E = int(visible_rows), float(total_lines), float(exposure_rows)
    want = (n - 1 - E) / 2
    if dark is None:
        return 0.0
    if isinstance(dark, str):
        return S / 2
    first, last = dark
    y_s = first + (S - E) if (last >= n - 1 and first > 0) else last + 1
    return (want - y_s + S / 2) % S - S / 2


class LockTimeout(RuntimeError):
    """The phase did not lock (or the single pulse did not settle) in time."""


def acquire_single(source, link, lock: PhaseLockLoop, decode, *, visible_rows: int,
                   exposure_s: float, timeout_s: float = 20.0, camera_timeout_s: float = 2.0,
                   settle_frames: int = 3) -> int:
    """Before a single-pulse calibration capture (paper Sec. 2.4): lock the strobe on banded
    frames, then switch the firmware to SINGLE and move the one pulse a frame into the window
    every row shares; return when ``settle_frames`` frames in a row are lit on every row.

    The exposure of such frames spans ~15 strobe periods, so banded frames show the train as
    rows with one pulse more or less (a few % modulation at the band pitch), which
    :func:`band_phase_rows` still measures; the lock's trim then keeps the single pulse from
    drifting out of the window (at -2,000 ppm untrimmed it would leave a 24-row window in
    about 24 frames). Frames seen here are not written. ``decode(rows)`` gives the (H, W)
    frame in DN. Returns the frames used.

    Raises
    ------
    LockTimeout
        Not locked, or the pulse not settled, within ``timeout_s``.
    """
    deadline = time.monotonic() + timeout_s
    first, used = None, 0
    line_s = lock.line_s

    def take():
        nonlocal first, used
        rows, md = source.next_frame(camera_timeout_s)
        ts = int(md["SensorTimestamp"])
        first = ts if first is None else first
        f = int(round((ts - first) * 1e-9 / lock.dt))
        lock.seen(f)
        used += 1
        return f, decode(rows)

    link.set("MODE", "BANDED")
    while not lock.locked:
        if time.monotonic() > deadline:
            raise LockTimeout(f"{link.port}: the strobe phase did not lock within {timeout_s:g} s "
                              f"({len(lock.commands)} commands)")
        f, img = take()
        lock.frame(f, img)
    link.set("MODE", "SINGLE")
    settled, wait_until = 0, lock.latest_index + 2 * lock.delay
    exposure_rows = exposure_s / line_s
    gap_rows = lock.S - exposure_rows
    while settled < settle_frames:
        if time.monotonic() > deadline:
            raise LockTimeout(f"{link.port}: the single pulse did not settle in the shared "
                              f"window within {timeout_s:g} s")
        f, img = take()
        if f <= wait_until:
            continue
        dark = single_pulse_rows(img, lock.black_dn)
        # A frame the mode switch or a shift passed through shows a wider dark block than the
        # S - E rows between two pulses: not a position to act on.
        if isinstance(dark, tuple) and dark[1] - dark[0] + 1 > gap_rows + 3 and \
                0 < dark[0] and dark[1] < visible_rows - 1:
            continue
        if isinstance(dark, tuple) and (dark[1] - dark[0] + 1 > gap_rows + 3):
            continue
        shift = single_pulse_shift_rows(dark, visible_rows=visible_rows, total_lines=lock.S,
                                        exposure_rows=exposure_rows)
        # Delays only (one pulse a frame: a delay of shift mod S rows lands it in the same
        # place), in steps no longer than the shared window (checked in between, so the pulse
        # walks into the window rather than jumping past it). Large advances, which shorten
        # periods to GAP_MIN past the pulse, moved the single pulse the wrong way in simavr
        # (which loads OCR1A at once, unlike the double-buffered silicon); delays lengthen
        # periods and behave on both.
        window_rows = exposure_rows - (visible_rows - 1)
        remaining = shift % lock.S
        shift = float(remaining if remaining <= 2 * window_rows else max(window_rows - 4, 1.0))
        if shift == 0.0:
            settled += 1
            continue
        settled = 0
        log.info("single pulse: frame %d, dark rows %s, shift %.1f rows", f,
                 single_pulse_rows(img, lock.black_dn), shift)
        s = link.get()
        tick_s = lock.dt / (lock.M * (s.period_ticks + s.trim_256th / 256))
        link.shift_phase(int(round(shift * line_s / tick_s)))
        wait_until = lock.latest_index + 2 * lock.delay
    return used
