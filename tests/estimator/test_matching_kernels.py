"""The matcher's compiled steps (estimator.matching.kernels) against their numpy forms: the
gated assignment against scipy's optimal assignment, the arc-order check, the cheap path's
rival check and the identities' confidences give the same identities and numbers (to
rounding), on random inputs that reach every branch and on the tracker's own bands."""

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from estimator.gaze import calibrated_problems
from estimator.matching import BandFollower, GlintMatcher, kernels
from estimator.tracker import Tracker
from tests.estimator.test_cheap_path import saccade_frames
from tests.estimator.test_tracker import calibration, setup  # noqa: F401 fixtures

pytestmark = pytest.mark.skipif(not kernels.ENABLED, reason="Numba not installed (fast extra)")


@pytest.fixture(scope="module")
def matcher(setup, calibration):  # noqa: F811
    problems = calibrated_problems(setup, calibration)
    return GlintMatcher(setup, calibration=calibration, problem=problems.orbit)


def optimal(g, pred, lights, gate):
    """The gated optimal assignment by scipy alone (the definition the kernel must meet)."""
    d2 = ((g[:, None, :] - pred[None, lights, :]) ** 2).sum(-1)
    k = g.shape[0]
    cost = np.full((k, lights.size + k), 1e6 * gate * gate)
    cost[:, :lights.size] = np.where(d2 <= gate * gate, d2, 1e6 * gate * gate)
    cost[np.arange(k), lights.size + np.arange(k)] = gate * gate
    r, c = linear_sum_assignment(cost)
    out = np.full(k, -1)
    real = c < lights.size
    real[real] = d2[r[real], c[real]] <= gate * gate
    out[r[real]] = lights[c[real]]
    return out


def test_nearest_assignment_is_the_optimal_one_where_it_claims_so():
    rng = np.random.default_rng(0)
    claimed = conflicts = 0
    for _ in range(400):
        n, k = rng.integers(3, 40), rng.integers(1, 30)
        pred = rng.uniform(0, 100, (n, 2))
        lights = np.flatnonzero(rng.random(n) < 0.7)
        if lights.size == 0:
            continue
        # Detections near some predictions (and some clutter), 2.5 px gate as the matcher's.
        g = np.concatenate([pred[rng.choice(n, k)] + rng.normal(0, 1.5, (k, 2)),
                            rng.uniform(0, 100, (3, 2))])
        assign = np.empty(g.shape[0], dtype=np.int64)
        dist = np.empty(g.shape[0])
        if kernels.nearest_assign(g, pred, lights, 2.5 ** 2, assign, dist):
            claimed += 1
            assert np.array_equal(assign, optimal(g, pred, lights, 2.5))
            m = assign >= 0
            assert np.allclose(dist[m], np.hypot(*(g[m] - pred[assign[m]]).T), rtol=0, atol=1e-12)
            assert np.isnan(dist[~m]).all()
        else:
            conflicts += 1
            taken = assign[assign >= 0]
            assert np.unique(taken).size < taken.size, "a conflict is claimed only for one"
    assert claimed > 50 and conflicts > 50, "both branches are reached"


@pytest.mark.parametrize("seed", range(3))
def test_matcher_assignments_and_order_agree_with_the_numpy_form(matcher, monkeypatch, seed):
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(150):
        angles = rng.uniform(-0.35, 0.35, 2)
        pred, vis = BandFollower(matcher).predict(angles)
        cand = vis & (rng.random(vis.size) < 0.8)
        lights = np.flatnonzero(cand)
        if lights.size < 2:
            continue
        pick = rng.choice(lights, min(lights.size, 12), replace=False)
        # Noise of up to 3 px swaps neighbours on an arc now and then: the order check works.
        g = pred[pick] + rng.normal(0, rng.choice([0.3, 1.5, 3.0]), (pick.size, 2))
        cases.append((g, pred, cand))
    results = []
    for enabled in (True, False):
        monkeypatch.setattr(kernels, "ENABLED", enabled)
        results.append([(matcher._assign(g, p, c, 2.5), matcher._final_assign(g, p, c))
                        for g, p, c in cases])
    for (a1, f1), (a0, f0) in zip(*results):
        assert np.array_equal(a1[0], a0[0]) and np.array_equal(f1[0], f0[0])
        assert np.allclose(a1[1], a0[1], rtol=0, atol=1e-12, equal_nan=True)
        assert np.allclose(f1[1], f0[1], rtol=0, atol=1e-12, equal_nan=True)


def test_order_check_drops_what_the_numpy_form_drops(matcher, monkeypatch):
    """Detections that run against their lights' order along an arc (swapped neighbours,
    several arcs, chains of violations): the same matches are dropped."""
    rng = np.random.default_rng(3)
    n = matcher.group.size
    cases = []
    for _ in range(300):
        pred = rng.uniform(0, 200, (n, 2))
        lights = rng.choice(n, rng.integers(2, 16), replace=False)
        g = pred[lights] + rng.normal(0, rng.choice([0.5, 5.0, 40.0]), (lights.size, 2))
        assign = np.where(rng.random(lights.size) < 0.9, lights, -1)
        cases.append((g, pred, assign))
    out = {}
    for enabled in (True, False):
        monkeypatch.setattr(kernels, "ENABLED", enabled)
        out[enabled] = [matcher._enforce_order(g, p, a) for g, p, a in cases]
    dropped = 0
    for a1, a0, (_, _, a) in zip(out[True], out[False], cases):
        assert np.array_equal(a1, a0)
        dropped += int((a1 >= 0).sum() < (a >= 0).sum())
    assert dropped > 30, "the order check drops matches in many cases"


