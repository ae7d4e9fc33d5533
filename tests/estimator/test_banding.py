"""Tests of the rolling-shutter banding model, Sec. 2.3 / Eqs. (2)-(8) of the SCET paper."""

from __future__ import annotations

import math
from dataclasses import FrozenInstanceError

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.banding import layout as banding
from estimator.banding import NO_PULSE, TIME_EPS_S, band_drift_rows, band_gap_rows, band_height, band_layout, band_rows, band_spacing_rows, exposure_start, first_lit_row, partial_lines, plan_strobe, pulse_times, readout_time, row_pulse_weights, row_strobe, tiling_period, usable_lines
from estimator.setup import Sensor, Strobe

# --------------------------------------------------------------------------- tolerances
#: Times that went through a few float64 operations on values up to ~0.1 s: 1e-15 s is
#: ~1e4 ulp of 0.1 s and still 1e-11 of a 100 µs pulse.
TIME_TOL_S = 1e-15
#: Rows computed from times: the same rounding, divided by a 21 µs line time.
ROW_TOL = 1e-9
#: Eqs. (5)-(7) give continuous heights; counting integer rows inside a continuous interval of
#: length h gives floor(h) or ceil(h) rows, so the counts may differ by up to one row.
ROW_COUNT_TOL = 1.0
#: Brute-force integration samples per exposure window.
N_SAMPLES = 100_000

# The paper's prototype (Sec. 4 and DESIGN.md): OV5647 VGA, 16 pulses of 100 µs every
# 1039.75 µs (16,636 ticks of a 16 MHz timer), exposure 1 ms.
PROTO_SENSOR = Sensor(total_lines=786, visible_lines=480, frame_period_s=16.636e-3, exposure_s=1e-3)
PROTO_PULSE_S = 100e-6
PROTO_PERIOD_S = 1039.75e-6


def proto_strobe(phase_s: float = 0.0) -> Strobe:
    return Strobe(pulses_per_frame=16, pulse_s=PROTO_PULSE_S, period_s=PROTO_PERIOD_S,
                  phase_s=phase_s)


def with_exposure(sensor: Sensor, exposure_s: float) -> Sensor:
    return Sensor(sensor.total_lines, sensor.visible_lines, sensor.frame_period_s, exposure_s)


def exact_weights(rows, pulse_starts_s, sensor, pulse_s, frame_index=0):
    """Independent exact path: ∫_E^R 1[s <= t < s + Δs] dt as a difference of clipped ramps."""
    R = readout_time(np.asarray(rows, float), sensor, frame_index)[:, None]
    E = R - sensor.exposure_s
    s = np.asarray(pulse_starts_s, float)[None, :]
    return (np.clip(R - s, 0.0, pulse_s) - np.clip(E - s, 0.0, pulse_s)) / pulse_s


def sampled_weights(rows, sensor, strobe, frame_index=0, n=N_SAMPLES):
    """Brute force: midpoint samples of every row's exposure window, binned by the lit pulse.

    Returns {(row, j): weight}. Each pulse edge inside a window misclassifies at most one
    sample, so the error per weight is at most 2 (Δe / n) / Δs.
    """
    t0 = frame_index * sensor.frame_period_s
    out = {}
    frac = (np.arange(n) + 0.5) / n
    for y in np.asarray(rows, int):
        r_local = y * sensor.frame_period_s / sensor.total_lines
        t = r_local - sensor.exposure_s + frac * sensor.exposure_s  # frame-local sample times
        x = (t + t0 - strobe.phase_s) / strobe.period_s
        j = np.floor(x).astype(np.int64)
        on = (x - j) * strobe.period_s < strobe.pulse_s
        if not on.any():
            continue
        js, counts = np.unique(j[on], return_counts=True)
        for jj, c in zip(js, counts):
            out[(int(y), int(jj))] = c * (sensor.exposure_s / n) / strobe.pulse_s
    return out


# --------------------------------------------------------------------------- Eqs. (2)-(4)


