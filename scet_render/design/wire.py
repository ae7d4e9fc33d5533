"""The designer's wire style: each arc is a wire-wound mirror lit by one LED (``kind =
"wire_mirror"``, :class:`estimator.geometry.wire_model.WireMirror`), as the prototype is built.

An arc of the family (:class:`~scet_render.design.families.Arc`: ``count`` lights on a circle
of radius r about an axis through the eye) becomes a strip of inner radius r + d/2 wound with
``count`` turns of wire of diameter d end to end, so that each turn's axis at mid-width is the
arc's light (the point-source model). Its LED sits at the mirror image, through the arc's
plane, of the turns' mean reflection point on the cornea at primary gaze: along each turn's axis the wire is a plane
mirror (:mod:`estimator.geometry.wire`, Eq. (A)), so an LED there puts every turn's highlight
near mid-width when the eye looks straight ahead, and the highlights then follow the cornea by
half its travel along the axis (:mod:`.wire_led`); :func:`centred_led` then moves it along the
arc's normal until the highlights' range over the screen centres on the strip (on the
prototype's mirror, 8 x 5 targets edge to edge: 11.1 % of the point model's glints lost on its
2 mm strip, none on 3 mm, against 54.8 % before centring and 13.7 % with the prototype scene's
LED; reports/wire_mirror.md, "Design"). The LED aims at the arc's middle turn.

The search scores such layouts by the two-bounce glints (:func:`wire_layout_glints`); a layout
whose LED is not admissible (outside the region or in the eye's view of the screen) or whose
mirror cannot be built is penalised like an inadmissible light.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from estimator.geometry import project_glints
from estimator.geometry.wire import eye_wire_glints
from estimator.geometry.wire_model import LedBeam, WireMirror
from estimator.setup import LightGroup, Setup

#: The prototype's strip (hardware/mirror.py): 2 mm wide, 1.5 mm thick [G].
STRIP_WIDTH_M = 2.0e-3
STRIP_THICKNESS_M = 1.5e-3
#: The LED's half-intensity angle (deg): a cos^1 lobe, e.g. Vishay VSMY1850 (datasheet 83397,
#: +-60 deg), the one lobe the renderer draws exactly (an area emitter).
LED_HALF_ANGLE_DEG = 60.0
#: The rendered LED's diameter (m), as scenes/prototype_ov5647_wire.toml.
LED_DIAMETER_M = 0.5e-3


def mirrored_led(setup: Setup, lights_m, normal, plane_point_m) -> np.ndarray:
    """(3,) the mean reflection point on the cornea of ``lights_m`` (k, 3) at primary gaze
    (the cornea's apex if none is visible), mirrored through the plane through
    ``plane_point_m`` with unit ``normal``: the LED that puts every turn's highlight near
    mid-width there (Eq. (A) of :mod:`estimator.geometry.wire` with l_a = -x_a, D_L = D_X)."""
    eye = setup.eye
    center = eye.cornea_center(0.0, 0.0)
    _, vis, pts = project_glints(setup.camera, center, eye.cornea_radius_m,
                                 np.asarray(lights_m, float).reshape(-1, 3), return_points=True)
    c = pts[vis].mean(axis=0) if vis.any() else eye.apex(0.0, 0.0)
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    return c - 2.0 * float((c - np.asarray(plane_point_m, float)) @ n) * n


def centred_led(setup: Setup, mirror: WireMirror, *, grid=(3, 3), rounds: int = 3) -> WireMirror:
    """The mirror (world frame) with its LED moved along the arc's normal so that the turns'
    highlights over the ``grid`` of screen targets (edge to edge) centre on mid-width: along the
    axis the highlight moves by D_X / (D_L + D_X) ~ 1/2 of the LED's move (Eq. (A)), so each
    round moves the LED by -2 x the middle of the range of all the turns' highlights (the
    narrowest strip that holds them all is then centred), solved on a strip
    :data:`~.wire_led.WIDE_STRIP_M` wide without occlusion, so that no highlight is cut off."""
    from .wire_led import WIDE_STRIP_M

    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(*grid, margin=0.0))
    m = mirror
    for _ in range(rounds):
        wide = replace(m, width_m=max(WIDE_STRIP_M, m.width_m))
        w = eye_wire_glints(setup.eye, setup.camera, wide, yaw, pitch, occlusion=False)
        s = np.where(w.visible, w.axial_m, np.nan)
        seen = np.isfinite(s).any(0)
        if not seen.any():
            break
        mid = 0.5 * (np.nanmax(s[:, seen]) + np.nanmin(s[:, seen]))
        m = replace(m, led_position_m=m.led_position_m - 2.0 * float(mid) * m.normal)
    mid_turn = m.wire_axes_m[m.turns // 2]
    return replace(m, led_aim=(mid_turn - m.led_position_m) / np.linalg.norm(mid_turn - m.led_position_m))


def arc_mirror(setup: Setup, arc, wire_diameter_m: float, *, width_m: float = STRIP_WIDTH_M,
               thickness_m: float = STRIP_THICKNESS_M, led_m=None) -> WireMirror:
    """The wire mirror (world frame) whose turns' axes are ``arc``'s lights
    (module docstring); ``led_m`` overrides the mirrored LED. Raises ``ValueError``
    (:class:`~estimator.geometry.wire_model.WireGeometryError`) for a mirror that cannot be
    built."""
    c_e = setup.eye.rotation_center_m
    c, r, axis, e1, e2 = arc.circle
    a0 = math.radians(arc.phi0_deg)
    u = math.cos(a0) * e1 + math.sin(a0) * e2
    v = np.cross(axis, u)
    center = np.asarray(c_e, float) + c
    # The loader spaces ``count`` turns over the span end to end; a closed ring leaves the
    # last gap open (as Arc.scene_table).
    span = arc.span_deg * (arc.count - 1) / arc.count if arc.closed else arc.span_deg
    d = float(wire_diameter_m)
    lights = center + r * (np.cos(np.radians(np.linspace(0.0, span, arc.count)))[:, None] * u
                           + np.sin(np.radians(np.linspace(0.0, span, arc.count)))[:, None] * v)
    led = mirrored_led(setup, lights, axis, center) if led_m is None else np.asarray(led_m, float)
    mid_angle = math.radians(span) / 2
    mid = center + r * (math.cos(mid_angle) * u + math.sin(mid_angle) * v)
    aim = (mid - led) / np.linalg.norm(mid - led)
    m = WireMirror(center, u, v, axis, r + d / 2, math.radians(max(span, 1e-9)), float(width_m),
                   float(thickness_m), arc.count, d, led, aim,
                   LedBeam.cos_power(math.radians(LED_HALF_ANGLE_DEG)), LED_DIAMETER_M)
    return m if led_m is not None else centred_led(setup, m)


def wire_groups(setup: Setup, arcs, wire_diameter_m: float, *, width_m: float = STRIP_WIDTH_M
                ) -> tuple[LightGroup, ...]:
    """One ``wire_mirror`` light group per arc (world frame, identity pose), as the scene
    loader builds them: the turns' axes as the group's points, the mirror as its emitter."""
    out = []
    for i, a in enumerate(arcs):
        m = arc_mirror(setup, a, wire_diameter_m, width_m=width_m)
        out.append(LightGroup(f"wire{i}", "wire_mirror", m.wire_axes_m,
                              source_radius_m=0.5 * m.wire_diameter_m, emitter=m))
    return tuple(out)


def _vec(v) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def wire_mirror_table(mirror: WireMirror, name: str) -> str:
    """The mirror (world frame) as a ``[[lights]]`` table of ``kind = "wire_mirror"``
    (``estimator.scene_wire``), full precision."""
    first = mirror.center_m + mirror.radius_m * mirror.u
    beam = mirror.beam
    half = math.degrees(math.acos(0.5 ** (1.0 / beam.exponent)))
    return (f"[[lights]]\nname = \"{name}\"\nkind = \"wire_mirror\"\n"
            f"radius_mm = {float(mirror.radius_m * 1e3)!r}\nspan_deg = {float(math.degrees(mirror.span_rad))!r}\n"
            f"first_m = {_vec(first)}\ncenter_direction = {_vec(-mirror.u)}\n"
            f"normal = {_vec(mirror.normal)}\nstrip_width_mm = {float(mirror.width_m * 1e3)!r}\n"
            f"strip_thickness_mm = {float(mirror.thickness_m * 1e3)!r}\nturns = {mirror.turns}\n"
            f"wire_diameter_mm = {float(mirror.wire_diameter_m * 1e3)!r}\nwinding = \"{mirror.winding}\"\n"
            f"led_position_m = {_vec(mirror.led_position_m)}\nled_aim = {_vec(mirror.led_aim)}\n"
            f"led_half_angle_deg = {float(half)!r}\nled_diameter_mm = {float(mirror.led_diameter_m * 1e3)!r}\n")


def led_positions(groups) -> np.ndarray:
    """(k, 3) the LEDs of the ``wire_mirror`` groups (world frame)."""
    return np.array([g.emitter.posed(g.pose).led_position_m for g in groups
                     if isinstance(g.emitter, WireMirror)]).reshape(-1, 3)


__all__ = ["STRIP_WIDTH_M", "STRIP_THICKNESS_M", "LED_HALF_ANGLE_DEG", "LED_DIAMETER_M",
           "mirrored_led", "arc_mirror", "wire_groups", "wire_mirror_table", "led_positions"]
