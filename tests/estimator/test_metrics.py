"""Angular error, accuracy and robustness summaries (Sec. 3 and 3.4 of the SCET paper)."""

import numpy as np
import pytest

from estimator.metrics import (AccuracySummary, angular_error_deg, gaze_accuracy, light_position_error_m,
                               summarize_errors)

#: Degrees: angles from atan2 of exact float64 geometry; rounding is ~1e-14 rad.
EXACT_DEG = 1e-10


def test_angle_is_measured_at_the_eye_centre():
    target = np.array([[0.0, 0.0, -0.7]])
    est = np.array([[0.7 * np.tan(np.radians(1.0)), 0.0, -0.7]])
    assert abs(angular_error_deg(est, target)[0] - 1.0) < EXACT_DEG
    # Seen from a vertex 0.1 m closer to the screen the same pair subtends atan(x / 0.6).
    vertex = np.array([0.0, 0.0, -0.1])
    expected = np.degrees(np.arctan(0.7 * np.tan(np.radians(1.0)) / 0.6))
    assert abs(angular_error_deg(est, target, vertex)[0] - expected) < EXACT_DEG


def test_screen_xy_is_placed_on_the_targets_plane():
    rng = np.random.default_rng(0)
    targets = np.column_stack([rng.uniform(-0.2, 0.2, 20), rng.uniform(-0.2, 0.1, 20), np.full(20, -0.7)])
    est = targets + np.column_stack([rng.normal(0, 0.01, (20, 2)), np.zeros(20)])
    assert np.allclose(angular_error_deg(est[:, :2], targets), angular_error_deg(est, targets), atol=EXACT_DEG)
    assert np.all(angular_error_deg(targets, targets) < EXACT_DEG)


def test_small_errors_keep_their_precision():
    # 1e-6 degrees at 0.7 m is 12 nm on the screen; arccos of a dot product would lose it.
    target = np.array([[0.1, -0.05, -0.7]])
    d = np.linalg.norm(target)
    perp = np.cross(target[0], [0.0, 1.0, 0.0])
    est = target + perp / np.linalg.norm(perp) * d * np.tan(np.radians(1e-6))
    assert abs(angular_error_deg(est, target)[0] - 1e-6) < 1e-12


def test_summary_counts_failures_against_robustness():
    err = np.array([0.5, 1.0, 1.5, 6.0, np.nan])
    s = summarize_errors(err)
    assert isinstance(s, AccuracySummary)
    assert (s.n, s.n_nan) == (5, 1)
    assert s.mean_deg == pytest.approx(np.mean([0.5, 1.0, 1.5, 6.0]))
    assert s.sd_deg == pytest.approx(np.std([0.5, 1.0, 1.5, 6.0], ddof=1))
    assert s.robustness == pytest.approx(3 / 5)  # the NaN counts as a failure
    assert s.robust_mean_deg == pytest.approx(1.0)
    assert s.robust_sd_deg == pytest.approx(0.5)
    assert s.as_dict()["threshold_deg"] == 5.0


def test_summary_of_nothing_is_nan_not_a_crash():
    s = summarize_errors(np.array([np.nan, np.nan]))
    assert np.isnan(s.mean_deg) and np.isnan(s.robust_mean_deg) and s.robustness == 0.0
    assert np.isnan(summarize_errors([]).robustness)


def test_gaze_accuracy_and_nan_estimates():
    targets = np.array([[0.0, 0.0, -0.7], [0.1, 0.0, -0.7]])
    est = np.array([[0.0, 0.0, -0.7], [np.nan, np.nan, np.nan]])
    s = gaze_accuracy(est, targets)
    assert s.n_nan == 1 and s.mean_deg < EXACT_DEG and s.robustness == 0.5


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match="estimated_m"):
        angular_error_deg(np.zeros((3, 4)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="estimated_m"):
        angular_error_deg(np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="same shape"):
        light_position_error_m(np.zeros((3, 3)), np.zeros((4, 3)))


def test_light_position_error_is_the_mean_distance():
    a = np.zeros((4, 3))
    b = np.array([[1e-3, 0, 0], [0, 2e-3, 0], [0, 0, 3e-3], [0, 0, 0]])
    assert light_position_error_m(a, b) == pytest.approx(1.5e-3)
