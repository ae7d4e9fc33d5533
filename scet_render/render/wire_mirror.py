"""The wire-wound mirror in a Mitsuba scene: the printed strip, the wire turns and the LED
(a ``kind = "wire_mirror"`` light group, :class:`estimator.geometry.wire_model.WireMirror`).

* **Strip**: a diffuse mesh of the band (inner face at R, outer at R + t, ±w/2 along the arc
  normal) over its angular extent (:attr:`WireMirror.strip_angles_rad`), 720 segments: the
  inner face's chords sag 0.1 µm inside the circle, under the wire it carries.
* **Wire turns**: each turn's stretch on the inner face as Mitsuba's analytic ``cylinder``
  (``p0``, ``p1``, ``radius``; open, no caps) from edge to edge of the strip: exactly the
  solver's cylinder. The rest of the turn, round the strip's edges, along its sides and back
  over its outer face, is :func:`wire_bend_mesh` (a tube mesh of the wire's centreline: the
  strip's cross-section offset by the wire's radius, quarter circles of radius d/2 round each
  corner); drawn only with ``bends=True``, since the solver labels a highlight that would sit
  on a bend not visible, so a render with them shows light the labels do not hold.
* **Wire material**: Mitsuba 3 has no layered coating BSDF, so the enamel over copper is a
  smooth ``conductor`` with copper's complex index at 850 nm (0.277 + 5.449i,
  :data:`~estimator.geometry.wire_model.COPPER_INDEX_850NM`) and ``specular_reflectance``
  scaled to the enamelled wire's normal-incidence reflectance (0.948 / 0.965 = 0.983,
  :func:`~estimator.geometry.wire_model.enamelled_copper_reflectance`): within 1.3 % of the
  layered model up to 70 deg incidence and 1.8 % at 85 deg. The enamel's own highlight
  sits on its outer surface, tens of µm from copper's: below 0.01 px after the cornea's 0.13x.
* **LED**: a disk area emitter of ``led_diameter_m`` facing ``led_aim``. An area emitter's
  radiance is constant, so its radiant intensity is I(θ) = L A cos θ: the cos^1 lobe, i.e. the
  datasheet pattern of a ±60 deg half-intensity LED (the default, Vishay VSMY1850). Other
  lobes are refused (:func:`wire_mirror_objects` raises) rather than drawn wrong.

The group's point lights are not drawn: the glints come from the LED through the wire. Light
from the LED reaching the iris through the cornea (MNEE) still uses the scene's light list,
the point-source model's turns.
"""

from __future__ import annotations

import numpy as np

from estimator.geometry.wire_model import (
    COPPER_INDEX_850NM,
    WireMirror,
    enamelled_copper_reflectance,
    fresnel_unpolarized,
)

from .layout import SCENE_UNITS_PER_M

#: Segments of the strip's mesh over its arc (module docstring: the chords' sag).
STRIP_SEGMENTS = 720
#: The LED's cos^m lobe exponent must be 1 within this to be drawn by an area emitter.
LAMBERTIAN_TOL = 0.02


def wire_reflectance_scale() -> float:
    """Enamelled copper's normal-incidence reflectance over bare copper's (0.983)."""
    return float(enamelled_copper_reflectance(1.0) / fresnel_unpolarized(1.0, 1.0, COPPER_INDEX_850NM))


def strip_mesh(mirror: WireMirror, segments: int = STRIP_SEGMENTS):
    """The strip as a closed ``trimesh.Trimesh`` in metres (world frame of ``mirror``)."""
    import trimesh

    lo, hi = mirror.strip_angles_rad
    a = np.linspace(lo, hi, segments + 1)
    radial = np.cos(a)[:, None] * mirror.u + np.sin(a)[:, None] * mirror.v  # (k, 3)
    hw = 0.5 * mirror.width_m
    rings = []  # inner-low, inner-high, outer-high, outer-low: a loop round the cross-section
    for r, z in ((mirror.radius_m, -hw), (mirror.radius_m, hw),
                 (mirror.radius_m + mirror.thickness_m, hw), (mirror.radius_m + mirror.thickness_m, -hw)):
        rings.append(mirror.center_m + r * radial + z * mirror.normal)
    k = a.size
    verts = np.concatenate(rings)  # ring j, sample i -> j * k + i
    faces = []
    for j in range(4):
        j2 = (j + 1) % 4
        i = np.arange(k - 1)
        p, q = j * k + i, j2 * k + i
        faces.append(np.c_[p, p + 1, q + 1])
        faces.append(np.c_[p, q + 1, q])
    # End caps (two triangles each).
    for i in (0, k - 1):
        ids = [j * k + i for j in range(4)]
        cap = np.array([[ids[0], ids[2], ids[1]], [ids[0], ids[3], ids[2]]])
        faces.append(cap if i == 0 else cap[:, ::-1])
    # Winding is not fixed here: the strip's BSDF is two-sided.
    return trimesh.Trimesh(verts, np.concatenate(faces), process=True)


