"""A sparse band's refinement from a prior as one compiled call
(:mod:`estimator.matching.refine_kernel`) against the Python form of
:meth:`HypothesisSearch._refine` it replaces in :meth:`GlintMatcher.match_near`: on bands of
1-4 glints with noise, clutter and priors 0.02-1.5 deg off, the same identities, rotations,
scores, margins, confidences and reasons; a band two detections share a light on goes to the
Python form."""

import math

import numpy as np
import pytest

from estimator.gaze import calibrated_problems
from estimator.matching import GlintMatcher, refine_kernel
from estimator.tracker import Tracker
from tests.estimator.test_cheap_path import assert_same_samples, saccade_frames
from tests.estimator.test_tracker import calibration, setup  # noqa: F401 fixtures

pytestmark = pytest.mark.skipif(not refine_kernel.ENABLED, reason="Numba is not installed")


@pytest.fixture(scope="module")
def matcher(setup, calibration):  # noqa: F811
    problems = calibrated_problems(setup, calibration)
    return GlintMatcher(setup, calibration=calibration, problem=problems.orbit)


def both(fn):
    """fn() with the compiled refinement and with the Python form."""
    out = []
    for on in (True, False):
        refine_kernel.ENABLED = on
        try:
            out.append(fn())
        finally:
            refine_kernel.ENABLED = True
    return out


def same_match(a, b):
    assert a.reason == b.reason
    assert np.array_equal(a.light_index, b.light_index)
    finite = np.isfinite(b.residual_px)
    assert np.array_equal(np.isfinite(a.residual_px), finite)
    # The same kernels in the same order: rounding only, 1e-9 relative (px, rad, m, score).
    close = dict(rtol=1e-9, atol=1e-12, equal_nan=True)
    assert np.allclose(a.residual_px, b.residual_px, **close)
    assert np.allclose(a.confidence, b.confidence, **close)
    assert np.allclose(a.cornea_center_m, b.cornea_center_m, **close)
    assert np.allclose(a.angles_rad, b.angles_rad, **close)
    for key in ("rms_px", "score", "hypothesis_margin"):
        x, y = getattr(a, key), getattr(b, key)
        assert (math.isnan(x) and math.isnan(y)) or (math.isinf(x) and x == y) \
            or math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-12), key
    assert a.iterations == b.iterations


def sparse_bands(matcher, rng, n):
    """(detections, rows, prior mean, prior covariance) of ``n`` bands of 1-4 glints (0.3 px
    of noise, up to 2 clutter blobs on the rows), priors 0.02-1.5 deg off with SDs of
    0.1-0.6 deg."""
    W = matcher.setup.camera.width_px
    out = []
    while len(out) < n:
        truth = np.radians(rng.uniform(-12, 12, 2))
        g, vis = matcher._predict_one(*truth)
        idx = np.flatnonzero(vis)
        if idx.size < 4:
            continue
        lo = float(g[rng.choice(idx), 1]) - rng.uniform(0.5, 3.0)
        rows = (lo, lo + rng.uniform(4.0, 12.0))
        inband = np.flatnonzero(vis & (g[:, 1] >= rows[0]) & (g[:, 1] <= rows[1]))[:4]
        det = g[inband] + rng.normal(0.0, 0.3, (inband.size, 2))
        c = int(rng.integers(0, 3))
        det = rng.permutation(np.concatenate(
            [det, np.stack([rng.uniform(0, W, c), rng.uniform(*rows, c)], axis=1)]))
        if det.shape[0] == 0:
            continue
        sd = np.radians(rng.uniform(0.1, 0.6))
        off = np.radians(rng.uniform(0.02, 1.5)) * rng.normal(size=2) / math.sqrt(2)
        out.append((det, rows, truth + off, sd ** 2 * np.eye(2)))
    return out


