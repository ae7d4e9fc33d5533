"""A Mitsuba 3 scene of one SCET :class:`~estimator.setup.Setup`: eye, lids, skin, lights, camera.

Geometry (SI units, world frame of the SCET paper's Fig. 3, eye in primary position looking -z):

* **cornea**: the sphere of radius r_c around the cornea centre (Sec. 2.1, Böhme's model), an
  exact analytic sphere by default (glints land where the closed form says); with
  ``cornea_geometry="mesh"`` a trimesh-built cap up to the limbus with radial vertex normals.
  An aspheric cornea (``cornea_asphericity`` Q != 0) is the conic's exact ellipsoid: a unit
  sphere in a shapegroup whose instance's ``to_world`` scales it (it moves like the sphere,
  without recompiling), masked transparent beyond the limbus (:func:`cornea_opacity`); its
  glints land where :func:`estimator.geometry.project_glints_conic` says;
* **sclera**: an analytic sphere around the rotation centre through the limbus circle whose
  cap inside the limbus is cut away by an opacity mask (the sphere's polar texture coordinate
  is the angle from the gaze). The cornea protrudes from it, and the sclera hides the rest of
  the corneal sphere: only the cap in front of the limbus is ever seen;
* **iris** (an analytic disk in the limbus plane, of the limbus radius) and **pupil** (a dark
  disk 20 µm in front of it), seen through the cornea;
* **eyelids** (optional, static meshes): two pieces of a shell around the eye above and below
  elevation bands that ``eyelid_openness`` narrows; at 1 they clear the cornea, with 5 degrees
  to spare, for every gaze at the screen. A Setup with ``eyelids`` gets lids that follow the
  eye's pitch, blink and carry lashes instead: meshes in shapegroups whose instances move
  (:mod:`~scet_render.render.lids`). **Skin**: a shell with a round opening around them, and a
  plane (the face) behind;
* **lights**: one small spherical area emitter per light (``LightGroup.source_radius_m``); a
  point light would be invisible in a mirror. **Ambient**: a constant near-IR environment;
* **appearance**: the iris, sclera and skin (shell, lids, face) reflect by seeded near-IR
  textures of the scene's ``[appearance]`` table (:mod:`~scet_render.render.textures`; the
  skin meshes carry planar texture coordinates), or by uniform albedos with
  ``textured = false``;
* **camera**: a perspective sensor with the Setup's intrinsics (:func:`sensor_dict` is the one
  place where OpenCV's pixel-centre convention meets Mitsuba's film).

Every moving part of the eye is analytic, so a new pose rebuilds Embree's BVH over a few hundred
static triangles only (Mitsuba rebuilds every shape on any change, ~5 µs per triangle here) and
the kernels read the new transforms from opaque variables: nothing recompiles.

Channels: near-IR transport is monochrome, so the RGB variant's channels carry light groups.
With ``channels="split"`` (the renderer's choice) the strobe lights emit in R and the ambient
environment in G, and one render yields both the strobe-only and the ambient-only image. In that
mode the path tracer carries no strobe light through the cornea (its strobe transmittance is 0):
strobe light reaching the iris through the cornea is a caustic that unidirectional path tracing
samples as fireflies as bright as glints (about one sample in a thousand). Manifold next-event
estimation adds it back exactly (:mod:`~scet_render.render.mnee`, ``strobe_through_cornea``).
``channels="grey"`` renders everything white and physically complete (used for export).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.eye import eye_rotation_matrix
from estimator.geometry import Camera
from estimator.geometry.wire import setup_wire_mirrors
from estimator.setup import Setup

from .cornea_bsdf import CORNEA_BSDF_TYPE, REFLECT_PROBABILITY, register_cornea_bsdf
from .layout import (
    FACE_BEHIND_CENTER_M,
    FILM_TO_OPENCV_PX,
    IRIS_OVERLAP,
    MOVING_KEYS,
    SCENE_UNITS_PER_M,
    EyeLayout,
    SceneOptions,
    eye_layout,
    pupil_radius,
)
from .lids import LASH_ALBEDO, LID_MOVING_KEYS, lash_mesh, lid_transforms, moving_lid_meshes
from .meshes import (
    _trimesh,
    cornea_mesh,
    cornea_opacity,
    eye_part_transforms,
    eyelid_meshes,
    sclera_opacity,
    skin_mesh,
)
from .mnee import light_table, mnee_radiance, pose_state, to_drjit
from .mnee_kernels import mnee_integrator
from .textures import (
    albedo_bitmap,
    cached_texture,
    iris_texture,
    scene_appearance,
    sclera_texture,
    skin_texture,
    skin_uv,
)
from .wire_mirror import wire_mirror_objects

log = logging.getLogger(__name__)


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


def _diffuse(albedo, twosided: bool = False) -> dict:
    """A diffuse BSDF of a uniform albedo, or of a texture's (a ``bitmap`` entry)."""
    reflectance = albedo if isinstance(albedo, dict) else _rgb([albedo] * 3)
    bsdf = {"type": "diffuse", "reflectance": reflectance}
    return {"type": "twosided", "bsdf": bsdf} if twosided else bsdf