#: Samples per quarter bend and round the wire's circumference of :func:`wire_bend_mesh`:
#: the tube's chords sag d/2 (1 - cos(pi / 24)) = 3.4 um round a 0.8 mm wire.
BEND_SEGMENTS = 12
TUBE_SEGMENTS = 24


def wire_turn_path_m(mirror: WireMirror, turn: int, bend_segments: int = BEND_SEGMENTS) -> np.ndarray:
    """(k, 3) the centreline of turn ``turn`` off the inner face: from the inner stretch's end at
    +w/2 round the strip's edge, over the side, round the outer corner, back along the outer
    face, round the other edges, to the inner stretch's end at -w/2 (world frame of
    ``mirror``). In the plane of the turn's radial direction and the arc's normal."""
    radial = mirror.radial[turn]
    rw, hw = mirror.wire_radius_m, 0.5 * mirror.width_m
    r_in, r_out = mirror.radius_m, mirror.radius_m + mirror.thickness_m
    q = np.linspace(0.0, 0.5 * np.pi, bend_segments + 1)
    # (radius from the arc's axis, position along the normal) of the path, corner by corner:
    # each corner of the strip's rectangular cross-section, the centreline a quarter circle of
    # radius d/2 about it, turning outward.
    corners = [((r_in, hw), np.pi, 0.5 * np.pi), ((r_out, hw), 0.5 * np.pi, 0.0),
               ((r_out, -hw), 0.0, -0.5 * np.pi), ((r_in, -hw), -0.5 * np.pi, -np.pi)]
    pts = []
    for (c_r, c_z), a0, a1 in corners:
        a = a0 + (a1 - a0) * q / q[-1]
        pts.append(np.c_[c_r + rw * np.cos(a), c_z + rw * np.sin(a)])
    rz = np.concatenate(pts)
    return mirror.center_m + rz[:, :1] * radial + rz[:, 1:] * mirror.normal


def _tube(path: np.ndarray, radius: float, segments: int):
    """(vertices, faces) of an open tube of ``radius`` round the polyline ``path`` (k, 3): a
    ring of ``segments`` vertices at each point, normal to the path's mean tangent there."""
    t = np.gradient(path, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    # A frame carried along the path (the path is planar: its plane's normal serves throughout).
    n_plane = np.cross(path[1] - path[0], path[-1] - path[0])
    if np.linalg.norm(n_plane) < 1e-15:
        n_plane = np.cross(t[0], [1.0, 0.0, 0.0] if abs(t[0][0]) < 0.9 else [0.0, 1.0, 0.0])
    n_plane /= np.linalg.norm(n_plane)
    b = np.cross(t, n_plane)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    phi = 2 * np.pi * np.arange(segments) / segments
    verts = (path[:, None, :] + radius * (np.cos(phi)[None, :, None] * n_plane
                                          + np.sin(phi)[None, :, None] * b[:, None, :]))
    k = path.shape[0]
    i, j = np.meshgrid(np.arange(k - 1), np.arange(segments), indexing="ij")
    a = i * segments + j
    c = i * segments + (j + 1) % segments
    faces = np.concatenate([np.stack([a, c, a + segments], -1).reshape(-1, 3),
                            np.stack([c, c + segments, a + segments], -1).reshape(-1, 3)])
    return verts.reshape(-1, 3), faces


def wire_bend_mesh(mirror: WireMirror, bend_segments: int = BEND_SEGMENTS,
                   tube_segments: int = TUBE_SEGMENTS):
    """Every turn's wire off the inner face (:func:`wire_turn_path_m`) as one
    ``trimesh.Trimesh`` (metres, world frame of ``mirror``): open tubes that meet the inner
    stretch's analytic cylinder at its end circles."""
    import trimesh

    verts, faces, n = [], [], 0
    for k in range(mirror.turns):
        v, f = _tube(wire_turn_path_m(mirror, k, bend_segments), mirror.wire_radius_m, tube_segments)
        verts.append(v)
        faces.append(f + n)
        n += v.shape[0]
    return trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)


