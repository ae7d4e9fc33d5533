"""The wire-wound circular mirror of the prototype (paper Sec. 4.1): a printable STL and the
positions of its wire turns, the glint sources, as a scene light list.

The part is a 90 deg arc of radius 33 mm, 2 mm wide (along the arc plane's normal), with a
radial thickness the paper does not give (1.5 mm [G], HARDWARE.md Sec. 11), and a mount: a
stem from the middle of the arc's outside to a crossbar, to clamp or glue. It is one outline in
the arc plane extruded by the width, so the mesh is closed by construction (checked with
trimesh). The wire (35 turns of 0.8 mm, spread evenly end to end over the arc) is wound around
the strip; each turn's stretch on the inner face shines as a point source, placed on the wire's
axis at radius R - d/2 and mid-width (the simple model of HARDWARE.md Sec. 11, within ~1 mm of
the true highlight).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.formats import atomic_file, atomic_write

__all__ = ["MirrorParams", "turn_positions_local_m", "mirror_outline_mm", "mirror_mesh",
           "light_list_toml", "write_mirror"]


@dataclass(frozen=True, slots=True)
class MirrorParams:
    """The mirror, in millimetres and degrees, and where its arc sits in the scene (the
    ``arc`` light group's keys of the scene format: first light, direction to the arc's
    centre, arc plane normal; the pose is applied by the scene file)."""

    radius_mm: float = 33.0
    span_deg: float = 90.0
    width_mm: float = 2.0
    thickness_mm: float = 1.5
    turns: int = 35
    wire_diameter_mm: float = 0.8
    stem_length_mm: float = 8.0
    stem_width_mm: float = 3.0
    bar_length_mm: float = 16.0
    bar_width_mm: float = 3.0
    first_m: tuple = (-0.010, 0.020, -0.015)
    center_direction: tuple = (0.0, 0.0, -1.0)
    normal: tuple = (0.0, 1.0, 0.0)

    def check(self) -> None:
        for name in ("radius_mm", "span_deg", "width_mm", "thickness_mm", "wire_diameter_mm",
                     "stem_length_mm", "stem_width_mm", "bar_length_mm", "bar_width_mm"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"mirror parameter {name} must be positive, got {v!r}")
        if not 0 < self.span_deg < 360:
            raise ValueError(f"mirror parameter span_deg must be in (0, 360), got {self.span_deg!r}")
        if self.turns < 1:
            raise ValueError(f"mirror parameter turns must be >= 1, got {self.turns!r}")
        pitch = self.radius_mm * math.radians(self.span_deg) / max(self.turns - 1, 1)
        if self.turns > 1 and pitch < self.wire_diameter_mm:
            raise ValueError(f"{self.turns} turns of {self.wire_diameter_mm} mm wire do not fit on "
                             f"the arc (pitch {pitch:.3f} mm)")
        if self.stem_width_mm >= self.radius_mm * math.radians(self.span_deg):
            raise ValueError("mirror parameter stem_width_mm is wider than the arc")


def _frame(p: MirrorParams):
    to_c = np.asarray(p.center_direction, float)
    n = np.asarray(p.normal, float)
    to_c, n = to_c / np.linalg.norm(to_c), n / np.linalg.norm(n)
    if abs(to_c @ n) > 1e-6:
        raise ValueError("mirror: normal must be perpendicular to center_direction")
    u = -to_c
    return u, np.cross(n, u), n


def turn_positions_local_m(p: MirrorParams = MirrorParams()) -> np.ndarray:
    """(turns, 3) glint-source positions (m) in the scene frame before the group's pose:
    on the arc of the scene's ``arc`` group with the same ``first_m``, ``center_direction``
    and ``normal``, at radius R - d/2."""
    p.check()
    u, v, _ = _frame(p)
    r = p.radius_mm * 1e-3
    center = np.asarray(p.first_m, float) + r * (-u)
    a = math.radians(p.span_deg) * np.arange(p.turns) / max(p.turns - 1, 1)
    rho = (p.radius_mm - p.wire_diameter_mm / 2) * 1e-3
    return center + rho * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * v)


def mirror_outline_mm(p: MirrorParams = MirrorParams(), segments: int = 90) -> np.ndarray:
    """(n, 2) counter-clockwise outline of the part in the arc plane (mm, origin at the arc's
    centre, angle 0 at the first turn): the band R..R+t and the mount on its outside."""
    p.check()
    span = math.radians(p.span_deg)
    r_in, r_out = p.radius_mm, p.radius_mm + p.thickness_mm
    mid = span / 2
    half = p.stem_width_mm / 2
    # The stem leaves the outer face where its straight sides cross the outer circle.
    d = math.asin(min(half / r_out, 1.0))
    a_out = np.linspace(0, span, segments + 1)
    left = a_out[a_out < mid - d]
    right = a_out[a_out > mid + d]
    er = np.array([math.cos(mid), math.sin(mid)])
    et = np.array([-math.sin(mid), math.cos(mid)])
    base = r_out * math.cos(d)
    foot = base + p.stem_length_mm
    stem_and_bar = [base * er - half * et,
                    foot * er - half * et,
                    foot * er - p.bar_length_mm / 2 * et,
                    (foot + p.bar_width_mm) * er - p.bar_length_mm / 2 * et,
                    (foot + p.bar_width_mm) * er + p.bar_length_mm / 2 * et,
                    foot * er + p.bar_length_mm / 2 * et,
                    foot * er + half * et,
                    base * er + half * et]
    outer = ([r_out * np.array([math.cos(a), math.sin(a)]) for a in left] + stem_and_bar
             + [r_out * np.array([math.cos(a), math.sin(a)]) for a in right])
    inner = [r_in * np.array([math.cos(a), math.sin(a)]) for a in np.linspace(span, 0, segments + 1)]
    return np.array(outer + inner)


def _ear_clip(poly: np.ndarray) -> np.ndarray:
    """(n - 2, 3) triangles of a simple counter-clockwise polygon (ear clipping)."""
    idx = list(range(len(poly)))
    tris = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3:
        guard += 1
        if guard > 10 * len(poly) ** 2:
            raise ValueError("mirror outline is not a simple polygon")
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if cross(a, b, c) <= 1e-12:
                continue
            inside = False
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                q = poly[j]
                if cross(a, b, q) >= 0 and cross(b, c, q) >= 0 and cross(c, a, q) >= 0:
                    inside = True
                    break
            if not inside:
                tris.append((i0, i1, i2))
                del idx[k]
                break
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


#: The prototype scene's pose of the mirror group (scenes/prototype_ov5647.toml).
PROTOTYPE_POSE = {"pivot_m": [-0.010, 0.020, -0.015], "rotation_axis": [1.0, 0.0, 0.0],
                  "rotation_deg": -45.0}


def write_mirror(out_dir, p: MirrorParams = MirrorParams(), pose: dict | None = PROTOTYPE_POSE) -> dict:
    """Write ``mirror.stl`` (mm) and ``lights.toml`` into ``out_dir``; the paths."""
    out = Path(out_dir)
    mesh = mirror_mesh(p)
    with atomic_file(out / "mirror.stl") as tmp:
        mesh.export(tmp, file_type="stl")
    lights = atomic_write(out / "lights.toml", light_list_toml(p, pose))
    return {"stl": out / "mirror.stl", "lights": lights, "volume_mm3": float(mesh.volume)}