def _with_uv(mesh, setup: Setup):
    """``mesh`` with the skin's planar texture coordinates (:func:`textures.skin_uv`)."""
    import trimesh

    mesh.visual = trimesh.visual.TextureVisuals(
        uv=skin_uv(mesh.vertices, setup.eye.rotation_center_m))
    return mesh


def _face_mesh(setup: Setup, half_m: float = 0.1):
    """The face plane: a square of half-side ``half_m`` facing -z, behind the skin shell's rim
    (:data:`FACE_BEHIND_CENTER_M`), with the skin's texture coordinates."""
    c = setup.eye.rotation_center_m + np.array([0.0, 0.0, FACE_BEHIND_CENTER_M])
    v = c + half_m * np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0],
                                [-1.0, 1.0, 0.0]])
    n = np.tile([0.0, 0.0, -1.0], (4, 1))
    return _with_uv(_trimesh(v, np.array([[0, 1, 2], [0, 2, 3]]), n), setup)


def _cornea_bsdf(setup: Setup, options: SceneOptions) -> dict:
    n = setup.eye.refractive_index
    if options.cornea == "conductor":
        # A mirror with the dielectric's Fresnel reflectance F(theta) (a conductor of eta = n,
        # k = 0: tests/scet_render/test_cornea_bsdf.py), no refraction: exact glint geometry
        # from every sample. At the sensor's default exposure, tuned on F0
        # (sensor.DEFAULT_ELECTRONS_PER_RADIANCE), glints beyond ~41 deg incidence clip, as
        # the default dielectric's do.
        return {"type": "conductor", "eta": n, "k": 0.0}
    # Split channels: the path tracer carries no strobe light through the cornea unless asked
    # to (the brute-force reference); MNEE adds it exactly (EyeScene.mnee_enabled).
    split_blocks = options.channels == "split" and options.strobe_through_cornea != "path"
    transmit = [0.0, 1.0, 1.0] if split_blocks else [1.0, 1.0, 1.0]
    if options.cornea == "plain_dielectric":
        return {"type": "dielectric", "int_ior": n, "ext_ior": 1.0,
                "specular_transmittance": _rgb(transmit)}
    return {"type": CORNEA_BSDF_TYPE, "int_ior": n, "ext_ior": 1.0,
            "reflect_probability": REFLECT_PROBABILITY, "transmittance": transmit}


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
    T = eye_part_transforms(setup, layout, yaw_rad, pitch_rad, pupil_radius(setup, options))
    cornea_bsdf = _cornea_bsdf(setup, options)
    app, table = scene_appearance(setup, options)
    textures = {"sclera_opacity": sclera_opacity(layout)}
    albedo = {part: table[f"{part}_albedo"] for part in ("iris", "sclera", "skin")}
    if app.textured:
        r_iris = layout.limbus_radius_m * IRIS_OVERLAP
        textures["iris_albedo"] = cached_texture(iris_texture, app, albedo["iris"], r_iris)
        textures["sclera_albedo"] = cached_texture(sclera_texture, app, albedo["sclera"],
                                             layout.sclera_radius_m, layout.cap_angle_rad)
        textures["skin_albedo"] = cached_texture(skin_texture, app, albedo["skin"])
        albedo = {part: albedo_bitmap(f"{part}_albedo") for part in albedo}
    objects = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(options.max_depth)},
        "camera": sensor_dict(setup.camera, spp),
        "sclera": {"type": "sphere", "to_world": T["sclera"], "bsdf": {
            "type": "mask", "bsdf": _diffuse(albedo["sclera"]),
            "opacity": {"type": "bitmap", "filename": "textures/sclera_opacity.png", "raw": True,
                        "filter_type": "nearest"}}},
        "iris": {"type": "disk", "to_world": T["iris"], "bsdf": _diffuse(albedo["iris"])},
        "pupil": {"type": "disk", "to_world": T["pupil"], "bsdf": _diffuse(options.pupil_albedo)},
    }
    # The face beyond the skin shell: a plane just behind the shell's rim, facing the camera.
    meshes = {"face": _face_mesh(setup), "skin": _with_uv(skin_mesh(setup, layout), setup)}
    lids = setup.eyelids if options.eyelid_openness is not None else None
    if lids is None and options.eyelid_openness is not None:
        meshes["lid_upper"], meshes["lid_lower"] = (
            _with_uv(m, setup) for m in eyelid_meshes(setup, layout))
    for name in meshes:
        objects[name] = {"type": "ply", "filename": f"meshes/{name}.ply", "face_normals": False,
                         "bsdf": _diffuse(albedo["skin"], twosided=True)}
    if lids is not None:
        _moving_lids(setup, layout, lids, albedo["skin"], pitch_rad, objects, meshes)
    if options.cornea_geometry == "mesh":
        mesh = cornea_mesh(setup, options.cornea_edge_m)
        R = eye_rotation_matrix(yaw_rad, pitch_rad)
        c_e = setup.eye.rotation_center_m
        meshes["cornea"] = _trimesh((mesh.vertices - c_e) @ R.T + c_e, mesh.faces,
                                    np.asarray(mesh.vertex_normals) @ R.T)
        objects["cornea"] = {"type": "ply", "filename": "meshes/cornea.ply",
                             "face_normals": False, "bsdf": cornea_bsdf}
    elif setup.eye.cornea_asphericity != 0:
        # An exact ellipsoid: a unit sphere in a shapegroup, scaled by its instance's
        # to_world (a scaled sphere alone renders a sphere; DESIGN.md, rendering notes).
        objects["cornea_surface"] = {"type": "shapegroup", "surface": {
            "type": "sphere", "bsdf": {
                "type": "mask", "bsdf": cornea_bsdf,
                "opacity": {"type": "bitmap", "filename": "textures/cornea_opacity.png",
                            "raw": True, "filter_type": "nearest"}}}}
        objects["cornea"] = {"type": "instance", "to_world": T["cornea"],
                             "shapegroup": {"type": "ref", "id": "cornea_surface"}}
    else:
        objects["cornea"] = {"type": "sphere", "to_world": T["cornea"], "bsdf": cornea_bsdf}
    L = options.light_radiance
    radii = [g.source_radius_m for g in setup.lights.groups for _ in range(g.count)]
    # A wire-wound mirror draws its strip, wire and LED instead of its point lights.
    drawn = np.ones(len(radii), dtype=bool)
    for gi, first, mirror in setup_wire_mirrors(setup):
        more, more_meshes = wire_mirror_objects(mirror, f"wire{gi}", radiance=L, split=split)
        objects.update(more)
        meshes.update(more_meshes)
        drawn[first:first + mirror.turns] = False
    for i, (radius, p) in enumerate(zip(radii, setup.lights_world_m)):
        if not drawn[i]:
            continue
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
    if "cornea_surface" in objects:
        textures["cornea_opacity"] = cornea_opacity(setup)
    return SceneDescription(objects, meshes, textures, layout)


