"""The fit path's packed rows (estimator.geometry.fit_rows.centre_fit_rows) against the general
Jacobian terms: same glints, same normal equations, same fallbacks, reusable work arrays; and
the small systems' closed-form solves."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from estimator.cornea import solve
from estimator.geometry.fit_rows import centre_fit_rows
from estimator.geometry import project_glints

#: Relative agreement of the two paths' normal equations: both are exact to rounding, summed
#: in different orders over 40 glints.
RTOL = 1e-11


def _centres(setup, rng, k):
    return setup.eye.cornea_center(rng.uniform(-0.35, 0.35, k), rng.uniform(-0.25, 0.15, k))


def _general(problem, x, glints, mask, lights=None):
    L = problem.lights_world_m if lights is None else lights
    return solve._general_sums(problem.camera, x, problem.cornea_radius_m, L, glints, mask, False)


def _assert_same(a, b):
    for u, v in zip(a, b):
        scale = np.abs(v).reshape(len(v), -1).max(axis=1)
        err = np.abs(u - v).reshape(len(v), -1).max(axis=1)
        assert np.all(err <= RTOL * scale), (err / scale).max()


@pytest.fixture(scope="module")
def observed(setup):
    """Glints of 60 poses with 0.5 px of noise, and the poses 20-60 um off (fit-like)."""
    rng = np.random.default_rng(21)
    C = _centres(setup, rng, 60)
    g, v = project_glints(setup.camera, C, setup.eye.cornea_radius_m, setup.lights_world_m)
    g = np.where(v[..., None], g + rng.normal(0, 0.5, g.shape), 0.0)
    return C + rng.normal(0, 3e-5, C.shape), g, v


def test_glints_match_the_projection(setup, problem):
    C = _centres(setup, np.random.default_rng(2), 50)
    g, v = project_glints(setup.camera, C, problem.cornea_radius_m, setup.lights_world_m)
    mask = np.isfinite(g).all(-1)
    G, _, fast = centre_fit_rows(setup.camera, C, problem.cornea_radius_m, setup.lights_world_m,
                                  np.where(mask[..., None], g, 0.0), mask)
    assert fast.all()
    # Row 3 holds the residuals against the projection's glints: zero to rounding of pixels.
    assert np.abs(G[:, 3]).max() < 1e-9


@pytest.mark.parametrize("masked", [False, True])
def test_normal_equations_match_the_general_path(problem, observed, masked):
    x, g, v = observed
    mask = v & (np.random.default_rng(3).random(v.shape) < 0.7) if masked else v
    _assert_same(solve.normal_equations("center", problem, x, g, mask), _general(problem, x, g, mask))


def test_orbit_normal_equations_follow_by_the_chain_rule(problem, observed):
    x, g, v = observed
    angles = np.random.default_rng(4).uniform(-0.3, 0.3, (len(x), 2))
    centre = solve.unpack("orbit", problem, angles)[0]
    cost, JtJ, Jtr = _general(problem, centre, g, v)
    D = solve.orbit_derivative(problem, angles)
    expected = cost, np.swapaxes(D, 1, 2) @ JtJ @ D, (Jtr[:, None] @ D)[:, 0]
    _assert_same(solve.normal_equations("orbit", problem, angles, g, v), expected)


def test_gathered_lights_per_sample(problem, observed):
    x, g, v = observed
    gg, mm, LL = solve.gather(g, v & (np.arange(40) % 5 == 0), problem.lights_world_m)
    assert LL.ndim == 3 and LL.shape[1] < 40
    _assert_same(solve.normal_equations("center", problem, x, gg, mm, LL), _general(problem, x, gg, mm, LL))


def test_awkward_samples_take_the_general_path(setup, problem, observed):
    # Sample 1 has a light on the line through the camera and its cornea centre (no plane of
    # reflection), sample 2 a light inside its cornea: only those two leave the fast path, and
    # every sample's normal equations are still the general path's.
    x, g, v = (a[:6].copy() for a in observed)
    L = np.broadcast_to(problem.lights_world_m, (6, 40, 3)).copy()
    L[1, 7] = x[1] + 0.5 * (setup.camera.position_m - x[1])
    L[2, 9] = x[2] + 0.3 * problem.cornea_radius_m
    _, _, fast = centre_fit_rows(setup.camera, x, problem.cornea_radius_m, L, g, v)
    assert fast.tolist() == [True, False, False, True, True, True]
    _assert_same(solve.normal_equations("center", problem, x, g, v, L), _general(problem, x, g, v, L))


def test_work_arrays_are_reused_safely(problem, observed):
    # Calls of shrinking, growing and differently shaped batches reuse the same memory; each
    # must still see only its own samples, also from two threads at once.
    x, g, v = observed
    shapes = [slice(0, 60), slice(10, 17), slice(0, 3), slice(5, 60)]
    expected = [_general(problem, x[s], g[s], v[s]) for s in shapes]
    for s, e in zip(shapes, expected):
        _assert_same(solve.normal_equations("center", problem, x[s], g[s], v[s]), e)
    gg, mm, LL = solve.gather(g, v & (np.arange(40) % 3 == 0), problem.lights_world_m)
    _assert_same(solve.normal_equations("center", problem, x, gg, mm, LL), _general(problem, x, gg, mm, LL))

    def run(k):
        s = shapes[k % len(shapes)]
        return k, solve.normal_equations("center", problem, x[s], g[s], v[s])

    with ThreadPoolExecutor(max_workers=2) as pool:
        for k, got in pool.map(run, range(40)):
            _assert_same(got, expected[k % len(shapes)])


@pytest.mark.parametrize("p", [2, 3])
def test_small_systems_solved_by_cofactors(p):
    rng = np.random.default_rng(p)
    J = rng.normal(size=(20, 80, p))
    A, b = np.swapaxes(J, 1, 2) @ J, rng.normal(size=(20, p))
    A[7] = 0.0  # singular: a non-finite solution, no exception
    x, det = solve._solve_small(A, b)
    ok = np.arange(20) != 7
    expected = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
    assert np.allclose(x[ok], expected, rtol=1e-12, atol=0)
    assert np.allclose(det[ok], np.linalg.det(A[ok]), rtol=1e-12, atol=0)
    assert det[7] == 0 and not np.isfinite(x[7]).any()
