"""The scene format's ``kind = "wire_mirror"`` light group: the wire-wound mirror and its LED
(:class:`estimator.geometry.wire_model.WireMirror`) from the keys of ``scet hardware mirror``.

Keys (lengths and angles take any unit suffix of :data:`estimator.scene.UNITS`): ``radius_mm``
(the strip's inner face), ``span_deg`` (first to last turn), ``first_m``, ``center_direction``,
``normal`` (as the ``arc`` group), ``strip_width_mm``, ``strip_thickness_mm``, ``turns``,
``wire_diameter_mm``, ``winding`` (``"end_to_end"``, default, or ``"mid_cell"``),
``led_position_m`` (the group's local frame: the LED rides with the group's pose), ``led_aim``
(default: toward the middle turn), ``led_half_angle_deg`` (a cos^m lobe, default 60 deg) or
``led_pattern`` (a datasheet table of [angle_deg, relative intensity] rows), ``led_diameter_mm``.
Every impossible mirror raises a :class:`~estimator.errors.SceneError` naming the key.
"""

from __future__ import annotations

import math

import numpy as np

from .geometry.wire_model import LedBeam, WireGeometryError, WireMirror

__all__ = ["read_wire_mirror"]


def _unit(t, key, v):
    n = np.linalg.norm(v)
    if n == 0:
        raise t.error(key, "expected a non-zero direction")
    return v / n


def read_arc_frame(t):
    """The keys an arc of lights and a wire mirror share: ``radius``, ``span``, ``first`` (SI
    units) and the unit ``center_direction`` and ``normal``, perpendicular to each other."""
    radius = t.quantity("radius", "length", lo=1e-3, hi=1.0)
    span = t.quantity("span", "angle", lo=0.0, hi=2 * math.pi)
    first = t.quantity("first", "length", shape=3)
    to_center = _unit(t, "center_direction", t.vector("center_direction"))
    normal = _unit(t, "normal", t.vector("normal"))
    if abs(to_center @ normal) > 1e-6:
        raise t.error("normal", "expected a normal perpendicular to center_direction")
    return radius, span, first, to_center, normal


def read_wire_mirror(t):
    """The :class:`~estimator.geometry.wire_model.WireMirror` of a ``kind = "wire_mirror"``
    group (``t``: the scene reader's table of the group; the keys in the module docstring). Its
    lights, the point-source model, are the turns' axes at mid-width."""
    radius, span, first, to_center, normal = read_arc_frame(t)
    width = t.quantity("strip_width", "length", lo=1e-5, hi=0.1)
    thickness = t.quantity("strip_thickness", "length", lo=1e-5, hi=0.1)
    turns = t.integer("turns", minimum=1, maximum=10000)
    wire = t.quantity("wire_diameter", "length", lo=1e-6, hi=0.1)
    winding = t.string("winding", "end_to_end", required=False, choices={"end_to_end", "mid_cell"})
    led = t.quantity("led_position", "length", shape=3)
    led_d = t.quantity("led_diameter", "length", default=0.5e-3, required=False, lo=1e-6, hi=10e-3)
    center = first + radius * to_center
    u = -to_center
    v = np.cross(normal, u)
    try:
        if t.has("led_pattern"):
            if t.has("led_half_angle_deg") or t.has("led_half_angle_rad"):
                raise t.error("led_pattern", "give either led_pattern or led_half_angle_deg, not both")
            rows = t.raw("led_pattern")
            if not isinstance(rows, list) or not all(isinstance(r, list) and len(r) == 2 for r in rows):
                raise t.error("led_pattern", "expected an array of [angle_deg, relative_intensity] rows")
            if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for r in rows for x in r):
                raise t.error("led_pattern", "expected numbers in the [angle_deg, relative_intensity] rows")
            vals = np.array(rows, dtype=np.float64).reshape(-1, 2)
            beam = LedBeam.table(np.radians(vals[:, 0]), vals[:, 1])
        else:
            half = t.quantity("led_half_angle", "angle", default=math.radians(60.0), required=False)
            beam = LedBeam.cos_power(half)
        # Aim: default the middle of the arc's wire (where the turns' brightness is balanced).
        mid = center + (radius - wire / 2) * (math.cos(span / 2) * u + math.sin(span / 2) * v)
        aim = t.vector("led_aim", 3, default=list(mid - led), required=False)
        aim = _unit(t, "led_aim", aim)
        return WireMirror(center, u, v, normal, radius, span, width, thickness, turns, wire, led,
                          aim, beam, led_d, winding)
    except WireGeometryError as exc:
        key = {"led_position_m": next((k for k in ("led_position_m", "led_position_mm", "led_position_cm")
                                       if t.has(k)), "led_position_m"),
               "radius_mm": next((k for k in ("radius_m", "radius_mm", "radius_cm") if t.has(k)), "radius_mm"),
               "wire_diameter_mm": next((k for k in ("wire_diameter_m", "wire_diameter_mm", "wire_diameter_cm")
                                         if t.has(k)), "wire_diameter_mm"),
               "span_deg": next((k for k in ("span_deg", "span_rad") if t.has(k)), "span_deg"),
               "led_half_angle_deg": next((k for k in ("led_half_angle_deg", "led_half_angle_rad")
                                           if t.has(k)), "led_half_angle_deg"),
               }.get(exc.key, exc.key)
        raise t.error(key, str(exc)) from None
