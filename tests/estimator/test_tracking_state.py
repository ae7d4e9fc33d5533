"""The tracking wing's small parts: the stream state a band step hands the next
(:class:`estimator.tracking.StreamState`), the reason vocabulary (:class:`estimator.reasons.Reason`,
whose values are what the samples CSV has always held), and the scalar screen point and orbit
centre the band steps use against the numpy functions they stand in for."""

import math

import numpy as np
import pytest

from estimator.eye import gaze_direction
from estimator.gaze import screen_intersection
from estimator.reasons import IDENTITY_FAILURES, Reason, flux_cut_failure, prior_failure
from estimator.scene import load_scene
from estimator.tracking import (JUMP_AGE_S, JUMP_SLACK_DEG, VELOCITY_AGE_S, StreamState,
                                Tracker, failed_sample, samples_csv)
from estimator.tracking.estimates import _orbit_center
from tests.estimator.simulated import ground_truth_calibration


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


def test_reasons_write_as_the_csv_strings_they_always_were():
    # The reason column of samples files written before the enum (scet-samples 1-3).
    assert [str(r) for r in (Reason.OK, Reason.OUT_OF_REACH, Reason.MATCH_TOO_FEW_GLINTS,
                             Reason.UNREADABLE_FRAME)] == [
        "ok", "band_out_of_reach", "match_too_few_glints", "unreadable_frame"]
    assert prior_failure(Reason.AMBIGUOUS) == "prior_ambiguous"
    assert flux_cut_failure(Reason.MATCH_TOO_FEW_GLINTS) == "flux_cut_glints_match_too_few_glints"
    assert "too_few_glints" in IDENTITY_FAILURES and Reason.OK == "ok"
    row = samples_csv([failed_sample(3, 7, 0.5, Reason.SATURATED_FRAME)]).splitlines()[2]
    assert row.split(",")[11] == "saturated_frame"


def test_the_state_measures_velocity_between_neighbouring_samples_only():
    cov = np.eye(2) * 1e-6
    s = StreamState().estimated(0.010, [0.10, 0.00], cov, prior_angles_rad=None, start=None)
    assert s.velocity_rad_s is None  # one sample: no velocity
    near = s.estimated(0.011, [0.11, -0.01], cov, prior_angles_rad=None, start=None)
    assert np.allclose(near.velocity_rad_s, [10.0, -10.0], rtol=1e-9)  # rad/s over 1 ms
    far = s.estimated(0.010 + 2 * VELOCITY_AGE_S, [0.11, 0.0], cov, prior_angles_rad=None,
                      start=None)
    assert far.velocity_rad_s is None
    # A failed band loses the prior of the next dense band, not the last estimate.
    kept = near.estimated(0.012, [0.12, 0.0], cov, prior_angles_rad=np.zeros(2),
                          start=np.zeros(3)).lost()
    assert kept.prior_angles_rad is None and kept.start is None and kept.last.time_s == 0.012
    # The carried prior moves on at the velocity, and expires after JUMP_AGE_S.
    assert np.allclose(near.carried_prior(0.012), [0.12, -0.02], atol=1e-12)
    assert near.carried_prior(0.011 + JUMP_AGE_S * 1.01) is None
    assert near.carried_prior(0.0105) is None  # before the sample: not a prior


def test_a_jump_further_than_the_eye_turns_is_implausible():
    s = StreamState().estimated(0.0, [0.0, 0.0], np.eye(2), prior_angles_rad=None, start=None)
    v = 600.0  # deg/s per axis
    dt = 1e-3
    reach = math.radians(v * math.sqrt(2.0) * dt + JUMP_SLACK_DEG)
    assert not s.implausible(dt, [0.99 * reach, 0.0], v)
    assert s.implausible(dt, [1.01 * reach, 0.0], v)
    assert not s.implausible(2 * JUMP_AGE_S, [1.0, 0.0], v)  # too old to judge


def test_the_scalar_screen_point_is_the_numpy_one(setup):
    ctx = Tracker(setup, ground_truth_calibration(setup), "geometric").context
    c = ctx.calibration.eye_center_m
    rng = np.random.default_rng(5)
    for a in rng.uniform(-1.2, 1.2, (500, 2)):
        p, hit = screen_intersection(c, gaze_direction(a[0], a[1])[None], setup.screen.z_m)
        got = ctx.gaze_point(None, a)
        if hit[0]:
            # The same operations: equal but for the platform's sin/cos (1 ulp, ~1e-16 m/m).
            assert np.allclose(got, p[0, :2], rtol=1e-15, atol=1e-15)
        else:
            assert np.isnan(got).all()
    assert np.isnan(ctx.gaze_point(None, [math.pi, 0.0])).all()  # looking away from the screen


def test_the_scalar_orbit_centre_is_the_numpy_one(setup):
    orbit = Tracker(setup, ground_truth_calibration(setup), "geometric").context.problems.orbit
    rng = np.random.default_rng(6)
    for a in rng.uniform(-0.8, 0.8, (200, 2)):
        want = orbit.eye_center_m + orbit.orbit_radius_m * gaze_direction(a[0], a[1])
        assert np.allclose(_orbit_center(orbit, a), want, rtol=0, atol=1e-18)
