"""Lids that follow the eye, blink, and carry lashes (a Setup's :class:`~estimator.eyelids.Eyelids`).

Each lid is a piece of a spherical shell about the eyeball rotation centre (as the static lids
of :func:`scet_render.render.meshes.eyelid_meshes`), built once at its rest pose (primary gaze,
open) and moved rigidly by a rotation about the world x axis through the rotation centre: the
lid's ``to_world`` in an ``instance`` of a ``shapegroup``. A rotation by δ about that axis moves
the margin's elevation on the vertical meridian by exactly δ, so the margins follow
:meth:`Eyelids.margins_rad`: the upper by ``upper_gain`` x pitch, the lower by ``lower_gain`` x
pitch, and a blink's closure c brings the upper margin onto the lower one (plus
:data:`CLOSED_OVERLAP_RAD`, so no crack stays open). Only instance transforms change per pose:
nothing recompiles, and Embree rebuilds the few hundred triangles of the lids (DESIGN.md).

The upper lid sits :data:`UPPER_LID_GAP_M` outside the lower one, so the two never meet in one
surface when shut, and it reaches past the crown of the shell (behind the face plane, hidden),
so that it still covers the eye when rotated down by a full blink.

Lashes: ``lash_count`` opaque curved ribbons rooted along the upper margin, drooping forward and
curling up (seeded: :func:`lash_mesh`), in the upper lid's shapegroup so that they move with it.
"""

from __future__ import annotations

import math

import numpy as np

from estimator.eyelids import Eyelids
from estimator.setup import Setup

from .layout import SCENE_UNITS_PER_M, EyeLayout
from .meshes import _affine, _grid_faces, _to_scene_units, _trimesh

#: Gap between the lower lid's shell and the upper lid's (m): below the 0.4 mm between the
#: lids and the skin, above float32 rounding at 1 cm scene units (~1e-9 m).
UPPER_LID_GAP_M = 0.2e-3
#: The shut upper lid passes the lower margin by this much (rad; 0.44 mm on the shell).
CLOSED_OVERLAP_RAD = math.radians(2.0)
#: Facet size of the moving lid shells (rad per row/column), as the static lids' ~10 degrees.
LID_FACET_RAD = math.radians(10.0)
#: Lashes: half span of their roots along the margin (rad of azimuth), droop below the
#: margin's outward normal and curl along their length (rad), root and tip widths (m), relative
#: length scatter, stations along each ribbon. Real upper lashes (Thibaut et al. 2010:
#: 8-12 mm, 0.1 mm thick, curving up) are more and thinner; these are a few dozen ribbons.
LASH_HALF_SPAN_RAD = math.radians(55.0)
LASH_DROOP_RAD = (math.radians(20.0), math.radians(10.0))   # mean, SD
LASH_CURL_RAD = (math.radians(70.0), math.radians(15.0))    # mean, SD
LASH_WIDTH_M = (0.12e-3, 0.04e-3)                            # root, tip
LASH_LENGTH_SCATTER = 0.15
LASH_STATIONS = 9
#: Near-IR albedo of lashes (dark hair, diffuse).
LASH_ALBEDO = 0.1
#: Scene parameters the moving lids add to :data:`scet_render.render.layout.MOVING_KEYS`.
LID_MOVING_KEYS = ("lid_upper.to_world", "lid_lower.to_world")


def _pencil_grid(center, radius, side, theta):
    """Vertices/normals/faces of a shell patch over (side, theta): ``side`` the angle from the
    y-z plane toward +x, ``theta`` the rotation about the x axis from -z toward +y. A curve of
    constant theta (a margin) is a great circle through the x axis, arched as seen from the
    front (y = sin(theta) cos(side)), and a rotation about x shifts theta everywhere by the
    rotation angle, so the shut upper lid meets the lower one along the whole margin."""
    S, T = np.meshgrid(side, theta, indexing="ij")
    n = np.stack([np.sin(S), np.cos(S) * np.sin(T), -np.cos(S) * np.cos(T)], axis=-1)
    n = n.reshape(-1, 3)
    return center + radius * n, n, _grid_faces(*S.shape)


def lid_radii_m(layout: EyeLayout) -> tuple[float, float]:
    """(upper, lower) shell radii of the moving lids (m)."""
    return layout.lid_radius_m + UPPER_LID_GAP_M, layout.lid_radius_m


def _elevations(lo: float, hi: float) -> np.ndarray:
    return np.linspace(lo, hi, max(2, math.ceil((hi - lo) / LID_FACET_RAD) + 1))


def moving_lid_meshes(setup: Setup, layout: EyeLayout, lids: Eyelids, n_az: int = 13):
    """(upper, lower) trimesh meshes (m, world frame) of the lids at rest (primary gaze, open).

    The upper shell runs from its margin up past the crown by the largest downward rotation
    (a full blink at the lowest gaze) so that a shut lid still covers the top of the eye.
    """
    r_up, r_low = lid_radii_m(layout)
    az = np.linspace(-math.radians(85.0), math.radians(85.0), n_az)
    top = math.radians(85.0)
    travel = lids.upper_margin_rad - lids.lower_margin_rad + CLOSED_OVERLAP_RAD + math.radians(30)
    c = setup.eye.rotation_center_m
    up = _pencil_grid(c, r_up, az, _elevations(lids.upper_margin_rad, min(top + travel,
                                                                           math.radians(175.0))))
    low = _pencil_grid(c, r_low, az, _elevations(-top - math.radians(30.0), lids.lower_margin_rad))
    return _trimesh(up[0], up[2], up[1]), _trimesh(low[0], low[2], low[1])


