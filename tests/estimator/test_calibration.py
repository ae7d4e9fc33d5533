"""Calibration round trips: simulate with known geometry, calibrate, compare (Sec. 2.4, 3.1-3.3)."""

import dataclasses
import json

import numpy as np
import pytest

from estimator.calibration import CORNEA_RADIUS_BOUNDS_M, CORNEA_RADIUS_INIT_M, Calibration, GazeMapping, calibrate_joint, calibrate_lighting_joint, calibrate_lighting_per_frame, corrected_lights, distance_reading, fit_gaze_mapping, orbit_law_of_sines, orbit_sphere_fit, pose_correction
from estimator.cornea import FitProblem, fit_cornea
from estimator.geometry import RigidPose
from estimator.metrics import gaze_accuracy, light_position_error_m
from estimator.scene import load_scene
from tests.estimator.simulated import screen_targets, simulate_glints

# Tolerances (units in the names), each with its reason.
#: Exact cornea centres: the law-of-sines iteration stops at c_e steps below 1e-13 m and the
#: sphere fit's LM at xtol 1e-15; 1e-9 m leaves three orders of magnitude for rounding.
EXACT_ORBIT_M = 1e-9
#: Noise-free glints: centres come from fits that stop at steps of ~1e-10 m; the brief's bound.
NOISE_FREE_ORBIT_M = 1e-6
#: Noise-free glints through a 7 + 3m-unknown TRF (xtol 1e-12 relative): lights to 1e-9 m.
NOISE_FREE_LIGHTS_M = 1e-9
#: e_f = 0.5 px, 25 frames x 36 glints: the joint fit measured 0.06 mm mean light error and
#: 0.02 mm r_c error on this seed (the paper's per-frame method: ~0.6 mm); 0.2 mm and 0.1 mm
#: leave room for other seeds while still failing a per-frame-quality fit.
NOISY_LIGHTS_M = 0.2e-3
NOISY_RADIUS_M = 0.1e-3


@pytest.fixture(scope="module")
def grid():
    return load_scene("lighting_grid")


@pytest.fixture(scope="module")
def arc():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def true_correction(grid):
    """The rig as built: 1 mm along x and 1 degree about (1, 1, 0) off its 3D model."""
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    return pose_correction(np.radians(1.0) * axis, [1e-3, 0.0, 0.0], grid.lights_world_m.mean(axis=0))


@pytest.fixture(scope="module")
def targets25(grid):
    return screen_targets("calib:5x5", grid)


@pytest.fixture(scope="module")
def grid_frames(grid, targets25, true_correction):
    return simulate_glints(grid, targets25, lights_world_m=true_correction.apply(grid.lights_world_m))


@pytest.fixture(scope="module")
def noisy_grid_frames(grid, targets25, true_correction):
    return simulate_glints(grid, targets25, noise_px=0.5, rng=np.random.default_rng(7),
                           lights_world_m=true_correction.apply(grid.lights_world_m))


def exact_centres(eye_center, orbit_radius, targets):
    v = targets - eye_center
    return eye_center + orbit_radius * v / np.linalg.norm(v, axis=1, keepdims=True)


# ---------------------------------------------------------------------------------------------
# Eye centre and orbit radius


@pytest.mark.parametrize("eye_center", [(0.0, 0.0, 0.0), (0.6e-3, -0.4e-3, 0.3e-3), (1e3, -2e3, 5e2)])
def test_law_of_sines_and_sphere_fit_are_exact_on_exact_centres(targets25, eye_center):
    # The last case shifts everything by ~1 km (scikit-image's conditioning test): the fits
    # must centre their data, not lose the millimetres in the offset.
    ce = np.asarray(eye_center)
    C = exact_centres(ce, 4.0e-3, targets25 + ce)
    scale = max(1.0, np.abs(ce).max())  # float64 keeps ~1e-16 relative of the offset
    for fit in (orbit_law_of_sines(C, targets25 + ce), orbit_sphere_fit(C)):
        assert np.abs(fit.eye_center_m - ce).max() < EXACT_ORBIT_M * scale, fit.method
        assert abs(fit.orbit_radius_m - 4.0e-3) < EXACT_ORBIT_M * scale, fit.method


