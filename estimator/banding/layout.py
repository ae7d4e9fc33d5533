"""Rolling-shutter banding under stroboscopic light: which rows each strobe lights, and how much.

Sec. 2.3 of the SCET paper (Eqs. (2)-(8), Fig. 2), made exact where the paper is approximate:

* Row y of frame f is read out at R(y) = t0_f + (y / S) Δt (Eq. (2)) with t0_f = f Δt, and
  starts exposing at E(y) = R(y) - Δe (Eq. (3)). Rows run on one lattice across frames: row
  y = S of frame f is row 0 of frame f + 1, and y < 0 are the last rows of frame f - 1.
* Pulse j (any integer, negative too) lights [s_j, s_j + Δs] with s_j = phase + j Δ_clk; the
  strobe runs freely across frame boundaries (:class:`estimator.setup.Strobe`).
* Row y collects the fraction w_j(y) = |[E(y), R(y)] ∩ [s_j, s_j + Δs]| / Δs of pulse j. As a
  function of y it is a trapezoid: zero up to k_j (Eq. (4)), a ramp over the partially lit
  onset rows (Eq. (5)), a plateau (the usable rows, Eq. (6)), a ramp down, zero from
  k'''_j = k_j + h_s (Eq. (7)). The paper assumes Δe >= Δs; for Δe < Δs the plateau holds
  rows that collect only Δe / Δs of the pulse, and the ramps are S Δe / Δt rows long.

A pulse belongs to a frame when it lights any of the frame's S lines, visible (y < N) or not,
including pulses that began during the previous frame's exposure windows (k_j < 0).

Times are float seconds, rows are float in the lattice above; everything is vectorised over rows
and pulses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..setup import Sensor, Strobe
from .equations import (
    TIME_EPS_S,
    _check_frame_index,
    _check_sensor,
    _check_strobe,
    _frame_start_s,
    exposure_start,
    first_lit_row,
    readout_time,
)

#: ``row_strobe``'s pulse index for a dark row. Not -1: pulse indices are global and pulse -1
#: (the last pulse before s^(0)) routinely lights the top rows of frame 0.
NO_PULSE = np.iinfo(np.int64).min


# --------------------------------------------------------------------------- pulses and weights


def strobe_instant(pulse_start_s, pulse_s):
    """The instant a pulse stands for: its centre s_j + Δs / 2.

    The one definition of a strobe instant: the time stamp of every row a pulse lights
    (:func:`row_strobe`), of every glint and gaze sample it lights, and of the eye pose it is
    rendered at. Plain arithmetic on floats or arrays (``pulse_start_s`` s, ``pulse_s`` s), so
    the compiled detector (:mod:`estimator.glints.kernels`) compiles this same function.
    """
    return pulse_start_s + 0.5 * pulse_s


def pulse_times(strobe: Strobe, t_start: float, t_end: float) -> tuple[np.ndarray, np.ndarray]:
    """Every pulse whose light [s_j, s_j + Δs] overlaps [t_start, t_end] for a positive time.

    Parameters
    ----------
    strobe : Strobe
    t_start, t_end : float
        Interval in seconds, t_start <= t_end (equal: the pulses lit at that instant).

    Returns
    -------
    pulse_indices : (P,) int64
        Global pulse indices j, increasing.
    pulse_start_s : (P,) float
        s_j = phase + j Δ_clk.
    """
    _check_strobe(strobe)
    t_start, t_end = float(t_start), float(t_end)
    if not (math.isfinite(t_start) and math.isfinite(t_end)) or t_end < t_start:
        raise ValueError(f"need finite t_start <= t_end, got [{t_start!r}, {t_end!r}]")
    T, phase, ds = strobe.period_s, strobe.phase_s, strobe.pulse_s
    # One candidate of margin on each side absorbs the rounding of the floor/ceil; the exact
    # test below decides.
    j_lo = math.floor((t_start - ds - phase) / T)
    j_hi = math.ceil((t_end - phase) / T)
    j = np.arange(j_lo, j_hi + 1, dtype=np.int64)
    s = phase + j * T
    if t_end > t_start:
        keep = (s < t_end) & (s + ds > t_start)
    else:
        keep = (s <= t_end) & (s + ds > t_end)
    return j[keep], s[keep]


def _overlap_weight(u_s: np.ndarray, exposure_s: float, pulse_s: float) -> np.ndarray:
    """w = |[u - Δe, u] ∩ [0, Δs]| / Δs, u = R(y) - s_j; overlaps below TIME_EPS_S are zero."""
    overlap = np.minimum(u_s, pulse_s) - np.maximum(u_s - exposure_s, 0.0)
    return np.where(overlap > TIME_EPS_S, overlap / pulse_s, 0.0)


def _band_rows(k: np.ndarray, sensor: Sensor, pulse_s: float) -> dict[str, np.ndarray]:
    """Float edges k, k', k'', k''' and the integer rows of each zone (unclipped lattice rows)."""
    S, dt = sensor.total_lines, sensor.frame_period_s
    lo, hi = min(sensor.exposure_s, pulse_s), max(sensor.exposure_s, pulse_s)
    k1 = k + S * lo / dt
    k2 = k + S * hi / dt
    k3 = k + S * (sensor.exposure_s + pulse_s) / dt
    eps = TIME_EPS_S / sensor.line_time_s
    return {
        "k": k,
        "k1": k1,
        "k2": k2,
        "k3": k3,
        "first": np.floor(k + eps).astype(np.int64) + 1,  # smallest y > k (weight > 0)
        "last": np.ceil(k3 - eps).astype(np.int64) - 1,  # largest y < k'''
        "full_first": np.ceil(k1 - eps).astype(np.int64),  # smallest y >= k' (plateau)
        "full_last": np.floor(k2 + eps).astype(np.int64),  # largest y <= k''
    }


def _frame_pulses(sensor: Sensor, strobe: Strobe, frame_index: int):
    """Pulses lighting any of the frame's S lines: (j (P,), s_j (P,), zones of _band_rows)."""
    _check_sensor(sensor)
    _check_strobe(strobe)
    S = sensor.total_lines
    t_lo = float(exposure_start(0, sensor, frame_index))
    t_hi = float(readout_time(S - 1, sensor, frame_index))
    j, s = pulse_times(strobe, t_lo, t_hi)
    zones = _band_rows(first_lit_row(s, sensor, frame_index), sensor, strobe.pulse_s)
    # The row test (rather than the time test alone) keeps pulses whose light reaches the frame
    # only for rounding-sized slivers out of the set, so that every listed pulse lights a row.
    keep = (zones["first"] <= np.minimum(zones["last"], S - 1)) & (zones["last"] >= 0)
    return j[keep], s[keep], {name: v[keep] for name, v in zones.items()}