def test_readout_and_exposure_follow_eqs_2_3():
    s = PROTO_SENSOR
    rows = np.array([0.0, 1.0, 479.0, 785.0])
    for f in (0, 1, 7):
        R = readout_time(rows, s, f)
        np.testing.assert_allclose(R, f * s.frame_period_s + rows * s.frame_period_s / 786,
                                   rtol=0, atol=TIME_TOL_S)
        np.testing.assert_allclose(exposure_start(rows, s, f), R - 1e-3, rtol=0, atol=TIME_TOL_S)
    # The row lattice runs on across frames: the line after S - 1 is row 0 of the next frame.
    assert readout_time(786, s, 0) == pytest.approx(readout_time(0, s, 1), abs=TIME_TOL_S)
    assert s.line_time_s == pytest.approx(21.1654e-6, rel=1e-4)  # DESIGN.md: 21.1657 µs


@given(phase=st.floats(-20e-3, 20e-3), f=st.integers(-3, 50))
def test_first_lit_row_inverts_readout_eq_4(phase, f):
    # Eq. (4) is defined by R(k_j) = s_j.
    s_j = phase + f * PROTO_SENSOR.frame_period_s
    k = first_lit_row(s_j, PROTO_SENSOR, f)
    assert readout_time(k, PROTO_SENSOR, f) == pytest.approx(s_j, abs=1e-14)


# --------------------------------------------------------------------------- prototype numbers


def test_prototype_eqs_5_to_8():
    s, ds = PROTO_SENSOR, PROTO_PULSE_S
    assert partial_lines(s, ds) == pytest.approx(786 * 100e-6 / 16.636e-3, rel=1e-12)  # 4.72
    assert usable_lines(s, ds) == pytest.approx(786 * 900e-6 / 16.636e-3, rel=1e-12)  # 42.5
    assert band_height(s, ds) == pytest.approx(
        usable_lines(s, ds) + 2 * partial_lines(s, ds), rel=1e-12)  # h_s below Eq. (6)
    assert tiling_period(s, ds) == pytest.approx(1.1e-3, rel=1e-12)


def test_prototype_leaves_no_dark_gap():
    # Δ_clk = 1039.75 µs < Δe + Δs = 1100 µs: bands overlap by 60.25 µs = 2.85 rows.
    strobe = proto_strobe()
    gap = band_gap_rows(PROTO_SENSOR, strobe)
    assert gap == pytest.approx(786 * (1039.75e-6 - 1.1e-3) / 16.636e-3, abs=ROW_TOL)
    assert gap == pytest.approx(-2.85, abs=0.01)
    # 16 x 1039.75 µs = 16.636 ms: the strobe is locked to the frame.
    assert band_drift_rows(PROTO_SENSOR, strobe) == pytest.approx(0.0, abs=ROW_TOL)


@settings(max_examples=40, deadline=None)
@given(phase=st.floats(-5e-3, 25e-3))
def test_prototype_every_visible_row_is_lit(phase):
    strobe = proto_strobe(phase)
    _, _, w = row_pulse_weights(PROTO_SENSOR, strobe)
    total = w.sum(axis=1)
    # Where two bands overlap, the ramp down of one and the ramp up of the next add to
    # -gap / (S Δs / Δt) = 2.85 / 4.72 = 0.60 of a pulse; nowhere is darker.
    darkest = -band_gap_rows(PROTO_SENSOR, strobe) / partial_lines(PROTO_SENSOR, PROTO_PULSE_S)
    # 1e-6 of a pulse: a pulse that reaches the frame only by a sliver too short to light a row
    # is left out by design (_frame_pulses); hypothesis found phase = -1.35e-13 s, whose sliver
    # is 1.35e-9 of a pulse.
    assert total.min() >= darkest - 1e-6
    index, time_s, weight = row_strobe(PROTO_SENSOR, strobe)
    assert np.all(index != NO_PULSE) and np.all(np.isfinite(time_s)) and np.all(weight > 0)


