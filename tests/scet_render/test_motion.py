"""Physical checks of the eye-motion model: main sequence, great circles, pursuit, seeding."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.eye import Eye, gaze_direction
from estimator.geometry import rotation_matrix
from estimator.setup import Screen
from scet_render.motion import (
    FixationalNoise,
    SaccadeModel,
    SegmentKind,
    concatenate,
    fixation_sequence,
    grid_sequence,
    main_sequence,
    pursuit,
    saccade_sequence,
)


class TOL:
    """Tolerances, with units and the reason for each."""

    #: rad. Directions are built from unit vectors and go through one Fick round trip: errors are
    #: a few 1e-16; 1e-12 leaves four decades of margin.
    exact_rad = 1e-12
    #: s. Finite-difference sampling step: fine enough to resolve the 2-4 ms speed ramps of the
    #: shortest profiles, coarse enough to keep the file fast.
    step_s = 1e-5
    #: s. Onset/offset are found on the sampling grid (+-1 step each) and the profile needs
    #: ~2 us to move 1e-12 rad off its end points (it starts as a cubic).
    duration_s = 2 * step_s + 5e-6
    #: relative. The plateau profile holds its peak speed over a finite interval, so a central
    #: difference measures it exactly up to rounding (~1e-11 on angles of ~1e-4 rad).
    peak_rel = 1e-6
    #: relative. A sample within 0.1 ms of a saccade's start or end moves at < 1 % of its peak.
    at_rest_rel = 1e-2
    #: rad/s. Analytic noise speed vs central differences: truncation error (2 pi f h)^2 / 6 at
    #: f = 100 Hz, h = 10 us is 7e-6 relative; rounding of angles of 1e-7 rad dominates.
    noise_speed_rad_s = 1e-4


EYE = Eye(np.array([0.012, -0.004, 0.003]))  # shifted centre: nothing may assume the origin
SCREEN = Screen((-0.26, 0.26), (-0.16, 0.16), -0.7)


def _angle(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _on_screen(direction):
    """World point on the screen plane along ``direction`` from the eye centre."""
    c = EYE.rotation_center_m
    return c + direction * (SCREEN.z_m - c[2]) / direction[2]


def _saccade_pair(amplitude_deg):
    """Two screen targets whose directions from the eye are ``amplitude_deg`` apart, obliquely."""
    d0 = gaze_direction(-0.2, -0.08)
    axis = np.cross(d0, _unit(np.array([0.3, 1.0, 0.0])))
    d1 = rotation_matrix(axis, np.deg2rad(amplitude_deg)) @ d0
    return np.stack([_on_screen(d0), _on_screen(d1)])


def _fd_speed(traj, t):
    """Central-difference angular speed (rad/s) at t[1:-1] for a uniform grid t."""
    d = traj.direction_at(t)
    return _angle(d[2:], d[:-2]) / (t[2] - t[0])


def _saccade_window(traj, k=1):
    """Uniform grid over segment k and 1 ms either side."""
    t0, dur = traj.start_s[k], traj.segment_duration_s[k]
    return np.arange(t0 - 1e-3, t0 + dur + 1e-3, TOL.step_s)


# -- main sequence ---------------------------------------------------------------------------


def test_main_sequence_values_and_overrides():
    d, v = main_sequence(np.array([[0.0, 10.0], [20.0, 40.0]]))
    assert d.shape == v.shape == (2, 2)
    np.testing.assert_allclose(d, 2.2e-3 * np.array([[0, 10], [20, 40]]) + 0.021, rtol=1e-15)
    np.testing.assert_allclose(v[0, 1], 500.0 * (1.0 - np.exp(-10.0 / 14.0)), rtol=1e-15)
    assert v[0, 0] == 0.0
    d2, v2 = main_sequence(10.0, slope_s_per_deg=3e-3, intercept_s=0.02, v_max_deg_s=700.0,
                           c_deg=10.0)
    assert d2 == pytest.approx(0.05) and v2 == pytest.approx(700.0 * (1.0 - np.exp(-1.0)))


@pytest.mark.parametrize(
    "amplitude_deg, model",
    [
        (10.0, SaccadeModel()),
        (20.0, SaccadeModel()),
        (40.0, SaccadeModel()),
        # Peak-to-mean ratio 1.73 and a skewed profile: still on the reachable range.
        (20.0, SaccadeModel(v_max_deg_s=700.0, acceleration_share=0.35)),
    ],
)
def test_saccade_duration_and_peak_velocity_follow_main_sequence(amplitude_deg, model):
    targets = _saccade_pair(amplitude_deg)
    traj = fixation_sequence(EYE, targets, 0.05, saccades=model)
    assert list(traj.kind) == [SegmentKind.FIXATION, SegmentKind.SACCADE, SegmentKind.FIXATION]
    d_ms, v_ms = main_sequence(amplitude_deg, slope_s_per_deg=model.slope_s_per_deg,
                               intercept_s=model.intercept_s, v_max_deg_s=model.v_max_deg_s,
                               c_deg=model.c_deg)

    t = _saccade_window(traj)
    d = traj.direction_at(t)
    d_start, d_end = _unit(targets - EYE.rotation_center_m)
    moved = _angle(d, d_start) > TOL.exact_rad
    arrived = _angle(d, d_end) <= TOL.exact_rad
    onset = t[np.argmax(moved) - 1]
    offset = t[np.argmax(arrived)]
    assert offset - onset == pytest.approx(d_ms, abs=TOL.duration_s)
    assert traj.segment_duration_s[1] == pytest.approx(d_ms, rel=1e-15)

    peak = _fd_speed(traj, t).max()
    assert peak == pytest.approx(np.deg2rad(v_ms), rel=TOL.peak_rel)
    assert traj.segment_peak_speed_rad_s[1] == pytest.approx(np.deg2rad(v_ms), rel=1e-12)
    assert traj.velocity_at(t).max() == pytest.approx(np.deg2rad(v_ms), rel=1e-12)


def test_small_saccade_is_clamped_keeping_duration():
    # At 2 deg the main sequence asks V_p D / A = 0.85 < 1: impossible from rest. The duration is
    # kept and the peak is raised to the profile's smallest peak-to-mean ratio.
    model = SaccadeModel()
    targets = _saccade_pair(2.0)
    traj = fixation_sequence(EYE, targets, 0.05, saccades=model)
    d_ms, v_ms = main_sequence(2.0)
    amp = np.deg2rad(2.0)
    expected_peak = model.peak_to_mean_range[0] * amp / d_ms
    assert expected_peak > np.deg2rad(v_ms)
    t = _saccade_window(traj)
    assert _fd_speed(traj, t).max() == pytest.approx(expected_peak, rel=TOL.peak_rel)
    assert traj.segment_duration_s[1] == pytest.approx(d_ms, rel=1e-15)


def test_large_peak_to_mean_ratio_is_clamped_to_raised_cosine():
    model = SaccadeModel(v_max_deg_s=2000.0)  # asks V_p D / A = 4.9 > 2
    duration, ramp, peak = model.kinematics(np.array([np.deg2rad(20.0)]))
    np.testing.assert_allclose(ramp.sum(axis=1), 1.0)
    np.testing.assert_allclose(peak, 2.0 * np.deg2rad(20.0) / duration)


@settings(max_examples=40, deadline=None)
@given(
    amplitude_deg=st.floats(0.1, 60.0),
    share=st.floats(0.05, 0.95),
    min_ramp=st.floats(0.02, 1.0),
    v_max_deg_s=st.floats(200.0, 1500.0),
)
def test_profile_family_ends_exactly_and_stays_monotone(
    amplitude_deg, share, min_ramp, v_max_deg_s
):
    model = SaccadeModel(v_max_deg_s=v_max_deg_s, acceleration_share=share,
                         min_ramp_fraction=min_ramp)
    targets = _saccade_pair(amplitude_deg)
    traj = fixation_sequence(EYE, targets, 0.01, saccades=model)
    t = np.linspace(traj.start_s[1], traj.start_s[2], 4001)
    d_start, d_end = _unit(targets - EYE.rotation_center_m)
    d = traj.direction_at(t)
    assert np.all(np.diff(_angle(d, d_start)) >= -TOL.exact_rad)
    assert _angle(traj.direction_at(traj.start_s[2] * (1 - 1e-16)), d_end) < TOL.exact_rad
    # The analytic peak is what the kinematics promised, and within the family's range.
    amp = _angle(d_start, d_end)
    q = traj.velocity_at(t).max() * traj.segment_duration_s[1] / amp
    q_lo, q_hi = model.peak_to_mean_range
    # 1e-3 below: the 4001-point grid may miss a raised-cosine peak by (pi / 4000)^2 / 2.
    assert q_lo * (1 - 1e-3) <= q <= q_hi * (1 + 1e-12)
    assert traj.velocity_at(t).max() <= traj.segment_peak_speed_rad_s[1] * (1 + 1e-12)


def test_saccade_monotone_and_at_rest_at_both_ends():
    targets = _saccade_pair(15.0)
    traj = fixation_sequence(EYE, targets, 0.05)
    t0, dur = traj.start_s[1], traj.segment_duration_s[1]
    t = np.linspace(t0, t0 + dur, 20001)
    d = traj.direction_at(t)
    progress = _angle(d, d[0])
    assert np.all(np.diff(progress) >= -TOL.exact_rad)
    amplitude = _angle(*_unit(targets - EYE.rotation_center_m))
    assert progress[-1] == pytest.approx(amplitude, abs=TOL.exact_rad)

    peak = traj.segment_peak_speed_rad_s[1]
    assert traj.velocity_at(t0) == 0.0
    assert traj.velocity_at(t0 + dur * (1 - 1e-12)) < 1e-9 * peak
    for edge in (t0, t0 + dur - 1e-4):
        ts = np.array([edge, edge + 1e-4])
        mean_speed = _angle(*traj.direction_at(ts)) / 1e-4
        assert mean_speed < TOL.at_rest_rel * peak


def test_saccade_follows_the_great_circle():
    targets = _saccade_pair(30.0)
    traj = fixation_sequence(EYE, targets, 0.05)
    d0, d1 = _unit(targets - EYE.rotation_center_m)
    normal = _unit(np.cross(d0, d1))
    t = np.linspace(traj.start_s[1], traj.start_s[2], 2001)
    d = traj.direction_at(t)
    assert np.abs(d @ normal).max() < TOL.exact_rad
    # In the plane and on the short arc: the two legs add up to the amplitude.
    np.testing.assert_allclose(_angle(d0, d) + _angle(d, d1), _angle(d0, d1), atol=TOL.exact_rad)


# -- fixations and grids ---------------------------------------------------------------------


def test_fixations_hold_targets_exactly():
    traj = grid_sequence(EYE, SCREEN, 4, 3, 0.2)
    targets = SCREEN.grid(4, 3)
    fix = np.flatnonzero(traj.kind == SegmentKind.FIXATION)
    assert fix.size == 12 and traj.segment_count == 23
    t = traj.start_s[fix, None] + traj.segment_duration_s[fix, None] * np.array([0.0, 0.37, 1.0])
    t[-1, -1] = traj.duration_s + 1.0  # beyond the end clamps to the last fixation
    d = traj.direction_at(t)
    want = _unit(targets - EYE.rotation_center_m)[:, None, :]
    assert _angle(d, want).max() < TOL.exact_rad
    np.testing.assert_array_equal(traj.target_at(t[:, 1]), targets)
    assert np.all(traj.velocity_at(t[:, 1]) == 0.0)
    assert traj.duration_s == pytest.approx(traj.segment_duration_s.sum(), rel=1e-14)


def test_repeated_target_has_no_saccade_and_saccade_labels_next_target():
    a, b = _saccade_pair(12.0)
    traj = fixation_sequence(EYE, np.stack([a, a, b]), [0.1, 0.2, 0.3])
    assert list(traj.kind) == [0, 0, 1, 0]
    mid = traj.start_s[2] + 0.5 * traj.segment_duration_s[2]
    np.testing.assert_array_equal(traj.target_at(mid), b)
    assert traj.segment_at(mid) == SegmentKind.SACCADE


# -- pursuit and concatenation ---------------------------------------------------------------


def test_pursuit_has_constant_speed_and_tracks_the_line():
    start, end = np.array([-0.2, 0.05, -0.7]), np.array([0.15, -0.1, -0.7])
    traj = pursuit(EYE, start, end, 20.0)
    amp = _angle(*_unit(np.stack([start, end]) - EYE.rotation_center_m))
    assert traj.duration_s == pytest.approx(amp / np.deg2rad(20.0), rel=1e-14)
    t = np.linspace(0.0, traj.duration_s, 5001)
    np.testing.assert_allclose(_fd_speed(traj, t), np.deg2rad(20.0), rtol=1e-8)
    np.testing.assert_allclose(traj.velocity_at(t), np.deg2rad(20.0), rtol=1e-14)
    assert np.all(traj.segment_at(t) == SegmentKind.PURSUIT)

    target = traj.target_at(t)
    np.testing.assert_allclose(target[[0, -1]], np.stack([start, end]), atol=1e-12)
    np.testing.assert_allclose(target[:, 2], -0.7, atol=1e-12)
    ray = _unit(target - EYE.rotation_center_m)
    assert _angle(ray, traj.direction_at(t)).max() < TOL.exact_rad


def test_concatenate_joins_with_saccades_and_stays_continuous():
    start, end = np.array([-0.2, 0.05, -0.7]), np.array([0.15, -0.1, -0.7])
    other = np.array([0.0, 0.12, -0.7])
    traj = concatenate([
        fixation_sequence(EYE, start[None], 0.1),
        pursuit(EYE, start, end, 15.0),
        fixation_sequence(EYE, other[None], 0.1),
    ])
    assert list(traj.kind) == [0, 2, 1, 0]
    np.testing.assert_array_equal(traj.from_target_m[2], end)
    np.testing.assert_array_equal(traj.to_target_m[2], other)
    t = np.arange(0.0, traj.duration_s, TOL.step_s)
    d = traj.direction_at(t)
    step = _angle(d[:-1], d[1:])
    # No jumps: no step is longer than the fastest segment could travel.
    assert step.max() <= traj.segment_peak_speed_rad_s.max() * TOL.step_s * (1 + 1e-6)
    with pytest.raises(ValueError, match="same eye"):
        concatenate([traj, pursuit(Eye(np.zeros(3)), start, end, 10.0)])


# -- seeding, noise and vectorisation --------------------------------------------------------


def test_same_seed_gives_identical_arrays():
    targets = SCREEN.grid(3, 3)
    a = saccade_sequence(EYE, targets, 123, noise=FixationalNoise())
    b = saccade_sequence(EYE, targets, np.random.default_rng(123), noise=FixationalNoise())
    c = saccade_sequence(EYE, targets, 124, noise=FixationalNoise())
    t = np.linspace(0.0, a.duration_s, 1001)
    for name in ("segment_duration_s", "noise_amplitude_rad", "noise_phase_rad",
                 "noise_frequency_hz"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(np.stack(a.angles_at(t)), np.stack(b.angles_at(t)))
    assert not np.array_equal(a.segment_duration_s, c.segment_duration_s)
    fix = a.segment_duration_s[a.kind == SegmentKind.FIXATION]
    assert np.all((fix >= 0.15) & (fix <= 0.4))


def test_fixational_noise_is_small_pinned_and_differentiated_correctly():
    noise = FixationalNoise()
    traj = fixation_sequence(EYE, SCREEN.grid(2, 1), 0.3, rng=5, noise=noise)
    fix = np.flatnonzero(traj.kind == SegmentKind.FIXATION)
    ends = np.concatenate([traj.start_s[fix], traj.start_s[fix] + traj.segment_duration_s[fix]])
    want = _unit(traj.from_target_m[np.concatenate([fix, fix])] - EYE.rotation_center_m)
    assert _angle(traj.direction_at(ends), want).max() < TOL.exact_rad

    t = np.arange(traj.start_s[0], traj.start_s[0] + traj.segment_duration_s[0], TOL.step_s)
    off = _angle(traj.direction_at(t), want[0])
    assert 0 < off.max() < 10 * (noise.drift_rms_rad + noise.tremor_rms_rad)
    np.testing.assert_allclose(_fd_speed(traj, t), traj.velocity_at(t[1:-1]),
                               atol=TOL.noise_speed_rad_s)
    with pytest.raises(ValueError, match="needs rng"):
        fixation_sequence(EYE, SCREEN.grid(2, 1), 0.3, noise=noise)


def test_vectorised_shapes_and_clamping():
    traj = grid_sequence(EYE, SCREEN, 3, 2, 0.1)
    t = np.linspace(-0.05, traj.duration_s + 0.05, 24).reshape(2, 3, 4)
    yaw, pitch = traj.angles_at(t)
    assert yaw.shape == pitch.shape == traj.velocity_at(t).shape == (2, 3, 4)
    assert traj.segment_at(t).shape == traj.segment_index_at(t).shape == (2, 3, 4)
    assert traj.target_at(t).shape == traj.direction_at(t).shape == (2, 3, 4, 3)
    np.testing.assert_array_equal(yaw.ravel(), traj.angles_at(t.ravel())[0])
    y0, p0 = traj.angles_at(0.0)
    assert y0.shape == () and traj.target_at(0.0).shape == (3,)
    assert traj.angles_at(-1.0) == (y0, p0)
    np.testing.assert_array_equal(traj.angles_at(1e3), traj.angles_at(traj.duration_s))


# -- bad input -------------------------------------------------------------------------------


A, B = np.array([-0.1, 0.0, -0.7]), np.array([0.1, 0.0, -0.7])


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: fixation_sequence(EYE, np.stack([A, B]), -0.1), "fixation_s"),
        (lambda: fixation_sequence(EYE, np.stack([A, B]), [0.1, 0.1, 0.1]), r"shape \(2,\)"),
        (lambda: fixation_sequence(EYE, np.stack([A, [np.nan, 0, -0.7]]), 0.1), "finite"),
        (lambda: fixation_sequence(EYE, np.stack([A, [0.0, 0.0, 0.5]]), 0.1), "not in front"),
        (lambda: fixation_sequence(EYE, A, 0.1), r"\(n, 3\)"),
        (lambda: saccade_sequence(EYE, np.stack([A, B]), 1, (0.4, 0.1)), "fixation_range_s"),
        (lambda: saccade_sequence(EYE, np.stack([A, B]), None), "needs rng"),
        (lambda: pursuit(EYE, A, B, 0.0), "speed_deg_s"),
        (lambda: pursuit(EYE, A, 2 * A - EYE.rotation_center_m, 10.0), "different directions"),
        (lambda: main_sequence(-1.0), "amplitude_deg"),
        (lambda: SaccadeModel(acceleration_share=1.0), "acceleration_share"),
        (lambda: SaccadeModel(c_deg=0.0), "c_deg"),
        (lambda: FixationalNoise(drift_band_hz=(5.0, 1.0)), "drift_band_hz"),
        (lambda: grid_sequence(EYE, SCREEN, 2, 2, 0.1).angles_at([0.0, np.inf]), "finite"),
        (lambda: concatenate([]), "non-empty"),
    ],
)
def test_bad_input_raises_value_error(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_rng_of_wrong_type_raises_type_error():
    with pytest.raises(TypeError, match="rng"):
        saccade_sequence(EYE, np.stack([A, B]), 1.5)


def test_trajectory_arrays_are_read_only():
    traj = fixation_sequence(EYE, np.stack([A, B]), 0.1)
    with pytest.raises(ValueError):
        traj.start_s[0] = 1.0
