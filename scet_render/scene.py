"""A Mitsuba 3 scene of one SCET :class:`~estimator.setup.Setup`: eye, lids, skin, lights, camera.

Geometry (SI units, world frame of the SCET paper's Fig. 3, eye in primary position looking -z):

* **cornea**: the sphere of radius r_c around the cornea centre (Sec. 2.1, Böhme's model), an
  exact analytic sphere by default (glints land where the closed form says); with
  ``cornea_geometry="mesh"`` a trimesh-built cap up to the limbus with radial vertex normals;
* **sclera**: an analytic sphere around the rotation centre through the limbus circle whose
  cap inside the limbus is cut away by an opacity mask (the sphere's polar texture coordinate
  is the angle from the gaze). The cornea protrudes from it, and the sclera hides the rest of
  the corneal sphere: only the cap in front of the limbus is ever seen;
* **iris** (an analytic disk in the limbus plane, of the limbus radius) and **pupil** (a dark
  disk 20 µm in front of it), seen through the cornea;
* **eyelids** (optional, static meshes): two pieces of a shell around the eye above and below
  elevation bands that ``eyelid_openness`` narrows; at 1 they clear the cornea, with 5 degrees
  to spare, for every gaze at the screen. **Skin**: a shell with a round opening around them,
  and a plane (the face) behind;
* **lights**: one small spherical area emitter per light (``LightGroup.source_radius_m``); a
  point light would be invisible in a mirror. **Ambient**: a constant near-IR environment;
* **camera**: a perspective sensor with the Setup's intrinsics (:func:`sensor_dict` is the one
  place where OpenCV's pixel-centre convention meets Mitsuba's film).

Every moving part of the eye is analytic, so a new pose rebuilds Embree's BVH over a few hundred
static triangles only (Mitsuba rebuilds every shape on any change, ~5 µs per triangle here) and
the kernels read the new transforms from opaque variables: nothing recompiles.

Channels: near-IR transport is monochrome, so the RGB variant's channels carry light groups.
With ``channels="split"`` (the renderer's choice) the strobe lights emit in R and the ambient
environment in G, and one render yields both the strobe-only and the ambient-only image. In that
mode the dielectric cornea transmits no strobe light: strobe light reaching the iris through the
cornea is a caustic that unidirectional path tracing samples as fireflies as bright as glints
(about one sample in a thousand), so the iris and pupil are lit by the ambient light only.
``channels="grey"`` renders everything white and physically complete (used for export).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.camera import Camera
from estimator.eye import eye_rotation_matrix
from estimator.setup import Setup

#: Strobe light source radiance and ambient environment radiance (W sr^-1 m^-2, near-IR).
#: With 40 lights of 0.2 mm at ~30 mm, skin and sclera under the strobe read ~1, a dielectric
#: glint ~25, and the ambient adds ~0.07 to them over a 1 ms exposure (see rolling_shutter).
DEFAULT_LIGHT_RADIANCE = 1000.0
DEFAULT_AMBIENT_RADIANCE = 0.01
#: Gap between the corneal apex sphere and the eyelid shell, and between lids and skin (m).
LID_CLEARANCE_M = 0.6e-3
SKIN_OVER_LID_M = 0.4e-3
#: Eyelid margin beyond the cornea at full openness (rad), and the pupil's offset in front of
#: the iris (m: far below a pixel, far above float32 rounding at 1 cm).
LID_MARGIN_RAD = math.radians(5.0)
PUPIL_OFFSET_M = 20e-6
#: The face plane (a 10 cm disk facing -z) lies this far behind the rotation centre (m), past
#: the rim of the skin shell (13 mm radius, out to 100 deg from the gaze: 2.3 mm behind).
FACE_BEHIND_CENTER_M = 3e-3
#: Mitsuba scene units per metre: scenes are built in centimetres. Mitsuba offsets every
#: spawned ray by ~9e-5 (1 + |p|) scene units to avoid self-intersection: 89 µm in metres,
#: which moves glints by 0.4 px at 1300 px focal length, but 2 µm (0.01 px) in centimetres.
#: Centimetres also keep the eye's sizes near 1, where float32 keeps Mitsuba's check of a
#: sphere's uniform scale (1e-6 absolute) quiet.
SCENE_UNITS_PER_M = 100.0
#: Mitsuba film pixel i covers [i, i + 1); OpenCV's pixel i is centred on i (DESIGN.md).
FILM_TO_OPENCV_PX = -0.5
#: Rows of the sclera's opacity mask over the polar angle 0..pi: 0.022 deg, 4 µm on the eyeball.
SCLERA_MASK_TEXELS = 8192
CORNEA_MODES = ("dielectric", "conductor")
CORNEA_GEOMETRIES = ("sphere", "mesh")
CHANNEL_MODES = ("split", "grey")
#: Scene parameters moved by :meth:`EyeScene.set_pose`.
MOVING_KEYS = ("cornea.to_world", "sclera.to_world", "iris.to_world", "pupil.to_world",
               "cornea.vertex_positions", "cornea.vertex_normals")


@dataclass(frozen=True, slots=True)
class SceneOptions:
    """Materials, lighting and geometry choices of a rendered scene (albedos are near-IR)."""

    cornea: str = "dielectric"
    cornea_geometry: str = "sphere"
    eyelid_openness: float | None = 1.0
    light_radiance: float = DEFAULT_LIGHT_RADIANCE
    ambient_radiance: float = DEFAULT_AMBIENT_RADIANCE
    channels: str = "split"
    pupil_radius_m: float = 2.0e-3
    sclera_albedo: float = 0.7
    iris_albedo: float = 0.3
    pupil_albedo: float = 0.02
    skin_albedo: float = 0.6
    max_depth: int = 6
    cornea_edge_m: float = 0.15e-3

    def __post_init__(self):
        for name, allowed in (("cornea", CORNEA_MODES), ("cornea_geometry", CORNEA_GEOMETRIES),
                              ("channels", CHANNEL_MODES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        o = self.eyelid_openness
        if o is not None and not (math.isfinite(o) and 0.0 <= o <= 1.0):
            raise ValueError(f"eyelid_openness must be None (no eyelids) or in [0, 1], got {o!r}")
        for name in ("light_radiance", "ambient_radiance"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        for name in ("sclera_albedo", "iris_albedo", "pupil_albedo", "skin_albedo"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)!r}")
        if not (self.pupil_radius_m > 0 and self.cornea_edge_m > 0 and self.max_depth >= 2):
            raise ValueError("pupil_radius_m and cornea_edge_m must be > 0 and max_depth >= 2")


@dataclass(frozen=True, slots=True)
class EyeLayout:
    """Derived eye dimensions (m, rad), all along the gaze axis from the rotation centre."""

    limbus_plane_m: float
    limbus_radius_m: float
    sclera_radius_m: float
    cap_angle_rad: float
    lid_radius_m: float
    skin_radius_m: float
    lid_upper_rad: float
    lid_lower_rad: float
    skin_hole_rad: float


def eye_layout(setup: Setup, options: SceneOptions = SceneOptions()) -> EyeLayout:
    """Sizes of the scene's eye parts, eyelid margins (elevations) and skin opening."""
    eye = setup.eye
    d_l = eye.cornea_offset_m + eye.cornea_radius_m - eye.limbus_depth_m
    r_l = eye.limbus_radius_m
    if d_l <= 0:
        raise ValueError(f"{setup.name}: the limbus plane lies behind the rotation centre "
                         f"(offset + radius - limbus depth = {d_l:.3g} m); no sclera fits")
    cap = math.atan2(r_l, d_l)  # angular radius of the cornea seen from the rotation centre
    lid_r = eye.cornea_offset_m + eye.cornea_radius_m + LID_CLEARANCE_M
    yaw, pitch = eye.angles_toward(setup.screen.grid(9, 9, margin=0.0))
    gaze_off_axis = np.arccos(np.clip(np.cos(yaw) * np.cos(pitch), -1.0, 1.0)).max()
    up_open = min(float(pitch.max()) + cap + LID_MARGIN_RAD, math.radians(80.0))
    low_open = max(float(pitch.min()) - cap - LID_MARGIN_RAD, math.radians(-80.0))
    o = 1.0 if options.eyelid_openness is None else options.eyelid_openness
    closed = 0.5 * (up_open + low_open)
    return EyeLayout(d_l, r_l, math.hypot(d_l, r_l), cap, lid_r, lid_r + SKIN_OVER_LID_M,
                     closed + o * (up_open - closed), closed + o * (low_open - closed),
                     min(float(gaze_off_axis) + cap + 2 * LID_MARGIN_RAD, math.radians(85.0)))