@settings(max_examples=40, deadline=None)
@given(phase=st.floats(-5e-3, 25e-3), f=st.integers(0, 20))
def test_prototype_visible_band_count(phase, f):
    bands = band_layout(PROTO_SENSOR, proto_strobe(phase), f)
    expected = 16 * 480 / 786  # 9.77 visible bands per frame
    # Summed visible light share. The visible window's edges can cut one band-overlap region,
    # where the per-row light is 0.40 pulse higher or lower than average over ~6.6 rows of a
    # 47-row band: at most 0.4 * 6.6 / 47.2 = 0.056 band.
    assert sum(b.fraction_visible for b in bands) == pytest.approx(expected, abs=0.06)
    # Bands with at least half their light visible: 9 or 10 (9.77 on average).
    assert sum(b.fraction_visible >= 0.5 for b in bands) in (9, 10)
    # Bands touching a visible row at all, slivers at the top and bottom included: the
    # visible rows plus one band height span (479 + 52) / 49.1 = 10.8 band spacings.
    assert sum(b.visible for b in bands) in (10, 11)


# --------------------------------------------------------------------------- layout vs Eqs. (5)-(7)


def _check_layout_against_equations(sensor, strobe, f=0):
    bands = band_layout(sensor, strobe, f)
    S, ds = sensor.total_lines, strobe.pulse_s
    j, s, w = row_pulse_weights(sensor, strobe, f, rows=np.arange(S))
    assert [b.pulse_index for b in bands] == list(j)
    plateau = min(1.0, sensor.exposure_s / ds)
    for col, b in enumerate(bands):
        assert b.k_first == pytest.approx(first_lit_row(b.strobe_time_s, sensor, f), abs=ROW_TOL)
        assert b.k_full_first - b.k_first == pytest.approx(partial_lines(sensor, ds), abs=ROW_TOL)
        if sensor.exposure_s >= ds:
            assert b.k_full_last - b.k_full_first == pytest.approx(
                usable_lines(sensor, ds), abs=ROW_TOL)
        assert b.height_rows == pytest.approx(band_height(sensor, ds), abs=ROW_TOL)
        col_w = w[:, col]
        lit = np.flatnonzero(col_w > 0)
        assert lit.size > 0, "every listed pulse lights a row of the frame"
        assert (b.first_row, b.last_row) == (lit[0], lit[-1])
        assert np.all(col_w[b.first_row:b.last_row + 1] > 0)  # a band has no holes
        np.testing.assert_allclose(col_w[range(*b.full_rows)], plateau, atol=1e-7)
        for rows in (b.onset_rows, b.end_rows):
            partial = col_w[range(*rows)]
            assert np.all((partial > 0) & (partial < plateau + 1e-7))
        # The four zones partition the band's rows.
        assert b.onset_rows[0] == b.first_row and b.end_rows[1] == b.last_row + 1
        assert b.onset_rows[1] == b.full_rows[0] and b.full_rows[1] == b.end_rows[0]
        inside = 0 < b.first_row and b.last_row < S - 1 and b.k_first > 0 and b.k_last < S - 1
        if inside:
            n_rows = b.last_row - b.first_row + 1
            assert abs(n_rows - band_height(sensor, ds)) <= ROW_COUNT_TOL
            assert abs(np.diff(b.onset_rows)[0] - partial_lines(sensor, ds)) <= ROW_COUNT_TOL
            assert abs(np.diff(b.end_rows)[0] - partial_lines(sensor, ds)) <= ROW_COUNT_TOL
            if sensor.exposure_s >= ds:
                assert abs(np.diff(b.full_rows)[0] - usable_lines(sensor, ds)) <= ROW_COUNT_TOL
        assert b.visible == bool(np.any(col_w[: sensor.visible_lines] > 0))
    return bands


@pytest.mark.parametrize("phase_s", [0.0, 0.3e-3, -0.5e-3, 7.77e-3, 16.0e-3])
def test_prototype_layout_matches_eqs_5_to_7(phase_s):
    bands = _check_layout_against_equations(PROTO_SENSOR, proto_strobe(phase_s))
    assert 16 <= len(bands) <= 18  # 16 pulses per frame plus ones shared with neighbours