def _moving_lids(setup, layout, lids, skin_albedo, pitch_rad, objects, meshes) -> None:
    """Add the lids that follow the eye (:mod:`~scet_render.render.lids`): each lid's meshes in a
    shapegroup, placed by an instance whose ``to_world`` moves them (lashes with the upper).
    The lids' skin texture is mapped at their rest pose, so it moves with them."""
    skin = _diffuse(skin_albedo, twosided=True)
    upper, lower = (_with_uv(m, setup) for m in moving_lid_meshes(setup, layout, lids))
    parts = {"lid_upper": {"lid_upper_surface": (upper, skin)},
             "lid_lower": {"lid_lower_surface": (lower, skin)}}
    lashes = lash_mesh(setup, layout, lids)
    if lashes is not None:
        parts["lid_upper"]["lashes"] = (lashes, _diffuse(LASH_ALBEDO, twosided=True))
    T = lid_transforms(setup, lids, pitch_rad)
    for lid, shapes in parts.items():
        group = {"type": "shapegroup"}
        for name, (mesh, bsdf) in shapes.items():
            meshes[name] = mesh
            group[name] = {"type": "ply", "filename": f"meshes/{name}.ply",
                           "face_normals": False, "bsdf": bsdf}
        objects[f"{lid}_shape"] = group
        objects[lid] = {"type": "instance", "to_world": T[lid],
                        "shapegroup": {"type": "ref", "id": f"{lid}_shape"}}


