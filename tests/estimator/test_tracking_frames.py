"""The grouping of a frame's detections by strobe (:meth:`estimator.tracking.Tracker.group`)
against one mask per band."""

import numpy as np

from estimator.glints import GlintDetections
from estimator.tracking import Tracker


def test_detections_are_grouped_as_one_mask_per_band():
    rng = np.random.default_rng(3)
    m = 60
    strobes = rng.integers(5, 12, size=m)
    glints = rng.uniform(0, 640, size=(m, 2))
    flux = rng.uniform(1, 9, size=m)
    det = GlintDetections(u_px=glints[:, 0], v_px=glints[:, 1], intensity=flux,
                          area_px=np.ones(m, dtype=np.int64), peak=flux,
                          strobe_index=strobes, time_s=np.zeros(m),
                          flags=np.zeros(m, dtype=np.int64), frame_index=0, noise_dn=1.0,
                          threshold_dn=5.0)
    bands = [(j, (0, 1)) for j in range(3, 14)]  # strobes with and without detections
    spans, g, fl = Tracker.group(det, bands)
    for (a, b), (j, _) in zip(spans, bands):
        assert np.array_equal(g[a:b], det.glints_px[strobes == j])
        assert np.array_equal(fl[a:b], flux[strobes == j])
    empty = det.select(np.zeros(m, dtype=bool))
    spans, g, _ = Tracker.group(empty, bands)
    assert all(a == b for a, b in spans) and g.shape == (0, 2)
