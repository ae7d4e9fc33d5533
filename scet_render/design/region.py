"""Where lights may sit: the design region, and what blocks a light's glint.

A light is *admissible* when it lies in the region (between a minimum and a maximum distance
from the eye's rotation centre, in front of the face plane, optionally on a glasses-frame
plane) and does not stand in the eye's view of the screen. Its glint at a given pose is
*unblocked* when the reflected ray from the cornea to the light, and the camera's ray to the
reflection point, pass through the openings of the rendered scene's eyelids and skin
(:func:`scet_render.render.eye_layout`): the closed-form projection knows nothing of lids, the
renders do.

Units: metres and radians inside; the CLI speaks millimetres and degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimator.setup import Setup

#: The lid shells of the rendered scene span this azimuth about -z (scet_render.render.meshes).
LID_AZIMUTH_RAD = math.radians(85.0)
#: The skin shell ends this far from -z (scet_render.render.skin_mesh).
SKIN_END_RAD = math.radians(100.0)


@dataclass(frozen=True, slots=True)
class Region:
    """The space lights may occupy (see the module docstring).

    Attributes
    ----------
    min_eye_distance_m, max_eye_distance_m : float
        Distance range from the eye's rotation centre. The default minimum, 20 mm, keeps a
        light about 8 mm in front of the corneal apex (12.05 mm from the centre in
        ``paper_sim``), clear of lashes; the maximum, 50 mm, is the reach of a glasses frame.
    max_z_m : float
        Lights lie in front of this plane (world z, the eye looks along -z): the face. The
        rendered face plane is 3 mm behind the rotation centre; -2 mm keeps a light off the
        brow and cheek skin shell.
    screen_margin_deg : float
        A light may not come within this angle of the eye's line of sight to any screen point,
        seen from the corneal apex at any gaze on the screen's 3 x 3 edge-to-edge grid.
    frame_z_m : float or None
        When set, lights sit on the glasses-frame plane z = ``frame_z_m`` (families are moved
        onto it along the ray from the rotation centre); None: anywhere in the volume.
    """

    min_eye_distance_m: float = 0.020
    max_eye_distance_m: float = 0.050
    max_z_m: float = -0.002
    screen_margin_deg: float = 2.0
    frame_z_m: float | None = None

    def __post_init__(self):
        for name in ("min_eye_distance_m", "max_eye_distance_m", "max_z_m", "screen_margin_deg"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"region {name} must be finite, got {getattr(self, name)!r}")
        if not 0 < self.min_eye_distance_m < self.max_eye_distance_m:
            raise ValueError(
                f"region needs 0 < min_eye_distance_m < max_eye_distance_m, got "
                f"{self.min_eye_distance_m!r} and {self.max_eye_distance_m!r}")
        if not 0 <= self.screen_margin_deg < 45:
            raise ValueError(f"region screen_margin_deg must be in [0, 45), got "
                             f"{self.screen_margin_deg!r}")
        if self.frame_z_m is not None and not (math.isfinite(self.frame_z_m)
                                               and self.frame_z_m < self.max_z_m):
            raise ValueError(f"region frame_z_m must be finite and below max_z_m = "
                             f"{self.max_z_m!r}, got {self.frame_z_m!r}")

    def describe(self) -> str:
        frame = ("anywhere in the volume" if self.frame_z_m is None
                 else f"on the frame plane z = {self.frame_z_m * 1e3:g} mm")
        return (f"{self.min_eye_distance_m * 1e3:g}-{self.max_eye_distance_m * 1e3:g} mm from the "
                f"eye's rotation centre, in front of z = {self.max_z_m * 1e3:g} mm, "
                f"{self.screen_margin_deg:g} deg clear of the eye's view of the screen, {frame}")


def on_frame(setup: Setup, region: Region, points_m) -> np.ndarray:
    """(..., 3) points moved onto the region's frame plane along the ray from the rotation
    centre (unchanged without a frame plane; points on the far side stay where they are and
    fail :func:`admissible`)."""
    p = np.asarray(points_m, dtype=np.float64)
    if region.frame_z_m is None:
        return p
    c = setup.eye.rotation_center_m
    d = p - c
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (region.frame_z_m - c[2]) / d[..., 2]
    ok = np.isfinite(s) & (s > 0)
    return np.where(ok[..., None], c + np.where(ok, s, 1.0)[..., None] * d, p)


def _apex_views(setup: Setup):
    """Corneal apexes (k, 3) for gazes at the screen's 3 x 3 edge-to-edge grid."""
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(3, 3, margin=0.0))
    return setup.eye.apex(yaw, pitch)


def in_screen_view(setup: Setup, region: Region, points_m) -> np.ndarray:
    """(...,) bool: the point hides part of the screen (plus the margin) from the eye."""
    p = np.asarray(points_m, dtype=np.float64)
    scr = setup.screen
    apex = _apex_views(setup)  # (k, 3)
    d = p[..., None, :] - apex  # (..., k, 3)
    depth = scr.z_m - apex[:, 2]  # < 0: the screen is at -z
    with np.errstate(divide="ignore", invalid="ignore"):
        s = depth / d[..., 2]
    ahead = (d[..., 2] < 0) & np.isfinite(s)
    hit = apex[:, :2] + np.where(ahead, s, 0.0)[..., None] * d[..., :2]
    pad = abs(depth) * math.tan(math.radians(region.screen_margin_deg))
    (x0, x1), (y0, y1) = scr.x_range_m, scr.y_range_m
    inside = ((hit[..., 0] >= x0 - pad) & (hit[..., 0] <= x1 + pad)
              & (hit[..., 1] >= y0 - pad) & (hit[..., 1] <= y1 + pad))
    return np.any(ahead & inside, axis=-1)


