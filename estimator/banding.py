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
import numbers
from dataclasses import dataclass

import numpy as np

from .setup import Sensor, Strobe

#: ``row_strobe``'s pulse index for a dark row. Not -1: pulse indices are global and pulse -1
#: (the last pulse before s^(0)) routinely lights the top rows of frame 0.
NO_PULSE = np.iinfo(np.int64).min

#: Overlaps shorter than this count as no light at all: far below any strobe's clock jitter, and
#: above the float64 rounding of s_j = phase + j Δ_clk for sequences up to about an hour
#: (one ulp of 4000 s is 4.5e-13 s); longer sequences should restart their time origin.
TIME_EPS_S = 1e-12


# --------------------------------------------------------------------------- validation


def _check_sensor(sensor: Sensor) -> None:
    S, N = sensor.total_lines, sensor.visible_lines
    if not isinstance(S, numbers.Integral) or not isinstance(N, numbers.Integral):
        raise ValueError(f"Sensor.total_lines and visible_lines must be integers, got {S!r}, {N!r}")
    if not 1 <= N <= S:
        raise ValueError(f"Sensor needs 1 <= visible_lines <= total_lines, got N={N}, S={S}")
    dt, de = sensor.frame_period_s, sensor.exposure_s
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"Sensor.frame_period_s must be positive and finite, got {dt!r}")
    if not (math.isfinite(de) and 0 < de <= dt):
        raise ValueError(
            f"Sensor.exposure_s must be in (0, frame_period_s = {dt!r}] "
            f"(a rolling-shutter row cannot expose longer than a frame), got {de!r}"
        )


def _check_pulse_s(pulse_s: float) -> float:
    pulse_s = float(pulse_s)
    if not (math.isfinite(pulse_s) and pulse_s > 0):
        raise ValueError(f"pulse_s must be positive and finite, got {pulse_s!r}")
    return pulse_s


def _check_strobe(strobe: Strobe) -> None:
    n = strobe.pulses_per_frame
    if not isinstance(n, numbers.Integral) or n < 1:
        raise ValueError(f"Strobe.pulses_per_frame must be an integer >= 1, got {n!r}")
    _check_pulse_s(strobe.pulse_s)
    T = strobe.period_s
    if not (math.isfinite(T) and T > 0):
        raise ValueError(f"Strobe.period_s must be positive and finite, got {T!r}")
    if strobe.pulse_s > T:
        raise ValueError(
            f"Strobe.pulse_s = {strobe.pulse_s!r} s is longer than its period_s = {T!r} s"
        )
    if not math.isfinite(strobe.phase_s):
        raise ValueError(f"Strobe.phase_s must be finite, got {strobe.phase_s!r}")


def _check_frame_index(frame_index) -> int:
    if isinstance(frame_index, bool) or not isinstance(frame_index, numbers.Integral):
        raise ValueError(f"frame_index must be an integer, got {frame_index!r}")
    return int(frame_index)


def _frame_start_s(sensor: Sensor, frame_index) -> float:
    """t0_f = f Δt, the readout of row 0 of frame f."""
    return _check_frame_index(frame_index) * sensor.frame_period_s


# --------------------------------------------------------------------------- Eqs. (2)-(4)


def readout_time(rows, sensor: Sensor, frame_index: int = 0) -> np.ndarray:
    """Readout instant R(y) of rows of frame ``frame_index``, Eq. (2).

    Parameters
    ----------
    rows : (...) float
        Row numbers y; values outside [0, S) address the neighbouring frames' lines.
    sensor : Sensor
    frame_index : int
        Frame f; its row 0 is read at t0_f = f Δt.

    Returns
    -------
    (...) float
        R(y) = t0_f + (y / S) Δt in seconds.
    """
    _check_sensor(sensor)
    rows = np.asarray(rows, dtype=np.float64)
    return _frame_start_s(sensor, frame_index) + rows / sensor.total_lines * sensor.frame_period_s


def exposure_start(rows, sensor: Sensor, frame_index: int = 0) -> np.ndarray:
    """Exposure start E(y) = R(y) - Δe of rows of frame ``frame_index``, Eq. (3).

    Parameters
    ----------
    rows : (...) float
    sensor : Sensor
    frame_index : int

    Returns
    -------
    (...) float
        E(y) in seconds.
    """
    return readout_time(rows, sensor, frame_index) - sensor.exposure_s


def first_lit_row(strobe_time_s, sensor: Sensor, frame_index: int = 0) -> np.ndarray:
    """First row k_j touched by a pulse starting at s_j, Eq. (4): R(k_j) = s_j.

    Parameters
    ----------
    strobe_time_s : (...) float
        Pulse start times s_j in seconds.
    sensor : Sensor
    frame_index : int

    Returns
    -------
    (...) float
        k_j = S (s_j - t0_f) / Δt. Rows y > k_j (and y < k_j + h_s, Eq. (7)) collect light;
        negative values are bands that began in the previous frame.
    """
    _check_sensor(sensor)
    s = np.asarray(strobe_time_s, dtype=np.float64)
    t0 = _frame_start_s(sensor, frame_index)
    return sensor.total_lines * (s - t0) / sensor.frame_period_s