def test_orbit_from_noise_free_glints(grid, grid_frames, targets25, true_correction):
    problem = FitProblem(grid.camera, true_correction.apply(grid.lights_world_m), grid.eye.cornea_radius_m)
    C = fit_cornea(problem, grid_frames.glints_px, grid_frames.visible, grid.eye.cornea_center(0, 0)).center_m
    for fit in (orbit_law_of_sines(C, targets25), orbit_sphere_fit(C)):
        assert np.linalg.norm(fit.eye_center_m - grid.eye.rotation_center_m) < NOISE_FREE_ORBIT_M
        assert abs(fit.orbit_radius_m - grid.eye.cornea_offset_m) < NOISE_FREE_ORBIT_M


def test_law_of_sines_iterates_from_a_poor_start(targets25):
    ce = np.array([2e-3, 1e-3, -1e-3])
    C = exact_centres(ce, 5.0e-3, targets25)
    fit = orbit_law_of_sines(C, targets25, eye_center0_m=np.zeros(3))
    assert fit.iterations > 1
    assert np.abs(fit.eye_center_m - ce).max() < EXACT_ORBIT_M


def test_orbit_fits_skip_failed_frames_and_reject_degenerate_ones(targets25):
    C = exact_centres(np.zeros(3), 4e-3, targets25)
    C[3] = np.nan
    assert orbit_sphere_fit(C).orbit_radius_m == pytest.approx(4e-3, abs=EXACT_ORBIT_M)
    assert orbit_law_of_sines(C, targets25).orbit_radius_m == pytest.approx(4e-3, abs=EXACT_ORBIT_M)
    with pytest.raises(ValueError, match="at least 4"):
        orbit_sphere_fit(C[:4])  # three finite centres
    flat = C[np.isfinite(C).all(axis=1)].copy()
    flat[:, 2] = 0.0
    with pytest.raises(ValueError, match="coplanar"):
        orbit_sphere_fit(flat)
    same = np.repeat(targets25[:1], 5, axis=0)
    with pytest.raises(ValueError, match="coincide"):
        orbit_law_of_sines(exact_centres(np.zeros(3), 4e-3, same), same)


# ---------------------------------------------------------------------------------------------
# Lighting pose and corneal radius


def test_read_2006_prior_holds_the_simulated_eye():
    lo, hi = CORNEA_RADIUS_BOUNDS_M
    assert lo < 7.8e-3 < hi and lo < CORNEA_RADIUS_INIT_M < hi


def test_pose_correction_matches_the_fit_parametrisation(grid):
    L = grid.lights_world_m
    rotvec, t = np.array([0.01, -0.02, 0.005]), np.array([1e-3, -2e-3, 0.5e-3])
    problem = FitProblem(grid.camera, L, 7.8e-3)
    assert np.allclose(pose_correction(rotvec, t, L.mean(axis=0)).apply(L), problem.lights_posed(rotvec, t)[0],
                       atol=1e-15)


def test_joint_lighting_recovers_a_perturbed_rig(grid, grid_frames, true_correction):
    fit = calibrate_lighting_joint(grid.camera, grid.lights_world_m, grid_frames.glints_px, grid_frames.visible,
                                   center0_m=grid.eye.cornea_center(0, 0))
    L_true = true_correction.apply(grid.lights_world_m)
    assert light_position_error_m(fit.correction.apply(grid.lights_world_m), L_true) < NOISE_FREE_LIGHTS_M
    assert abs(fit.cornea_radius_m - grid.eye.cornea_radius_m) < NOISE_FREE_LIGHTS_M
    assert np.abs(fit.cornea_centers_m - grid_frames.cornea_center_m).max() < NOISE_FREE_LIGHTS_M


def test_the_grids_correction_calibrates_the_arc(grid, arc, grid_frames, true_correction):
    fit = calibrate_lighting_joint(grid.camera, grid.lights_world_m, grid_frames.glints_px, grid_frames.visible,
                                   center0_m=grid.eye.cornea_center(0, 0))
    arc_true = true_correction.apply(arc.lights_world_m)
    arc_estimated = corrected_lights(fit.correction, arc.lights_world_m)
    assert light_position_error_m(arc_estimated, arc_true) < NOISE_FREE_LIGHTS_M
    cal = Calibration.from_fits(fit)
    assert not cal.has_orbit and cal.methods == {"lighting": "joint"}
    assert np.allclose(cal.lights_world_m(arc.lights_world_m), arc_true, atol=NOISE_FREE_LIGHTS_M)


