"""The wire-wound circular mirror of the prototype (paper Sec. 4.1): a printable STL and the
positions of its wire turns, the glint sources, as a scene light list.

The part is a 90 deg arc of radius 33 mm, 2 mm wide (along the arc plane's normal), with a
radial thickness the paper does not give (1.5 mm [G], HARDWARE.md Sec. 11). The wire (35 turns
of 0.8 mm, spread evenly end to end over the 90 deg) is wound around the strip; each turn's
stretch on the inner face shines as a point source, placed on the wire's axis at radius
R - d/2 and mid-width (the simple model of HARDWARE.md Sec. 11, within ~1 mm of the true
highlight). What the part must let the winding do:

* every turn goes all the way round the strip, so nothing may stand on the outer face where a
  turn passes: the part is mounted by two lugs beyond the end turns (a stem at mid-arc, as
  before, blocked turns 16-18 of 35);
* the end turns sit on the strip, not half off it: the strip runs on past the first and last
  turn by the wire's radius plus a clearance before the lug starts;
* a V notch on the outer face at each turn's angle (depth ``notch_depth_mm``, as wide as the
  wire) holds the turn where the light list says it is; the inner face, where the glints are,
  stays smooth.

The turns' positions, the notches' angles and the written ``wire_mirror`` scene group all
come from one :class:`~estimator.geometry.wire_model.WireMirror` (:func:`wire_mirror`), with
either winding (``end_to_end``, ``mid_cell``); :data:`DESIGNED` is the part the LED study chose
(reports/wire_mirror.md, "Design": a 3 mm strip and its LED).

The part is one outline in the arc plane extruded by the width, so the mesh is closed by
construction (checked with trimesh); :func:`turn_clearance_mm` measures from the outline
itself how much room each turn has.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.formats import atomic_file, atomic_write

__all__ = ["MirrorParams", "DESIGNED", "wire_mirror", "turn_angles_rad", "turn_positions_local_m", "mirror_outline_mm",
           "turn_clearance_mm", "mirror_mesh", "light_list_toml", "wire_group_toml", "write_mirror"]


#: The prototype scene's pose of the mirror group (scenes/prototype_ov5647.toml).
PROTOTYPE_POSE = {"pivot_m": [-0.010, 0.020, -0.015], "rotation_axis": [1.0, 0.0, 0.0],
                  "rotation_deg": -45.0}
#: The LED of scenes/prototype_ov5647_wire.toml (the group's local frame): the best single LED
#: position of ``scet study wire --design`` under :data:`PROTOTYPE_POSE` (reports/wire_mirror.md).
PROTOTYPE_LED_M = (0.0024, 0.04, -0.0265226)
#: The LED's half-intensity angle (deg): an 850 nm part with a cos^1 lobe, e.g. Vishay
#: VSMY1850 (datasheet 83397, ±60 deg); the paper's Osram part is not named.
PROTOTYPE_LED_HALF_ANGLE_DEG = 60.0



@dataclass(frozen=True, slots=True)
class MirrorParams:
    """The mirror, in millimetres and degrees, and where its arc sits in the scene (the
    ``arc`` light group's keys of the scene format: first light, direction to the arc's
    centre, arc plane normal; the pose is applied by the scene file). ``span_deg`` is the
    angle from the first turn to the last; the strip runs on beyond both."""

    radius_mm: float = 33.0
    span_deg: float = 90.0
    width_mm: float = 2.0
    thickness_mm: float = 1.5
    turns: int = 35
    wire_diameter_mm: float = 0.8
    #: Free arc (mm, on the outer face) between an end turn's wire and its lug.
    clearance_mm: float = 0.5
    lug_length_mm: float = 8.0
    lug_width_mm: float = 3.0
    notch_depth_mm: float = 0.3
    first_m: tuple = (-0.010, 0.020, -0.015)
    center_direction: tuple = (0.0, 0.0, -1.0)
    normal: tuple = (0.0, 1.0, 0.0)
    #: ``"end_to_end"`` (a turn at each end of the span) or ``"mid_cell"`` (the span split
    #: into ``turns`` cells, a turn in the middle of each): the scene format's ``winding``.
    winding: str = "end_to_end"
    #: The LED (m, the group's local frame, as the arc's keys) and its beam: the scene
    #: group's ``led_position_m``, ``led_half_angle_deg``, ``led_diameter_mm``.
    led_position_m: tuple = PROTOTYPE_LED_M
    led_half_angle_deg: float = PROTOTYPE_LED_HALF_ANGLE_DEG
    led_diameter_mm: float = 0.5

    def check(self) -> None:
        for name in ("radius_mm", "span_deg", "width_mm", "thickness_mm", "wire_diameter_mm",
                     "clearance_mm", "lug_length_mm", "lug_width_mm"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"mirror parameter {name} must be positive, got {v!r}")
        if not (math.isfinite(self.notch_depth_mm) and 0 <= self.notch_depth_mm < self.thickness_mm / 2):
            raise ValueError(f"mirror parameter notch_depth_mm must be in [0, thickness_mm / 2), "
                             f"got {self.notch_depth_mm!r}")
        if self.turns < 1:
            raise ValueError(f"mirror parameter turns must be >= 1, got {self.turns!r}")
        if not 0 < self.span_deg + 2 * math.degrees(self.end_angle_rad) < 360:
            raise ValueError(f"mirror parameter span_deg must leave room for the end lugs within "
                             f"360 deg, got {self.span_deg!r}")
        pitch = self.radius_mm * math.radians(self.span_deg) / max(self.turns - 1, 1)
        if self.turns > 1 and pitch < self.wire_diameter_mm:
            raise ValueError(f"{self.turns} turns of {self.wire_diameter_mm} mm wire do not fit on "
                             f"the arc (pitch {pitch:.3f} mm)")
        if self.lug_width_mm >= self.radius_mm + self.thickness_mm:
            raise ValueError("mirror parameter lug_width_mm is wider than the arc's radius")
        if self.winding not in ("end_to_end", "mid_cell"):
            raise ValueError(f"mirror parameter winding must be 'end_to_end' or 'mid_cell', got "
                             f"{self.winding!r}")

    @property
    def end_angle_rad(self) -> float:
        """How far (rad) the strip runs on past the first and the last turn: the lug's width
        on the outer face, plus the wire's radius and the clearance."""
        r_out = self.radius_mm + self.thickness_mm
        return (math.asin(min(self.lug_width_mm / r_out, 1.0))
                + (self.wire_diameter_mm / 2 + self.clearance_mm) / r_out)


