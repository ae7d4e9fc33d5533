"""Eqs. (2)-(8) of the SCET paper: readout and exposure start of each row, the first
lit row of a pulse, partially lit and usable lines, band height, spacing, gap and drift.

See :mod:`estimator.banding.layout` for the lattice of rows and the exact trapezoid these approximate.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from ..setup import Sensor, Strobe

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