def row_pulse_weights(
    sensor: Sensor, strobe: Strobe, frame_index: int = 0, rows=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fraction of each pulse collected by each row, in closed form (Eqs. (2)-(3)).

    Parameters
    ----------
    sensor : Sensor
    strobe : Strobe
    frame_index : int
    rows : (n_rows,) float, optional
        Rows of the frame, 0 <= y <= S - 1; default all visible rows 0..N-1.

    Returns
    -------
    pulse_indices : (P,) int64
        Every pulse that lights any of the frame's S lines (visible or invisible, including
        pulses that began during the previous frame), increasing.
    pulse_start_s : (P,) float
        s_j.
    weights : (n_rows, P) float
        w_j(y) = |[E(y), R(y)] ∩ [s_j, s_j + Δs]| / Δs in [0, 1]; a column of zeros for a pulse
        that lights only rows outside ``rows``.
    """
    _check_sensor(sensor)
    if rows is None:
        rows = np.arange(sensor.visible_lines, dtype=np.float64)
    rows = np.asarray(rows, dtype=np.float64)
    if rows.ndim != 1:
        raise ValueError(f"rows must be a (n_rows,) array, got shape {rows.shape}")
    if not np.all(np.isfinite(rows)) or np.any(rows < 0) or np.any(rows > sensor.total_lines - 1):
        raise ValueError(f"rows must lie in [0, S - 1 = {sensor.total_lines - 1}]")
    j, s, _ = _frame_pulses(sensor, strobe, frame_index)
    # u = R(y) - s_j in frame-local time, so that late frames lose no precision to t0_f.
    s_local = s - _frame_start_s(sensor, frame_index)
    u = rows[:, None] * sensor.line_time_s - s_local[None, :]
    return j, s, _overlap_weight(u, sensor.exposure_s, strobe.pulse_s)


def row_strobe(
    sensor: Sensor, strobe: Strobe, frame_index: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The strobe that time-stamps each visible row: the one whose light dominates it.

    Parameters
    ----------
    sensor : Sensor
    strobe : Strobe
    frame_index : int

    Returns
    -------
    pulse_index : (N,) int64
        Global index j of the pulse with the largest weight in the row (the earlier pulse on an
        exact tie); :data:`NO_PULSE` for a dark row (-1 is a real pulse: the one before s^(0)).
    time_s : (N,) float
        Its time stamp, the pulse centre s_j + Δs / 2; NaN for a dark row. A partially lit row
        saw only part of the pulse, so its true mean instant is within Δs / 2 of this.
    weight : (N,) float
        The dominant pulse's weight w_j(y) (0 for a dark row).
    """
    j, s, w = row_pulse_weights(sensor, strobe, frame_index)
    n = w.shape[0]
    if w.shape[1] == 0:
        return np.full(n, NO_PULSE, dtype=np.int64), np.full(n, np.nan), np.zeros(n)
    best = np.argmax(w, axis=1)
    weight = w[np.arange(n), best]
    lit = weight > 0
    index = np.where(lit, j[best], NO_PULSE)
    time_s = np.where(lit, strobe_instant(s[best], strobe.pulse_s), np.nan)
    return index.astype(np.int64), time_s, weight