#: The designed part (reports/wire_mirror.md, "Design"; scet_render.design.wire_report): the
#: prototype's placement with a 3 mm strip and the design rule's LED (the turns' mean corneal
#: reflection point at primary gaze mirrored through the arc's plane, moved along its normal
#: until all highlights over the screen, edge to edge, centre on the strip: they span +-1.35 mm).
#: Over the paper's 24 x 15 grid it loses none of the 12,600 glints the point model shows (2 mm:
#: 7.9 %, 2.5 mm: 1.0 %). ``scet hardware mirror --designed``.
DESIGNED = MirrorParams(width_mm=3.0, led_position_m=(0.0030813078766464093, 0.037950675466686845,
                                                      -0.025556115572069847))


def _frame(p: MirrorParams):
    to_c = np.asarray(p.center_direction, float)
    n = np.asarray(p.normal, float)
    to_c, n = to_c / np.linalg.norm(to_c), n / np.linalg.norm(n)
    if abs(to_c @ n) > 1e-6:
        raise ValueError("mirror: normal must be perpendicular to center_direction")
    u = -to_c
    return u, np.cross(n, u), n


def wire_mirror(p: MirrorParams = MirrorParams(), *, led: bool = True):
    """The :class:`~estimator.geometry.wire_model.WireMirror` the scene group of these
    parameters describes (group's local frame, before its pose): the one source of the turns'
    positions, so the notches of the printed part (:func:`mirror_outline_mm`) sit where the
    written group's turns are. ``led=False`` puts the LED at the arc's centre (for the
    geometry alone, whatever the LED). Raises ``ValueError`` naming the parameter at fault."""
    from estimator.geometry.wire_model import LedBeam, WireMirror

    p.check()
    u, v, n = _frame(p)
    center = np.asarray(p.first_m, float) + p.radius_mm * 1e-3 * (-u)
    span = math.radians(p.span_deg)
    led = np.asarray(p.led_position_m, float) if led else center
    try:
        # Aim: the scene format's default, the middle of the arc's wire.
        mid = center + (p.radius_mm - p.wire_diameter_mm / 2) * 1e-3 * (
            math.cos(span / 2) * u + math.sin(span / 2) * v)
        aim = (mid - led) / np.linalg.norm(mid - led)
        return WireMirror(center, u, v, n, p.radius_mm * 1e-3, span, p.width_mm * 1e-3,
                          p.thickness_mm * 1e-3, p.turns, p.wire_diameter_mm * 1e-3, led, aim,
                          LedBeam.cos_power(math.radians(p.led_half_angle_deg)),
                          p.led_diameter_mm * 1e-3, p.winding)
    except ValueError as exc:  # WireGeometryError names the scene key
        raise ValueError(f"mirror parameter {getattr(exc, 'key', '')}: {exc}") from None


