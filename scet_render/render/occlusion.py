"""Which glints the moving lids and lashes hide or cut (ground truth for the labels).

A glint is the image of a light's small spherical emitter (radius ρ) in the cornea. It is
sampled by :data:`SPOT_SAMPLES` points on the emitter's disk facing the eye: each point has its
own reflection point on the cornea (:func:`estimator.geometry.reflection_points`, or the conic's),
and its light path runs light -> reflection point -> camera. A path is blocked when a lid or a
lash meets either segment (Mitsuba ``ray_test`` on the very triangles that are rendered, the
rays taken into each lid's rest frame). Per glint:

* ``blocked_fraction``: the fraction of its sample paths that are blocked;
* **hidden**: every path blocked (the reflection point covered, or the light shadowed);
* **cut**: some but not all blocked (a lid edge or a lash across the spot): the detector sees a
  truncated spot whose centroid is biased;
* ``occluder``: what blocks it, :data:`OCCLUDER_NAMES` ("lid" wins over "lash" when both do).

:meth:`LidOccluder.toward_camera` tests other light paths the same way: from points where a
ray leaves the cornea toward the camera (the pupil's refraction points, for the pupil labels'
``pupil_occluder`` and ``pupil_edge_visible_fraction``).

Only meaningful where the glint exists (on the corneal cap, seen by camera and light).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.eye import gaze_direction
from estimator.geometry import conic_reflection_points, reflection_points
from estimator.setup import Setup

from .backend import activate, is_jit_variant
from .layout import SCENE_UNITS_PER_M, eye_layout
from .lids import lash_mesh, lid_rotations_rad, moving_lid_meshes
from .scene import mitsuba_mesh

#: Sample points on each emitter's disk: its centre and two rings (radii 0.5 ρ and 0.95 ρ,
#: 8 and 16 points): 25 paths per glint, so a cut is told from a hidden glint to ~4 % of the
#: spot.
SPOT_RINGS = ((0.5, 8), (0.95, 16))
SPOT_SAMPLES = 1 + sum(n for _, n in SPOT_RINGS)
OCCLUDER_NAMES = ("none", "lid", "lash")


@dataclass(frozen=True, slots=True)
class GlintOcclusion:
    """Occlusion of every light's glint at m poses.

    Attributes
    ----------
    blocked_fraction : (m, n) float
        Fraction of each glint's sample paths a lid or lash blocks (0 where nothing does).
    occluder : (m, n) int8
        Index into :data:`OCCLUDER_NAMES`.
    """

    blocked_fraction: np.ndarray
    occluder: np.ndarray

    @property
    def hidden(self) -> np.ndarray:
        return self.blocked_fraction >= 1.0

    @property
    def cut(self) -> np.ndarray:
        return (self.blocked_fraction > 0.0) & (self.blocked_fraction < 1.0)


def _disk_offsets() -> np.ndarray:
    """(K, 2) unit-disk sample offsets: the centre and the rings of :data:`SPOT_RINGS`."""
    pts = [np.zeros((1, 2))]
    for r, n in SPOT_RINGS:
        phi = 2 * np.pi * (np.arange(n) + 0.5 * (n % 2 == 0)) / n
        pts.append(r * np.stack([np.cos(phi), np.sin(phi)], -1))
    return np.concatenate(pts)


def _rotation_x(angle):
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1),
                     np.stack([z, s, c], -1)], -2)


class LidOccluder:
    """Ray tests of glint paths against a Setup's moving lids and lashes (module docstring).

    Parameters
    ----------
    setup : Setup
        Must have ``eyelids``.
    mi : module, optional
        Mitsuba with a variant set (default :func:`scet_render.render.backend.activate`).
    """

    def __init__(self, setup: Setup, mi=None):
        if setup.eyelids is None:
            raise ValueError(f"{setup.name}: the scene has no [eyelids] table (no moving lids)")
        self.setup, self.lids = setup, setup.eyelids
        self.mi = activate() if mi is None else mi
        layout = eye_layout(setup)
        upper, lower = moving_lid_meshes(setup, layout, self.lids)
        parts = {"lid_upper": upper, "lid_lower": lower}
        lashes = lash_mesh(setup, layout, self.lids)
        if lashes is not None:
            parts["lashes"] = lashes
        mi = self.mi
        self._scenes = {}
        for name, mesh in parts.items():
            mesh = mesh.copy()
            mesh.apply_scale(SCENE_UNITS_PER_M)
            shape = mitsuba_mesh(mi, name, mesh, mi.load_dict({"type": "diffuse"}))
            self._scenes[name] = mi.load_dict({"type": "scene", name: shape})
        lights = setup.lights_world_m
        radii = np.array([g.source_radius_m for g in setup.lights.groups for _ in range(g.count)])
        self._lights, self._radii = lights, radii
        self._disk = _disk_offsets()

    def _blocked(self, name: str, origin, direction, length) -> np.ndarray:
        """(r,) bool: does part ``name`` (rest frame, metres) meet the segments?"""
        mi = self.mi
        scene = self._scenes[name]
        o = np.asarray(origin * SCENE_UNITS_PER_M, np.float32)
        d = np.asarray(direction, np.float32)
        t = np.asarray(length * SCENE_UNITS_PER_M, np.float32)
        if is_jit_variant(mi.variant()):
            ray = mi.Ray3f(mi.Point3f(*(mi.Float(np.ascontiguousarray(c)) for c in o.T)),
                           mi.Vector3f(*(mi.Float(np.ascontiguousarray(c)) for c in d.T)),
                           mi.Float(t), mi.Float(np.zeros_like(t)), [])
            return np.asarray(scene.ray_test(ray), dtype=bool)
        return np.array([bool(scene.ray_test(mi.Ray3f(mi.Point3f(*oi), mi.Vector3f(*di),
                                                      float(ti))))
                         for oi, di, ti in zip(o, d, t)], dtype=bool)

    def _segments(self, pitch, closure, start, ends) -> dict[str, np.ndarray]:
        """Per part, (m, r) bool: does it meet any of the segments from ``start`` (m, r, 3) to
        each of ``ends`` (each (m, r, 3)), world frame (m), at the m poses' lid rotations?"""
        c_e = self.setup.eye.rotation_center_m
        seg = np.stack([np.asarray(e, np.float64) for e in ends], axis=0) - start[None]
        length = np.linalg.norm(seg, axis=-1)
        direction = seg / np.maximum(length, 1e-30)[..., None]
        rot_up, rot_low = lid_rotations_rad(self.lids, pitch, closure)
        blocked = {}
        for name in self._scenes:
            angle = rot_low if name == "lid_lower" else rot_up
            Rt = np.swapaxes(_rotation_x(angle), -1, -2)  # world -> rest frame, (m, 3, 3)
            o = np.einsum("mij,smrj->smri", Rt, np.broadcast_to(start - c_e, seg.shape)) + c_e
            d = np.einsum("mij,smrj->smri", Rt, direction)
            hit = self._blocked(name, o.reshape(-1, 3), d.reshape(-1, 3), length.reshape(-1))
            blocked[name] = hit.reshape(seg.shape[:-1]).any(axis=0)
        return blocked

    def toward_camera(self, pitch_rad, closure, points_m) -> np.ndarray:
        """(m, r) int8 :data:`OCCLUDER_NAMES` codes: what blocks the straight path from each
        of ``points_m`` (m, r, 3), world frame (m; points on the cornea where a ray from inside
        leaves toward the camera, e.g. the pupil's refraction points) to the camera, at m eye
        pitches and blink closures; NaN points give "none"."""
        pts = np.asarray(points_m, np.float64)
        pitch = np.atleast_1d(np.asarray(pitch_rad, np.float64))
        closure = np.broadcast_to(np.asarray(closure, np.float64), pitch.shape)
        if pts.ndim != 3 or pts.shape[0] != pitch.size or pts.shape[2] != 3:
            raise ValueError(f"points_m must be (m, r, 3) for {pitch.size} poses, got {pts.shape}")
        finite = np.isfinite(pts).all(axis=-1)
        O = self.setup.camera.position_m
        start = np.where(finite[..., None], pts, O + np.array([0.0, 0.0, 1e-3]))
        blocked = self._segments(pitch, closure, start, [np.broadcast_to(O, start.shape)])
        lid = blocked["lid_upper"] | blocked["lid_lower"]
        lash = blocked.get("lashes", np.zeros_like(lid))
        return np.where(finite & lid, 1, np.where(finite & lash, 2, 0)).astype(np.int8)

    def glints(self, yaw_rad, pitch_rad, closure=0.0) -> GlintOcclusion:
        """Occlusion of every light's glint at m eye poses and blink closures ((m,) each)."""
        yaw = np.atleast_1d(np.asarray(yaw_rad, np.float64))
        pitch = np.atleast_1d(np.asarray(pitch_rad, np.float64))
        closure = np.broadcast_to(np.asarray(closure, np.float64), yaw.shape)
        m, n, K = yaw.size, self._lights.shape[0], self._disk.shape[0]
        eye, cam = self.setup.eye, self.setup.camera
        O = cam.position_m
        # Emitter disk samples facing each cornea centre: (m, n, K, 3).
        center = eye.cornea_center(yaw, pitch).reshape(m, 3)
        toward = center[:, None, :] - self._lights[None]
        toward /= np.linalg.norm(toward, axis=-1, keepdims=True)
        helper = np.where(np.abs(toward[..., 1:2]) < 0.9, [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
        u = np.cross(toward, helper)
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        v = np.cross(toward, u)
        rho = self._radii[None, :, None, None]
        samples = (self._lights[None, :, None, :]
                   + rho * (self._disk[:, 0, None] * u[:, :, None] + self._disk[:, 1, None]
                            * v[:, :, None]))
        flat = samples.reshape(m, n * K, 3)
        if eye.cornea_asphericity == 0:
            P, _, ok = reflection_points(O, center, eye.cornea_radius_m, flat)
        else:
            axis = gaze_direction(yaw, pitch).reshape(m, 3)
            P, _, ok = conic_reflection_points(O, center + eye.cornea_radius_m * axis, axis,
                                               eye.cornea_radius_m, eye.cornea_asphericity, flat)
        P = np.where(np.isfinite(P), P, center[:, None, :])  # no reflection: nothing to block
        blocked = self._segments(pitch, closure, P, [np.broadcast_to(O, P.shape), flat])
        blocked = {k: v.reshape(m, n, K) for k, v in blocked.items()}
        lid = blocked["lid_upper"] | blocked["lid_lower"]
        lash = blocked.get("lashes", np.zeros_like(lid))
        fraction = (lid | lash).mean(axis=-1)
        occluder = np.where(lid.any(-1), 1, np.where(lash.any(-1), 2, 0)).astype(np.int8)
        valid = ok.reshape(m, n, K).any(-1)
        return GlintOcclusion(np.where(valid, fraction, 0.0),
                              np.where(valid, occluder, 0).astype(np.int8))


def occluder_names(codes) -> list:
    """Codes of :attr:`GlintOcclusion.occluder` -> names (:data:`OCCLUDER_NAMES`)."""
    return [OCCLUDER_NAMES[int(c)] for c in np.asarray(codes).reshape(-1)]

