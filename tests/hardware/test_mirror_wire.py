"""``scet hardware mirror`` writes the ``wire_mirror`` scene group of the part it prints: the
same turns as its point-source list and as scenes/prototype_ov5647_wire.toml."""

from __future__ import annotations

import re

import numpy as np

from estimator.geometry.wire import setup_wire_mirrors
from estimator.scene import load_scene, parse_scene, resolve_scene
from hardware.mirror import MirrorParams, write_mirror


def _scene_with(group_text: str) -> str:
    text = resolve_scene("prototype_ov5647_wire").read_text()
    return text[:text.index("[[lights]]")] + group_text


def test_written_group_is_the_prototype_wire_scene(tmp_path):
    out = write_mirror(tmp_path)
    written = parse_scene(_scene_with(out["wire_lights"].read_text()))
    ((_, _, a),) = setup_wire_mirrors(written)
    ((_, _, b),) = setup_wire_mirrors(load_scene("prototype_ov5647_wire"))
    for name in ("center_m", "u", "v", "normal", "led_position_m", "led_aim"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-12)
    assert (a.turns, a.wire_diameter_m, a.width_m, a.thickness_m) == (b.turns, b.wire_diameter_m, b.width_m, b.thickness_m)
    # Its lights are the point-source list written beside it.
    listed = parse_scene(_scene_with(out["lights"].read_text().replace("# 35", "#")))
    np.testing.assert_allclose(written.lights_world_m, listed.lights_world_m, atol=1e-15)


def test_written_group_follows_the_parameters(tmp_path):
    out = write_mirror(tmp_path, MirrorParams(turns=20, wire_diameter_mm=0.5))
    text = out["wire_lights"].read_text()
    assert re.search(r"^turns = 20$", text, re.M) and re.search(r"^wire_diameter_mm = 0.5$", text, re.M)
    setup = parse_scene(_scene_with(text))
    assert setup.lights.count == 20
