"""Geometric and polynomial gaze on simulated glints (Sec. 2.2 and 3.2 of the SCET paper)."""

import numpy as np
import pytest

from estimator.calibration import Calibration, fit_gaze_mapping
from estimator.cornea import TOO_FEW_GLINTS
from estimator.gaze import (MISSES_SCREEN, REASONS, fit_cornea_centers, geometric_gaze, polynomial_gaze,
                           screen_intersection)
from estimator.metrics import angular_error_deg, gaze_accuracy
from estimator.scene import load_scene
from tests.estimator.simulated import screen_targets, simulate_glints

#: Degrees: with exact glints and ground-truth geometry the orbit fit stops at steps of ~1e-10 rad.
EXACT_DEG = 1e-6
#: Degrees: LM (batched or chained) and the paper's TRF reach the same least-squares minimum.
#: LM ends on a step below 1e-7 m, which leaves <= 4e-10 m in the cornea centre; a quadratic
#: mapping turns that into ~6e-6 deg at the screen (measured). 2e-5 deg is 1e-3 of the 0.02 deg
#: error the noise causes.
SAME_MINIMUM_DEG = 2e-5


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def grid(setup):
    return screen_targets("grid:24x15", setup)


@pytest.fixture(scope="module")
def noisy(setup, grid):
    return simulate_glints(setup, grid, noise_px=0.5, rng=np.random.default_rng(2))


@pytest.fixture(scope="module")
def truth(setup):
    return Calibration.ground_truth(setup)


def test_geometric_gaze_is_exact_without_noise(setup, grid, truth):
    obs = simulate_glints(setup, grid)
    est = geometric_gaze(setup, truth, obs.glints_px, obs.visible)
    assert est.ok.all() and est.method == "geometric"
    assert angular_error_deg(est.point_m, grid, setup.eye.rotation_center_m).max() < EXACT_DEG
    assert np.allclose(est.angles_rad, np.column_stack([obs.yaw_rad, obs.pitch_rad]), atol=1e-8)
    assert np.allclose(est.point_m[:, 2], setup.screen.z_m)


def test_geometric_gaze_accuracy_at_half_a_pixel(setup, grid, noisy, truth):
    est = geometric_gaze(setup, truth, noisy.glints_px, noisy.visible)
    acc = gaze_accuracy(est.point_m, grid, setup.eye.rotation_center_m)
    # The paper: 0.022 deg (SD 0.012) with ground-truth c_e, r_co and lights at e_f = 0.5 px.
    # Measured here: 0.020 deg (SD 0.011) on this seed; 0.015-0.030 bounds the seed-to-seed spread.
    assert 0.015 < acc.mean_deg < 0.030
    assert 0.005 < acc.sd_deg < 0.020
    assert acc.robustness == 1.0 and acc.n == 360 and acc.n_nan == 0


def test_chained_and_batched_lm_and_papers_trf_agree(setup, grid, noisy, truth):
    sl = slice(0, 360, 24)  # 15 samples: the TRF reference is slow
    g, v = noisy.glints_px[sl], noisy.visible[sl]
    batch = geometric_gaze(setup, truth, g, v)
    chained = geometric_gaze(setup, truth, g, v, chain=True)
    trf = geometric_gaze(setup, truth, g, v, chain=True, solver="trf")
    for other in (chained, trf):
        err = angular_error_deg(other.point_m, batch.point_m, setup.eye.rotation_center_m)
        assert err.max() < SAME_MINIMUM_DEG


def test_a_stream_resumes_from_the_previous_batch(setup, grid, noisy, truth):
    whole = geometric_gaze(setup, truth, noisy.glints_px[:40], noisy.visible[:40])
    first = geometric_gaze(setup, truth, noisy.glints_px[:20], noisy.visible[:20])
    assert np.array_equal(first.resume_from, first.angles_rad[19])
    second = geometric_gaze(setup, truth, noisy.glints_px[20:40], noisy.visible[20:40],
                            start=first.resume_from)
    both = np.vstack([first.point_m, second.point_m])
    assert angular_error_deg(both, whole.point_m, setup.eye.rotation_center_m).max() < SAME_MINIMUM_DEG