# --------------------------------------------------------------------------- meshes


def _ring_faces(counts: list[int]) -> np.ndarray:
    """Triangles joining consecutive closed rings of ``counts`` vertices (1 = a pole)."""
    faces, start = [], np.cumsum([0] + counts)
    for k in range(len(counts) - 1):
        a0, na, b0, nb = start[k], counts[k], start[k + 1], counts[k + 1]
        ea, eb = (na if na > 1 else 0), (nb if nb > 1 else 0)  # a pole takes no steps
        i = j = 0
        while i < ea or j < eb:
            if i < ea and (j >= eb or (i + 1) / ea <= (j + 1) / eb):
                faces.append((a0 + i % na, a0 + (i + 1) % na, b0 + j % nb))
                i += 1
            else:
                faces.append((a0 + i % na, b0 + (j + 1) % nb, b0 + j % nb))
                j += 1
    return np.asarray(faces, dtype=np.int64)


def _sphere_rings(center, radius, axis_frame, thetas, counts):
    """Vertices and outward normals on rings of polar angle ``thetas`` about frame[:, 2]."""
    pts = []
    for theta, n in zip(thetas, counts):
        phi = 2 * np.pi * np.arange(n) / n
        local = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                          np.full(n, np.cos(theta))], axis=-1)
        pts.append(local @ axis_frame.T)
    normals = np.concatenate(pts)
    return center + radius * normals, normals