# --------------------------------------------------------------------------- loading


def _to_mitsuba(value, mi, desc: SceneDescription, name: str = "", bsdfs: dict | None = None):
    """Plain description -> ``mi.load_dict`` input (transforms, in-memory meshes, textures).

    Meshes with equal BSDF descriptions share one loaded BSDF (``bsdfs``, filled as it goes):
    the skin's texture then exists once. Two copies of one texture among a frozen kernel's
    inputs made Dr.Jit 1.5 record the MNEE kernel anew at every call (measured: 4 recordings
    in 4 poses against 2-3 with one copy)."""
    bsdfs = {} if bsdfs is None else bsdfs
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
        key = repr(value["bsdf"])
        if key not in bsdfs:
            bsdfs[key] = mi.load_dict(_to_mitsuba(value["bsdf"], mi, desc, bsdfs=bsdfs))
        return mitsuba_mesh(mi, name, desc.meshes[name], bsdfs[key])
    return {k: _to_mitsuba(v, mi, desc, k, bsdfs) for k, v in value.items()}


def mitsuba_mesh(mi, name: str, m, bsdf):
    """A ``mi.Mesh`` with a trimesh mesh's vertices, faces and vertex normals, and a BSDF."""
    props = mi.Properties()
    props["bsdf"] = bsdf
    uv = getattr(m.visual, "uv", None)
    mesh = mi.Mesh(name, len(m.vertices), len(m.faces), props=props, has_vertex_normals=True,
                   has_vertex_texcoords=uv is not None)
    p = mi.traverse(mesh)
    buffers = [("vertex_positions", m.vertices, np.float32), ("faces", m.faces, np.uint32),
               ("vertex_normals", m.vertex_normals, np.float32)]
    if uv is not None:
        buffers.append(("vertex_texcoords", uv, np.float32))
    # Buffer types differ between variants (Float vs ArrayXf): reuse the mesh's own.
    for key, data, dtype in buffers:
        p[key] = type(p[key])(np.asarray(data, dtype).ravel())
    p.update()
    return mesh


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
        The ``mitsuba`` module with a variant set; default :func:`scet_render.render.backend.activate`.

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
        register_cornea_bsdf(mi)
        desc = describe_scene(setup, options, spp=spp)
        self.layout = desc.layout
        self.scene = mi.load_dict(_to_mitsuba(desc.objects, mi, desc))
        self.sensor = self.scene.sensors()[0]
        self.integrator = self.scene.integrator()
        # Strobe light through the cornea by MNEE: split channels, a refracting cornea, a
        # JIT variant (its solve runs in float64 Dr.Jit arrays), and the analytic cornea,
        # sphere or conic (the solve refracts at the exact quadric; a mesh cap is only near it).
        wanted = (options.channels == "split" and options.cornea != "conductor"
                  and options.strobe_through_cornea == "mnee")
        self.mnee_enabled = (wanted and not mi.variant().startswith("scalar")
                             and options.cornea_geometry == "sphere")
        if wanted and not self.mnee_enabled:
            log.warning("%s, %s cornea: no strobe light through the cornea (MNEE needs an "
                        "LLVM or CUDA variant and the analytic cornea)", mi.variant(),
                        options.cornea_geometry)
        self.appearance, self.appearance_table = scene_appearance(setup, options)
        iris = (self.appearance_table["iris_albedo"], desc.textures.get("iris_albedo"))
        self.mnee_lights = (light_table(setup, options, self.layout, mi, iris)
                            if self.mnee_enabled else None)
        self.mnee_state = None
        self.render_integrator = self.scene.integrator()
        if self.mnee_enabled:
            self.render_integrator = mnee_integrator(mi, self)
        params = mi.traverse(self.scene)
        params.keep([k for k in MOVING_KEYS + LID_MOVING_KEYS if k in params])
        self._params = params
        mesh = desc.meshes.get("cornea")
        self._center = setup.eye.rotation_center_m * SCENE_UNITS_PER_M
        self._cornea_rest = None if mesh is None else (
            mesh.vertices - self._center, np.asarray(mesh.vertex_normals))
        # Write the primary pose once through set_pose, so that every pose's parameters come
        # from the same code path (the loaded ones differ in the last float32 bit).
        self.pose = (math.nan, math.nan)
        self.closure = math.nan
        #: The scene's pupil radius (m), and the one now drawn (set_pose may change it).
        self.pupil_radius_m = pupil_radius(setup, options)
        self.pupil_now_m = math.nan
        self.moving_lids = setup.eyelids if options.eyelid_openness is not None else None
        self.set_pose(0.0, 0.0)

    def set_pose(self, yaw_rad: float, pitch_rad: float, closure: float = 0.0,
                 pupil_radius_m: float | None = None) -> bool:
        """Move cornea, sclera, iris and pupil to an eye pose, and the lids that follow the eye
        (a Setup with ``eyelids``) to its pitch and a blink ``closure`` in [0, 1] (0: open);
        False when nothing changed. Static lids ignore ``closure``. ``pupil_radius_m`` sizes
        the pupil (m; None: the scene's): the pupil disk's ``to_world`` scale and MNEE's pose
        input, so a new size recompiles nothing."""
        pose = (float(yaw_rad), float(pitch_rad))
        if not all(math.isfinite(a) for a in pose):
            raise ValueError(f"eye pose must be finite, got {pose}")
        closure = float(closure)
        if not 0.0 <= closure <= 1.0:
            raise ValueError(f"closure must lie in [0, 1], got {closure!r}")
        if self.moving_lids is None:
            closure = 0.0
        pupil = self.pupil_radius_m if pupil_radius_m is None else float(pupil_radius_m)
        if not (math.isfinite(pupil) and 0 < pupil < self.layout.limbus_radius_m):
            raise ValueError(f"pupil radius must be > 0 and inside the iris "
                             f"({self.layout.limbus_radius_m} m), got {pupil!r}")
        if pose == self.pose and closure == self.closure and pupil == self.pupil_now_m:
            return False
        mi, p = self.mi, self._params
        T = eye_part_transforms(self.setup, self.layout, *pose, pupil)
        if self.moving_lids is not None:
            T.update(lid_transforms(self.setup, self.moving_lids, pose[1], closure))
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
        if self.mnee_enabled:
            # The lights ride along: a frozen kernel may only read variables it is given.
            self.mnee_state = {"pose": to_drjit(pose_state(self.setup, self.layout,
                                                           T["cornea"], *pose, pupil), mi),
                               "lights": self.mnee_lights}
        self.pose, self.closure, self.pupil_now_m = pose, closure, pupil
        return True

    def mnee(self, sampler, ray):
        """The strobe radiance MNEE adds along camera rays at the current pose (an
        ``mi.Color3f``, zero when it is off)."""
        mi = self.mi
        if not self.mnee_enabled:
            return mi.Color3f(0.0)
        return mnee_radiance(mi, self.scene, sampler, ray, self.mnee_state["pose"],
                             self.mnee_lights, float(self.setup.eye.refractive_index),
                             float(self.options.light_radiance))

