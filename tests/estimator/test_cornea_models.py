"""Cornea fits beyond the centre: free radius, Gaussian priors, gathered bands, covariance."""

import numpy as np
import pytest

from estimator.cornea import FitProblem, fit_cornea, fit_covariance
from estimator.geometry import glint_jacobians
from tests.estimator.simulated import screen_targets, simulate_glints

#: m: the LM stops on a step below 1e-7 m, which leaves <= 4e-10 m (estimator.cornea.solve).
SAME_MINIMUM_M = 1e-8
#: rad: the same on the orbit (1e-8 m over r_co = 4.25 mm).
SAME_MINIMUM_RAD = 1e-8 / 4.25e-3


@pytest.fixture(scope="module")
def noisy(setup):
    return simulate_glints(setup, screen_targets("grid:6x4", setup), noise_px=0.5, rng=np.random.default_rng(5))


def test_camera_frame_jacobian_is_the_world_one_rotated(setup):
    cam = setup.camera
    c = setup.eye.cornea_center(np.array([0.1, -0.2]), np.array([0.05, 0.1]))
    _, _, world, _, light_w = glint_jacobians(cam, c, 7.8e-3, setup.lights_world_m)
    _, _, local, _, light_c = glint_jacobians(cam, c, 7.8e-3, setup.lights_world_m, frame="camera")
    # J_world = J_camera R, to rounding (1e-12 relative).
    assert np.allclose(local @ cam.rotation, world, rtol=0, atol=1e-12 * np.abs(world).max())
    assert np.allclose(light_c @ cam.rotation, light_w, rtol=0, atol=1e-12 * np.abs(light_w).max())
    with pytest.raises(ValueError, match="frame"):
        glint_jacobians(cam, c, 7.8e-3, setup.lights_world_m, frame="eye")


@pytest.mark.parametrize("solver", ["lm", "trf"])
def test_center_and_radius_from_exact_glints(setup, solver):
    # A 7.6 mm cornea fitted from the 7.8 mm default within Read et al.'s bounds.
    truth = FitProblem(setup.camera, setup.lights_world_m, 7.6e-3)
    C = setup.eye.cornea_center(np.linspace(-0.3, 0.3, 6), np.linspace(-0.2, 0.1, 6))
    from estimator.geometry import project_glints
    g, v = project_glints(setup.camera, C, truth.cornea_radius_m, setup.lights_world_m)
    problem = FitProblem(setup.camera, setup.lights_world_m, 7.8e-3)
    x0 = np.append(setup.eye.cornea_center(0, 0), 7.8e-3)
    fit = fit_cornea(problem, g, v, x0, model="center_radius", solver=solver,
                     lower=[-1, -1, -1, 7.0e-3], upper=[1, 1, 1, 8.6e-3])
    assert fit.ok.all()
    # 1e-9 m: exact glints, quadratic convergence (see test_cornea.py).
    assert np.abs(fit.center_m - C).max() < 1e-9
    assert np.abs(fit.radius_m - 7.6e-3).max() < 1e-9


def test_center_radius_lm_matches_trf_on_noisy_glints(setup, problem, noisy):
    x0 = np.append(setup.eye.cornea_center(0, 0), 7.8e-3)
    bounds = dict(lower=[-1, -1, -1, 7.0e-3], upper=[1, 1, 1, 8.6e-3])
    lm = fit_cornea(problem, noisy.glints_px, noisy.visible, x0, model="center_radius", **bounds)
    trf = fit_cornea(problem, noisy.glints_px, noisy.visible, x0, model="center_radius", solver="trf", **bounds)
    assert lm.ok.all() and trf.ok.all()
    assert np.abs(lm.center_m - trf.center_m).max() < SAME_MINIMUM_M
    assert np.abs(lm.radius_m - trf.radius_m).max() < SAME_MINIMUM_M
    assert np.allclose(lm.rms_px, trf.rms_px, rtol=1e-6)


def test_prior_with_no_glints_returns_its_mean(setup, problem, noisy):
    B = 4
    mu = np.array([[0.1, -0.05]] * B)
    info = np.broadcast_to(np.eye(2) * 1e6, (B, 2, 2))
    none = np.zeros((B, 40), bool)
    fit = fit_cornea(problem, noisy.glints_px[:B], none, np.zeros((B, 2)) + mu, model="orbit",
                     prior_mean=mu, prior_information=info)
    assert fit.ok.all() and np.allclose(fit.angles_rad, mu, atol=1e-12)
    assert np.isnan(fit.rms_px).all() and (fit.glints_used == 0).all()
    # Without the prior the same samples have too few glints.
    bare = fit_cornea(problem, noisy.glints_px[:B], none, np.zeros(2), model="orbit")
    assert (bare.reason == "too_few_glints").all()