def test_tracker_gives_the_same_samples_with_and_without_kernels(setup, calibration,  # noqa: F811
                                                                 monkeypatch):
    """End to end (rival check and confidences included): the same identities, the same
    confidences and estimates to rounding."""
    frames = saccade_frames(setup)
    out = {}
    for enabled in (True, False):
        monkeypatch.setattr(kernels, "ENABLED", enabled)
        tr = Tracker(setup, calibration, "polynomial")
        out[enabled] = [s for f, img in enumerate(frames) for s in tr.process(img, f)]
        assert tr.counts["cheap"] > 0
    assert sum(s.ok for s in out[True]) > 10
    for a, b in zip(out[True], out[False]):
        assert a.reason == b.reason
        assert np.array_equal(a.light_index, b.light_index)
        if a.ok:
            # Searched bands' refits run the batched fit's rules compiled
            # (estimator.cornea.fit_replica) and prior-assisted ones the compiled small fit
            # with the prior on one side, the batched fit on the other: the same minimum to
            # ~2e-9 m (test_cornea_replica, test_cheap_path), which moves predictions and so
            # confidences by ~1e-8.
            assert np.allclose(a.confidence, b.confidence, rtol=0, atol=1e-6)
            assert np.abs(a.cornea_center_m - b.cornea_center_m).max() < 5e-9
    assert any(s.ok and s.prior_assisted for s in out[True]), "prior-assisted bands are checked"


def test_rival_margin_agrees_with_the_numpy_form(matcher, monkeypatch):
    fo = BandFollower(matcher)
    rng = np.random.default_rng(7)
    margins = {True: [], False: []}
    inputs = []
    for _ in range(60):
        truth = rng.uniform(-0.3, 0.3, 2)
        pred, vis = fo.predict(truth)
        top = pred[vis, 1].min() + rng.uniform(0, 150)
        rows = (top, top + 60)
        inband = np.flatnonzero(vis & (pred[:, 1] >= rows[0]) & (pred[:, 1] <= rows[1]))
        if inband.size < 3:
            continue
        g = pred[inband] + rng.normal(0, 0.3, (inband.size, 2))
        assign = inband.copy()
        assign[rng.random(assign.size) < 0.15] = -1
        x = truth + rng.normal(0, 0.002, 2)
        inputs.append((g, assign, x, truth + rng.normal(0, 0.005, 2), rows, rng.uniform(0, 20),
                       rng.choice([0.0, 1.0])))
    for enabled in (True, False):
        monkeypatch.setattr(kernels, "ENABLED", enabled)
        for g, assign, x, prior, rows, score, weight in inputs:
            margins[enabled].append(fo._rival_margin(g, assign, x, prior, *rows, score, weight))
    a, b = np.array(margins[True]), np.array(margins[False])
    assert np.isfinite(a).sum() > 30
    # Scores are sums of ~10-40 squared residuals / 0.25 px^2: 1e-9 of rounding at most.
    assert np.allclose(a, b, rtol=1e-12, atol=1e-9)


def test_coarse_search_finds_the_numpy_form_minima(matcher, monkeypatch):
    """Bands of random rotations (some clutter, some glints hidden; whole image and 60-row
    bands; all nodes and a subset): the same local minima in the same order, and the scores to
    rounding."""
    fo = BandFollower(matcher)
    rng = np.random.default_rng(11)
    cases = []
    for _ in range(25):
        pred, vis = fo.predict(rng.uniform(-0.3, 0.3, 2))
        top = pred[vis, 1].min() + rng.uniform(0, 120)
        lo, hi = (top, top + 60) if rng.random() < 0.7 else (-0.5, 479.5)
        keep = vis & (pred[:, 1] >= lo) & (pred[:, 1] <= hi) & (rng.random(vis.size) < 0.85)
        g = np.concatenate([pred[keep] + rng.normal(0, 0.5, (keep.sum(), 2)),
                            rng.uniform([0, lo], [640, hi], (2, 2))])
        nodes = None if rng.random() < 0.5 else rng.random(matcher.grid_visible.shape[0]) < 0.5
        cases.append((g, lo, hi, nodes))
    out = {}
    for enabled in (True, False):
        monkeypatch.setattr(kernels, "ENABLED", enabled)
        out[enabled] = [matcher._coarse(g, lo, hi, nodes, 8) for g, lo, hi, nodes in cases]
    found = 0
    for a, b in zip(out[True], out[False]):
        assert len(a) == len(b)
        assert all(np.array_equal(x, y) for x, y in zip(a, b))
        found += len(a)
    assert found > 50
