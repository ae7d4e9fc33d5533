"""The tracker's per-frame layout (:class:`estimator.tracking.frame_bands.FrameBands`, bands
and strobe instants cached per strobe phase) against :func:`estimator.banding.band_rows`, the
timing equations it stands in for, and the grouping of a frame's detections by strobe
(:meth:`estimator.tracking.Tracker.group`) against one mask per band."""

from dataclasses import replace

import numpy as np
import pytest

from estimator.banding import band_rows, strobe_instant
from estimator.glints import GlintDetections
from estimator.scene import load_scene
from estimator.tracking import Tracker
from estimator.tracking.frame_bands import FrameBands


def _reference(setup, f, start):
    pulses, starts, first, last = band_rows(setup.sensor, setup.strobe, f)
    shift = 0.0 if start is None else start - f * setup.sensor.frame_period_s
    bands = [(int(j), (int(a), int(b))) for j, a, b in zip(pulses, first, last)]
    return bands, strobe_instant(starts, setup.strobe.pulse_s) + shift


@pytest.mark.parametrize("scene", ["paper_sim", "prototype_ov5647"])
@pytest.mark.parametrize("phase_us, period_us", [(0.0, None), (330.0, None), (0.0, 1041.3)])
def test_frame_bands_are_band_rows_bit_for_bit(scene, phase_us, period_us):
    # Phase 0 puts a pulse's first edge exactly on row 0 (the float edge on an integer: the
    # case the check exists for); 1041.3 us is a strobe not locked to the 16.636 ms frame
    # (a new phase every frame: nothing to reuse, every frame computed as before).
    setup = load_scene(scene)
    strobe = replace(setup.strobe, phase_s=phase_us * 1e-6)
    if period_us is not None:
        strobe = replace(strobe, period_s=period_us * 1e-6)
    setup = replace(setup, strobe=strobe)
    fb = FrameBands(setup.sensor, setup.strobe)
    frames = [*range(0, 120), *range(10 ** 6, 10 ** 6 + 20)]  # and ~4.6 h into a stream
    for f in frames:
        start = None if f % 3 else f * setup.sensor.frame_period_s + 2.5e-5  # a timing sidecar
        bands, times = fb(f, start)
        ref_bands, ref_times = _reference(setup, f, start)
        assert bands == ref_bands
        assert np.asarray(times).tobytes() == ref_times.tobytes()
    if period_us is None:
        assert fb.hits == len(frames) - 1 and len(fb.cache) == 1
    else:
        assert fb.hits == 0


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
