"""The eye's meshes (trimesh) and the rigid transforms that pose its parts: cornea
and sclera shells, eyelids, skin, and the sclera's opacity mask.
"""

from __future__ import annotations

import math

import numpy as np

from estimator.eye import eye_rotation_matrix
from estimator.setup import Setup

from .layout import IRIS_OVERLAP, PUPIL_OFFSET_M, SCENE_UNITS_PER_M, SCLERA_MASK_TEXELS, EyeLayout

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
    if eye.cornea_asphericity != 0:
        raise ValueError(f"{setup.name}: the mesh cornea is spherical; an aspheric cornea "
                         f"(cornea_asphericity = {eye.cornea_asphericity:g}) renders as an "
                         "analytic ellipsoid (cornea_geometry='sphere')")
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
    n = n.reshape(-1, 3)
    return center + radius * n, n, _grid_faces(*A.shape)


def _grid_faces(nu: int, nv: int) -> np.ndarray:
    """Triangles (2 (nu-1)(nv-1), 3) of a (nu, nv) grid of vertices numbered row-major."""
    idx = np.arange(nu * nv).reshape(nu, nv)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                           np.stack([a, c, d], -1).reshape(-1, 3)])


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


def cornea_opacity(setup: Setup, texels: int = SCLERA_MASK_TEXELS) -> np.ndarray:
    """(texels, 2) float32 opacity of a conic cornea's unit sphere over its polar coordinate.

    The aspheric cornea is a unit sphere scaled to the ellipsoid (semi-axes b, b, a about the
    gaze, :func:`eye_part_transforms`); its polar angle θ from the gaze maps to the depth
    z = a (1 - cos θ) behind the apex. Opaque (1) on the cap, down to one texel beyond the
    limbus (the sliver hides inside the sclera, so no crack opens), transparent beyond: a
    prolate ellipsoid reaches far behind the eyeball (2a = 28.6 mm at Q = -0.454) and must
    not show through it.
    """
    eye = setup.eye
    a = eye.cornea_semi_axes_m[0]
    limbus = math.acos(1.0 - eye.limbus_depth_m / a)
    theta = (np.arange(texels) + 0.5) * np.pi / texels
    opacity = (theta <= limbus + np.pi / texels).astype(np.float32)
    return np.repeat(opacity[:, None], 2, axis=1)


def _to_scene_units(M: np.ndarray) -> np.ndarray:
    """An object-to-world matrix in metres -> object-to-scene (scene units)."""
    return np.diag([SCENE_UNITS_PER_M] * 3 + [1.0]) @ M


def eye_part_transforms(setup: Setup, layout: EyeLayout, yaw_rad: float, pitch_rad: float,
                        pupil_radius_m: float) -> dict[str, np.ndarray]:
    """(4, 4) object-to-scene matrices (scene units) of the analytic eye parts at a pose.

    ``cornea``: unit sphere to the corneal sphere, or for an aspheric cornea (Q != 0) to its
    ellipsoid (semi-axes b, b across and a along the gaze, local +z along the gaze, centred a
    behind the apex). ``sclera``: unit sphere to the eyeball, its local +z along the gaze. ``iris``/``pupil``: Mitsuba's unit disk (normal +z) to disks facing
    the cornea in the limbus plane (the pupil 20 µm in front).
    """
    R = eye_rotation_matrix(yaw_rad, pitch_rad)
    c_e = setup.eye.rotation_center_m
    gaze = R @ np.array([0.0, 0.0, -1.0])
    face = R @ _GAZE_FRAME  # local +z along the gaze
    r_c, r_s = setup.eye.cornea_radius_m, layout.sclera_radius_m
    r_iris = layout.limbus_radius_m * IRIS_OVERLAP
    if setup.eye.cornea_asphericity == 0:
        cornea = _affine(translation=setup.eye.cornea_center(yaw_rad, pitch_rad),
                         scale=(r_c, r_c, r_c))
    else:
        a, b = setup.eye.cornea_semi_axes_m
        cornea = _affine(face, setup.eye.cornea_ellipsoid_center(yaw_rad, pitch_rad), (b, b, a))
    metres = {
        "cornea": cornea,
        "sclera": _affine(face, c_e, (r_s, r_s, r_s)),
        "iris": _affine(face, c_e + layout.limbus_plane_m * gaze, (r_iris, r_iris, 1.0)),
        "pupil": _affine(face, c_e + (layout.limbus_plane_m + PUPIL_OFFSET_M) * gaze,
                         (pupil_radius_m, pupil_radius_m, 1.0)),
    }
    return {name: _to_scene_units(M) for name, M in metres.items()}
