"""The printed part's notches and the written ``wire_mirror`` group come from one design
(hardware/mirror.py ``wire_mirror``): the turns sit where the notches hold them, for either
winding and for the designed part, and the designed part keeps every glint."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from estimator.geometry.wire import eye_wire_glints, setup_wire_mirrors
from estimator.scene import parse_scene, resolve_scene
from hardware.mirror import DESIGNED, MirrorParams, mirror_outline_mm, write_mirror

#: A notch holds its turn to well under the wire's radius (0.4 mm); both come from one
#: WireMirror, so they agree to rounding (mm, along the outer face).
NOTCH_MM = 1e-6


def _scene_with(group_text: str):
    text = resolve_scene("prototype_ov5647_wire").read_text()
    return parse_scene(text[:text.index("[[lights]]")] + group_text, "<test>")


def _notch_angles(p: MirrorParams) -> np.ndarray:
    """Angles (rad) of the notches' bottoms, read off the outline: its points at the outer
    radius minus the notch depth."""
    poly = mirror_outline_mm(p)
    r = np.hypot(poly[:, 0], poly[:, 1])
    bottom = np.abs(r - (p.radius_mm + p.thickness_mm - p.notch_depth_mm)) < 1e-9
    return np.sort(np.arctan2(poly[bottom, 1], poly[bottom, 0]))


@pytest.mark.parametrize("p", [MirrorParams(), MirrorParams(winding="mid_cell", turns=24), DESIGNED],
                         ids=["end_to_end", "mid_cell", "designed"])
def test_written_turns_sit_in_the_notches(tmp_path, p):
    out = write_mirror(tmp_path, p)
    setup = _scene_with(out["wire_lights"].read_text())
    group = setup.lights.groups[0]
    m = group.emitter  # the group's local frame: the part's arc plane before the pose
    rel = m.wire_axes_m - m.center_m
    turn_angles = np.sort(np.arctan2(rel @ m.v, rel @ m.u))
    notches = _notch_angles(p)
    assert notches.size == p.turns == m.turns
    r_out = p.radius_mm + p.thickness_mm
    np.testing.assert_allclose(r_out * notches, r_out * turn_angles, atol=NOTCH_MM)
    # And the STL's part: the strip's width is the group's.
    assert m.width_m == pytest.approx(p.width_mm * 1e-3, abs=1e-15)


def test_mid_cell_moves_the_notches_by_half_a_cell():
    a = _notch_angles(MirrorParams(turns=10))
    b = _notch_angles(MirrorParams(turns=10, winding="mid_cell"))
    assert a[0] == pytest.approx(0.0, abs=1e-12) and a[-1] == pytest.approx(math.pi / 2, abs=1e-12)
    assert b[0] == pytest.approx(math.pi / 2 / 20, abs=1e-12)


def test_designed_part_keeps_every_glint(tmp_path):
    """The design (reports/wire_mirror.md, Design): on its 3 mm strip with its LED no glint that
    the point-source model shows over the paper's 24 x 15 grid of gaze targets is lost; the
    prototype scene's 2 mm strip with the same LED loses some."""
    def lost(p):
        setup = _scene_with(write_mirror(tmp_path / p.winding / str(p.width_mm), p)["wire_lights"].read_text())
        ((_, _, m),) = setup_wire_mirrors(setup)
        yaw, pitch = setup.eye.angles_toward(setup.screen.grid(24, 15))
        vis = eye_wire_glints(setup.eye, setup.camera, m, yaw, pitch).visible
        ref = setup.eye.glints(setup.camera, m.wire_axes_m, yaw, pitch)[1]
        return int((ref & ~vis).sum()), int(ref.sum())

    from dataclasses import replace

    n_lost, n_ref = lost(DESIGNED)
    assert n_ref > 0.9 * 360 * DESIGNED.turns and n_lost == 0
    narrow, _ = lost(replace(DESIGNED, width_mm=2.0))
    assert narrow > 0


def test_cli_writes_the_designed_part_and_refuses_a_led_behind_the_strip(tmp_path, capsys):
    from scet_render.cli import main

    assert main(["hardware", "mirror", "--designed", "--out", str(tmp_path / "d")]) == 0
    text = (tmp_path / "d" / "wire_lights.toml").read_text()
    assert re.search(r"^strip_width_mm = 3.0$", text, re.M)
    capsys.readouterr()
    assert main(["hardware", "mirror", "--led-mm", "0", "60", "0", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "led_position_m" in err[0]


def test_bad_winding_is_refused():
    with pytest.raises(ValueError, match="winding"):
        MirrorParams(winding="random").check()
