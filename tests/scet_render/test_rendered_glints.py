"""A Mitsuba render through the estimator's detector and matcher: glints where the closed form
puts them, strobes where the timing equations put them, and the right light for each glint.

Moved here from ``tests/estimator/test_glints.py`` so that the estimator's tests run on the base
install; the tolerances are the detector's own, imported from there.
"""

import numpy as np
import pytest

from estimator.banding import NO_PULSE, band_layout, row_pulse_weights
from estimator.glints import TWO_PULSES, detect_glints
from estimator.matching import GlintMatcher
from estimator.scene import load_scene
from scet_render.render import BandedRenderer, SensorModel
from scet_render.simulate import ground_truth_glints
from tests.estimator.test_glints import CENTROID_MAX_PX, CENTROID_MEDIAN_PX, MATCH_PX, nearest


@pytest.fixture(scope="module")
def rendered():
    """One paper_sim frame rendered by Mitsuba (BandedRenderer, every band at its strobe
    instant; conductor cornea: exact glints at low spp) through the OV5647 sensor model."""
    pytest.importorskip("mitsuba")

    class Fixation:
        def angles_at(self, t):
            t = np.asarray(t, dtype=float)
            return np.full(t.shape, -0.12), np.full(t.shape, 0.04)

    setup = load_scene("paper_sim")
    renderer = BandedRenderer(setup, spp=32, cornea="conductor", seed=3)
    frame = renderer.render_frame(Fixation(), 0)
    dn = SensorModel.from_sensor(setup.sensor).apply(frame.radiance, np.random.default_rng(0))
    g, vis, _ = ground_truth_glints(setup, -0.12, 0.04)
    return setup, dn, np.flatnonzero(vis), g[vis], detect_glints(dn, setup, 0)


@pytest.mark.slow  # the render takes 5-10 s on 2 cores: kept out of the fast suite
def test_rendered_glints_land_on_the_closed_form(rendered):
    """DESIGN.md: a rendered glint must land where the closed-form projection says, to a tenth
    of a pixel (Mitsuba's i + 0.5 film convention converted once, in the renderer)."""
    setup, _, _, g, det = rendered
    idx, dist = nearest(det, g)
    assert (dist < MATCH_PX).all()
    assert np.median(dist) < CENTROID_MEDIAN_PX  # measured 0.05 px
    assert dist.max() < CENTROID_MAX_PX  # measured 0.10 px
    # Pulses as the timing equations give them for each glint's row.
    j, _, w = row_pulse_weights(setup.sensor, setup.strobe, 0, rows=np.rint(g[:, 1]))
    single = (det.flags[idx] & TWO_PULSES) == 0
    assert np.array_equal(det.strobe_index[idx][single], j[w.argmax(axis=1)][single])
    # Monte Carlo noise on the bright sclera at 32 spp leaves a few single-pixel blobs.
    assert len(det) - len(g) <= 8


@pytest.mark.slow
def test_rendered_bands_are_identified(rendered):
    setup, _, lights, g, det = rendered
    matcher = GlintMatcher(setup)
    bands = {b.pulse_index: b for b in band_layout(setup.sensor, setup.strobe, 0)}
    right = total = 0
    for j in np.unique(det.strobe_index[det.strobe_index != NO_PULSE]):
        band = det.of_strobe(int(j))
        r = matcher.match(band.glints_px, (bands[j].first_row, bands[j].last_row))
        d = np.linalg.norm(band.glints_px[:, None] - g[None], axis=-1)
        truth = np.where(d.min(axis=1) < MATCH_PX, lights[d.argmin(axis=1)], -1)
        if (truth >= 0).sum() >= 3:
            right += (r.light_index == truth).sum()
            total += len(band)
    assert total >= 30 and right / total >= 0.99
