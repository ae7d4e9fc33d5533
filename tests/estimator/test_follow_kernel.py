"""The cheap path as one compiled call (:mod:`estimator.matching.follow_kernel`) against the
Python form of :meth:`estimator.matching.BandFollower.follow` it replaces: on bands of
synthetic glints with noise, hidden glints, clutter and priors from 0.05 to 3 deg off, both
accept and decline the same bands with the same identities, fits, scores and confidences,
and a band two detections share a light on goes to the Python form, which solves it."""

import math

import numpy as np
import pytest

from estimator.gaze import calibrated_problems
from estimator.matching import BandFollower, FollowParams, GlintMatcher, follow_kernel
from estimator.tracker import MIN_GLINTS, Tracker
from tests.estimator.test_cheap_path import assert_same_samples, saccade_frames
from tests.estimator.test_tracker import calibration, setup  # noqa: F401 fixtures

pytestmark = pytest.mark.skipif(not follow_kernel.ENABLED, reason="Numba is not installed")


@pytest.fixture(scope="module")
def follower(setup, calibration):  # noqa: F811
    problems = calibrated_problems(setup, calibration)
    m = GlintMatcher(setup, calibration=calibration, problem=problems.orbit)
    return BandFollower(m, FollowParams(min_matches=MIN_GLINTS))


def both(fo, det, rows, prior, prior_term):
    """follow's answer compiled and in Python on the same band."""
    out = []
    for compiled in (True, False):
        fo.compiled = compiled
        try:
            out.append(fo.follow(det, rows, prior, prior_term=prior_term))
        finally:
            fo.compiled = follow_kernel.ENABLED
    return out


def bands(fo, rng, n):
    """(detections, rows, prior, prior_term) of ``n`` bands: a rotation's glints on 20-80 rows
    with 0.3 px of noise, up to 3 hidden, up to 4 clutter blobs, a prior 0.05-3 deg off."""
    W = fo.matcher.setup.camera.width_px
    out = []
    while len(out) < n:
        truth = np.radians(rng.uniform(-12, 12, 2))
        g, vis = fo.predict(truth)
        if vis.sum() < 8:
            continue
        v = g[vis, 1]
        lo = rng.uniform(v.min() - 10, v.max() - 20)
        rows = (lo, lo + rng.uniform(20, 80))
        inband = np.flatnonzero(vis & (g[:, 1] >= rows[0]) & (g[:, 1] <= rows[1]))
        keep = rng.permutation(inband)[rng.integers(0, min(3, inband.size) + 1):]
        det = g[keep] + rng.normal(0.0, 0.3, (keep.size, 2))
        k = int(rng.integers(0, 5))
        clutter = np.stack([rng.uniform(0, W, k), rng.uniform(*rows, k)], axis=1)
        det = rng.permutation(np.concatenate([det, clutter]))
        off = np.radians(rng.uniform(0.05, 3.0)) * rng.normal(size=2) / math.sqrt(2)
        out.append((det, rows, truth + off, bool(rng.random() < 0.7)))
    return out


def same(a, b):
    """The compiled and the Python answers agree (both None, or the same match and fit)."""
    if a is None or b is None:
        return a is None and b is None
    ma, mb = a.match, b.match
    assert np.array_equal(ma.light_index, mb.light_index)
    finite = np.isfinite(mb.residual_px)
    assert np.array_equal(np.isfinite(ma.residual_px), finite)
    # The same kernels in the same order: rounding only, 1e-9 relative (px, rad, m, score).
    close = dict(rtol=1e-9, atol=1e-12)
    assert np.allclose(ma.residual_px[finite], mb.residual_px[finite], **close)
    assert np.allclose(ma.confidence, mb.confidence, **close)
    assert np.allclose(ma.cornea_center_m, mb.cornea_center_m, **close)
    assert np.allclose(ma.angles_rad, mb.angles_rad, **close)
    for key in ("rms_px", "score", "hypothesis_margin"):
        x, y = getattr(ma, key), getattr(mb, key)
        assert (math.isinf(x) and x == y) or math.isclose(x, y, rel_tol=1e-9), key
    assert ma.reason == mb.reason and ma.iterations == mb.iterations
    assert np.allclose(a.fit.x, b.fit.x, **close)
    assert math.isclose(a.fit.rms_px, b.fit.rms_px, rel_tol=1e-9, abs_tol=1e-12)
    assert np.allclose(a.fit.JtJ, b.fit.JtJ, rtol=1e-9, atol=0.0)
    return True


def test_compiled_follow_is_the_python_follow(follower):
    rng = np.random.default_rng(11)
    accepted = declined = 0
    for det, rows, prior, term in bands(follower, rng, 400):
        a, b = both(follower, det, rows, prior, term)
        assert same(a, b), (rows, prior, term)
        accepted += a is not None
        declined += a is None
    # Both outcomes are exercised: priors 0.05-0.5 deg off are mostly followed, 2-3 deg
    # (more than a light's spacing along the arcs) mostly declined.
    assert accepted >= 100 and declined >= 50, (accepted, declined)


def test_two_detections_on_one_light(follower):
    """Two detections 0.4 px apart on one glint: the compiled optimal assignment solves the
    band as the Python form's linear_sum_assignment does; where it may visit no node the
    compiled call says FALLBACK, and follow's answer is the Python form's."""
    truth = np.radians([3.0, -1.0])
    g, vis = follower.predict(truth)
    v = g[vis, 1]
    rows = (v.min() - 1, v.min() + 60)
    inband = np.flatnonzero(vis & (g[:, 1] >= rows[0]) & (g[:, 1] <= rows[1]))
    assert inband.size >= 6
    det = np.concatenate([g[inband], g[inband[:1]] + 0.4])
    fo = follower
    gg, lo, hi = fo.matcher._inputs(det, rows)
    prior = truth + np.radians([0.1, 0.05])
    got = fo._follow_compiled(gg, lo, hi, prior, 1.0)
    assert got is not follow_kernel.FALLBACK and got is not None
    assert (got.match.light_index == inband[0]).sum() == 1
    a, b = both(fo, det, rows, prior, True)
    assert same(a, b)
    fixed = fo._fixed
    fo._fixed = (*fixed[:-1], 0)  # max_nodes 0: the optimal assignment always gives up
    try:
        assert fo._follow_compiled(gg, lo, hi, prior, 1.0) is follow_kernel.FALLBACK
        assert same(fo.follow(det, rows, prior), b)
    finally:
        fo._fixed = fixed


@pytest.mark.parametrize("method", ["polynomial", "geometric"])
def test_the_tracker_gives_the_same_samples_compiled_or_not(setup, calibration, method):  # noqa: F811
    """End to end on saccade frames (180 deg/s, hidden glints): the same samples, reasons
    and identities, estimates to 1e-9 m of cornea centre, with the compiled follow or not."""
    frames = saccade_frames(setup, n=6, seed=4)
    out = {}
    for compiled in (True, False):
        tr = Tracker(setup, calibration, method)
        tr.follower.compiled = compiled
        out[compiled] = [s for f, img in enumerate(frames) for s in tr.process(img, f)]
        if compiled:
            assert tr.counts["cheap"] > 0
    assert_same_samples(out[True], out[False], center_m=1e-9, screen_m=1e-9)