@settings(max_examples=25, deadline=None)
@given(
    exposure_s=st.floats(20e-6, 8e-3),
    pulse_s=st.floats(20e-6, 1e-3),
    # Periods of at least 0.3 ms keep the frame to ~60 bands, each checked row by row.
    extra_period_s=st.floats(0.3e-3, 3e-3),
    phase_s=st.floats(-20e-3, 20e-3),
    f=st.integers(0, 5),
)
def test_random_layout_matches_eqs_5_to_7(exposure_s, pulse_s, extra_period_s, phase_s, f):
    sensor = with_exposure(PROTO_SENSOR, exposure_s)
    strobe = Strobe(8, pulse_s, pulse_s + extra_period_s, phase_s)
    _check_layout_against_equations(sensor, strobe, f)


@settings(max_examples=40, deadline=None)
@given(
    exposure_s=st.floats(20e-6, 8e-3),
    pulse_s=st.floats(20e-6, 1e-3),
    extra_period_s=st.floats(0.3e-3, 3e-3),
    phase_s=st.floats(-20e-3, 20e-3),
    f=st.integers(0, 400),
)
def test_band_rows_are_the_visible_bands_of_the_layout(exposure_s, pulse_s, extra_period_s,
                                                        phase_s, f):
    # The tracker's array form must be the layout's visible bands exactly (same pulses, same
    # integer rows): it replaced band_layout in the tracker's per-frame loop.
    sensor = with_exposure(PROTO_SENSOR, exposure_s)
    strobe = Strobe(8, pulse_s, pulse_s + extra_period_s, phase_s)
    bands = [b for b in band_layout(sensor, strobe, f) if b.visible]
    j, s, first, last = band_rows(sensor, strobe, f)
    assert j.tolist() == [b.pulse_index for b in bands]
    assert s.tolist() == [b.strobe_time_s for b in bands]
    assert first.tolist() == [b.first_row for b in bands]
    assert last.tolist() == [b.last_row for b in bands]


# --------------------------------------------------------------------------- closed-form weights