def turn_angles_rad(p: MirrorParams = MirrorParams()) -> np.ndarray:
    """(turns,) angle of each turn on the arc from the first turn's end of the span: 0 to
    ``span_deg`` end to end, or the cells' middles (``winding``); the notches' angles."""
    return np.asarray(wire_mirror(p, led=False).turn_angles_rad)


def turn_positions_local_m(p: MirrorParams = MirrorParams()) -> np.ndarray:
    """(turns, 3) glint-source positions (m) in the scene frame before the group's pose:
    on the arc of the scene's ``arc`` group with the same ``first_m``, ``center_direction``
    and ``normal``, at radius R - d/2 (the turns' axes of :func:`wire_mirror`)."""
    return np.asarray(wire_mirror(p, led=False).wire_axes_m)


def _polar(r, a):
    return np.array([r * math.cos(a), r * math.sin(a)])


def mirror_outline_mm(p: MirrorParams = MirrorParams(), segments: int = 90) -> np.ndarray:
    """(n, 2) counter-clockwise outline of the part in the arc plane (mm, origin at the arc's
    centre, angle 0 at the first turn): the band R..R+t from -e to span + e (e =
    :attr:`MirrorParams.end_angle_rad`), a V notch on the outer face at each turn, and a lug
    outward at each end, its end face flush with the strip's."""
    p.check()
    span, e = math.radians(p.span_deg), p.end_angle_rad
    r_in, r_out = p.radius_mm, p.radius_mm + p.thickness_mm
    w, tip = p.lug_width_mm, p.radius_mm + p.thickness_mm + p.lug_length_mm
    a0, a1 = -e, span + e
    lug_foot = math.asin(w / r_out)     # where a lug's inner side meets the outer face

    def et(a):
        return np.array([-math.sin(a), math.cos(a)])

    # The outer face, angle rising: arc samples, each notch as three points (its edges on the
    # face and its bottom), samples inside a notch left out.
    half = (p.wire_diameter_mm / 2) / r_out
    notches = turn_angles_rad(p) if p.notch_depth_mm > 0 else np.zeros(0)
    lo, hi = a0 + lug_foot, a1 - lug_foot
    points = [(a, r_out) for a in np.linspace(lo, hi, segments + 1)
              if not np.any(np.abs(a - notches) <= half * 1.001)]
    for a in notches:
        points += [(a - half, r_out), (a, r_out - p.notch_depth_mm), (a + half, r_out)]
    points.sort()
    outer = [_polar(r, a) for a, r in points]
    # Each lug: its end face on the strip's radial end line, its inner side parallel to it at
    # the lug's width, meeting the outer face at the first (last) arc sample.
    start_lug = [tip * np.array([math.cos(a0), math.sin(a0)]),
                 tip * np.array([math.cos(a0), math.sin(a0)]) + w * et(a0)]
    end_lug = [tip * np.array([math.cos(a1), math.sin(a1)]) - w * et(a1),
               tip * np.array([math.cos(a1), math.sin(a1)])]
    inner = [_polar(r_in, a) for a in np.linspace(a1, a0, segments + 1)]
    return np.array(start_lug + outer + end_lug + inner)


