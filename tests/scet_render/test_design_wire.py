"""``scet design-lights --style wire``: each arc is a wire-wound mirror lit by one LED, scored by
the two-bounce glints, written as ``wire_mirror`` groups (scet_render.design.wire), and the
LED placement's measures (scet_render.design.wire_led)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.geometry.wire import eye_wire_glints, setup_wire_mirrors, wire_glint_flux
from estimator.scene import load_scene, parse_scene
from scet_render.design import Budget, Region, SearchSettings, design_lights
from scet_render.design.families import Arc
from scet_render.design.objective import design_poses, layout_glints, setup_layout_glints
from scet_render.design.report import designed_scene_text
from scet_render.design.wire import arc_mirror, centred_led, mirrored_led
from scet_render.design.wire_led import (WIDE_STRIP_M, run_strip, score_led, wire_group,
                                         with_led)

#: Positions written to TOML at full precision (repr) come back to the last bits (m).
ROUND_TRIP_M = 1e-12
#: The turns' axes are the arc's lights: the same circle by two formulas (m).
AXES_M = 1e-12


@pytest.fixture(scope="module")
def proto():
    return load_scene("prototype_ov5647")


@pytest.fixture(scope="module")
def designed(proto):
    """A tiny wire-style search (2 generations): enough to exercise the path end to end."""
    settings = SearchSettings(maxiter=2, popsize=3, motion=8, grid=(6, 4), search_step=2,
                              candidates=200, evaluate=False)
    return design_lights(proto, Budget(lights=24, arcs=1, free=0, style="wire"), Region(), settings)


def test_arc_mirror_turns_are_the_arcs_lights(proto):
    arc = Arc(30.0, -10.0, 35.0, 200.0, 120.0, 0.035, 20)
    m = arc_mirror(proto, arc, 0.8e-3)
    np.testing.assert_allclose(m.wire_axes_m, arc.positions(proto.eye.rotation_center_m), atol=AXES_M)
    # The strip's inner face carries the wire: R = r + d / 2.
    assert m.radius_m == pytest.approx(arc.circle[1] + 0.4e-3, abs=1e-15)


def test_designed_groups_are_wire_mirrors_with_their_led(designed):
    groups = designed.setup.lights.groups
    assert [g.kind for g in groups] == ["wire_mirror"]
    m = groups[0].emitter
    assert m.turns == designed.arcs[0].count
    # The LED lights the inner face: inside the arc, clear of the wire (the mirror's check).
    rel = m.led_position_m - m.center_m
    assert math.hypot(rel @ m.u, rel @ m.v) < m.radius_m - m.wire_diameter_m


def test_objective_counts_two_bounce_glints_not_points(designed):
    setup = designed.setup
    poses = design_poses(setup, (4, 3), 0)
    g, usable = setup_layout_glints(setup, poses)
    ((_, first, mirror),) = setup_wire_mirrors(setup)
    w = eye_wire_glints(setup.eye, setup.camera, mirror, poses.yaw_rad, poses.pitch_rad)
    sl = slice(first, first + mirror.turns)
    both = usable[:, sl]
    assert both.any() and not (both & ~w.visible).any()  # usable only where the solver sees it
    np.testing.assert_array_equal(g[:, sl][both], w.glints_px[both])
    # The point-source model's glints differ by the highlight's offset: more than render noise.
    gp, up = layout_glints(setup, setup.lights_world_m, poses)
    off = np.linalg.norm(g[both] - gp[:, sl][both], axis=-1)
    assert np.nanmax(off) > 0.1


def test_written_scene_reproduces_the_design(proto, designed):
    text = designed_scene_text(proto, designed, "wire_designed")
    assert 'kind = "wire_mirror"' in text
    loaded = parse_scene(text, "<test>")
    ((_, _, a),) = setup_wire_mirrors(loaded)
    ((_, _, b),) = setup_wire_mirrors(designed.setup)
    for key in ("center_m", "u", "v", "normal", "led_position_m", "led_aim"):
        np.testing.assert_allclose(getattr(a, key), getattr(b, key), atol=ROUND_TRIP_M)
    assert (a.turns, a.winding, a.beam.exponent) == (b.turns, b.winding, pytest.approx(b.beam.exponent))
    # The loaded scene's glints count the same bands as the design's result.
    from scet_render.design.objective import band_counts, band_model

    poses = design_poses(proto, designed.settings.grid, designed.settings.motion, designed.settings.seed)
    g, u = setup_layout_glints(loaded, poses)
    np.testing.assert_array_equal(band_counts(band_model(loaded), g, u), designed.counts_after)


def test_renderer_draws_the_designed_mirror(proto, designed):
    from scet_render.render.scene import describe_scene

    loaded = parse_scene(designed_scene_text(proto, designed, "wire_designed"), "<test>")
    objs = describe_scene(loaded).objects
    m = designed.setup.lights.groups[0].emitter
    assert sum(k.startswith("wire0_turn_") for k in objs) == m.turns
    assert objs["wire0_led"]["emitter"]["type"] == "area"
    assert not any(k.startswith("light_") for k in objs)


def test_strip_narrower_than_the_wire_is_refused():
    with pytest.raises(ValueError, match="strip_width_m"):
        Budget(lights=24, arcs=1, free=0, style="wire", strip_width_m=0.5e-3)


# -- the LED's placement ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def wire_scene():
    return load_scene("prototype_ov5647_wire")


def test_centring_puts_the_highlights_on_the_strip(wire_scene):
    """Along a turn the wire is a plane mirror: moving the LED along the normal moves every
    highlight by ~half as much, so the centred LED's highlights' range straddles mid-width."""
    _, m, pose = wire_group(wire_scene)
    world = m.posed(pose)
    rule = with_led(world, mirrored_led(wire_scene, world.wire_axes_m, world.normal, world.center_m))
    centred = centred_led(wire_scene, rule)
    yaw, pitch = wire_scene.eye.angles_toward(wire_scene.screen.grid(3, 3, margin=0.0))

    def middle(mm):
        from dataclasses import replace

        w = eye_wire_glints(wire_scene.eye, wire_scene.camera, replace(mm, width_m=WIDE_STRIP_M),
                            yaw, pitch, occlusion=False)
        s = np.where(w.visible, w.axial_m, np.nan)
        return 0.5 * float(np.nanmax(s) + np.nanmin(s))

    before, after = middle(rule), middle(centred)
    # Centred to well inside the wire's radius (0.4 mm); the rule alone is off by more.
    assert abs(after) < 0.05e-3 < abs(before)


def test_brightness_ratio_is_the_solvers_flux(wire_scene):
    """The score's ratio, computed again from wire_glint_flux at one pose by hand."""
    _, m, pose = wire_group(wire_scene)
    yaw, pitch = np.zeros(1), np.zeros(1)
    sc = score_led(wire_scene, m, pose, m.led_position_m, yaw, pitch, yaw, pitch)
    eye = wire_scene.eye
    c = eye.cornea_center(0.0, 0.0)
    axis = (eye.apex(0.0, 0.0) - c) / np.linalg.norm(eye.apex(0.0, 0.0) - c)
    wide = with_led(m, m.led_position_m, width_m=WIDE_STRIP_M).posed(pose)
    _, f = wire_glint_flux(wire_scene.camera, wide, c, eye.cornea_radius_m, cornea_axis=axis,
                           cap_cos_min=eye.cap_cos_min, occlusion=False)
    lit = f[f > 0]
    assert sc.flux_ratio == pytest.approx(lit.max() / lit.min(), rel=1e-12)
    # The prototype's mirror spans more than the 4x target (reports/wire_mirror.md: ~19x).
    assert sc.flux_ratio > 4.0
    a, b = run_strip(sc.flux)
    seg = sc.flux[0, a:b]
    assert seg.max() / seg.min() <= 4.0 and 0 < b - a < m.turns