# Phases that put a pulse (a) straddling the frame start t0, (a') wholly before t0 but inside
# the top rows' exposure windows, (b) entirely within the invisible lines (rows 480..785),
# (c) straddling the end of the frame into the next, (d) on an exact row boundary (k_j an
# integer), (e) a free-running, unlocked period at a late frame.
CASES = {
    "straddles_frame_start": (PROTO_SENSOR, proto_strobe(-50e-6), 0),
    "before_frame_start": (PROTO_SENSOR, proto_strobe(-0.4e-3), 0),
    "in_invisible_lines": (PROTO_SENSOR, proto_strobe(12.5e-3 - 11 * PROTO_PERIOD_S), 0),
    "straddles_frame_end": (PROTO_SENSOR, Strobe(16, 300e-6, 1.2e-3, 16.5e-3), 0),
    "integer_k": (PROTO_SENSOR, proto_strobe(10 * 16.636e-3 / 786), 0),
    "unlocked_late_frame": (with_exposure(PROTO_SENSOR, 2.5e-3),
                            Strobe(10, 250e-6, 1.7e-3, 0.123e-3), 9),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_weights_match_sampled_integration(name):
    sensor, strobe, f = CASES[name]
    S = sensor.total_lines
    bands = band_layout(sensor, strobe, f)
    # Rows around every band edge, where the closed form's clipping matters, plus random rows.
    edges = np.concatenate([[b.k_first, b.k_full_first, b.k_full_last, b.k_last] for b in bands])
    rows = np.concatenate([np.floor(edges) + d for d in (-1, 0, 1, 2)])
    rows = np.concatenate([rows, np.random.default_rng(0).integers(0, S, 20), [0, S - 1]])
    rows = np.unique(np.clip(rows, 0, S - 1)).astype(int)
    j, _, w = row_pulse_weights(sensor, strobe, f, rows=rows)
    brute = sampled_weights(rows, sensor, strobe, f)
    tol = 2 * (sensor.exposure_s / N_SAMPLES) / strobe.pulse_s
    col = {int(jj): c for c, jj in enumerate(j)}
    for (y, jj), value in brute.items():
        if value > tol:
            assert jj in col, f"pulse {jj} lights row {y} but is not listed"
    for r, y in enumerate(rows):
        for jj, c in col.items():
            assert w[r, c] == pytest.approx(brute.get((int(y), jj), 0.0), abs=tol)
    if name == "in_invisible_lines":
        hidden = [b for b in bands if b.first_row >= sensor.visible_lines]
        assert hidden and not any(b.visible for b in hidden)
        jv, _, wv = row_pulse_weights(sensor, strobe, f)  # visible rows only
        assert set(b.pulse_index for b in hidden) <= set(jv.tolist())
        for b in hidden:
            assert np.all(wv[:, list(jv).index(b.pulse_index)] == 0)
    if name == "straddles_frame_start":
        assert any(b.strobe_time_s < 0.0 < b.strobe_time_s + strobe.pulse_s for b in bands)
    if name == "before_frame_start":
        assert bands[0].strobe_time_s + strobe.pulse_s < 0.0 and bands[0].first_row == 0
    if name == "straddles_frame_end":
        end = (f + 1) * sensor.frame_period_s
        assert any(b.strobe_time_s < end < b.strobe_time_s + strobe.pulse_s for b in bands)


@settings(max_examples=40, deadline=None)
@given(
    exposure_s=st.floats(20e-6, 16e-3),
    pulse_s=st.floats(10e-6, 2e-3),
    extra_period_s=st.floats(0.0, 5e-3),
    phase_s=st.floats(-40e-3, 40e-3),
    f=st.integers(-2, 30),
)
def test_weights_match_exact_piecewise_integral(exposure_s, pulse_s, extra_period_s, phase_s, f):
    sensor = with_exposure(PROTO_SENSOR, exposure_s)
    strobe = Strobe(8, pulse_s, pulse_s + extra_period_s, phase_s)
    rows = np.arange(sensor.total_lines)
    j, s, w = row_pulse_weights(sensor, strobe, f, rows=rows)
    # Overlaps under TIME_EPS_S are zeroed on purpose; float rounding of the times is far below.
    tol = 2 * TIME_EPS_S / pulse_s
    np.testing.assert_allclose(w, exact_weights(rows, s, sensor, pulse_s, f), rtol=0, atol=tol)
    np.testing.assert_allclose(s, phase_s + j * strobe.period_s, rtol=0, atol=TIME_TOL_S * 100)
    # Completeness: the pulses just before and after the listed ones light no row of the frame.
    if j.size:
        j_out = np.array([j[0] - 1, j[-1] + 1])
    else:
        j_out = np.arange(-3, 4) + round((f * sensor.frame_period_s - phase_s) / strobe.period_s)
    outside = exact_weights(rows, phase_s + j_out * strobe.period_s, sensor, pulse_s, f)
    assert outside.max() <= tol
    assert np.all(np.diff(j) == 1)


@settings(max_examples=40, deadline=None)
@given(
    pulse_s=st.floats(50e-6, 1e-3),
    duty=st.floats(0.02, 0.9),
    m=st.integers(1, 3),
    phase_s=st.floats(-20e-3, 20e-3),
)
def test_rows_collect_whole_pulses_when_exposure_is_a_multiple_of_the_period(pulse_s, duty, m,
                                                                              phase_s):
    # A window of m periods holds exactly m pulses' worth of light wherever it starts.
    period = pulse_s / duty
    if m * period > PROTO_SENSOR.frame_period_s:
        return
    sensor = with_exposure(PROTO_SENSOR, m * period)
    _, _, w = row_pulse_weights(sensor, Strobe(4, pulse_s, period, phase_s),
                                rows=np.arange(sensor.total_lines))
    np.testing.assert_allclose(w.sum(axis=1), m, rtol=0, atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(
    exposure_s=st.floats(100e-6, 4e-3),
    pulse_s=st.floats(100e-6, 1e-3),
    phase_s=st.floats(0.0, 16e-3),
)
def test_each_pulse_is_collected_for_its_exposure_worth_of_rows(exposure_s, pulse_s, phase_s):
    # ∫ w_j(y) dy = S Δe / Δt rows (each instant of the pulse is seen by the rows whose window
    # holds it: Δe worth of readouts). Summed on integer rows the trapezoid's Poisson-summation
    # error is at most 1 / (3 b) with b = S Δs / Δt the ramp length in rows.
    sensor = with_exposure(PROTO_SENSOR, exposure_s)
    strobe = Strobe(16, pulse_s, 1.5 * (exposure_s + pulse_s), phase_s)
    S, dt = sensor.total_lines, sensor.frame_period_s
    expected = S * exposure_s / dt
    tol = 1 / (3 * S * pulse_s / dt) + 1e-9
    rows = np.arange(S)
    j0, _, w0 = row_pulse_weights(sensor, strobe, 0, rows=rows)
    j1, _, w1 = row_pulse_weights(sensor, strobe, 1, rows=rows)
    checked = 0
    for b in band_layout(sensor, strobe, 0):
        # Pulses lighting only frames 0 and 1 (straddlers included): sum over both frames.
        if b.k_first < 0 or b.k_last > 2 * S - 1:
            continue
        total = w0[:, list(j0).index(b.pulse_index)].sum()
        if b.pulse_index in j1:
            total += w1[:, list(j1).index(b.pulse_index)].sum()
        assert total == pytest.approx(expected, abs=tol)
        checked += 1
    assert checked > 0


def test_straddling_pulse_appears_in_both_frames_with_lattice_weights():
    sensor, strobe, _ = CASES["straddles_frame_end"]
    S = sensor.total_lines
    b0 = {b.pulse_index: b for b in band_layout(sensor, strobe, 0)}
    b1 = {b.pulse_index: b for b in band_layout(sensor, strobe, 1)}
    shared = sorted(set(b0) & set(b1))
    assert shared
    for jj in shared:
        assert b0[jj].last_row == S - 1 and b1[jj].first_row == 0
        assert b1[jj].k_first == pytest.approx(b0[jj].k_first - S, abs=ROW_TOL)


# --------------------------------------------------------------------------- row_strobe


def test_row_strobe_time_stamps_by_dominant_pulse():
    strobe = proto_strobe(0.3e-3)
    index, time_s, weight = row_strobe(PROTO_SENSOR, strobe)
    j, s, w = row_pulse_weights(PROTO_SENSOR, strobe)
    assert index.shape == time_s.shape == weight.shape == (480,)
    np.testing.assert_array_equal(weight, w.max(axis=1))
    np.testing.assert_allclose(time_s, s[np.searchsorted(j, index)] + 50e-6, rtol=0,
                               atol=TIME_TOL_S)
    # Later rows are read later: strobe indices and time stamps never go back down the frame.
    assert np.all(np.diff(index) >= 0) and np.all(np.diff(time_s) >= 0)
    assert index[0] == -1  # pulse -1 (before s^(0)) lights the top rows: a real pulse


def test_row_strobe_marks_dark_rows():
    # Δe = 200 µs: bands of (200 + 100) µs x S / Δt = 14 rows every 49 rows, dark in between.
    sensor = with_exposure(PROTO_SENSOR, 200e-6)
    strobe = proto_strobe(1e-3)
    assert band_gap_rows(sensor, strobe) > 30
    index, time_s, weight = row_strobe(sensor, strobe)
    _, _, w = row_pulse_weights(sensor, strobe)
    dark = ~np.any(w > 0, axis=1)
    assert dark.sum() > 200
    np.testing.assert_array_equal(index == NO_PULSE, dark)
    assert np.all(np.isnan(time_s[dark])) and np.all(weight[dark] == 0)
    assert np.all(np.isfinite(time_s[~dark]))


def test_no_pulse_in_frame():
    # One pulse per second: most frames see no light at all.
    strobe = Strobe(1, 100e-6, 1.0, 0.5)
    assert band_layout(PROTO_SENSOR, strobe, 0) == []
    j, s, w = row_pulse_weights(PROTO_SENSOR, strobe, 0)
    assert j.shape == s.shape == (0,) and w.shape == (480, 0)
    index, time_s, weight = row_strobe(PROTO_SENSOR, strobe, 0)
    assert np.all(index == NO_PULSE) and np.all(np.isnan(time_s)) and np.all(weight == 0)


# --------------------------------------------------------------------------- pulse_times


@settings(max_examples=60, deadline=None)
@given(
    pulse_s=st.floats(1e-6, 1e-3),
    extra_s=st.floats(0.0, 2e-3),
    phase_s=st.floats(-0.1, 0.1),
    t_start=st.floats(-0.1, 0.1),
    length_s=st.floats(0.0, 0.02),
)
def test_pulse_times_lists_exactly_the_overlapping_pulses(pulse_s, extra_s, phase_s, t_start,
                                                          length_s):
    strobe = Strobe(1, pulse_s, pulse_s + extra_s, phase_s)
    t_end = t_start + length_s
    j, s = pulse_times(strobe, t_start, t_end)
    T = strobe.period_s
    centre = round((t_start - phase_s) / T)
    span = int(length_s / T) + 5
    jj = np.arange(centre - span, centre + span + 1)
    ss = phase_s + jj * T
    if t_end > t_start:
        truth = (ss < t_end) & (ss + pulse_s > t_start)
    else:
        truth = (ss <= t_end) & (ss + pulse_s > t_end)
    np.testing.assert_array_equal(j, jj[truth])
    np.testing.assert_allclose(s, ss[truth], rtol=0, atol=TIME_TOL_S * 100)


# --------------------------------------------------------------------------- planner


@pytest.mark.parametrize("bands", range(1, 21))
def test_plan_tiles_the_frame(bands):
    plan = plan_strobe(PROTO_SENSOR, bands)
    S, N, dt = 786, 480, PROTO_SENSOR.frame_period_s
    P = plan.pulses_per_frame
    assert P * N / S >= bands > (P - 1) * N / S  # the fewest pulses that give the bands
    assert plan.bands_visible == pytest.approx(P * N / S, rel=1e-12)
    assert P * plan.period_s == pytest.approx(dt, rel=1e-12)  # locked to the frame
    assert plan.exposure_s + plan.pulse_s == pytest.approx(plan.period_s, rel=1e-12)  # Eq. (8)
    assert plan.pulse_s == pytest.approx(0.1 * plan.period_s, rel=1e-12)
    # A phase off the row grid, so that no band boundary falls exactly on a row.
    sensor, strobe = plan.apply(PROTO_SENSOR, phase_s=0.37 * PROTO_SENSOR.line_time_s)
    assert band_gap_rows(sensor, strobe) == pytest.approx(0.0, abs=ROW_TOL)
    assert band_drift_rows(sensor, strobe) == pytest.approx(0.0, abs=ROW_TOL)
    assert band_spacing_rows(sensor, strobe) == pytest.approx(S / P, rel=1e-12)
    layout = band_layout(sensor, strobe)
    for a, b in zip(layout, layout[1:]):
        assert b.k_first == pytest.approx(a.k_last, abs=ROW_TOL)  # k_{j+1} = k'''_j
    _, _, w = row_pulse_weights(sensor, strobe)
    assert np.all((w > 0).sum(axis=1) == 1)  # every visible row lit, by one pulse only
    # Visible light share: the plan's estimate, up to one boundary's V-shaped dip
    # (b rows of light missing from an a-row band: Δs / Δe of a band) at the window's edges.
    got = sum(b.fraction_visible for b in layout)
    assert got == pytest.approx(plan.bands_visible, abs=plan.pulse_s / plan.exposure_s + 0.01)


@pytest.mark.parametrize("bands", [1, 4, 9.77, 16])
def test_plan_overlap_variant_lights_rows_uniformly(bands):
    # k_{j+1} = k''_j (Δe = Δ_clk): every row collects exactly one pulse's worth of light.
    plan = plan_strobe(PROTO_SENSOR, bands, pulse_s=50e-6, overlap=True)
    assert plan.exposure_s == pytest.approx(plan.period_s, rel=1e-12)
    assert plan.pulse_s == 50e-6
    sensor, strobe = plan.apply(PROTO_SENSOR, phase_s=1.234e-3)
    _, _, w = row_pulse_weights(sensor, strobe)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=0, atol=1e-9)
    assert (w > 0).sum(axis=1).max() == 2  # boundary rows mix two instants


def test_plan_reproduces_the_prototype():
    plan = plan_strobe(PROTO_SENSOR, 16 * 480 / 786, pulse_s=PROTO_PULSE_S)
    assert plan.pulses_per_frame == 16
    assert plan.period_s == pytest.approx(PROTO_PERIOD_S, rel=1e-12)
    assert plan.exposure_s == pytest.approx(939.75e-6, rel=1e-12)
    assert plan.bands_visible == pytest.approx(9.77, abs=0.01)


def test_band_is_frozen():
    b = band_layout(PROTO_SENSOR, proto_strobe())[0]
    with pytest.raises(FrozenInstanceError):
        b.first_row = 3


# --------------------------------------------------------------------------- bad input

BAD_SENSORS = {
    "zero_frame": Sensor(786, 480, 0.0, 1e-3),
    "negative_exposure": Sensor(786, 480, 16.636e-3, -1e-3),
    "zero_exposure": Sensor(786, 480, 16.636e-3, 0.0),
    "exposure_longer_than_frame": Sensor(786, 480, 16.636e-3, 20e-3),
    "more_visible_than_total": Sensor(480, 786, 16.636e-3, 1e-3),
    "no_lines": Sensor(0, 0, 16.636e-3, 1e-3),
    "nan_frame": Sensor(786, 480, math.nan, 1e-3),
}
BAD_STROBES = {
    "pulse_longer_than_period": Strobe(16, 2e-3, 1e-3, 0.0),
    "zero_pulse": Strobe(16, 0.0, 1e-3, 0.0),
    "negative_period": Strobe(16, 1e-4, -1e-3, 0.0),
    "no_pulses": Strobe(0, 1e-4, 1e-3, 0.0),
    "inf_phase": Strobe(16, 1e-4, 1e-3, math.inf),
}


@pytest.mark.parametrize("name", sorted(BAD_SENSORS))
def test_bad_sensor_raises(name):
    with pytest.raises(ValueError):
        band_layout(BAD_SENSORS[name], proto_strobe())
    with pytest.raises(ValueError):
        readout_time(0, BAD_SENSORS[name])


@pytest.mark.parametrize("name", sorted(BAD_STROBES))
def test_bad_strobe_raises(name):
    with pytest.raises(ValueError):
        row_pulse_weights(PROTO_SENSOR, BAD_STROBES[name])


@pytest.mark.parametrize(
    "call",
    [
        lambda: partial_lines(PROTO_SENSOR, 0.0),
        lambda: band_height(PROTO_SENSOR, -1e-4),
        lambda: usable_lines(PROTO_SENSOR, math.nan),
        lambda: pulse_times(proto_strobe(), 1.0, 0.5),
        lambda: row_pulse_weights(PROTO_SENSOR, proto_strobe(), rows=[-1]),
        lambda: row_pulse_weights(PROTO_SENSOR, proto_strobe(), rows=[786]),
        lambda: row_pulse_weights(PROTO_SENSOR, proto_strobe(), rows=np.zeros((2, 2))),
        lambda: band_layout(PROTO_SENSOR, proto_strobe(), frame_index=1.5),
        lambda: readout_time(0, PROTO_SENSOR, frame_index=True),
        lambda: plan_strobe(PROTO_SENSOR, 0),
        lambda: plan_strobe(PROTO_SENSOR, 4, duty=1.0),
        lambda: plan_strobe(PROTO_SENSOR, 4, duty=0.0),
        lambda: plan_strobe(PROTO_SENSOR, 16, pulse_s=2e-3),
        lambda: plan_strobe(PROTO_SENSOR, 4, pulse_s=0.0),
    ],
)
def test_bad_arguments_raise(call):
    with pytest.raises(ValueError):
        call()


def test_module_does_not_import_heavy_dependencies():
    # The estimator runs on a Raspberry Pi: numpy only here.
    src = open(banding.__file__, encoding="utf-8").read()
    for name in ("scipy", "matplotlib", "mitsuba", "print("):
        assert name not in src