# --------------------------------------------------------------------------- band layout


@dataclass(frozen=True, slots=True)
class Band:
    """The rows that one strobe lights in one frame (Fig. 2).

    Float edges are in the frame's row lattice and may fall outside [0, S) for bands that
    straddle a frame boundary; integer rows are clipped to the frame, 0..S-1, and row ranges are
    half-open ``(start, stop)`` (use ``range(*band.full_rows)``; empty when start == stop).

    Attributes
    ----------
    pulse_index : int
        Global pulse index j.
    strobe_time_s : float
        Pulse start s_j.
    frame_index : int
    k_first, k_full_first, k_full_last, k_last : float
        k_j (Eq. (4)), k'_j = k_j + Eq. (5), k''_j = k'_j + Eq. (6), k'''_j = k_j + h_s (Eq. (7)).
        Rows in (k_j, k'''_j) collect light; rows in [k'_j, k''_j] are on the plateau (the whole
        pulse when Δe >= Δs).
    first_row, last_row : int
        First and last rows of the frame with nonzero weight.
    full_rows : (int, int)
        Plateau rows.
    onset_rows, end_rows : (int, int)
        Partially lit rows on the ramp up (k_j, k'_j) and on the ramp down (k''_j, k'''_j).
    visible : bool
        Whether any visible row (y < N) collects light.
    fraction_visible : float
        Share of the pulse's light, summed over the whole row lattice, that lands on visible
        rows of this frame. Summed over a frame's bands it is about P N / S visible bands.
    """

    pulse_index: int
    strobe_time_s: float
    frame_index: int
    k_first: float
    k_full_first: float
    k_full_last: float
    k_last: float
    first_row: int
    last_row: int
    full_rows: tuple[int, int]
    onset_rows: tuple[int, int]
    end_rows: tuple[int, int]
    visible: bool
    fraction_visible: float

    @property
    def height_rows(self) -> float:
        """h_s = k'''_j - k_j, Eq. (7)."""
        return self.k_last - self.k_first


