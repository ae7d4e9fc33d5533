"""The ``kind = "wire_mirror"`` light group of the scene format: its lights are the point-source
model's (``scet hardware mirror``'s list), and each impossible mirror is one SceneError naming
the key."""

from __future__ import annotations

import re

import numpy as np
import pytest

from estimator.errors import SceneError
from estimator.geometry.wire import WireMirror
from estimator.scene import load_scene, parse_scene, resolve_scene

TEXT = resolve_scene("prototype_ov5647_wire").read_text()


def _with(**changes) -> str:
    text = TEXT
    for key, value in changes.items():
        pattern = rf"^{key} = .*$"
        if re.search(pattern, text, flags=re.M):
            text = re.sub(pattern, f"{key} = {value}" if value is not None else "", text, count=1, flags=re.M)
        else:
            text = text.replace('kind = "wire_mirror"\n', f'kind = "wire_mirror"\n{key} = {value}\n')
    return text


def _error(**changes) -> SceneError:
    with pytest.raises(SceneError) as exc:
        parse_scene(_with(**changes), source="wire.toml")
    return exc.value


def test_lights_are_the_point_source_model():
    wire = load_scene("prototype_ov5647_wire")
    point = load_scene("prototype_ov5647")
    np.testing.assert_array_equal(wire.lights_world_m, point.lights_world_m)
    g = wire.lights.groups[0]
    assert g.kind == "wire_mirror" and isinstance(g.emitter, WireMirror)
    assert g.source_radius_m == pytest.approx(0.4e-3)
    assert g.emitter.beam.exponent == pytest.approx(1.0)
    # moved() keeps the emitter
    assert g.moved(g.pose).emitter is g.emitter


@pytest.mark.parametrize("changes, key, words", [
    ({"led_position_m": "[-0.010, 0.020, -0.0155]"}, "lights[0].led_position_m", "inside the strip"),
    ({"led_position_m": "[-0.010, 0.020, -0.005]"}, "lights[0].led_position_m", "behind the strip"),
    ({"turns": "70"}, "lights[0].turns", "overlap"),
    ({"wire_diameter_mm": "2.5"}, "lights[0].wire_diameter_mm", "wider than the strip"),
    ({"led_half_angle_deg": "95.0"}, "lights[0].led_half_angle_deg", "half-intensity angle"),
    ({"led_half_angle_deg": None, "led_pattern": "[[0.0, 1.0], [30.0, -0.2]]"}, "lights[0].led_pattern",
     "non-negative"),
    ({"led_half_angle_deg": None, "led_pattern": "[[5.0, 1.0], [30.0, 0.5]]"}, "lights[0].led_pattern",
     "from 0"),
    ({"led_pattern": "[[0.0, 1.0], [30.0, 0.5]]"}, "lights[0].led_pattern", "not both"),
    ({"winding": '"helix"'}, "lights[0].winding", "expected one of"),
    ({"led_aim": "[0.0, 0.0, 0.0]"}, "lights[0].led_aim", "non-zero"),
])
def test_bad_mirror_names_the_key(changes, key, words):
    err = _error(**changes)
    assert err.key == key, str(err)
    assert words in str(err) and "wire.toml" in str(err)


def test_datasheet_table_fits_a_lobe():
    # A cos^4 table (half-intensity at 32.8 deg) fits m = 4.
    a = np.arange(0, 91, 10)
    rows = ", ".join(f"[{x}.0, {np.cos(np.radians(x)) ** 4:.6f}]" for x in a)
    setup = parse_scene(_with(led_half_angle_deg=None, led_pattern=f"[{rows}]"))
    beam = setup.lights.groups[0].emitter.beam
    assert beam.exponent == pytest.approx(4.0, rel=1e-3)
    assert beam(np.cos(np.radians(20.0))) == pytest.approx(np.cos(np.radians(20.0)) ** 4, abs=0.01)
    assert beam(-0.5) == 0.0
