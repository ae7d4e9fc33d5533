"""Cornea fits: recover known cornea centres from simulated glints, with both solvers."""

import numpy as np
import pytest

from estimator.cornea import FitProblem, fit_cornea
from estimator.geometry import glint_jacobians, project_glints
from tests.estimator.simulated import screen_targets, simulate_glints


def test_glint_jacobians_match_finite_differences(setup):
    cam, r, L = setup.camera, setup.eye.cornea_radius_m, setup.lights_world_m
    c = setup.eye.cornea_center(0.2, -0.1)
    g, v, d_c, d_r, d_l = glint_jacobians(cam, c, r, L)
    h = 1e-7  # m: central differences are accurate to ~h^2 * g''' ~ 1e-9 relative here
    for k in range(3):
        e = np.eye(3)[k] * h
        fd = (project_glints(cam, c + e, r, L)[0] - project_glints(cam, c - e, r, L)[0]) / (2 * h)
        assert np.abs(fd - d_c[..., k])[v].max() < 1e-6 * np.abs(d_c).max()
        fd = (project_glints(cam, c, r, L + e)[0] - project_glints(cam, c, r, L - e)[0]) / (2 * h)
        assert np.abs(fd - d_l[..., k])[v].max() < 1e-6 * np.abs(d_c).max()
    fd = (project_glints(cam, c, r + h, L)[0] - project_glints(cam, c, r - h, L)[0]) / (2 * h)
    assert np.abs(fd - d_r)[v].max() < 1e-6 * np.abs(d_c).max()


@pytest.mark.parametrize("solver", ["lm", "trf"])
def test_noise_free_glints_give_the_exact_centre(setup, problem, solver):
    obs = simulate_glints(setup, screen_targets("grid:6x4", setup))
    fit = fit_cornea(problem, obs.glints_px, obs.visible, setup.eye.cornea_center(0, 0), solver=solver)
    assert fit.ok.all()
    # 1e-9 m: LM ends on a Gauss-Newton step below 1e-7 m, which leaves <= 4e4 /m x (1e-7 m)²
    # = 4e-10 m with exact glints (quadratic convergence); TRF stops at xtol 1e-12.
    assert np.abs(fit.center_m - obs.cornea_center_m).max() < 1e-9
    # 2e-5 px: that 4e-10 m times the steepest glint, ~4.6e4 px/m on paper_sim.
    assert fit.rms_px.max() < 2e-5


def test_lm_matches_the_papers_trf_on_noisy_glints(setup, problem):
    obs = simulate_glints(setup, screen_targets("grid:6x4", setup), noise_px=0.5, rng=5)
    a = fit_cornea(problem, obs.glints_px, obs.visible, setup.eye.cornea_center(0, 0), solver="lm")
    b = fit_cornea(problem, obs.glints_px, obs.visible, setup.eye.cornea_center(0, 0), solver="trf")
    # Both reach the same least-squares minimum: 1e-8 m is 1e-3 of the noise-induced error.
    assert np.abs(a.center_m - b.center_m).max() < 1e-8
    assert np.allclose(a.rms_px, b.rms_px, atol=1e-9)
    # e_f = 0.5 px uniform: RMS residual near 0.5/sqrt(3) = 0.29 px per axis.
    assert 0.2 < np.median(a.rms_px) < 0.45
    err = np.linalg.norm(a.center_m - obs.cornea_center_m, axis=1)
    assert np.median(err) < 20e-6  # metres; ~40 glints at 0.3 px locate the centre to microns


def test_orbit_model_recovers_gaze_angles(setup, problem):
    obs = simulate_glints(setup, screen_targets("grid:5x3", setup), noise_px=0.0)
    fit = fit_cornea(problem, obs.glints_px, obs.visible, [0.0, 0.0], model="orbit")
    assert fit.ok.all()
    assert np.abs(fit.angles_rad - np.stack([obs.yaw_rad, obs.pitch_rad], 1)).max() < 1e-9


def test_one_glint_is_enough_on_the_orbit(setup, problem):
    obs = simulate_glints(setup, screen_targets("grid:4x3", setup))
    mask = np.zeros_like(obs.visible)
    mask[:, 20] = obs.visible[:, 20]
    fit = fit_cornea(problem, obs.glints_px, mask, [0.0, 0.0], model="orbit")
    ok = mask[:, 20]
    assert fit.ok[ok].all()
    assert np.abs(fit.angles_rad[ok] - np.stack([obs.yaw_rad, obs.pitch_rad], 1)[ok]).max() < 1e-6


def test_missing_glints_are_masks_and_too_few_is_nan(setup, problem):
    obs = simulate_glints(setup, screen_targets("grid:3x2", setup))
    glints = obs.glints_px.copy()
    glints[0, 5:] = np.nan  # 5 glints left: still enough for 3 unknowns
    glints[1, 1:] = np.nan  # 1 glint: too few for the centre model (2 equations < 3 unknowns)
    fit = fit_cornea(problem, glints, None, setup.eye.cornea_center(0, 0))
    assert fit.reason[0] == "ok" and fit.glints_used[0] == 5
    assert np.abs(fit.center_m[0] - obs.cornea_center_m[0]).max() < 1e-9
    assert fit.reason[1] == "too_few_glints" and np.isnan(fit.center_m[1]).all()
    assert fit.ok[2:].all()


def test_bad_input(problem, setup):
    with pytest.raises(ValueError, match="shape"):
        fit_cornea(problem, np.zeros((2, 3, 2)), None, [0, 0, 0])
    with pytest.raises(ValueError, match="model"):
        fit_cornea(problem, np.zeros((1, 40, 2)), None, [0, 0, 0], model="ellipsoid")
    with pytest.raises(ValueError, match="solver"):
        fit_cornea(problem, np.zeros((1, 40, 2)), None, [0, 0, 0], solver="adam")
    with pytest.raises(ValueError, match="orbit"):
        fit_cornea(FitProblem(setup.camera, setup.lights_world_m, 7.8e-3), np.zeros((1, 40, 2)), None,
                   [0, 0], model="orbit")


def test_lm_reaches_the_bounded_minimum_like_trf(setup, problem):
    """A bound that cuts off the free minimum: LM's active set must find the same constrained
    minimum as scipy's TRF (a clipped step alone stops up to 0.2 mm away)."""
    obs = simulate_glints(setup, screen_targets("grid:6x4", setup), noise_px=0.5, rng=1)
    lo = [-1.0, -1.0, -1.0]
    hi = [1.0, 1.0, obs.cornea_center_m[:, 2].min() - 1e-4]
    a = fit_cornea(problem, obs.glints_px, obs.visible, setup.eye.cornea_center(0, 0), lower=lo, upper=hi)
    b = fit_cornea(problem, obs.glints_px, obs.visible, setup.eye.cornea_center(0, 0), solver="trf",
                   lower=lo, upper=hi)
    assert a.ok.all() and b.ok.all()
    assert np.all(a.center_m[:, 2] == hi[2])
    assert np.abs(a.center_m - b.center_m).max() < 1e-9  # metres
    assert np.allclose(a.rms_px, b.rms_px, atol=1e-9)