def test_compiled_refinement_is_the_python_refinement(matcher):
    rng = np.random.default_rng(21)
    reasons = {}
    for det, rows, mean, cov in sparse_bands(matcher, rng, 300):
        a, b = both(lambda: matcher.match_near(det, mean, cov, rows=rows))
        same_match(a, b)
        reasons[a.reason] = reasons.get(a.reason, 0) + 1
    # Accepted and refused bands both exercised (a tight prior near the truth identifies
    # the glints; a loose one far off leaves a shifted chain's rival within the margin).
    assert reasons.get("ok", 0) >= 100 and sum(reasons.values()) - reasons["ok"] >= 30, reasons


def test_two_detections_on_one_light(matcher):
    """Two detections 0.5 px apart on one glint: the compiled refinement solves the band's
    assignments as the Python form does; where its optimal assignment may visit no node it
    hands the band to the Python form (None)."""
    truth = np.radians([2.0, 1.0])
    g, vis = matcher._predict_one(*truth)
    i = int(np.flatnonzero(vis)[0])
    det = np.array([g[i], g[i] + [0.5, 0.0]])
    rows = (g[i, 1] - 3.0, g[i, 1] + 3.0)
    mean, cov = truth + np.radians([0.05, 0.0]), np.radians(0.2) ** 2 * np.eye(2)
    gg, lo, hi = matcher._inputs(det, rows)
    info = (mean, matcher.params.noise_px ** 2 * np.linalg.inv(cov))
    args = (gg, lo, hi, mean[None], matcher.params.gate_px, None, info)
    assert matcher._refine_compiled(*args) is not None
    a, b = both(lambda: matcher.match_near(det, mean, cov, rows=rows))
    same_match(a, b)
    assert a.ok and a.light_index.tolist().count(i) == 1
    saved = matcher._refine_args
    matcher._refine_args = (*saved[:-1], 0)  # max_nodes 0: the optimal assignment gives up
    try:
        assert matcher._refine_compiled(*args) is None
    finally:
        matcher._refine_args = saved


def test_the_compiled_optimal_assignment_is_linear_sum_assignment(matcher):
    """kernels.optimal_assign against HypothesisSearch._assign's linear_sum_assignment on
    2,000 random bands where detections compete for lights (2-7 detections, 3-12 candidates
    within a few gates): the same assignment and distances."""
    from estimator.matching import kernels

    rng = np.random.default_rng(17)
    n = matcher.lights_world_m.shape[0]
    conflicts = 0
    for _ in range(2000):
        gate = 3.0
        m = int(rng.integers(3, 13))
        lights = np.sort(rng.choice(n, m, replace=False))
        pred = np.zeros((n, 2))
        pred[lights] = rng.uniform(0, 8.0, (m, 2))
        k = int(rng.integers(2, 8))
        g = rng.uniform(0, 8.0, (k, 2))
        cand = np.zeros(n, dtype=bool)
        cand[lights] = True
        a0, d0 = np.empty(k, dtype=np.int64), np.empty(k)
        if kernels.nearest_assign(g, pred, lights, gate * gate, a0, d0):
            continue
        conflicts += 1
        want, want_d = matcher._assign(g, pred, cand, gate)  # linear_sum_assignment
        a, d = np.empty(k, dtype=np.int64), np.empty(k)
        assert kernels.optimal_assign(g, pred, lights, gate * gate, a, d, 10 ** 6)
        assert np.array_equal(a, want)
        assert np.allclose(d, want_d, rtol=1e-12, atol=0, equal_nan=True)
    assert conflicts >= 1000
@pytest.mark.parametrize("method", ["polynomial", "geometric"])
def test_the_tracker_gives_the_same_samples(setup, calibration, method):  # noqa: F811
    """End to end on saccade frames: the same samples, reasons and identities, estimates to
    1e-9 m of cornea centre, with the compiled refinement or the Python form."""
    frames = saccade_frames(setup, n=6, seed=7)

    def track():
        tr = Tracker(setup, calibration, method)
        return [s for f, img in enumerate(frames) for s in tr.process(img, f)]

    assert_same_samples(*both(track), center_m=1e-9, screen_m=1e-9)