def lash_mesh(setup: Setup, layout: EyeLayout, lids: Eyelids):
    """(trimesh.Trimesh or None) The lashes at the upper lid's rest pose (m, world frame).

    Lash i is rooted on the margin at an azimuth spread evenly over +-:data:`LASH_HALF_SPAN_RAD`
    (jittered by up to 0.4 of the spacing), leaves the lid along its outward normal tilted down
    by a droop, and bends upward along a circular arc through a curl angle; a ribbon facing
    forward, tapering from root to tip. Seeded by ``lids.lash_seed``: the same seed gives the
    same lashes.
    """
    n = lids.lash_count
    if n == 0:
        return None
    rng = np.random.default_rng(lids.lash_seed)
    spacing = 2 * LASH_HALF_SPAN_RAD / n
    az = -LASH_HALF_SPAN_RAD + spacing * (np.arange(n) + 0.5) + rng.uniform(-0.4, 0.4, n) * spacing
    droop = rng.normal(*LASH_DROOP_RAD, n)
    curl = np.maximum(rng.normal(*LASH_CURL_RAD, n), math.radians(10.0))
    length = lids.lash_length_m * (1.0 + LASH_LENGTH_SCATTER * rng.uniform(-1.0, 1.0, n))
    E = lids.upper_margin_rad
    r_root = lid_radii_m(layout)[0] + 0.05e-3  # just off the lid's surface
    s = np.linspace(0.0, 1.0, LASH_STATIONS)
    width = LASH_WIDTH_M[0] + (LASH_WIDTH_M[1] - LASH_WIDTH_M[0]) * s
    verts, normals, faces = [], [], []
    for i in range(n):
        a = az[i]  # side angle of the root on the margin (theta = E), as in _pencil_grid
        radial = np.array([math.sin(a), math.cos(a) * math.sin(E), -math.cos(a) * math.cos(E)])
        t_up = np.array([0.0, math.cos(E), math.sin(E)])  # d radial / d theta, normalised
        t_side = np.array([math.cos(a), -math.sin(a) * math.sin(E), math.sin(a) * math.cos(E)])
        d0 = math.cos(droop[i]) * radial - math.sin(droop[i]) * t_up
        u0 = math.sin(droop[i]) * radial + math.cos(droop[i]) * t_up
        bend = curl[i] * s
        rc = length[i] / curl[i]
        centre = (setup.eye.rotation_center_m + r_root * radial
                  + rc * (np.sin(bend)[:, None] * d0 + (1.0 - np.cos(bend))[:, None] * u0))
        tangent = np.cos(bend)[:, None] * d0 + np.sin(bend)[:, None] * u0
        normal = np.cross(t_side, tangent)
        base = i * 2 * LASH_STATIONS
        for side in (-0.5, 0.5):
            verts.append(centre + side * width[:, None] * t_side)
            normals.append(normal)
        k = np.arange(LASH_STATIONS - 1)
        left, right = base + k, base + LASH_STATIONS + k
        faces.append(np.stack([left, right, left + 1], -1))
        faces.append(np.stack([left + 1, right, right + 1], -1))
    v = np.concatenate(verts)
    nn = np.concatenate(normals)
    nn /= np.linalg.norm(nn, axis=1, keepdims=True)
    return _trimesh(v, np.concatenate(faces), nn)


def lid_rotations_rad(lids: Eyelids, pitch_rad, closure=0.0) -> tuple[np.ndarray, np.ndarray]:
    """(upper, lower) rotations (rad, about world x through the rotation centre, + raises the
    margin) that take the rest lids to an eye pitch and blink closure."""
    c = np.asarray(closure, dtype=np.float64)
    upper, lower = lids.margins_rad(pitch_rad, c)
    return (upper - lids.upper_margin_rad - c * CLOSED_OVERLAP_RAD,
            lower - lids.lower_margin_rad)


def _rotation_x(angle_rad: float) -> np.ndarray:
    # +angle raises the front (-z) of the shell: y' = y cos - z sin, z' = y sin + z cos.
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def lid_transforms_m(setup: Setup, lids: Eyelids, pitch_rad: float,
                     closure: float = 0.0) -> dict[str, np.ndarray]:
    """(4, 4) rest-to-world matrices (metres) of ``lid_upper`` and ``lid_lower``."""
    c_e = setup.eye.rotation_center_m
    out = {}
    for name, angle in zip(("lid_upper", "lid_lower"),
                           lid_rotations_rad(lids, float(pitch_rad), float(closure))):
        R = _rotation_x(float(angle))
        out[name] = _affine(R, c_e - R @ c_e)
    return out


def lid_transforms(setup: Setup, lids: Eyelids, pitch_rad: float,
                   closure: float = 0.0) -> dict[str, np.ndarray]:
    """:func:`lid_transforms_m` in scene units, for a rest mesh already scaled to scene units
    (conjugated by the scale: S M S^-1)."""
    S_inv = np.diag([1.0 / SCENE_UNITS_PER_M] * 3 + [1.0])
    return {k: _to_scene_units(M) @ S_inv for k, M in
            lid_transforms_m(setup, lids, pitch_rad, closure).items()}