def test_papers_per_frame_fit_is_exact_without_noise(grid, grid_frames, true_correction):
    frames = slice(0, 25, 6)  # 5 frames: TRF per frame is the slow reference
    fit = calibrate_lighting_per_frame(grid.camera, grid.lights_world_m, grid_frames.glints_px[frames],
                                       grid_frames.visible[frames], center0_m=grid.eye.cornea_center(0, 0))
    assert fit.method == "per_frame_trf" and fit.frame_radius_m.shape == (5,)
    L_true = true_correction.apply(grid.lights_world_m)
    assert light_position_error_m(fit.correction.apply(grid.lights_world_m), L_true) < NOISE_FREE_ORBIT_M
    assert abs(fit.cornea_radius_m - grid.eye.cornea_radius_m) < NOISE_FREE_ORBIT_M


def test_joint_lighting_with_noise(grid, noisy_grid_frames, true_correction):
    fit = calibrate_lighting_joint(grid.camera, grid.lights_world_m, noisy_grid_frames.glints_px,
                                   noisy_grid_frames.visible, center0_m=grid.eye.cornea_center(0, 0))
    L_true = true_correction.apply(grid.lights_world_m)
    assert light_position_error_m(fit.correction.apply(grid.lights_world_m), L_true) < NOISY_LIGHTS_M
    assert abs(fit.cornea_radius_m - grid.eye.cornea_radius_m) < NOISY_RADIUS_M
    assert 0.3 < fit.rms_px < 0.5  # uniform e_f = 0.5 px on two axes: sqrt(2 * 0.5**2 / 3) = 0.41 px


@pytest.mark.parametrize("angles", ["targets", "free"])
def test_joint_calibration_recovers_everything(grid, grid_frames, targets25, true_correction, angles):
    light, orbit = calibrate_joint(grid.camera, grid.lights_world_m, grid_frames.glints_px, targets25,
                                   grid_frames.visible, center0_m=grid.eye.cornea_center(0, 0), angles=angles)
    L_true = true_correction.apply(grid.lights_world_m)
    assert light_position_error_m(light.correction.apply(grid.lights_world_m), L_true) < NOISE_FREE_ORBIT_M
    assert abs(light.cornea_radius_m - grid.eye.cornea_radius_m) < NOISE_FREE_ORBIT_M
    assert np.linalg.norm(orbit.eye_center_m - grid.eye.rotation_center_m) < NOISE_FREE_ORBIT_M
    assert abs(orbit.orbit_radius_m - grid.eye.cornea_offset_m) < NOISE_FREE_ORBIT_M


def test_joint_calibration_with_noise_beats_fitting_centres_first(grid, noisy_grid_frames, targets25):
    light, orbit = calibrate_joint(grid.camera, grid.lights_world_m, noisy_grid_frames.glints_px, targets25,
                                   noisy_grid_frames.visible, center0_m=grid.eye.cornea_center(0, 0))
    # Measured on this seed: 0.13 mm c_e error, 0.02 mm r_co error (the per-frame paper method
    # is off by millimetres, see the report); 0.5 mm / 0.2 mm bound other seeds.
    assert np.linalg.norm(orbit.eye_center_m - grid.eye.rotation_center_m) < 0.5e-3
    assert abs(orbit.orbit_radius_m - grid.eye.cornea_offset_m) < 0.2e-3