def _point(p) -> list:
    return [float(c * SCENE_UNITS_PER_M) for c in p]


def _led_to_world(mirror: WireMirror) -> np.ndarray:
    """4x4 scene-units transform of Mitsuba's unit disk (normal +z) onto the LED."""
    z = mirror.led_aim / np.linalg.norm(mirror.led_aim)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = 0.5 * mirror.led_diameter_m * SCENE_UNITS_PER_M
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x * r, y * r, z * r
    T[:3, 3] = np.asarray(mirror.led_position_m) * SCENE_UNITS_PER_M
    return T


def wire_mirror_objects(mirror: WireMirror, name: str, *, radiance: float, split: bool,
                        strip_albedo: float = 0.5, bends: bool = False) -> tuple[dict, dict]:
    """Mitsuba scene entries for one wire mirror (world frame).

    Parameters
    ----------
    mirror : WireMirror
        In the world frame (``group.emitter.posed(group.pose)``).
    name : str
        Prefix of the entries' names.
    radiance : float
        The LED's radiance (W sr⁻¹ m⁻²), in the strobe channel (R) when ``split``.
    split : bool
        The renderer's split channels (strobe light in R).
    strip_albedo : float
        The printed strip's near-IR albedo (a light PLA/PETG print: ~0.5 [G]).
    bends : bool
        Also draw the wire round the strip's edges and over its outer face
        (:func:`wire_bend_mesh`, ``<name>_bends``, the wire's material).

    Returns
    -------
    objects : dict
        Scene entries (plain dicts; the strip as a ``ply`` entry named ``<name>_strip``).
    meshes : dict
        ``{"<name>_strip": trimesh.Trimesh}`` in metres.
    """
    m = mirror.beam.exponent
    if abs(m - 1.0) > LAMBERTIAN_TOL:
        raise ValueError(f"{name}: the renderer draws the LED as an area emitter, a cos^1 lobe "
                         f"(half-intensity angle 60 deg); this LED's lobe is cos^{m:.3g}")
    L = float(radiance)
    rgb = (L, 0.0, 0.0) if split else (L, L, L)
    eta, k = COPPER_INDEX_850NM.real, COPPER_INDEX_850NM.imag
    scale = wire_reflectance_scale()
    wire_bsdf = {"type": "conductor",
                 "eta": {"type": "rgb", "value": [eta, eta, eta]},
                 "k": {"type": "rgb", "value": [k, k, k]},
                 "specular_reflectance": {"type": "rgb", "value": [scale, scale, scale]}}
    objects = {}
    hw = 0.5 * mirror.width_m
    for i, axis in enumerate(mirror.wire_axes_m):
        objects[f"{name}_turn_{i:03d}"] = {
            "type": "cylinder", "p0": _point(axis - hw * mirror.normal),
            "p1": _point(axis + hw * mirror.normal),
            "radius": float(mirror.wire_radius_m * SCENE_UNITS_PER_M), "bsdf": wire_bsdf}
    objects[f"{name}_led"] = {"type": "disk", "to_world": _led_to_world(mirror),
                              "emitter": {"type": "area",
                                          "radiance": {"type": "rgb", "value": list(rgb)}}}
    strip = f"{name}_strip"
    objects[strip] = {"type": "ply", "filename": f"meshes/{strip}.ply", "face_normals": False,
                      "bsdf": {"type": "twosided", "bsdf": {
                          "type": "diffuse", "reflectance": {"type": "rgb", "value": [strip_albedo] * 3}}}}
    meshes = {strip: strip_mesh(mirror)}
    if bends:
        objects[f"{name}_bends"] = {"type": "ply", "filename": f"meshes/{name}_bends.ply",
                                    "face_normals": False, "bsdf": wire_bsdf}
        meshes[f"{name}_bends"] = wire_bend_mesh(mirror)
    return objects, meshes


__all__ = ["wire_mirror_objects", "strip_mesh", "wire_bend_mesh", "wire_turn_path_m",
           "wire_reflectance_scale", "STRIP_SEGMENTS", "BEND_SEGMENTS", "TUBE_SEGMENTS"]