def _inside(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(m,) whether each of (m, 2) points lies inside the polygon (even-odd ray casting)."""
    x, y = pts[:, 0][:, None], pts[:, 1][:, None]
    x0, y0 = poly[:, 0][None, :], poly[:, 1][None, :]
    x1, y1 = np.roll(poly[:, 0], -1)[None, :], np.roll(poly[:, 1], -1)[None, :]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (crosses & (x < xc)).sum(axis=1) % 2 == 1


def turn_clearance_mm(p: MirrorParams = MirrorParams(), outlines=None, *, step_mm: float = 0.01,
                      reach_mm: float = 10.0) -> dict:
    """Room for each turn, measured on the outline (:func:`mirror_outline_mm`).

    Parameters
    ----------
    outlines : list of (n, 2) float, optional
        The part as polygons in the arc plane (mm; a point inside any is material); default
        ``[mirror_outline_mm(p)]``.
    reach_mm : float
        How far along the inner face the strip is followed (``support_mm`` saturates there).

    Returns
    -------
    dict
        ``blocked`` (turns,) bool: part material lies in the wire's path round the outer
        face (radially from the notch bottom to one wire diameter above the face, across the
        wire's width); ``support_mm`` (turns,) float: the strip under the turn on the inner
        face, from the wire's centre to the strip's nearer end, measured along the arc (at
        least the wire's radius: the turn sits wholly on the strip).
    """
    polys = [mirror_outline_mm(p)] if outlines is None else [np.asarray(o, float) for o in outlines]

    def inside(pts):
        return np.logical_or.reduce([_inside(poly, pts) for poly in polys])

    r_in, r_out = p.radius_mm, p.radius_mm + p.thickness_mm
    rw = p.wire_diameter_mm / 2
    blocked, support = [], []
    radii = np.arange(r_out + 1e-3, r_out + 2 * rw + 1e-3, step_mm)
    for a in turn_angles_rad(p):
        across = np.linspace(-rw, rw, 9)
        pts = np.concatenate([np.c_[r * np.cos(a) - across * np.sin(a),
                                    r * np.sin(a) + across * np.cos(a)] for r in radii])
        blocked.append(bool(inside(pts).any()))
        # Along the inner face (just inside the part), each way until the strip ends.
        s = np.arange(1, int(reach_mm / step_mm) + 1) * step_mm
        far = []
        for sign in (-1.0, 1.0):
            ang = a + sign * s / r_in
            out = ~inside(np.c_[(r_in + 1e-3) * np.cos(ang), (r_in + 1e-3) * np.sin(ang)])
            far.append(float(s[np.argmax(out)] - step_mm) if out.any() else float(s[-1]))
        support.append(min(far))
    return {"blocked": np.array(blocked), "support_mm": np.array(support)}


def _ear_clip(poly: np.ndarray) -> np.ndarray:
    """(n - 2, 3) triangles of a simple counter-clockwise polygon (ear clipping; the test of
    the other vertices against a candidate ear is vectorised, the notches make many reflex
    vertices)."""
    poly = np.asarray(poly, dtype=np.float64)
    idx = list(range(len(poly)))
    tris = []

    def cross(o, a, b):
        return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (b[..., 0] - o[..., 0])

    while len(idx) > 3:
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if cross(a, b, c) <= 1e-12:
                continue
            rest = np.array([j for j in idx if j not in (i0, i1, i2)], dtype=np.int64)
            q = poly[rest]
            if rest.size and np.any((cross(a, b, q) >= 0) & (cross(b, c, q) >= 0) & (cross(c, a, q) >= 0)):
                continue
            tris.append((i0, i1, i2))
            del idx[k]
            break
        else:
            raise ValueError("mirror outline is not a simple polygon")
    tris.append(tuple(idx))
    return np.array(tris)


def mirror_mesh(p: MirrorParams = MirrorParams()):
    """The part as a closed ``trimesh.Trimesh`` in millimetres (z along the arc normal,
    0..width)."""
    import trimesh

    poly = mirror_outline_mm(p)
    n = len(poly)
    tris = _ear_clip(poly)
    verts = np.vstack([np.c_[poly, np.zeros(n)], np.c_[poly, np.full(n, p.width_mm)]])
    bottom = tris[:, ::-1]
    top = tris + n
    i = np.arange(n)
    j = (i + 1) % n
    sides = np.vstack([np.c_[i, j, j + n], np.c_[i, j + n, i + n]])
    mesh = trimesh.Trimesh(verts, np.vstack([bottom, top, sides]), process=True)
    if not (mesh.is_watertight and mesh.is_volume):
        raise ValueError("mirror mesh is not a closed volume (check the parameters)")
    return mesh


def light_list_toml(p: MirrorParams = MirrorParams(), pose: dict | None = None) -> str:
    """A ``[[lights]]`` group of ``kind = "list"`` (the scene format) with the turns."""
    pos = turn_positions_local_m(p)
    lines = [f"# {p.turns} wire turns ({p.wire_diameter_mm:g} mm wire) on a {p.span_deg:g} deg arc of "
             f"radius {p.radius_mm:g} mm: scet hardware mirror",
             "[[lights]]", 'name = "wire_mirror"', 'kind = "list"',
             f"source_diameter_mm = {p.wire_diameter_mm:g}", "positions_m = ["]
    # Full precision: the list is the arc to the last bit, not a rounded copy of it.
    lines += [f"    [{float(x)!r}, {float(y)!r}, {float(z)!r}]," for x, y, z in pos]
    lines.append("]")
    if pose:
        lines.append("[lights.pose]")
        for k, v in pose.items():
            lines.append(f"{k} = {list(v) if isinstance(v, (list, tuple)) else v}")
    return "\n".join(lines) + "\n"


def wire_group_toml(p: MirrorParams = MirrorParams(), pose: dict | None = None) -> str:
    """A ``[[lights]]`` group of ``kind = "wire_mirror"`` (the scene format): the same mirror
    as :func:`light_list_toml`'s turns and the STL's notches, with its strip, wire and LED
    (``estimator.scene_wire``; checked by building it, :func:`wire_mirror`)."""
    wire_mirror(p)
    lines = [f"# {p.turns} turns of {p.wire_diameter_mm:g} mm wire on a {p.span_deg:g} deg arc of "
             f"radius {p.radius_mm:g} mm, lit by one LED: scet hardware mirror",
             "[[lights]]", 'name = "wire_mirror"', 'kind = "wire_mirror"',
             f"radius_mm = {float(p.radius_mm)!r}", f"span_deg = {float(p.span_deg)!r}",
             f"first_m = {[float(x) for x in p.first_m]}",
             f"center_direction = {[float(x) for x in p.center_direction]}",
             f"normal = {[float(x) for x in p.normal]}",
             f"strip_width_mm = {float(p.width_mm)!r}", f"strip_thickness_mm = {float(p.thickness_mm)!r}",
             f"turns = {p.turns}", f"wire_diameter_mm = {float(p.wire_diameter_mm)!r}",
             f'winding = "{p.winding}"',
             f"led_position_m = {[float(x) for x in p.led_position_m]}",
             f"led_half_angle_deg = {float(p.led_half_angle_deg)!r}",
             f"led_diameter_mm = {float(p.led_diameter_mm)!r}"]
    if pose:
        lines.append("[lights.pose]")
        for k, v in pose.items():
            lines.append(f"{k} = {list(v) if isinstance(v, (list, tuple)) else v}")
    return "\n".join(lines) + "\n"


def write_mirror(out_dir, p: MirrorParams = MirrorParams(), pose: dict | None = PROTOTYPE_POSE) -> dict:
    """Write ``mirror.stl`` (mm), ``lights.toml`` (the turns as point sources) and
    ``wire_lights.toml`` (the ``wire_mirror`` group: strip, wire and LED) into ``out_dir``;
    the paths."""
    out = Path(out_dir)
    mesh = mirror_mesh(p)
    with atomic_file(out / "mirror.stl") as tmp:
        mesh.export(tmp, file_type="stl")
    lights = atomic_write(out / "lights.toml", light_list_toml(p, pose))
    wire = atomic_write(out / "wire_lights.toml", wire_group_toml(p, pose))
    return {"stl": out / "mirror.stl", "lights": lights, "wire_lights": wire,
            "volume_mm3": float(mesh.volume)}
