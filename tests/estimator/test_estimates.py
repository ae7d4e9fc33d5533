"""A searched band's estimate by the compiled small fit (:mod:`estimator.tracking.estimates`) against
the batched fits of :mod:`estimator.gaze` it stands in for: the same cornea centre and screen
point on noisy glints of random gazes, both methods; None where the batched fits would refuse
(a residual above the limit), so that they decide and name the failure."""

import numpy as np
import pytest

from estimator.gaze import calibrated_problems, geometric_gaze, polynomial_gaze
from estimator.geometry import project_glints
from estimator.matching import kernels
from estimator.tracking import MAX_RESIDUAL_PX, Tracker, searched_estimate
from tests.estimator.test_tracker import calibration, setup  # noqa: F401 fixtures

pytestmark = pytest.mark.skipif(not kernels.ENABLED, reason="Numba is not installed")


def identified(setup, rng):
    """Noisy glints (k, 2) (0.3 px) of 6-10 visible lights (k,) at a random gaze."""
    eye = setup.eye
    while True:
        a = rng.uniform(-0.3, 0.3, 2)
        g, vis = project_glints(setup.camera, eye.cornea_center(*a), eye.cornea_radius_m,
                                setup.lights_world_m)
        idx = np.flatnonzero(vis)
        if idx.size >= 6:
            lights = np.sort(rng.choice(idx, min(idx.size, int(rng.integers(6, 11))),
                                        replace=False))
            return g[lights] + rng.normal(0.0, 0.3, (lights.size, 2)), lights, a


@pytest.mark.parametrize("method", ["polynomial", "geometric"])
def test_the_small_fit_estimate_is_the_batched_one(setup, calibration, method):  # noqa: F811
    problems = calibrated_problems(setup, calibration)
    tr = Tracker(setup, calibration, method)
    rng = np.random.default_rng(12)
    n = setup.lights_world_m.shape[0]
    for _ in range(25):
        g, lights, a = identified(setup, rng)
        full = np.full((n, 2), np.nan)
        full[lights] = g
        start = setup.eye.cornea_center(*a) if method == "polynomial" else a
        if method == "polynomial":
            ref = polynomial_gaze(setup, calibration, full, start=start, problems=problems)
        else:
            ref = geometric_gaze(setup, calibration, full, start=start, problems=problems)
        got = searched_estimate(tr.context, g, lights, start, None)
        assert got is not None and ref.reason[0] == "ok"
        xy, center, rms, _ = got
        # Both stop within ~1e-9 m of one minimum (test_cheap_path): 1e-7 m of centre and
        # 1e-5 m on the screen (~1e-3 deg) leave room for the batched fit's looser stop.
        assert np.abs(center - ref.cornea_center_m[0]).max() < 1e-7
        assert np.abs(xy - ref.screen_xy_m[0, :2]).max() < 1e-5
        assert abs(rms - ref.rms_px[0]) < 1e-4


def test_a_residual_above_the_limit_is_left_to_the_batched_fits(setup, calibration):  # noqa: F811
    tr = Tracker(setup, calibration, "polynomial")
    rng = np.random.default_rng(13)
    g, lights, a = identified(setup, rng)
    g = g + rng.normal(0.0, 4.0 * MAX_RESIDUAL_PX, g.shape)  # wrong glints: px of residual
    got = searched_estimate(tr.context, g, lights, None, setup.eye.cornea_center(*a))
    assert got is None
