"""One band's small fit on Python floats (:mod:`estimator.cornea.scalar`, what
:func:`estimator.cornea.fit_small` runs without Numba): the compiled fit's arithmetic to the
last bit, its minimum with the batched fit's early stop, and a fit that cannot be evaluated
is a failed fit, not an exception."""

import math

import numpy as np
import pytest

from estimator.cornea import fit_cornea, fit_small
from estimator.cornea.scalar import camera_floats, lm_floats
from estimator.cornea.small import XTOL_M, lm_kernel
from estimator.gaze import calibrated_problems
from estimator.geometry import camera_arrays, compiled, project_glints
from tests.estimator.test_tracker import calibration, setup  # noqa: F401 fixtures
from tests.tolerances import TOL

#: fit_small's Gauss-Newton stop without Numba (m of cornea-centre motion):
#: estimator.cornea.solve._GN_STOP, the batched fit's.
GN_STOP_M = 1e-7


def bands(setup, problem, model, n, seed):
    """n bands of 3-14 noisy glints (0.4 px) of random rotations, each with its start 0.01
    rad off and, for every third orbit band, a prior (a sparse band's, as the tracker's)."""
    rng = np.random.default_rng(seed)
    eye = setup.eye
    for t in range(n):
        a = rng.uniform(-0.3, 0.3, 2)
        g, vis = project_glints(setup.camera, eye.cornea_center(*a), eye.cornea_radius_m,
                                problem.lights_world_m)
        sel = np.flatnonzero(vis)[: rng.integers(3, 15)]
        glints = g[sel] + rng.normal(0.0, 0.4, (sel.size, 2))
        x0 = a + 0.01 if model == "orbit" else eye.cornea_center(*(a + 0.01))
        p = x0.size
        pm, P = np.zeros(p), np.zeros((p, p))
        if model == "orbit" and t % 3 == 0:
            pm = a + rng.normal(0, 0.004, 2)
            P = 0.5 ** 2 * np.linalg.inv(np.diag([0.005, 0.008]) ** 2)
        yield problem.lights_world_m[sel], glints, x0, pm, P


def model_args(problem, model):
    """(model code, c_e, r_co, xtol) as fit_small passes them."""
    if model == "orbit":
        rco = float(problem.orbit_radius_m)
        return 1, np.asarray(problem.eye_center_m, dtype=np.float64), rco, XTOL_M / rco
    return 0, np.zeros(3), 0.0, XTOL_M


@pytest.mark.skipif(not compiled.ENABLED, reason="needs Numba (the compiled fit to compare)")
@pytest.mark.parametrize("model", ["orbit", "center"])
def test_the_float_fit_is_the_compiled_fit_to_the_last_bit(setup, calibration, model):  # noqa: F811
    """Without the early stop the float fit runs the compiled fit's operations in the same
    order: the same parameters, JᵀJ, cost, iterations and outcome, bit for bit."""
    problems = calibrated_problems(setup, calibration)
    problem = problems.orbit if model == "orbit" else problems.center
    arrays = camera_arrays(setup.camera)
    cam = camera_floats(*arrays)
    code, ce, rco, xtol = model_args(problem, model)
    for L, glints, x0, pm, P in bands(setup, problem, model, 40, seed=5):
        L, glints = np.ascontiguousarray(L), np.ascontiguousarray(glints)
        x, JtJ = np.empty(x0.size), np.zeros((x0.size, x0.size))
        cost, iters, conv = lm_kernel(*arrays, code, x0, ce, rco, problem.cornea_radius_m, L,
                                      glints, 50, xtol, pm, P, x, JtJ)
        fx, fJ, fcost, fiters, fconv = lm_floats(cam, code, x0, ce, rco,
                                                 problem.cornea_radius_m, L, glints, 50, xtol,
                                                 0.0, pm, P)
        assert np.array(fx).tobytes() == x.tobytes()
        assert np.array(fJ).tobytes() == JtJ.tobytes()
        assert np.float64(fcost).tobytes() == np.float64(cost).tobytes()
        assert (fiters, fconv) == (iters, conv)


