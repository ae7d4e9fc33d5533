"""The compiled replica of the batched Levenberg-Marquardt (issue 15: the hypothesis search's
cold refits) against :func:`estimator.cornea.fit_cornea` itself: on good starts and on the
poor hypotheses a cold search refines (few glints, wrong identities, starts degrees off), the
two converge or fail alike and reach the same parameters; and the search answers the same
with and without it."""

from dataclasses import replace

import numpy as np
import pytest

import estimator.matching.kernels as kernels
from estimator.cornea import fit_cornea, fit_replica
from estimator.cornea.replica import ENABLED
from estimator.gaze import calibrated_problems
from estimator.geometry import project_glints
from estimator.matching import GlintMatcher
from tests.estimator.test_tracker import calibration, setup  # noqa: F401 fixtures

pytestmark = pytest.mark.skipif(not ENABLED, reason="the replica runs compiled only (Numba)")


def hypotheses(setup, problem, model, rng, n=150):
    """(glints, lights, x0) of refits as a cold search makes them: 2-8 glints of a random
    pose with 0.5 px noise, a third of them with identities shifted by one light (a wrong
    chain), starts 0.5-6 deg off."""
    eye, L = setup.eye, problem.lights_world_m
    out = []
    for i in range(n):
        a = rng.uniform(-0.35, 0.35, 2)
        g, vis = project_glints(setup.camera, eye.cornea_center(*a), eye.cornea_radius_m, L)
        seen = np.flatnonzero(vis)
        k = int(rng.integers(2, 9))
        start = int(rng.integers(0, max(seen.size - k, 1)))
        sel = seen[start:start + k]
        glints = g[sel] + rng.normal(0.0, 0.5, (sel.size, 2))
        ids = (sel + 1) % L.shape[0] if i % 3 == 0 else sel
        off = np.radians(rng.uniform(0.5, 6.0)) * rng.choice([-1.0, 1.0], 2)
        x0 = a + off if model == "orbit" else eye.cornea_center(*(a + off))
        out.append((glints, L[ids], x0))
    return out


@pytest.mark.parametrize("model", ["orbit", "center"])
def test_the_replica_converges_where_fit_cornea_does(setup, calibration, model):  # noqa: F811
    problems = calibrated_problems(setup, calibration)
    problem = problems.orbit if model == "orbit" else problems.center
    rng = np.random.default_rng(11)
    ok_count = 0
    scale = problem.orbit_radius_m if model == "orbit" else 1.0
    for glints, lights, x0 in hypotheses(setup, problem, model, rng):
        ref = fit_cornea(replace(problem, lights_world_m=lights), glints[None], None, x0[None],
                         model=model)
        x, ok, iters = fit_replica(problem, glints, lights, x0, model=model)
        assert ok == bool(ref.ok[0]), (ref.reason[0], ref.iterations[0], iters)
        if ok:
            ok_count += 1
            x_ref = (ref.angles_rad if model == "orbit" else ref.center_m)[0]
            # Both stop on the same rules; their Jacobians differ by ~1e-9 relative (central
            # differences against the analytic rows), which moves where the last step lands
            # by far less than the 4e-10 m error the Gauss-Newton stop leaves: 2e-9 m of
            # cornea-centre motion, 1e-3 of the scatter 0.5 px of noise leaves.
            assert np.abs(x - x_ref).max() * scale < 2e-9
            assert abs(iters - int(ref.iterations[0])) <= 1
        else:
            assert np.isnan(x).all()
    # The orbit's set (the search's model) holds both outcomes: converged refits and
    # hypotheses that run out of iterations (the poor ones of a cold search); the centre's
    # 3 unknowns converge on every one of these.
    assert 0.3 * 150 < ok_count < (150 if model == "orbit" else 151)


def test_the_replica_refuses_too_few_glints(setup, calibration):  # noqa: F811
    problem = calibrated_problems(setup, calibration).center
    with pytest.raises(ValueError, match="coordinates"):
        fit_replica(problem, np.zeros((1, 2)), problem.lights_world_m[:1],
                    setup.eye.cornea_center(0.0, 0.0), model="center")
    with pytest.raises(ValueError, match="model"):
        fit_replica(problem, np.zeros((3, 2)), problem.lights_world_m[:3], np.zeros(3),
                    model="full")


def test_the_search_answers_the_same_with_the_replica(setup, calibration):  # noqa: F811
    """Cold searches of bands with clutter: identities, reasons and estimates as with the
    batched numpy fit (kernels off)."""
    matcher = GlintMatcher(setup, calibration=calibration)
    eye, L = setup.eye, matcher.lights_world_m
    rng = np.random.default_rng(3)
    results = {True: [], False: []}
    cases = []
    for _ in range(16):
        a = rng.uniform(-0.3, 0.3, 2)
        g, vis = project_glints(setup.camera, eye.cornea_center(*a), eye.cornea_radius_m, L)
        seen = np.flatnonzero(vis)
        v = g[seen, 1]
        lo = float(rng.uniform(v.min(), v.max() - 50))
        band = seen[(v >= lo) & (v <= lo + 50)]
        det = g[band] + rng.normal(0.0, 0.4, (band.size, 2))
        clutter = np.column_stack([rng.uniform(g[seen, 0].min(), g[seen, 0].max(), 1),
                                   rng.uniform(lo, lo + 50, 1)])
        cases.append((np.vstack([det, clutter]), (lo, lo + 50)))
    saved = kernels.ENABLED
    try:
        for on in (True, False):
            kernels.ENABLED = on
            results[on] = [matcher.match(d, rows=rows) for d, rows in cases]
    finally:
        kernels.ENABLED = saved
    assert sum(r.ok for r in results[True]) >= 6  # the bands mostly identify
    for a, b in zip(results[True], results[False]):
        assert a.reason == b.reason
        assert np.array_equal(a.light_index, b.light_index)
        if a.ok:
            # Angles to 1e-7 rad: the refits' 2e-9 m (above) seen through the final fit.
            assert np.abs(a.angles_rad - b.angles_rad).max() < 1e-7
