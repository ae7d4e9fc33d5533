"""``scet study wire`` (solver level): the point-source model's ideal is the tracker's noise-free
floor, the wire's glints cost accuracy, and the per-turn split is consistent."""

from __future__ import annotations

import numpy as np
import pytest

from scet_render.study.wire import run_wire_study, wire_report


@pytest.fixture(scope="module")
def study():
    return run_wire_study()


def test_point_sources_are_the_floor(study):
    point = study["accuracy"]["point"]["geometric"]["errors_deg"]
    wire = study["accuracy"]["wire"]["geometric"]["errors_deg"]
    # Noise-free point glints through the same calibration: the model is exact (< 0.01 deg).
    assert np.nanmax(point) < 0.01
    # The wire's moving virtual sources are not: a median error well above that floor.
    assert np.nanmedian(wire) > 10 * np.nanmedian(point) + 0.05


def test_per_turn_split(study):
    seen = study["visible_wire"] > 0
    assert seen.any() and not seen.all()
    # Offsets exist exactly where both models see the glint; lost + seen = the point's share.
    assert np.all(np.isfinite(study["fixed_px"][seen])) and np.all(np.isnan(study["fixed_px"][~seen]))
    np.testing.assert_allclose(study["lost"] + study["visible_wire"] / study["visible_point"], 1.0, atol=1e-12)
    # A turn never seen has its highlight beyond the strip's half width at every pose.
    lo, hi = study["axial_mm"]
    assert np.all((lo[~seen] > 1.0) | (hi[~seen] < -1.0))
    text = wire_report(study)
    assert "| 34 |" in text and "calibrated lighting pose" in text