def test_designed_part_has_the_rules_led(wire_scene):
    """hardware/mirror.py's DESIGNED LED is the design rule's on the prototype's mirror (the
    printed part and the scene group it writes match the design)."""
    from hardware.mirror import DESIGNED

    _, m, pose = wire_group(wire_scene)
    world = m.posed(pose)
    rule = centred_led(wire_scene, with_led(world, mirrored_led(wire_scene, world.wire_axes_m,
                                                                world.normal, world.center_m)))
    np.testing.assert_allclose(pose.inverse().apply(rule.led_position_m), DESIGNED.led_position_m,
                               atol=1e-6)  # 1 um: far below the LED's own 0.5 mm


#: The rendered LED's diameter (mm) in the render check: a 0.5 mm LED's glint through a 0.8 mm
#: wire is a line ~0.01 px wide that a few spp rarely hit (tests/scet_render/test_wire_render.py);
#: 2 mm is a 5 mm lensed LED's apparent emitter.
RENDER_LED_MM = 2.0
#: Samples per pixel: a glint of the 2 mm LED is still hit by ~1 of 16 paths of its pixel (one
#: hit reads ~35-40 DN above the median); at 16 spp 8 of 17 labelled glints got none.
RENDER_SPP = 64
#: A pixel counts as lit this far above the frame's median (DN, 10-bit): one hit of 64 paths.
LIT_DN = 8.0
#: Share of the labelled visible glints whose 5 x 5 pixels hold a lit pixel (sampling leaves
#: a few dark at this spp; measured 17 of 17, and 0 of 17 boxes 40 px aside).
LIT_SHARE = 0.8
@pytest.mark.slow  # ~1-2 min on 2 busy cores
def test_scet_render_renders_the_designed_scene(proto, designed, tmp_path):
    """`scet render` one frame of the designed wire scene: the glints the two-bounce labels call
    visible (rows the band lights fully) are lit where labelled."""
    pytest.importorskip("mitsuba")
    import json

    import cv2

    from scet_render.cli import main

    text = designed_scene_text(proto, designed, "wire_designed")
    text = text.replace("led_diameter_mm = 0.5\n", f"led_diameter_mm = {RENDER_LED_MM}\n")
    scene = tmp_path / "wire_designed.toml"
    scene.write_text(text)
    out = tmp_path / "render"
    assert main(["render", str(scene), "--frames", "1", "--spp", str(RENDER_SPP), "--cornea",
                 "conductor", "--out", str(out)]) == 0
    img = cv2.imread(str(out / "frames" / "000000.png"), cv2.IMREAD_UNCHANGED).astype(float)
    lit = img > np.median(img) + LIT_DN
    seen, control = [], []
    for line in (out / "labels.jsonl").read_text().splitlines():
        lab = json.loads(line)
        a, b = lab["full_rows"]
        for (x, y), vis in zip(lab["glints_px"], lab["glints_visible"]):
            if vis and a + 2 <= y <= b - 2:
                xi, yi = int(round(x)), int(round(y))
                seen.append(lit[yi - 2:yi + 3, xi - 2:xi + 3].any())
                # The same box 40 px aside, on the iris: dark (the light is the glints').
                control.append(lit[yi - 2:yi + 3, xi + 38:xi + 43].any())
    assert len(seen) >= 3 and np.mean(seen) >= LIT_SHARE
    assert np.mean(control) <= 1 - LIT_SHARE