def test_lighting_fits_reject_bad_input(grid, grid_frames, targets25):
    c0 = grid.eye.cornea_center(0, 0)
    with pytest.raises(ValueError, match="glints_px must have shape"):
        calibrate_lighting_joint(grid.camera, grid.lights_world_m, grid_frames.glints_px[:, :5], center0_m=c0)
    with pytest.raises(ValueError, match="cannot determine"):
        calibrate_lighting_joint(grid.camera, grid.lights_world_m, np.full((3, 36, 2), np.nan), center0_m=c0)
    with pytest.raises(ValueError, match="targets_m"):
        calibrate_joint(grid.camera, grid.lights_world_m, grid_frames.glints_px, targets25[:3], center0_m=c0)
    with pytest.raises(ValueError, match="angles"):
        calibrate_joint(grid.camera, grid.lights_world_m, grid_frames.glints_px, targets25, center0_m=c0,
                        angles="sometimes")


# ---------------------------------------------------------------------------------------------
# Gaze mappings


@pytest.fixture(scope="module")
def arc_fits(arc):
    """Cornea centres fitted to noise-free arc glints: calibration patterns and the 24x15 grid."""
    problem = FitProblem(arc.camera, arc.lights_world_m, arc.eye.cornea_radius_m)
    out = {}
    for spec in ("calib:3x3", "calib:5x5", "grid:24x15"):
        T = screen_targets(spec, arc)
        obs = simulate_glints(arc, T)
        out[spec] = (fit_cornea(problem, obs.glints_px, obs.visible, arc.eye.cornea_center(0, 0)).center_m, T)
    return out


def test_eq1_from_25_points_is_well_under_a_degree(arc, arc_fits):
    C, T = arc_fits["calib:5x5"]
    m = fit_gaze_mapping(C, T, "eq1")
    assert m.rank == 8 and m.n_points == 25
    # Training targets: the 8-term polynomial misses a 25-point pattern by ~0.1 mm on the screen
    # (measured 0.08 mm rms, 0.007 deg); 0.5 mm is 0.04 deg at 0.7 m.
    assert np.abs(m.predict(C) - T[:, :2]).max() < 0.5e-3
    G_C, G = arc_fits["grid:24x15"]
    acc = gaze_accuracy(m.predict(G_C), G, arc.eye.rotation_center_m)
    assert acc.mean_deg < 0.05  # measured 0.006 deg; the paper's e_f = 0.5 px figure is 0.31


def test_full_quadratic_is_redundant_on_the_orbit_sphere(arc, arc_fits):
    # On a spherical orbit x²+y²+z² is a combination of the other nine terms, so noise-free
    # centres cannot determine all ten coefficients: the default refuses, min_norm fits.
    C, T = arc_fits["calib:5x5"]
    with pytest.raises(ValueError, match="determine only 9 of its 10 terms"):
        fit_gaze_mapping(C, T, "quadratic")
    m = fit_gaze_mapping(C, T, "quadratic", degenerate="min_norm")
    assert m.rank == 9
    assert np.abs(m.predict(C) - T[:, :2]).max() < 0.5e-3
    G_C, G = arc_fits["grid:24x15"]
    assert gaze_accuracy(m.predict(G_C), G, arc.eye.rotation_center_m).mean_deg < 0.05  # measured 0.007


def test_eq1_from_a_symmetric_3x3_grid_is_degenerate(arc, arc_fits):
    # Mirror pairs of targets about the eye's vertical plane fix only three of the four
    # coefficients of x, xy, xz, xyz.
    C, T = arc_fits["calib:3x3"]
    with pytest.raises(ValueError, match="rank-deficient"):
        fit_gaze_mapping(C, T, "eq1")
    m = fit_gaze_mapping(C, T, "eq1", degenerate="min_norm")
    assert m.rank == 7
    G_C, G = arc_fits["grid:24x15"]
    # Measured 0.54 deg (SD 0.48); the paper reports 0.70 deg (SD 0.54) at e_f = 0.5 px.
    assert gaze_accuracy(m.predict(G_C), G, arc.eye.rotation_center_m).mean_deg < 1.0


def test_eq1_from_an_asymmetric_3x3_grid_is_determined(arc):
    T = screen_targets("calib:3x3", arc) + [0.03, 0.0, 0.0]
    obs = simulate_glints(arc, T)
    m = fit_gaze_mapping(obs.cornea_center_m, T, "eq1")
    assert m.rank == 8