def _clipped(start: int, stop: int, S: int) -> tuple[int, int]:
    start, stop = min(max(int(start), 0), S), min(max(int(stop), 0), S)
    return (start, max(start, stop))


def _row_span(z: dict, sensor: Sensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First and last lit rows clipped to the frame's S lines, and whether a visible row
    (y < N) is lit, of every pulse's zones (:func:`_band_rows`)."""
    first, last = z["first"], z["last"]
    return (np.maximum(first, 0), np.minimum(last, sensor.total_lines - 1),
            (first <= sensor.visible_lines - 1) & (last >= 0))


def band_layout(sensor: Sensor, strobe: Strobe, frame_index: int = 0) -> list[Band]:
    """Every band in frame ``frame_index``: one per pulse lighting any of its S lines.

    Parameters
    ----------
    sensor : Sensor
    strobe : Strobe
    frame_index : int

    Returns
    -------
    list of Band
        Ordered by pulse index (top to bottom). Includes bands seen only by invisible lines and
        bands of pulses that began during the previous frame's exposure windows.
    """
    j, s, z = _frame_pulses(sensor, strobe, frame_index)
    S, N = sensor.total_lines, sensor.visible_lines
    frame_index = _check_frame_index(frame_index)
    s_local = s - _frame_start_s(sensor, frame_index)
    first_row, last_row, visible = _row_span(z, sensor)
    bands = []
    for i in range(j.size):
        # The pulse's light over its whole lattice extent (all frames) normalises the visible
        # share; the band spans about h_s rows, so this loop is over a few dozen values.
        lattice = np.arange(z["first"][i], z["last"][i] + 1, dtype=np.float64)
        w = _overlap_weight(lattice * sensor.line_time_s - s_local[i], sensor.exposure_s,
                            strobe.pulse_s)
        visible_light = w[(lattice >= 0) & (lattice < N)].sum()
        total = w.sum()
        first, last = int(z["first"][i]), int(z["last"][i])
        bands.append(
            Band(
                pulse_index=int(j[i]),
                strobe_time_s=float(s[i]),
                frame_index=frame_index,
                k_first=float(z["k"][i]),
                k_full_first=float(z["k1"][i]),
                k_full_last=float(z["k2"][i]),
                k_last=float(z["k3"][i]),
                first_row=int(first_row[i]),
                last_row=int(last_row[i]),
                full_rows=_clipped(z["full_first"][i], z["full_last"][i] + 1, S),
                onset_rows=_clipped(first, min(z["full_first"][i], last + 1), S),
                end_rows=_clipped(max(z["full_last"][i] + 1, first), last + 1, S),
                visible=bool(visible[i]),
                fraction_visible=float(visible_light / total) if total > 0 else 0.0,
            )
        )
    return bands


def band_rows(sensor: Sensor, strobe: Strobe, frame_index: int = 0
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The visible bands of frame ``frame_index`` as arrays: what a tracker needs of
    :func:`band_layout` (the same pulses and rows), without its per-band light shares.

    Returns
    -------
    pulse_index : (B,) int64
        Global pulse index j of every band that lights a visible row, increasing.
    pulse_start_s : (B,) float
        s_j.
    first_row, last_row : (B,) int64
        ``Band.first_row`` and ``Band.last_row``: first and last rows with nonzero weight,
        clipped to the frame's S lines.
    """
    j, s, z = _frame_pulses(sensor, strobe, frame_index)
    first_row, last_row, visible = _row_span(z, sensor)
    return j[visible], s[visible], first_row[visible], last_row[visible]