def test_failed_samples_are_nan_with_a_reason(setup, grid, noisy, truth):
    glints = noisy.glints_px[:6].copy()
    glints[1] = np.nan  # no glints at all
    glints[4, 1:] = np.nan  # one glint: enough for the 2-unknown orbit fit, not for the 3-unknown centre
    geo = geometric_gaze(setup, truth, glints, chain=True)
    assert list(geo.reason) == ["ok", TOO_FEW_GLINTS, "ok", "ok", "ok", "ok"]
    assert np.isnan(geo.point_m[1]).all() and np.isfinite(geo.point_m[[0, 2, 3, 4, 5]]).all()
    C = simulate_glints(setup, screen_targets("calib:5x5", setup)).cornea_center_m
    cal = truth.with_mappings(eq1_25=fit_gaze_mapping(C, screen_targets("calib:5x5", setup), "eq1"))
    poly = polynomial_gaze(setup, cal, glints)
    assert list(poly.reason) == ["ok", TOO_FEW_GLINTS, "ok", "ok", TOO_FEW_GLINTS, "ok"]
    assert np.isnan(poly.screen_xy_m[[1, 4]]).all() and set(poly.reason) <= set(REASONS)
    assert poly.resume_from.shape == (3,)
    none = geometric_gaze(setup, truth, np.full((2, setup.lights.count, 2), np.nan))
    assert none.resume_from is None and not none.ok.any()


def test_axes_that_point_away_from_the_screen_miss_it():
    directions = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    points, hits = screen_intersection(np.zeros(3), directions, -0.7)
    assert hits.tolist() == [True, False, False]
    assert np.allclose(points[0], [0, 0, -0.7]) and np.isnan(points[1:]).all()
    assert MISSES_SCREEN in REASONS


def test_polynomial_gaze_with_ground_truth_lighting(setup, grid, noisy, truth):
    T = screen_targets("calib:5x5", setup)
    calib = simulate_glints(setup, T, noise_px=0.5, rng=np.random.default_rng(4))
    centres = fit_cornea_centers(setup, truth, calib.glints_px, calib.visible).center_m
    cal = truth.with_mappings(eq1_25=fit_gaze_mapping(centres, T, "eq1"),
                              quadratic_25=fit_gaze_mapping(centres, T, "quadratic"))
    for name in ("eq1_25", "quadratic_25"):
        est = polynomial_gaze(setup, cal, noisy.glints_px, noisy.visible, mapping=name)
        assert est.method == "polynomial" and est.ok.all() and np.isnan(est.angles_rad).all()
        acc = gaze_accuracy(est.point_m, grid, setup.eye.rotation_center_m)
        # Measured 0.06 deg (eq1) and 0.03 deg (quadratic); the paper reports 0.31 and 0.30.
        assert acc.mean_deg < 0.15, name
    trf = polynomial_gaze(setup, cal, noisy.glints_px[:10], noisy.visible[:10], solver="trf", chain=True)
    lm = polynomial_gaze(setup, cal, noisy.glints_px[:10], noisy.visible[:10])
    assert angular_error_deg(trf.point_m, lm.point_m, setup.eye.rotation_center_m).max() < SAME_MINIMUM_DEG


def test_gaze_rejects_incomplete_calibrations(setup, noisy, truth):
    with pytest.raises(ValueError, match="eye centre and orbit radius"):
        geometric_gaze(setup, Calibration(), noisy.glints_px[:2])
    with pytest.raises(ValueError, match="no gaze mapping 'eq1_25'"):
        polynomial_gaze(setup, truth, noisy.glints_px[:2])
    T = screen_targets("calib:5x5", setup)
    C = simulate_glints(setup, T).cornea_center_m
    da = fit_gaze_mapping(np.column_stack([C, np.linspace(-1, 0, 25)]), T, "quadratic_da", degenerate="min_norm")
    with pytest.raises(ValueError, match="distance readings"):
        polynomial_gaze(setup, truth, noisy.glints_px[:2], mapping=da)
    with pytest.raises(ValueError, match="distance must have shape"):
        polynomial_gaze(setup, truth, noisy.glints_px[:2], mapping=da, distance=np.zeros(3))
    assert polynomial_gaze(setup, truth, noisy.glints_px[:2], mapping=da, distance=np.zeros(2)).ok.all()