def test_degenerate_calibrations_raise(arc_fits):
    C, T = arc_fits["calib:5x5"]
    with pytest.raises(ValueError, match="at least 8 calibration points"):
        fit_gaze_mapping(C[:7], T[:7], "eq1")
    dup = np.repeat(np.arange(5), 5)  # 25 frames of only 5 targets
    with pytest.raises(ValueError, match=r"\(5 distinct\)"):
        fit_gaze_mapping(C[dup], T[dup], "eq1")
    bad = C.copy()
    bad[4] = np.nan
    with pytest.raises(ValueError, match=r"\[4\] are not finite"):
        fit_gaze_mapping(bad, T, "eq1")
    with pytest.raises(ValueError, match="shape"):
        fit_gaze_mapping(C, T, "quadratic_da")
    with pytest.raises(ValueError, match="kind"):
        fit_gaze_mapping(C, T, "cubic")


def test_predict_handles_nan_and_checks_shape(arc_fits):
    C, T = arc_fits["calib:5x5"]
    m = fit_gaze_mapping(C, T, "eq1")
    out = m.predict(np.vstack([C[:2], np.full((1, 3), np.nan)]))
    assert np.isfinite(out[:2]).all() and np.isnan(out[2]).all()
    with pytest.raises(ValueError, match=r"\(m, 3\)"):
        m.predict(np.zeros((2, 4)))


def test_distance_reading_matches_sec_331(arc):
    sensor = arc.distance_sensor
    d = distance_reading(np.full(200_000, -0.5e-3), sensor, np.random.default_rng(3))
    half = np.sqrt(3) * sensor.noise_sd
    assert np.all(np.abs(d + 0.5) <= half)
    # SD of 2e5 uniform draws is known to ~0.2 %; 1 % and 1e-4 of the reading are loose bounds.
    assert d.std() == pytest.approx(sensor.noise_sd, rel=1e-2)
    assert d.mean() == pytest.approx(-0.5, abs=1e-4)


def test_distance_term_compensates_rig_translation(arc):
    """Sec. 3.3.1: a 15-term mapping in (x, y, z, d_a) calibrated at 9 points x 3 depths keeps
    its accuracy when camera and lights slide along z; the 10-term one does not."""
    rng = np.random.default_rng(11)
    problem = FitProblem(arc.camera, arc.lights_world_m, arc.eye.cornea_radius_m)
    c0 = arc.eye.cornea_center(0, 0)

    def observe(targets, t):
        cam = dataclasses.replace(arc.camera, position_m=arc.camera.position_m + [0.0, 0.0, t])
        obs = simulate_glints(dataclasses.replace(arc, camera=cam), targets,
                              lights_world_m=arc.lights_world_m + [0.0, 0.0, t])
        c = fit_cornea(problem, obs.glints_px, obs.visible, c0).center_m  # in the nominal rig's frame
        return np.column_stack([c, distance_reading(np.full(len(targets), t), arc.distance_sensor, rng)])

    T9, T25 = screen_targets("calib:3x3", arc), screen_targets("calib:5x5", arc)
    F = np.concatenate([observe(T9, t) for t in (0.0, -0.5e-3, -1e-3)])
    m_da = fit_gaze_mapping(F, np.tile(T9, (3, 1)), "quadratic_da")
    assert m_da.rank == 15  # the sensor's noise lifts the sphere redundancy
    m_q = fit_gaze_mapping(observe(T25, 0.0)[:, :3], T25, "quadratic", degenerate="min_norm")
    G = screen_targets("grid:12x8", arc)
    F_G = observe(G, -0.75e-3)
    acc_da = gaze_accuracy(m_da.predict(F_G), G, arc.eye.rotation_center_m).mean_deg
    acc_q = gaze_accuracy(m_q.predict(F_G[:, :3]), G, arc.eye.rotation_center_m).mean_deg
    # Measured 0.04 deg with d_a against 3.3 deg without (Fig. 7 and 8 of the paper: degrees
    # lost within half a millimetre, recovered by the compensation).
    assert acc_da < 0.2 and acc_q > 1.0


# ---------------------------------------------------------------------------------------------
# Files


