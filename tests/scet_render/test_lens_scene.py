"""A lens changed in code reaches the effective scene a dataset records (so that calibrate,
track and compare load the lens the frames were rendered with), and a pinhole setup's
fingerprint is what it was before the lens existed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimator.geometry import Camera
from estimator.scene import load_scene, parse_scene, resolve_scene
from scet_render.dataset.effective import effective_scene_text, setup_differences
from scet_render.dataset.manifest import setup_fingerprint


def _with_lens(setup, *lens):
    c = setup.camera
    return dataclasses.replace(setup, camera=Camera(
        c.position_m, c.rotation, c.fx_px, c.fy_px, c.cx_px, c.cy_px, c.width_px, c.height_px, *lens))


@pytest.mark.parametrize("lens", [
    ([-0.1, 0.01, 0.0, 0.0, 0.0], 2.9, 0.035, 5.6e-6 * 643 / 1300),
    ((), 2.8, 0.0351, 3.3e-6),
    ([-0.02, 0.0, 0.001, 0.0],),
])
def test_a_lens_set_in_code_is_written_into_the_effective_scene(lens):
    base = load_scene("paper_sim")
    text = resolve_scene("paper_sim").read_text(encoding="utf-8")
    setup = _with_lens(base, *lens)
    eff = effective_scene_text(setup, text)
    assert "camera" in eff[1] and not eff[2]  # rewritten, nothing it could not say
    assert setup_differences(parse_scene(eff[0]), setup) == []  # bit for bit
    back = effective_scene_text(base, eff[0])  # and the lens taken out again
    assert setup_differences(parse_scene(back[0]), base) == []


def test_pinhole_fingerprints_are_unchanged():
    """paper_sim's fingerprint from before the lens fields (the value test_dataset pins)."""
    setup = load_scene("paper_sim")
    assert setup_fingerprint(setup) == \
        "3098afe1dda6ce85dc3f7e3174bc17bc84ec658f472633092cfcae423793c661"
    lensed = _with_lens(setup, [-0.01, 0.0, 0.0, 0.0])
    assert setup_fingerprint(lensed) != setup_fingerprint(setup)
    np.testing.assert_array_equal(lensed.camera.distortion, [-0.01, 0.0, 0.0, 0.0])