def admissible(setup: Setup, region: Region, points_m) -> np.ndarray:
    """(...,) bool: inside the region and out of the eye's view of the screen."""
    p = np.asarray(points_m, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise ValueError(f"points_m must have shape (..., 3), got {p.shape}")
    dist = np.linalg.norm(p - setup.eye.rotation_center_m, axis=-1)
    ok = np.isfinite(p).all(axis=-1)
    ok &= (dist >= region.min_eye_distance_m) & (dist <= region.max_eye_distance_m)
    ok &= p[..., 2] <= region.max_z_m
    if region.frame_z_m is not None:
        ok &= np.abs(p[..., 2] - region.frame_z_m) <= 1e-6
    return ok & ~in_screen_view(setup, region, p)


@dataclass(frozen=True, slots=True)
class Shells:
    """The rendered scene's eyelid and skin shells about the rotation centre (m, rad)."""

    center_m: np.ndarray
    lid_radius_m: float
    lid_upper_rad: float
    lid_lower_rad: float
    skin_radius_m: float
    skin_hole_rad: float


def scene_shells(setup: Setup) -> Shells:
    """The shells of :func:`scet_render.render.eye_layout` with the renderer's default options
    (eyelids fully open)."""
    from scet_render.render import eye_layout

    lay = eye_layout(setup)
    return Shells(setup.eye.rotation_center_m, lay.lid_radius_m, lay.lid_upper_rad,
                  lay.lid_lower_rad, lay.skin_radius_m, lay.skin_hole_rad)


def _crossing(a, b, center, radius):
    """Unit directions (from ``center``) where segments a -> b leave the sphere, and whether
    they cross it at all (a inside, b outside)."""
    d = b - a
    oc = a - center
    A = np.sum(d * d, axis=-1)
    B = np.sum(d * oc, axis=-1)
    C = np.sum(oc * oc, axis=-1) - radius * radius
    disc = np.maximum(B * B - A * C, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-B + np.sqrt(disc)) / A
    crosses = (C < 0) & (t > 0) & (t < 1)
    q = oc + np.where(crosses, t, 0.0)[..., None] * d
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / np.where(n > 0, n, 1.0), crosses


def _blocked(shells: Shells, inner, outer) -> np.ndarray:
    """Segments from points inside the lid shell to points outside the skin that hit a lid or
    the skin."""
    q, cross = _crossing(inner, outer, shells.center_m, shells.lid_radius_m)
    el = np.arcsin(np.clip(q[..., 1], -1.0, 1.0))
    az = np.arctan2(q[..., 0], -q[..., 2])
    lid = cross & (np.abs(az) <= LID_AZIMUTH_RAD) & (
        (el >= shells.lid_upper_rad) | (el <= shells.lid_lower_rad))
    q, cross = _crossing(inner, outer, shells.center_m, shells.skin_radius_m)
    theta = np.arccos(np.clip(-q[..., 2], -1.0, 1.0))
    skin = cross & (theta >= shells.skin_hole_rad) & (theta <= SKIN_END_RAD)
    return lid | skin


def glint_unblocked(setup: Setup, shells: Shells, points_m, lights_m) -> np.ndarray:
    """(P, n) bool: the light's reflected ray and the camera's ray to the reflection point pass
    the lids and the skin.

    Parameters
    ----------
    points_m : (P, n, 3) float
        Reflection points on the cornea (NaN where there is none).
    lights_m : (n, 3) float
    """
    pts = np.asarray(points_m, dtype=np.float64)
    finite = np.isfinite(pts).all(axis=-1)
    pts = np.where(finite[..., None], pts, shells.center_m)
    lights = np.broadcast_to(np.asarray(lights_m, dtype=np.float64), pts.shape)
    cam = np.broadcast_to(setup.camera.position_m, pts.shape)
    return finite & ~_blocked(shells, pts, lights) & ~_blocked(shells, pts, cam)


def sample_region(setup: Setup, region: Region, count: int, rng: np.random.Generator
                  ) -> np.ndarray:
    """Up to ``count`` admissible positions (k, 3), uniform over directions in front of the eye
    and over the distance range (or over the frame plane); inadmissible draws are dropped."""
    if count < 1:
        raise ValueError(f"count must be >= 1, got {count}")
    c = setup.eye.rotation_center_m
    # Directions over the front hemisphere (z < 0), uniform in solid angle.
    z = -rng.uniform(0.0, 1.0, count)
    phi = rng.uniform(0.0, 2 * math.pi, count)
    r = np.sqrt(1.0 - z * z)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    lo, hi = region.min_eye_distance_m, region.max_eye_distance_m
    dist = np.cbrt(rng.uniform(lo ** 3, hi ** 3, count))
    p = on_frame(setup, region, c + dist[:, None] * d)
    return p[admissible(setup, region, p)]
