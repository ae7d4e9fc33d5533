"""The cheap path on bands where clutter outnumbers the glints (issue 31, sixth pass): it takes
such a band from the prior where the hypothesis search would, with the same detections on the
same lights, and leaves it to the search where a detection near an identified glint makes the
search's own assignment uncertain (:data:`estimator.matching.follow_kernel.CROWD_GATES`).

The designed lighting's renders put 5-8 glints and up to ~40 clutter spots in a band; the
cheap path asked for as many matched detections as unmatched and sent those bands to the
search, which kept the prior's identification (it asks for 3 matches *or* half)."""

import math

import numpy as np
import pytest

from estimator.matching import follow_kernel
from tests.estimator.test_follow_kernel import both, follower, same  # noqa: F401 fixture
from tests.estimator.test_tracker import calibration, setup  # noqa: F401 fixtures

pytestmark = pytest.mark.skipif(not follow_kernel.ENABLED, reason="Numba is not installed")


def band(fo, truth, rows):
    """Indices and predicted glints (i, 2) of the lights visible in ``rows`` at ``truth``."""
    g, vis = fo.predict(truth)
    inband = np.flatnonzero(vis & (g[:, 1] >= rows[0]) & (g[:, 1] <= rows[1]))
    return inband, g[inband]


def far_clutter(rng, pred, rows, width, n, min_px):
    """``n`` clutter detections in ``rows``, each at least ``min_px`` from every glint (px)."""
    out = []
    while len(out) < n:
        p = np.array([rng.uniform(0, width), rng.uniform(*rows)])
        if np.hypot(*(pred - p).T).min() >= min_px:
            out.append(p)
    return np.array(out).reshape(-1, 2)


def identities(det, light_index):
    """{detection's rounded position: its light} of the matched detections."""
    return {tuple(np.round(d, 9)): int(li) for d, li in zip(det, light_index) if li >= 0}


def test_clutter_beside_lone_glints_is_followed_as_the_search_identifies(follower):  # noqa: F811
    """6 glints with 0.3 px noise and 10 clutter spots at least 8 px from every glint (more
    than 3x the 2.5 px gate): the cheap path follows the band from a prior 0.2 deg off, and
    its detections and lights are the search's from the same prior."""
    fo, rng = follower, np.random.default_rng(5)
    truth = np.radians([4.0, -2.0])
    v = fo.predict(truth)[0][fo.predict(truth)[1], 1]
    rows = (v.min() - 1.0, v.min() + 45.0)
    lights, pred = band(fo, truth, rows)
    assert lights.size >= 5
    glints = pred + rng.normal(0.0, 0.3, pred.shape)
    clutter = far_clutter(rng, pred, rows, fo.matcher.setup.camera.width_px, 2 * lights.size,
                          8.0)
    det = rng.permutation(np.concatenate([glints, clutter]))
    prior = truth + np.radians([0.15, -0.12])
    a, b = both(fo, det, rows, prior, True)
    assert same(a, b) and a is not None  # more unmatched than matched, followed
    assert int((a.match.light_index >= 0).sum()) == lights.size
    searched = fo.matcher.match(det, rows=rows, prior_angles_rad=prior)
    assert searched.ok
    assert identities(det, a.match.light_index) == identities(det, searched.light_index)


def test_a_detection_beside_a_glint_leaves_the_band_to_the_search(follower):  # noqa: F811
    """The same band with one more clutter spot 1.6 px from a glint (within two gates of its
    light's prediction): the cheap path declines (the search decides which detection is the
    glint); with fewer clutter spots than glints the same spot does not stop it (the rule
    it had before)."""
    fo, rng = follower, np.random.default_rng(5)
    truth = np.radians([4.0, -2.0])
    v = fo.predict(truth)[0][fo.predict(truth)[1], 1]
    rows = (v.min() - 1.0, v.min() + 45.0)
    lights, pred = band(fo, truth, rows)
    glints = pred + rng.normal(0.0, 0.3, pred.shape)
    near = glints[:1] + np.array([[1.6 * math.cos(0.7), 1.6 * math.sin(0.7)]])
    width = fo.matcher.setup.camera.width_px
    prior = truth + np.radians([0.15, -0.12])
    many = far_clutter(rng, pred, rows, width, 2 * lights.size, 8.0)
    a, b = both(fo, np.concatenate([glints, near, many]), rows, prior, True)
    assert a is None and b is None
    few = np.concatenate([glints, near])  # 1 unmatched beside 6 matched
    a, b = both(fo, few, rows, prior, True)
    assert same(a, b) and a is not None


def test_followed_cluttered_bands_are_the_searchs(follower):  # noqa: F811
    """Random bands (a rotation within 12 deg, 20-80 rows, up to 3 glints hidden, 0.3 px of
    noise) with 1-3x as many clutter spots as glints anywhere in the band, priors 0.05-0.5
    deg off: wherever the cheap path follows one with more unmatched detections than
    matched, the search from the same prior assigns the same detections to the same lights."""
    fo, rng = follower, np.random.default_rng(23)
    width = fo.matcher.setup.camera.width_px
    followed = declined = 0
    for _ in range(120):
        truth = np.radians(rng.uniform(-12, 12, 2))
        g, vis = fo.predict(truth)
        if vis.sum() < 8:
            continue
        v = g[vis, 1]
        lo = rng.uniform(v.min() - 10, v.max() - 20)
        rows = (lo, lo + rng.uniform(20, 80))
        lights, pred = band(fo, truth, rows)
        keep = rng.permutation(lights.size)[rng.integers(0, min(3, lights.size) + 1):]
        det = pred[keep] + rng.normal(0.0, 0.3, (keep.size, 2))
        k = int(rng.integers(keep.size + 1, 3 * keep.size + 2))
        clutter = np.stack([rng.uniform(0, width, k), rng.uniform(*rows, k)], axis=1)
        det = rng.permutation(np.concatenate([det, clutter]))
        prior = truth + np.radians(rng.uniform(0.05, 0.5)) * rng.normal(size=2) / math.sqrt(2)
        a, b = both(fo, det, rows, prior, True)
        assert same(a, b)
        if a is None:
            declined += 1
            continue
        matched = int((a.match.light_index >= 0).sum())
        assert matched < 0.5 * det.shape[0]
        followed += 1
        searched = fo.matcher.match(det, rows=rows, prior_angles_rad=prior)
        assert searched.ok
        assert identities(det, a.match.light_index) == identities(det, searched.light_index)
    assert followed >= 20 and declined >= 5, (followed, declined)