# --------------------------------------------------------------------------- Eqs. (5)-(8)


def partial_lines(sensor: Sensor, pulse_s: float) -> float:
    """Height in rows of the partially lit ramp at a band's onset (and at its end), Eq. (5).

    Parameters
    ----------
    sensor : Sensor
    pulse_s : float
        Δs.

    Returns
    -------
    float
        k'_j - k_j = S Δs / Δt (paper, Δe >= Δs); S Δe / Δt when Δe < Δs, where the ramp ends
        once the whole exposure window lies inside the pulse.
    """
    _check_sensor(sensor)
    pulse_s = _check_pulse_s(pulse_s)
    return sensor.total_lines * min(pulse_s, sensor.exposure_s) / sensor.frame_period_s


def usable_lines(sensor: Sensor, pulse_s: float) -> float:
    """Rows that collect the whole pulse, k''_j - k'_j, Eq. (6).

    Parameters
    ----------
    sensor : Sensor
    pulse_s : float
        Δs.

    Returns
    -------
    float
        S (Δe - Δs) / Δt, or 0 when Δe < Δs (no row's exposure window holds the whole pulse).
    """
    _check_sensor(sensor)
    pulse_s = _check_pulse_s(pulse_s)
    return sensor.total_lines * max(sensor.exposure_s - pulse_s, 0.0) / sensor.frame_period_s


def band_height(sensor: Sensor, pulse_s: float) -> float:
    """Band height h_s = k'''_j - k_j in rows, Eq. (7): S (Δe + Δs) / Δt.

    Parameters
    ----------
    sensor : Sensor
    pulse_s : float
        Δs.

    Returns
    -------
    float
        Rows between the first and the last row touched by one pulse (exclusive, continuous).
    """
    _check_sensor(sensor)
    pulse_s = _check_pulse_s(pulse_s)
    return sensor.total_lines * (sensor.exposure_s + pulse_s) / sensor.frame_period_s


def tiling_period(sensor: Sensor, pulse_s: float) -> float:
    """Strobe period Δ_clk = Δe + Δs that makes each band end where the next begins, Eq. (8).

    Parameters
    ----------
    sensor : Sensor
    pulse_s : float
        Δs.

    Returns
    -------
    float
        Δ_clk in seconds. The paper's variant k_{j+1} = k''_j uses Δ_clk = Δe instead (see
        :func:`plan_strobe`).
    """
    _check_sensor(sensor)
    return sensor.exposure_s + _check_pulse_s(pulse_s)


def band_spacing_rows(sensor: Sensor, strobe: Strobe) -> float:
    """Rows between the onsets of consecutive bands, k_{j+1} - k_j = S Δ_clk / Δt (Eq. (4))."""
    _check_sensor(sensor)
    _check_strobe(strobe)
    return sensor.total_lines * strobe.period_s / sensor.frame_period_s


def band_gap_rows(sensor: Sensor, strobe: Strobe) -> float:
    """Dark rows between consecutive bands, k_{j+1} - k'''_j, in rows (Eqs. (4), (7), (8)).

    Parameters
    ----------
    sensor : Sensor
    strobe : Strobe

    Returns
    -------
    float
        S (Δ_clk - Δe - Δs) / Δt. Positive: a dark gap no pulse lights. Zero: Eq. (8) tiling.
        Negative: the bands overlap and those rows mix two pulses (two instants). The paper's
        prototype (Δe = 1 ms, Δs = 100 µs, Δ_clk = 1039.75 µs, Δt = 16.636 ms, S = 786) gives
        -2.85 rows: no dark gap.
    """
    _check_sensor(sensor)
    _check_strobe(strobe)
    return (
        sensor.total_lines
        * (strobe.period_s - sensor.exposure_s - strobe.pulse_s)
        / sensor.frame_period_s
    )


def band_drift_rows(sensor: Sensor, strobe: Strobe) -> float:
    """Rows by which the bands move down from one frame to the next.

    Pulse j + P (P = ``pulses_per_frame``) of frame f + 1 lands S (P Δ_clk - Δt) / Δt rows
    below pulse j of frame f; zero when the strobe is locked to the frame (P Δ_clk = Δt).
    """
    _check_sensor(sensor)
    _check_strobe(strobe)
    return (
        sensor.total_lines
        * (strobe.pulses_per_frame * strobe.period_s - sensor.frame_period_s)
        / sensor.frame_period_s
    )