@pytest.mark.parametrize("model", ["orbit", "center"])
def test_the_float_fit_with_the_early_stop_reaches_the_batched_minimum(
        setup, calibration, model):  # noqa: F811
    """With the batched fit's stop (a Gauss-Newton step below 1e-7 m is the last) the float
    fit ends within that stop's error of fit_cornea's minimum (with and without a prior), and
    of the compiled fit's where Numba is installed."""
    from dataclasses import replace
    problems = calibrated_problems(setup, calibration)
    problem = problems.orbit if model == "orbit" else problems.center
    arrays = camera_arrays(setup.camera)
    cam = camera_floats(*arrays)
    code, ce, rco, xtol = model_args(problem, model)
    scale = setup.eye.cornea_offset_m if model == "orbit" else 1.0  # m per unit of x
    gn_stop = GN_STOP_M / rco if model == "orbit" else GN_STOP_M
    for L, glints, x0, pm, P in bands(setup, problem, model, 30, seed=9):
        x, JtJ, cost, iters, conv = lm_floats(cam, code, x0, ce, rco, problem.cornea_radius_m,
                                              L, glints, 50, xtol, gn_stop, pm, P)
        prior = dict(prior_mean=pm, prior_information=P) if P.any() else {}
        ref = fit_cornea(replace(problem, lights_world_m=L), glints[None], None, x0,
                         model=model, **prior)
        x_ref = (ref.angles_rad if model == "orbit" else ref.center_m)[0]
        assert conv and ref.ok[0]
        assert np.abs(np.array(x) - x_ref).max() * scale < TOL.refit_center_m
        # Both report the cost of their last Gauss-Newton step to second order: 1e-5 px of
        # RMS against the 2 px the tracker refuses above (MAX_RESIDUAL_PX).
        assert abs(math.sqrt(cost / len(glints)) - ref.rms_px[0]) < 1e-5
        if compiled.ENABLED:
            ours = fit_small(problem, glints, L, x0, model=model, arrays=arrays, **prior)
            assert np.abs(np.array(x) - ours.x).max() * scale < TOL.refit_center_m
            # JᵀJ one step (<= 1e-7 m) apart: the covariance it sizes moves by ~1e-5.
            assert np.allclose(JtJ, ours.JtJ, rtol=1e-4, atol=0)


def test_a_fit_that_cannot_be_evaluated_fails_without_raising(setup, calibration):  # noqa: F811
    """A problem Python cannot evaluate (a zero corneal radius divides by zero; Numba's
    arithmetic carries infinities there) is a fit that did not converge, not an exception;
    through fit_small's float form too."""
    center = calibrated_problems(setup, calibration).center
    cam = camera_floats(*camera_arrays(setup.camera))
    L = center.lights_world_m[:6]
    x, JtJ, cost, iters, conv = lm_floats(cam, 0, setup.eye.cornea_center(0.0, 0.0),
                                          np.zeros(3), 0.0, 0.0, L, np.full((6, 2), 100.0),
                                          50, XTOL_M, GN_STOP_M, np.zeros(3), np.zeros((3, 3)))
    assert not conv and not math.isfinite(cost) and iters == 0


def test_the_float_projection_is_the_kernels(setup):  # noqa: F811
    """Every light's glint, visibility (the cap and the image included) and d glint / d centre
    for one pose on floats: numpy's projection and Jacobian to ~1e-12 px (as the compiled
    kernel, tests/estimator/test_cheap_path.py), and the compiled kernel to the last bit where
    Numba is installed."""
    from estimator.eye import gaze_direction
    from estimator.geometry import glint_jacobians
    from estimator.cornea.scalar import glints_floats, lights_in_camera
    rng = np.random.default_rng(11)
    eye, lights = setup.eye, setup.lights.positions_world_m
    arrays = camera_arrays(setup.camera)
    cam = camera_floats(*arrays)
    rq = lights_in_camera(cam, lights)
    hidden = 0
    for _ in range(30):
        a = rng.uniform(-0.45, 0.45, 2)
        center, axis = eye.cornea_center(*a), gaze_direction(*a)
        g, vis, jac = glints_floats(cam, [float(v) for v in center], eye.cornea_radius_m, rq,
                                    [float(v) for v in axis], float(eye.cap_cos_min), True)
        g, vis, jac = np.array(g), np.array(vis), np.array(jac)
        ref_g, ref_vis, d_c, _, _ = glint_jacobians(setup.camera, center, eye.cornea_radius_m,
                                                    lights, cornea_axis=axis,
                                                    cap_cos_min=eye.cap_cos_min,
                                                    radius_and_lights=False)
        assert np.array_equal(vis, ref_vis)
        hidden += (~vis).sum()
        assert np.abs(g[vis] - ref_g[vis]).max() < 1e-9
        assert np.allclose(jac[vis], d_c[vis], rtol=1e-9, atol=1e-6)  # px per m
        if compiled.ENABLED:
            out, v2 = np.empty((len(lights), 2)), np.empty(len(lights), dtype=np.bool_)
            j2 = np.empty((len(lights), 2, 3))
            compiled.glints_kernel(*arrays, center, eye.cornea_radius_m,
                                   np.ascontiguousarray(lights), axis, eye.cap_cos_min, True,
                                   out, v2, True, j2)
            assert g.tobytes() == out.tobytes() and np.array_equal(vis, v2)
            assert jac.tobytes() == j2.tobytes()
    assert hidden > 0  # the cap and the image edge were exercised