def test_mapping_json_round_trip(arc_fits):
    C, T = arc_fits["calib:5x5"]
    m = fit_gaze_mapping(C, T, "eq1")
    back = GazeMapping.from_dict(json.loads(json.dumps(m.to_dict())))
    assert back.kind == m.kind and back.rank == m.rank and back.n_points == 25
    assert np.array_equal(back.predict(C), m.predict(C))
    with pytest.raises(ValueError, match="the file says 99"):
        GazeMapping.from_dict({**m.to_dict(), "version": 99})
    with pytest.raises(ValueError, match="scet-gaze-mapping"):
        GazeMapping.from_dict({**m.to_dict(), "format": "something-else"})
    with pytest.raises(ValueError, match="key .coefficients.: expected 8 entries"):
        GazeMapping.from_dict({**m.to_dict(), "coefficients": [[0.0, 0.0]]})


def test_calibration_json_round_trip(arc, arc_fits):
    C, T = arc_fits["calib:5x5"]
    corr = RigidPose.from_rotvec([0.01, 0.0, -0.02], [1e-3, 2e-3, -3e-3])
    cal = Calibration(corr, 7.71e-3, [1e-4, -2e-4, 3e-4], 4.2e-3, {"eq1_25": fit_gaze_mapping(C, T, "eq1")},
                      {"lighting": "joint"})
    back = Calibration.from_json(cal.to_json())
    assert np.array_equal(back.lighting_correction.rotation, corr.rotation)
    assert np.array_equal(back.lighting_correction.translation_m, corr.translation_m)
    assert (back.cornea_radius_m, back.orbit_radius_m) == (7.71e-3, 4.2e-3)
    assert np.array_equal(back.eye_center_m, cal.eye_center_m) and back.methods == {"lighting": "joint"}
    assert np.array_equal(back.mappings["eq1_25"].predict(C), cal.mappings["eq1_25"].predict(C))
    # Without an orbit (polynomial gaze only) c_e and r_co are written as null, read as NaN.
    partial = Calibration.from_json(Calibration(corr, 7.7e-3).to_json())
    assert not partial.has_orbit and np.isnan(partial.eye_center_m).all()
    assert json.loads(Calibration(corr, 7.7e-3).to_json())["eye_center_m"] is None
    with pytest.raises(ValueError, match="this SCET reads"):
        Calibration.from_dict({**cal.to_dict(), "version": 2})
    with pytest.raises(ValueError, match="not JSON"):
        Calibration.from_json("{")
    with pytest.raises(ValueError, match="key .mappings.: missing required key"):
        Calibration.from_dict({k: v for k, v in cal.to_dict().items() if k != "mappings"})


def test_ground_truth_calibration(arc):
    cal = Calibration.ground_truth(arc)
    assert cal.has_orbit and cal.orbit_radius_m == arc.eye.cornea_offset_m
    assert np.array_equal(cal.lights_world_m(arc.lights_world_m), arc.lights_world_m)
    with pytest.raises(ValueError, match="GazeMapping"):
        Calibration(mappings={"x": 1})


def test_papers_per_frame_fit_lm_matches_trf_with_noise(grid, noisy_grid_frames):
    # The 10-unknown per-frame problem has a flat valley (a shifted cornea looks like a shifted
    # lighting); a solver that stops on small steps there lands hundreds of um away from TRF
    # (it did: 217 um). Both must converge on every frame and agree to 1 um in the centres
    # (measured 0.14 um on 25 frames) and 1e-5 in the pose (rad, m).
    frames = slice(0, 25)  # all 25: fewer frames missed the regression
    args = (grid.camera, grid.lights_world_m, noisy_grid_frames.glints_px[frames], noisy_grid_frames.visible[frames])
    fits = {s: calibrate_lighting_per_frame(*args, center0_m=grid.eye.cornea_center(0, 0), solver=s)
            for s in ("lm", "trf")}
    lm, trf = fits["lm"], fits["trf"]
    assert np.isfinite(lm.cornea_centers_m).all() and np.isfinite(trf.cornea_centers_m).all()
    assert np.abs(lm.cornea_centers_m - trf.cornea_centers_m).max() < 1e-6
    assert np.abs(lm.correction.rotation - trf.correction.rotation).max() < 1e-5
    assert np.abs(lm.correction.translation_m - trf.correction.translation_m).max() < 1e-5