def test_prior_lm_matches_trf_and_pulls_toward_its_mean(setup, problem, noisy):
    B = noisy.glints_px.shape[0]
    plain = fit_cornea(problem, noisy.glints_px, noisy.visible, np.zeros(2), model="orbit")
    # A prior 0.02 rad off the unconstrained estimate, as informative as the glints are.
    cov = fit_covariance(problem, plain.angles_rad, noisy.visible, model="orbit", noise_px=0.5)
    mu = plain.angles_rad + 0.02
    info = 0.5 ** 2 * np.linalg.inv(cov)
    kw = dict(model="orbit", prior_mean=mu, prior_information=info)
    lm = fit_cornea(problem, noisy.glints_px, noisy.visible, plain.angles_rad, **kw)
    trf = fit_cornea(problem, noisy.glints_px, noisy.visible, plain.angles_rad, solver="trf", **kw)
    assert lm.ok.all() and trf.ok.all()
    assert np.abs(lm.angles_rad - trf.angles_rad).max() < SAME_MINIMUM_RAD
    # Equal information from glints and prior: the estimate lands halfway, to first order
    # (0.01 rad; the glints' Jacobian changes over 0.02 rad by a few per cent).
    assert np.abs(lm.angles_rad - (plain.angles_rad + 0.01)).max() < 1e-3
    # A sample whose prior is not finite has none.
    mu_nan = mu.copy()
    mu_nan[0] = np.nan
    part = fit_cornea(problem, noisy.glints_px, noisy.visible, plain.angles_rad, model="orbit",
                      prior_mean=mu_nan, prior_information=info)
    assert np.abs(part.angles_rad[0] - plain.angles_rad[0]).max() < SAME_MINIMUM_RAD
    assert np.abs(part.angles_rad[1:] - lm.angles_rad[1:]).max() < SAME_MINIMUM_RAD
    assert B > 1


def test_prior_bad_input(problem, noisy):
    g, v = noisy.glints_px[:2], noisy.visible[:2]
    with pytest.raises(ValueError, match="together"):
        fit_cornea(problem, g, v, np.zeros(2), model="orbit", prior_mean=np.zeros(2))
    with pytest.raises(ValueError, match="positive semi-definite"):
        fit_cornea(problem, g, v, np.zeros(2), model="orbit", prior_mean=np.zeros(2),
                   prior_information=-np.eye(2))


def test_banded_fits_gather_their_glints_and_match_trf(setup, problem, noisy):
    # Bands of 3 to 6 glints: LM gathers the seen glints (each sample's lights follow), TRF
    # works on the full masks; both must reach the same minimum.
    rng = np.random.default_rng(8)
    mask = np.zeros_like(noisy.visible)
    for b in range(mask.shape[0]):
        seen = np.flatnonzero(noisy.visible[b])
        start = rng.integers(0, seen.size - 6)
        mask[b, seen[start:start + rng.integers(3, 7)]] = True
    lm = fit_cornea(problem, noisy.glints_px, mask, np.zeros(2), model="orbit")
    trf = fit_cornea(problem, noisy.glints_px, mask, np.zeros(2), model="orbit", solver="trf")
    assert lm.ok.all() and trf.ok.all()
    assert np.abs(lm.angles_rad - trf.angles_rad).max() < SAME_MINIMUM_RAD
    assert np.allclose(lm.rms_px, trf.rms_px, rtol=1e-6)
    assert (lm.glints_used == mask.sum(axis=1)).all()


def test_covariance_matches_the_scatter_of_repeated_fits(setup, problem):
    # 400 noisy realisations of one pose: the sample covariance of the fitted angles against
    # sigma² (JᵀJ)⁻¹. The variance of a variance estimate from 400 samples has a relative SD of
    # sqrt(2 / 400) = 7 %: 25 % is 3.5 SD.
    T = np.repeat(screen_targets("grid:3x3", setup)[4:5], 400, axis=0)
    obs = simulate_glints(setup, T, noise_px=0.5, noise_model="gaussian", rng=np.random.default_rng(9))
    fit = fit_cornea(problem, obs.glints_px, obs.visible, np.zeros(2), model="orbit")
    emp = np.cov(fit.angles_rad.T)
    pred = fit_covariance(problem, fit.angles_rad[:1], obs.visible[:1], model="orbit", noise_px=0.5)[0]
    assert np.allclose(np.diag(emp), np.diag(pred), rtol=0.25)
    # Not determined: no glints, or one glint for the 3-unknown centre (2 equations).
    one = np.zeros((1, 40), bool)
    one[0, 5] = True
    assert np.isinf(fit_covariance(problem, fit.angles_rad[:1], one & False, model="orbit", noise_px=0.5)).all()
    centre = fit_covariance(problem, fit.center_m[:1], one, model="center", noise_px=0.5)
    assert np.isinf(centre).all()
    with pytest.raises(ValueError, match="model"):
        fit_covariance(problem, fit.center_m[:1], one, model="full", noise_px=0.5)


def test_large_batches_run_in_blocks_with_the_same_answers(setup, problem, monkeypatch):
    # The samples are independent: blocks of 200 must give exactly what one block gives.
    T = screen_targets("grid:24x15", setup)
    obs = simulate_glints(setup, T, noise_px=0.5, rng=np.random.default_rng(11))
    import estimator.cornea.solve as solve
    monkeypatch.setattr(solve, "_BLOCK", 200)
    blocks = fit_cornea(problem, obs.glints_px, obs.visible, np.zeros(2), model="orbit")
    monkeypatch.setattr(solve, "_BLOCK", 10_000)
    whole = fit_cornea(problem, obs.glints_px, obs.visible, np.zeros(2), model="orbit")
    assert len(T) == 360 and blocks.ok.all()
    assert np.array_equal(blocks.angles_rad, whole.angles_rad)
    assert np.array_equal(blocks.iterations, whole.iterations)