def test_end_to_end_with_the_joint_calibration(setup, grid, noisy):
    """Calibrate on the 6x6 grid (rig 1 mm and 1 deg off its model), track with the arc."""
    from estimator.calibration import calibrate_joint, pose_correction

    grid_scene = load_scene("lighting_grid")
    L = grid_scene.lights_world_m
    rig = pose_correction(np.radians(1.0) * np.array([1.0, 1.0, 0.0]) / np.sqrt(2), [1e-3, 0, 0], L.mean(axis=0))
    T = screen_targets("calib:5x5", grid_scene)
    frames = simulate_glints(grid_scene, T, noise_px=0.5, rng=np.random.default_rng(9), lights_world_m=rig.apply(L))
    light, orbit = calibrate_joint(grid_scene.camera, L, frames.glints_px, T, frames.visible,
                                   center0_m=grid_scene.eye.cornea_center(0, 0))
    cal = Calibration.from_fits(light, orbit)
    track = simulate_glints(setup, grid, noise_px=0.5, rng=np.random.default_rng(10),
                            lights_world_m=rig.apply(setup.lights_world_m))
    acc = gaze_accuracy(geometric_gaze(setup, cal, track.glints_px, track.visible).point_m, grid,
                        setup.eye.rotation_center_m)
    # Measured 0.05 deg over 50 trials (the paper's own calibration gave 4.62 deg); 0.2 deg
    # bounds the trial-to-trial spread.
    assert acc.mean_deg < 0.2 and acc.n_nan == 0


# --------------------------------------------------------------------------- priors


def one_glint(obs, seed=4):
    """Each sample's glints cut down to one visible glint (the middle one)."""
    g = np.full(obs.glints_px.shape, np.nan)
    for b in range(g.shape[0]):
        vis = np.flatnonzero(obs.visible[b])
        g[b, vis[vis.size // 2]] = obs.glints_px[b, vis[vis.size // 2]]
    return g


def test_a_prior_makes_one_glint_enough(setup, grid, noisy, truth):
    """A prior 0.3° off the truth with 0.6° SD: one glint (0.5 px) per sample on the orbit."""
    g = one_glint(noisy)
    yaw, pitch = setup.eye.angles_toward(grid)
    mean = np.column_stack([yaw, pitch]) + np.radians(0.3)
    cov = np.eye(2) * np.radians(0.6) ** 2
    est = geometric_gaze(setup, truth, g, prior_mean_rad=mean, prior_cov_rad2=cov, noise_px=0.5)
    assert est.ok.all()
    err = angular_error_deg(est.point_m, grid, setup.eye.rotation_center_m)
    # One glint at 0.5 px pins the rotation to ~0.15°, far tighter than the prior's 0.6°.
    assert np.median(err) < 0.25
    assert not geometric_gaze(setup, truth, g[:, :, :] * np.nan, prior_mean_rad=mean,
                              prior_cov_rad2=np.full((2, 2), np.nan), noise_px=0.5).ok.any()


def test_polynomial_gaze_with_a_prior_maps_the_orbit_centre(setup, grid, noisy, truth):
    c = fit_cornea_centers(setup, truth, noisy.glints_px).center_m
    cal = truth.with_mappings(q=fit_gaze_mapping(c, grid, "quadratic"))
    g = one_glint(noisy)
    yaw, pitch = setup.eye.angles_toward(grid)
    mean = np.column_stack([yaw, pitch])
    cov = np.eye(2) * np.radians(0.6) ** 2
    with_prior = polynomial_gaze(setup, cal, g, mapping="q", prior_mean_rad=mean,
                                 prior_cov_rad2=cov, noise_px=0.5)
    assert with_prior.ok.all() and np.isfinite(with_prior.angles_rad).all()
    geo = geometric_gaze(setup, cal, g, prior_mean_rad=mean, prior_cov_rad2=cov, noise_px=0.5)
    assert np.allclose(with_prior.cornea_center_m, geo.cornea_center_m, atol=1e-9)
    # Without a prior one glint cannot fix the free centre (3 unknowns).
    assert (polynomial_gaze(setup, cal, g, mapping="q").reason == TOO_FEW_GLINTS).all()


@pytest.mark.parametrize("kwargs, message", [
    (dict(prior_mean_rad=(0.0, 0.0)), "together"),
    (dict(prior_mean_rad=(0.0, 0.0), prior_cov_rad2=np.eye(2), noise_px=0.0), "positive"),
    (dict(prior_mean_rad=np.zeros(3), prior_cov_rad2=np.eye(2), noise_px=0.5), "shape"),
])
def test_bad_priors(setup, noisy, truth, kwargs, message):
    with pytest.raises(ValueError, match=message):
        geometric_gaze(setup, truth, noisy.glints_px[:2], **kwargs)