# --------------------------------------------------------------------------- pulses and weights


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
    time_s = np.where(lit, s[best] + 0.5 * strobe.pulse_s, np.nan)
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
                first_row=max(first, 0),
                last_row=min(last, S - 1),
                full_rows=_clipped(z["full_first"][i], z["full_last"][i] + 1, S),
                onset_rows=_clipped(first, min(z["full_first"][i], last + 1), S),
                end_rows=_clipped(max(z["full_last"][i] + 1, first), last + 1, S),
                visible=bool(first <= N - 1 and last >= 0),
                fraction_visible=float(visible_light / total) if total > 0 else 0.0,
            )
        )
    return bands


# --------------------------------------------------------------------------- planning


@dataclass(frozen=True, slots=True)
class StrobePlan:
    """A strobe and exposure setting whose bands tile the frame (see :func:`plan_strobe`).

    Attributes
    ----------
    pulses_per_frame : int
        P; P * period_s == Δt, so the bands stay on the same rows frame after frame.
    period_s, pulse_s, exposure_s : float
        Δ_clk, Δs and the camera exposure Δe to set.
    bands_visible : float
        Expected visible bands per frame, P N / S.
    """

    pulses_per_frame: int
    period_s: float
    pulse_s: float
    exposure_s: float
    bands_visible: float

    def apply(self, sensor: Sensor, phase_s: float = 0.0) -> tuple[Sensor, Strobe]:
        """The sensor with this plan's exposure and the planned :class:`Strobe` at ``phase_s``."""
        planned = Sensor(
            sensor.total_lines,
            sensor.visible_lines,
            sensor.frame_period_s,
            self.exposure_s,
            sensor.bit_depth,
            sensor.black_level_dn,
        )
        return planned, Strobe(self.pulses_per_frame, self.pulse_s, self.period_s, phase_s)


def plan_strobe(
    sensor: Sensor,
    bands_visible: float,
    pulse_s: float | None = None,
    duty: float = 0.1,
    overlap: bool = False,
) -> StrobePlan:
    """Plan pulses, period, pulse width and exposure for at least ``bands_visible`` visible bands.

    P = ceil(bands_visible S / N) pulses per frame (only N of the S lines are transferred, so a
    frame shows about P N / S bands). The period is locked to the frame, Δ_clk = Δt / P: pulse
    j + P then falls on the same rows one frame later as pulse j did, and the bands do not drift
    (:func:`band_drift_rows` is 0). The pulse is ``pulse_s`` or ``duty`` Δ_clk.

    The exposure follows Eq. (8), Δe = Δ_clk - Δs: band j ends exactly where band j + 1 begins
    (k'''_j = k_{j+1}, :func:`band_gap_rows` = 0), so no row is dark over a positive height and
    no row mixes two pulses; the price is a V-shaped dip in brightness 2 S Δs / Δt rows wide at
    each boundary (the ramps of Eq. (5)). With ``overlap=True`` the paper's variant
    k_{j+1} = k''_j is used instead, Δe = Δ_clk (Δs drops out of Eqs. (7) and (8)): every row then
    collects exactly one pulse's worth of light, with no dip, but the S Δs / Δt rows at each
    boundary mix two pulses, i.e. two instants Δ_clk apart.

    Parameters
    ----------
    sensor : Sensor
        Its S, N and Δt are used; its exposure is an output of the plan, not an input.
    bands_visible : float
        Wanted visible bands per frame, > 0.
    pulse_s : float, optional
        Δs; default ``duty`` * Δ_clk.
    duty : float
        Δs / Δ_clk when ``pulse_s`` is not given, in (0, 1).
    overlap : bool
        Use the k_{j+1} = k''_j variant.

    Returns
    -------
    StrobePlan
    """
    _check_sensor(sensor)
    bands_visible = float(bands_visible)
    if not (math.isfinite(bands_visible) and bands_visible > 0):
        raise ValueError(f"bands_visible must be positive, got {bands_visible!r}")
    S, N, dt = sensor.total_lines, sensor.visible_lines, sensor.frame_period_s
    # The small tolerance keeps e.g. 16 N / S requested bands at 16 pulses despite rounding.
    P = max(1, math.ceil(bands_visible * S / N - 1e-9))
    period = dt / P
    if pulse_s is None:
        duty = float(duty)
        if not (math.isfinite(duty) and 0 < duty < 1):
            raise ValueError(f"duty must be in (0, 1), got {duty!r}")
        pulse_s = duty * period
    else:
        pulse_s = _check_pulse_s(pulse_s)
        if pulse_s >= period:
            raise ValueError(
                f"pulse_s = {pulse_s!r} s does not fit in the period Δt / P = {period!r} s "
                f"needed for {bands_visible} visible bands"
            )
    exposure = period if overlap else period - pulse_s
    return StrobePlan(P, period, pulse_s, exposure, P * N / S)