def _trimesh(vertices, faces, normals):
    """A trimesh mesh whose faces wind like the given (outward) vertex normals."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, vertex_normals=normals, process=False)
    flip = np.einsum("ij,ij->i", mesh.face_normals, normals[faces].mean(axis=1)) < 0
    if flip.any():
        f = faces.copy()
        f[flip] = f[flip][:, ::-1]
        mesh = trimesh.Trimesh(vertices, f, vertex_normals=normals, process=False)
    return mesh


#: Frame whose third axis is the primary gaze -z (a proper rotation).
_GAZE_FRAME = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def cornea_mesh(setup: Setup, edge_m: float = 0.15e-3):
    """(trimesh.Trimesh) The corneal cap up to the limbus, primary position, radial normals.

    Vertex normals point exactly away from the cornea centre, so Mitsuba's interpolated
    shading normal at any surface point is the sphere's normal there; what remains of the
    tessellation is the facets' sagitta, below edge² / (8 r_c) (0.4 µm at 0.15 mm edges).
    """
    eye = setup.eye
    half = math.acos(eye.cap_cos_min)
    rings = max(2, math.ceil(half * eye.cornea_radius_m / edge_m))
    thetas = np.linspace(0.0, half, rings + 1)
    counts = [1] + [max(6, math.ceil(2 * np.pi * eye.cornea_radius_m * np.sin(t) / edge_m))
                    for t in thetas[1:]]
    center = eye.rotation_center_m + np.array([0.0, 0.0, -eye.cornea_offset_m])
    v, n = _sphere_rings(center, eye.cornea_radius_m, _GAZE_FRAME, thetas, counts)
    return _trimesh(v, _ring_faces(counts), n)


def _shell_grid(center, radius, az, el):
    """Vertices/normals/faces of a shell patch over an (az, el) grid, az about -z, el up."""
    A, E = np.meshgrid(az, el, indexing="ij")
    n = np.stack([np.cos(E) * np.sin(A), np.sin(E), -np.cos(E) * np.cos(A)], axis=-1)
    nu, nv = A.shape
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                            np.stack([a, c, d], -1).reshape(-1, 3)])
    n = n.reshape(-1, 3)
    return center + radius * n, n, faces


def eyelid_meshes(setup: Setup, layout: EyeLayout, n_az: int = 13, n_el: int = 5):
    """(upper, lower) trimesh meshes: shell pieces above and below the eyelid margins."""
    az = np.linspace(-math.radians(85.0), math.radians(85.0), n_az)
    top = math.radians(85.0)
    up = _shell_grid(setup.eye.rotation_center_m, layout.lid_radius_m, az,
                     np.linspace(layout.lid_upper_rad, top, n_el))
    low = _shell_grid(setup.eye.rotation_center_m, layout.lid_radius_m, az,
                      np.linspace(-top, layout.lid_lower_rad, n_el))
    return _trimesh(up[0], up[2], up[1]), _trimesh(low[0], low[2], low[1])


def skin_mesh(setup: Setup, layout: EyeLayout, az_count: int = 32):
    """(trimesh.Trimesh) The skin: a shell around -z from the opening out to 100 degrees."""
    thetas = np.linspace(layout.skin_hole_rad, math.radians(100.0), 4)
    counts = [az_count] * len(thetas)
    v, n = _sphere_rings(setup.eye.rotation_center_m, layout.skin_radius_m, _GAZE_FRAME,
                         thetas, counts)
    return _trimesh(v, _ring_faces(counts), n)


# --------------------------------------------------------------------------- transforms


def _affine(rotation=np.eye(3), translation=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = np.asarray(rotation) @ np.diag(scale)
    M[:3, 3] = translation
    return M


def sclera_opacity(layout: EyeLayout, texels: int = SCLERA_MASK_TEXELS) -> np.ndarray:
    """(texels, 2) float32 opacity of the sclera sphere over its polar texture coordinate.

    Mitsuba's sphere maps the angle θ from its local +z axis (the gaze) to v = θ / π.
    Transparent (0) inside the limbus, opaque (1) outside; the edge sits one texel inside the
    limbus, so no crack opens between sclera and cornea (the sliver hides behind the cornea).
    """
    theta = (np.arange(texels) + 0.5) * np.pi / texels
    opacity = (theta >= layout.cap_angle_rad - np.pi / texels).astype(np.float32)
    return np.repeat(opacity[:, None], 2, axis=1)


def _to_scene_units(M: np.ndarray) -> np.ndarray:
    """An object-to-world matrix in metres -> object-to-scene (scene units)."""
    return np.diag([SCENE_UNITS_PER_M] * 3 + [1.0]) @ M


def eye_part_transforms(setup: Setup, layout: EyeLayout, yaw_rad: float, pitch_rad: float,
                        pupil_radius_m: float) -> dict[str, np.ndarray]:
    """(4, 4) object-to-scene matrices (scene units) of the analytic eye parts at a pose.

    ``cornea``: unit sphere to the corneal sphere. ``sclera``: unit sphere to the eyeball, its
    local +z along the gaze. ``iris``/``pupil``: Mitsuba's unit disk (normal +z) to disks facing
    the cornea in the limbus plane (the pupil 20 µm in front).
    """
    R = eye_rotation_matrix(yaw_rad, pitch_rad)
    c_e = setup.eye.rotation_center_m
    gaze = R @ np.array([0.0, 0.0, -1.0])
    face = R @ _GAZE_FRAME  # local +z along the gaze
    r_c, r_s = setup.eye.cornea_radius_m, layout.sclera_radius_m
    r_iris = layout.limbus_radius_m * 1.002  # reaches under the sclera's mask edge
    metres = {
        "cornea": _affine(translation=setup.eye.cornea_center(yaw_rad, pitch_rad),
                          scale=(r_c, r_c, r_c)),
        "sclera": _affine(face, c_e, (r_s, r_s, r_s)),
        "iris": _affine(face, c_e + layout.limbus_plane_m * gaze, (r_iris, r_iris, 1.0)),
        "pupil": _affine(face, c_e + (layout.limbus_plane_m + PUPIL_OFFSET_M) * gaze,
                         (pupil_radius_m, pupil_radius_m, 1.0)),
    }
    return {name: _to_scene_units(M) for name, M in metres.items()}


def sensor_dict(camera: Camera, spp: int = 16) -> dict:
    """Mitsuba ``perspective`` sensor with the camera's exact intrinsics and pose.

    The single conversion between conventions (DESIGN.md): OpenCV pixel (u, v) is Mitsuba film
    position (u + 0.5, v + 0.5); Mitsuba's camera frame is OpenCV's with x and y negated (x
    left, y up, z forward). Mitsuba models square pixels only, so fx must equal fy.

    Raises
    ------
    ValueError
        When fx != fy (to 1e-9 relative).
    """
    if abs(camera.fx_px - camera.fy_px) > 1e-9 * camera.fx_px:
        raise ValueError(f"Mitsuba's perspective sensor needs square pixels; got fx = "
                         f"{camera.fx_px} px, fy = {camera.fy_px} px")
    W, H = camera.width_px, camera.height_px
    # Principal point in normalised film coordinates, measured from the film centre.
    film_cx = (camera.cx_px - FILM_TO_OPENCV_PX) / W
    film_cy = (camera.cy_px - FILM_TO_OPENCV_PX) / H
    to_world = np.eye(4)
    to_world[:3, 0] = -camera.rotation[0]
    to_world[:3, 1] = -camera.rotation[1]
    to_world[:3, 2] = camera.rotation[2]
    to_world[:3, 3] = camera.position_m * SCENE_UNITS_PER_M
    return {
        "type": "perspective", "fov_axis": "x",
        "fov": math.degrees(2.0 * math.atan(W / (2.0 * camera.fx_px))),
        "principal_point_offset_x": 0.5 - film_cx, "principal_point_offset_y": 0.5 - film_cy,
        "near_clip": 1e-4 * SCENE_UNITS_PER_M, "far_clip": 100.0 * SCENE_UNITS_PER_M,
        "to_world": to_world,
        "sampler": {"type": "independent", "sample_count": int(spp)},
        "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"},
                 "pixel_format": "rgb", "component_format": "float32"},
    }


# --------------------------------------------------------------------------- description


def _rgb(values) -> dict:
    return {"type": "rgb", "value": [float(v) for v in values]}


def _diffuse(albedo: float, twosided: bool = False) -> dict:
    bsdf = {"type": "diffuse", "reflectance": _rgb([albedo] * 3)}
    return {"type": "twosided", "bsdf": bsdf} if twosided else bsdf


def _cornea_bsdf(setup: Setup, options: SceneOptions) -> dict:
    n = setup.eye.refractive_index
    if options.cornea == "conductor":
        # A mirror scaled by the normal-incidence Fresnel reflectance: exact glint geometry
        # from every sample (a dielectric reflects only ~2.5 % of them).
        f0 = ((n - 1.0) / (n + 1.0)) ** 2
        return {"type": "conductor", "material": "none", "specular_reflectance": _rgb([f0] * 3)}
    transmit = (0.0, 1.0, 1.0) if options.channels == "split" else (1.0, 1.0, 1.0)
    return {"type": "dielectric", "int_ior": n, "ext_ior": 1.0,
            "specular_transmittance": _rgb(transmit)}


@dataclass(frozen=True, slots=True)
class SceneDescription:
    """A scene as plain data.

    Lengths are in scene units (centimetres, :data:`SCENE_UNITS_PER_M`). ``objects`` is in
    Mitsuba's dict layout with (4, 4) numpy transforms; every
    ``{"type": "ply", "filename": "meshes/<id>.ply"}`` has its trimesh mesh in ``meshes[<id>]``
    and every ``{"type": "bitmap", "filename": "textures/<id>.png"}`` its (rows, cols) array in
    ``textures[<id>]``.
    """

    objects: dict
    meshes: dict
    textures: dict
    layout: EyeLayout


def describe_scene(setup: Setup, options: SceneOptions = SceneOptions(), *, spp: int = 16,
                   yaw_rad: float = 0.0, pitch_rad: float = 0.0) -> SceneDescription:
    """The scene of a Setup with the eye at a pose (see the module docstring)."""
    layout = eye_layout(setup, options)
    split = options.channels == "split"
    T = eye_part_transforms(setup, layout, yaw_rad, pitch_rad, options.pupil_radius_m)
    cornea_bsdf = _cornea_bsdf(setup, options)
    objects = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(options.max_depth)},
        "camera": sensor_dict(setup.camera, spp),
        "sclera": {"type": "sphere", "to_world": T["sclera"], "bsdf": {
            "type": "mask", "bsdf": _diffuse(options.sclera_albedo),
            "opacity": {"type": "bitmap", "filename": "textures/sclera_opacity.png", "raw": True,
                        "filter_type": "nearest"}}},
        "iris": {"type": "disk", "to_world": T["iris"], "bsdf": _diffuse(options.iris_albedo)},
        "pupil": {"type": "disk", "to_world": T["pupil"], "bsdf": _diffuse(options.pupil_albedo)},
    }
    # The face beyond the skin shell: a plane just behind the shell's rim, facing the camera.
    face_at = setup.eye.rotation_center_m + np.array([0.0, 0.0, FACE_BEHIND_CENTER_M])
    objects["face"] = {"type": "disk",
                       "to_world": _to_scene_units(_affine(_GAZE_FRAME, face_at, (0.1, 0.1, 1.0))),
                       "bsdf": _diffuse(options.skin_albedo, twosided=True)}
    meshes = {"skin": skin_mesh(setup, layout)}
    if options.eyelid_openness is not None:
        meshes["lid_upper"], meshes["lid_lower"] = eyelid_meshes(setup, layout)
    for name in meshes:
        objects[name] = {"type": "ply", "filename": f"meshes/{name}.ply", "face_normals": False,
                         "bsdf": _diffuse(options.skin_albedo, twosided=True)}
    if options.cornea_geometry == "mesh":
        mesh = cornea_mesh(setup, options.cornea_edge_m)
        R = eye_rotation_matrix(yaw_rad, pitch_rad)
        c_e = setup.eye.rotation_center_m
        meshes["cornea"] = _trimesh((mesh.vertices - c_e) @ R.T + c_e, mesh.faces,
                                    np.asarray(mesh.vertex_normals) @ R.T)
        objects["cornea"] = {"type": "ply", "filename": "meshes/cornea.ply",
                             "face_normals": False, "bsdf": cornea_bsdf}
    else:
        objects["cornea"] = {"type": "sphere", "to_world": T["cornea"], "bsdf": cornea_bsdf}
    L = options.light_radiance
    radii = [g.source_radius_m for g in setup.lights.groups for _ in range(g.count)]
    for i, (radius, p) in enumerate(zip(radii, setup.lights_world_m)):
        objects[f"light_{i:03d}"] = {
            "type": "sphere", "center": [float(c * SCENE_UNITS_PER_M) for c in p],
            "radius": float(radius * SCENE_UNITS_PER_M),
            "emitter": {"type": "area", "radiance": _rgb((L, 0, 0) if split else (L, L, L))}}
    A = options.ambient_radiance
    if A > 0:
        objects["ambient"] = {"type": "constant",
                              "radiance": _rgb((0, A, 0) if split else (A, A, A))}
    for mesh in meshes.values():
        mesh.apply_scale(SCENE_UNITS_PER_M)
    return SceneDescription(objects, meshes, {"sclera_opacity": sclera_opacity(layout)}, layout)


# --------------------------------------------------------------------------- loading


def _to_mitsuba(value, mi, desc: SceneDescription, name: str = ""):
    """Plain description -> ``mi.load_dict`` input (transforms, in-memory meshes, textures)."""
    if isinstance(value, np.ndarray) and value.shape == (4, 4):
        return mi.ScalarTransform4f(value)
    if not isinstance(value, dict):
        return value
    kind = value.get("type")
    if kind == "bitmap":
        data = desc.textures[Path(value["filename"]).stem]
        rest = {k: v for k, v in value.items() if k != "filename"}
        return {**rest, "data": mi.TensorXf(np.ascontiguousarray(data[..., None]))}
    if kind == "ply":
        m = desc.meshes[name]
        props = mi.Properties()
        props["bsdf"] = mi.load_dict(_to_mitsuba(value["bsdf"], mi, desc))
        mesh = mi.Mesh(name, len(m.vertices), len(m.faces), props=props, has_vertex_normals=True)
        p = mi.traverse(mesh)
        # Buffer types differ between variants (Float vs ArrayXf): reuse the mesh's own.
        for key, data, dtype in (("vertex_positions", m.vertices, np.float32),
                                 ("faces", m.faces, np.uint32),
                                 ("vertex_normals", m.vertex_normals, np.float32)):
            p[key] = type(p[key])(np.asarray(data, dtype).ravel())
        p.update()
        return mesh
    return {k: _to_mitsuba(v, mi, desc, k) for k, v in value.items()}


class EyeScene:
    """A loaded Mitsuba scene whose eye moves by Fick angles without recompiling kernels.

    The Mitsuba scene is in centimetres (:data:`SCENE_UNITS_PER_M`); radiance does not depend
    on the unit of length, so images are those of the metre-scale Setup.

    Parameters
    ----------
    setup : Setup
    options : SceneOptions
    spp : int
        Samples per pixel of the scene's sensor (the default of ``mi.render``).
    mi : module, optional
        The ``mitsuba`` module with a variant set; default :func:`scet_render.backend.activate`.

    Attributes
    ----------
    scene, sensor, integrator
        Mitsuba objects.
    layout : EyeLayout
    pose : (float, float)
        Current (yaw_rad, pitch_rad).
    """

    def __init__(self, setup: Setup, options: SceneOptions = SceneOptions(), *, spp: int = 16,
                 mi=None):
        if mi is None:
            from .backend import activate

            mi = activate()
        self.mi, self.setup, self.options = mi, setup, options
        desc = describe_scene(setup, options, spp=spp)
        self.layout = desc.layout
        self.scene = mi.load_dict(_to_mitsuba(desc.objects, mi, desc))
        self.sensor = self.scene.sensors()[0]
        self.integrator = self.scene.integrator()
        params = mi.traverse(self.scene)
        params.keep([k for k in MOVING_KEYS if k in params])
        self._params = params
        mesh = desc.meshes.get("cornea")
        self._center = setup.eye.rotation_center_m * SCENE_UNITS_PER_M
        self._cornea_rest = None if mesh is None else (
            mesh.vertices - self._center, np.asarray(mesh.vertex_normals))
        # Write the primary pose once through set_pose, so that every pose's parameters come
        # from the same code path (the loaded ones differ in the last float32 bit).
        self.pose = (math.nan, math.nan)
        self.set_pose(0.0, 0.0)

    def set_pose(self, yaw_rad: float, pitch_rad: float) -> bool:
        """Move cornea, sclera, iris and pupil to an eye pose; False when nothing changed."""
        pose = (float(yaw_rad), float(pitch_rad))
        if not all(math.isfinite(a) for a in pose):
            raise ValueError(f"eye pose must be finite, got {pose}")
        if pose == self.pose:
            return False
        mi, p = self.mi, self._params
        T = eye_part_transforms(self.setup, self.layout, *pose, self.options.pupil_radius_m)
        for name, M in T.items():
            if f"{name}.to_world" in p:
                p[f"{name}.to_world"] = mi.ScalarTransform4f(M)
        if self._cornea_rest is not None:
            R = eye_rotation_matrix(*pose)
            v, n = self._cornea_rest
            v_world = v @ R.T + self._center
            for key, data in (("cornea.vertex_positions", v_world), ("cornea.vertex_normals",
                                                                     n @ R.T)):
                p[key] = type(p[key])(np.asarray(data, np.float32).ravel())
        p.update()
        self.pose = pose
        return True


# --------------------------------------------------------------------------- export


_TAGS = {"scene": "scene", "path": "integrator", "perspective": "sensor", "independent": "sampler",
         "hdrfilm": "film", "box": "rfilter", "disk": "shape", "sphere": "shape", "ply": "shape",
         "diffuse": "bsdf", "twosided": "bsdf", "dielectric": "bsdf", "conductor": "bsdf",
         "mask": "bsdf", "bitmap": "texture", "area": "emitter", "constant": "emitter"}


def _xml_node(parent, key, value):
    if isinstance(value, dict) and value.get("type") == "rgb":
        ET.SubElement(parent, "rgb", name=key, value=", ".join(f"{v:.9g}" for v in value["value"]))
    elif isinstance(value, dict):
        node = ET.SubElement(parent, _TAGS[value["type"]], type=value["type"], id=key)
        if _TAGS[value["type"]] == "texture":
            node.attrib["name"] = node.attrib.pop("id")  # the parameter it feeds
        elif _TAGS[value["type"]] != "shape":
            del node.attrib["id"]
        for k, v in value.items():
            if k != "type":
                _xml_node(node, k, v)
    elif isinstance(value, np.ndarray):
        t = ET.SubElement(parent, "transform", name=key)
        ET.SubElement(t, "matrix", value=" ".join(f"{v:.17g}" for v in value.ravel()))
    elif isinstance(value, bool):
        ET.SubElement(parent, "boolean", name=key, value=str(value).lower())
    elif isinstance(value, int):
        ET.SubElement(parent, "integer", name=key, value=str(value))
    elif isinstance(value, float):
        ET.SubElement(parent, "float", name=key, value=f"{value:.17g}")
    elif isinstance(value, str):
        ET.SubElement(parent, "string", name=key, value=value)
    elif isinstance(value, list) and len(value) == 3:
        ET.SubElement(parent, "point", name=key, **{a: f"{v:.17g}" for a, v in zip("xyz", value)})
    else:
        raise ValueError(f"cannot write scene entry {key!r} = {value!r} as Mitsuba XML")


def export_mitsuba(setup: Setup, out_dir: str | Path, options: SceneOptions | None = None, *,
                   yaw_rad: float = 0.0, pitch_rad: float = 0.0, spp: int = 64) -> Path:
    """Write ``scene.xml``, ``meshes/*.ply`` and ``textures/*.png`` that ``mitsuba scene.xml``
    renders unchanged.

    Parameters
    ----------
    setup : Setup
    out_dir : path
        Created if needed; existing files of the same names are replaced.
    options : SceneOptions, optional
        Default: the renderer's defaults with ``channels="grey"`` (white lights and ambient).
    yaw_rad, pitch_rad : float
        Eye pose.
    spp : int
        Samples per pixel written into the sensor.

    Returns
    -------
    Path
        The XML file.
    """
    options = SceneOptions(channels="grey") if options is None else options
    desc = describe_scene(setup, options, spp=spp, yaw_rad=yaw_rad, pitch_rad=pitch_rad)
    import cv2

    out = Path(out_dir)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    (out / "textures").mkdir(parents=True, exist_ok=True)
    for name, mesh in desc.meshes.items():
        mesh.export(out / "meshes" / f"{name}.ply", encoding="binary", vertex_normal=True)
    for name, data in desc.textures.items():
        # 8-bit is exact for a 0/1 mask; "raw" keeps Mitsuba from linearising it as sRGB.
        if not cv2.imwrite(str(out / "textures" / f"{name}.png"),
                           np.round(np.clip(data, 0, 1) * 255).astype(np.uint8)):
            raise OSError(f"cannot write {out / 'textures' / f'{name}.png'}")
    root = ET.Element("scene", version="3.0.0")
    for key, value in desc.objects.items():
        if key != "type":
            _xml_node(root, key, value)
    ET.indent(root)
    path = out / "scene.xml"
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(f"<!-- SCET scene {setup.name}: yaw {yaw_rad:.9g} rad, pitch {pitch_rad:.9g}"
                   f" rad -->\n" + ET.tostring(root, encoding="unicode") + "\n")
    tmp.replace(path)
    return path
