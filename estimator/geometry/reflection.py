"""Closed-form forward projection of point lights reflected by the corneal sphere.

The reflection point G_s of a light G on a spherical mirror (centre c, radius r) seen from the
camera centre O lies in the plane of O, c and G (Sec. 2.1 of the SCET paper; Agrawal et al.
2010; Barone et al. 2018). In that plane, put c at the origin, scale by r, let the camera
direction be the first axis and measure the reflection point by its angle θ from it:

    o = (α, 0),   l = β (cos φ, sin φ),   p = (cos θ, sin θ),
    α = |O - c| / r,  β = |G - c| / r,  φ = ∠(O - c, G - c) ∈ [0, π].

The law of reflection (the normal p bisects p→o and p→l) is
``cross(p, o) (p·l - 1) + cross(p, l) (p·o - 1) = 0``, which in θ reads

    F(θ) = α β sin(φ - 2θ) + α sin θ - β sin(φ - θ) = 0.                          (R)

With t = tan(θ / 2) this is the quartic of Agrawal et al. (2010) (:func:`reflection_quartic`):

    β sφ (α + 1) t⁴ + 2 (2αβ cφ + α + β cφ) t³ - 6 αβ sφ t² + 2 (α + β cφ - 2αβ cφ) t
    + β sφ (α - 1) = 0.

For a convex mirror and both points outside it, exactly one root lies on the arc between the
directions of O and G: F(0) = β sφ (α - 1) > 0 and F(φ) = -α sφ (β - 1) < 0. We take that root
either from the quartic's companion matrix (``solver="quartic"``) or, by default, by a
bracketed Newton iteration on (R) started from its first-order closed-form solution
(``solver="newton"``): the same root, a few times faster and accurate to ~1e-15 rad. Both end
with a Newton polish on (R).

Everything is vectorised over lights and over a batch of cornea positions.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .camera import Camera
from .rigid import as_points
from .roots import _first_order_root, _newton_unit, _quartic_root


class _Plane(NamedTuple):
    """The plane of reflection of every (pose, light) pair, in a frame centred on the camera.

    Component arrays rather than (..., 3) vectors: numpy is several times faster on separate
    x, y, z arrays than on reductions over a length-3 axis. Angles are carried as cosine and
    sine pairs (cos φ, sin φ; cos θ, sin θ), which the geometry yields without trigonometric
    calls (numpy's sin and cos cost ~15 ns an element, ten times a multiplication).
    """

    c: tuple  # cornea centre, 3 x (..., 1)
    r: np.ndarray  # radius, (..., 1) or scalar
    e1: tuple  # unit vector from c toward the camera, 3 x (..., 1)
    e2: tuple  # in-plane unit vector perpendicular to e1 toward the light, 3 x (..., n)
    alpha: np.ndarray  # |O - c| / r, (..., 1) or (..., n)
    beta: np.ndarray  # |G - c| / r, (..., n)
    cp: np.ndarray  # cos φ
    sp: np.ndarray  # sin φ >= 0
    outside: np.ndarray  # camera and light both outside the sphere


def _components(a, tail: int):
    """Split the last axis of ``a`` into 3 arrays, each with ``tail`` trailing singleton axes."""
    return tuple(a[..., i][(...,) + (None,) * tail] for i in range(3))


def _plane(center_local, radius, lights_local) -> _Plane:
    """Plane frames for centres (..., 3) and lights (n, 3) or (..., n, 3), both given relative
    to the camera centre (the camera sits at the origin)."""
    r = np.asarray(radius, dtype=np.float64)
    if not (r.min() > 0 and r.max() < np.inf):  # also NaN
        raise ValueError(f"cornea_radius_m must be positive and finite, got {radius}")
    cx, cy, cz = _components(center_local, 1)
    o_norm = np.sqrt(cx * cx + cy * cy + cz * cz)
    inv_o = 1.0 / np.where(o_norm > 0, o_norm, 1.0)
    e1x, e1y, e1z = -cx * inv_o, -cy * inv_o, -cz * inv_o
    lx = lights_local[..., 0] - cx
    ly = lights_local[..., 1] - cy
    lz = lights_local[..., 2] - cz
    l_par = lx * e1x + ly * e1y + lz * e1z
    px, py, pz = lx - l_par * e1x, ly - l_par * e1y, lz - l_par * e1z
    l_perp = np.sqrt(px * px + py * py + pz * pz)
    l_norm = np.sqrt(l_par * l_par + l_perp * l_perp)
    inv_n = 1.0 / np.where(l_norm > 0, l_norm, 1.0)
    degenerate = l_perp <= 1e-12 * l_norm
    if degenerate.any():
        # A light on the line through the camera and c (θ = 0 or π): any plane through the line
        # will do; take a fixed unit vector perpendicular to e1, per pose.
        e1 = np.stack(np.broadcast_arrays(e1x, e1y, e1z), -1)[..., 0, :]
        fb = np.cross(e1, np.array([0.0, 0.0, 1.0]))
        fb = np.where(np.linalg.norm(fb, axis=-1, keepdims=True) > 1e-6, fb,
                      np.cross(e1, np.array([1.0, 0.0, 0.0])))
        fb = fb / np.linalg.norm(fb, axis=-1, keepdims=True)
        inv = 1.0 / np.where(degenerate, 1.0, l_perp)
        e2 = tuple(np.where(degenerate, f, q * inv) for f, q in zip(_components(fb, 1), (px, py, pz)))
    else:
        inv = 1.0 / l_perp
        e2 = (px * inv, py * inv, pz * inv)
    r_b = r[..., None] if r.ndim else r
    alpha = o_norm / r_b  # (..., 1) unless the radius varies per light
    beta = l_norm / r_b
    return _Plane((cx, cy, cz), r_b, (e1x, e1y, e1z), e2, alpha, beta,
                  l_par * inv_n, l_perp * inv_n, (alpha > 1) & (beta > 1))


class _Solution(NamedTuple):
    """Reflection points in the local (camera-centred) frame and the quantities the Jacobians
    reuse."""

    plane: _Plane
    alpha: np.ndarray  # α, β with harmless stand-ins where there is no reflection
    beta: np.ndarray
    ct: np.ndarray  # cos θ, (..., n)
    st: np.ndarray  # sin θ
    c1: np.ndarray  # cos(φ - θ)
    normal: tuple  # outward unit normal at the reflection point, 3 x (..., n)
    point: tuple  # reflection point relative to the camera centre, 3 x (..., n)
    ok: np.ndarray  # the reflection exists and faces camera and light


def _solve_local(center_local, radius, lights_local, solver) -> _Solution:
    """Reflection points for centres and lights given relative to the camera centre."""
    pl = _plane(center_local, radius, lights_local)
    # With the camera or a light inside the sphere there is no reflection; solve a harmless
    # stand-in problem there so that the iteration's stopping test only sees real ones.
    if pl.outside.all():
        alpha, beta = pl.alpha, pl.beta
    else:
        alpha = np.where(pl.outside, pl.alpha, 2.0)
        beta = np.where(pl.outside, pl.beta, 2.0)
    if solver == "newton":
        ct, st = _newton_unit(alpha, beta, pl.cp, pl.sp, *_first_order_root(alpha, beta, pl.cp, pl.sp))
    elif solver == "quartic":
        ct, st = _quartic_root(alpha, beta, pl.cp, pl.sp)
    else:
        raise ValueError(f"solver must be 'newton' or 'quartic', got {solver!r}")
    normal = tuple(ct * a + st * b for a, b in zip(pl.e1, pl.e2))
    point = tuple(c + pl.r * nn for c, nn in zip(pl.c, normal))
    c1 = pl.cp * ct + pl.sp * st
    ok = pl.outside & (alpha * ct > 1) & (beta * c1 > 1)
    return _Solution(pl, alpha, beta, ct, st, c1, normal, point, ok)


def _to_local(camera_position_m, rotation, cornea_center, lights):
    """Centres and lights relative to the camera centre, rotated into the camera frame if a
    world-to-camera ``rotation`` is given."""
    c = cornea_center - camera_position_m
    L = lights - camera_position_m
    if rotation is not None:
        c, L = _apply(rotation, c), _apply(rotation, L)
    return c, L


def _apply(M, v):
    """M v for (..., 3) vectors. einsum's loop sums in the same order for every vector, so the
    result of one does not depend on the batch it comes in (a BLAS product may not)."""
    return np.einsum("ij,...j->...i", M, v)


def _stack(comps):
    return np.stack(np.broadcast_arrays(*comps), axis=-1)


def reflection_points(camera_position_m, cornea_center_m, cornea_radius_m, lights_world_m, *,
                      solver: str = "newton"):
    """3D reflection points of lights on the corneal sphere.

    Parameters
    ----------
    camera_position_m : (3,) float
        Camera centre O.
    cornea_center_m : (..., 3) float
        Sphere centres, a batch of cornea positions.
    cornea_radius_m : float or (...,) float
        Sphere radii.
    lights_world_m : (n, 3) or (..., n, 3) float
        Light positions.
    solver : {"newton", "quartic"}
        How the reflection quartic is solved (see the module docstring).

    Returns
    -------
    points_m : (..., n, 3) float
        Reflection point G_s on the sphere.
    normals : (..., n, 3) float
        Outward unit normal at G_s.
    ok : (..., n) bool
        True where the reflection exists and is seen: camera and light outside the sphere and
        both on the outer side of the tangent plane at G_s.
    """
    O = as_points(camera_position_m, "camera_position_m").reshape(3)
    c = as_points(cornea_center_m, "cornea_center_m")
    L = as_points(lights_world_m, "lights_world_m")
    if L.ndim == 1:
        L = L[None, :]
    c_loc, L_loc = _to_local(O, None, c, L)
    sol = _solve_local(c_loc, cornea_radius_m, L_loc, solver)
    return _stack(sol.point) + O, _stack(sol.normal), np.broadcast_to(sol.ok, sol.ct.shape).copy()


def project_glints(camera: Camera, cornea_center, cornea_radius, lights_world, *,
                   cornea_axis=None, cap_cos_min: float | None = None,
                   solver: str = "newton", return_points: bool = False):
    """Where each light's corneal reflection (glint) lands in the image.

    Parameters
    ----------
    camera : Camera
        Calibrated pinhole camera.
    cornea_center : (..., 3) float
        Cornea centres in metres; a batch of poses.
    cornea_radius : float or (...,) float
        Corneal radius r_c in metres.
    lights_world : (n, 3) or (..., n, 3) float
        Light positions in metres.
    cornea_axis : (..., 3) float, optional
        Unit optical axis of the cornea for each pose. With ``cap_cos_min`` it restricts glints
        to the corneal cap: a reflection point with normal n counts iff n · axis >= cap_cos_min
        (:attr:`estimator.eye.Eye.cap_cos_min`, the limbus).
    cap_cos_min : float, optional
        See ``cornea_axis``.
    solver : {"newton", "quartic"}
        See :func:`reflection_points`.
    return_points : bool
        Also return the 3D reflection points (..., n, 3).

    Returns
    -------
    glints_px : (..., n, 2) float64
        Image positions (pixel-centre convention). Finite wherever the reflection point lies in
        front of the camera, NaN otherwise.
    visible : (..., n) bool
        True where the glint exists, lies on the corneal cap, faces both camera and light, and
        falls inside the image.
    points_m : (..., n, 3) float64
        Only with ``return_points``.
    """
    center = as_points(cornea_center, "cornea_center")
    lights = as_points(lights_world, "lights_world")
    if lights.ndim == 1:
        lights = lights[None, :]
    radius = np.asarray(cornea_radius, dtype=np.float64)
    if (cornea_axis is None) != (cap_cos_min is None):
        raise ValueError("cornea_axis and cap_cos_min must be given together")
    axis = None if cornea_axis is None else as_points(cornea_axis, "cornea_axis")
    batch = np.broadcast_shapes(center.shape[:-1], radius.shape, lights.shape[:-2],
                                () if axis is None else axis.shape[:-1])
    n = lights.shape[-2]
    total = int(np.prod(batch, dtype=np.int64))
    # Work through large batches in blocks that stay in the CPU cache (about 2x faster
    # than one pass over 10,000 poses x 40 lights).
    block = max(1, _BLOCK_PAIRS // max(n, 1))
    if total <= block:
        return _project_block(camera, center, radius, lights, axis, cap_cos_min, solver, return_points)
    flat = lambda a, tail: np.broadcast_to(a, batch + tail).reshape((total,) + tail)  # noqa: E731
    center_f = flat(center, (3,))
    radius_f = flat(radius, ())
    lights_f = lights if lights.ndim == 2 else flat(lights, (n, 3))
    axis_f = None if axis is None else flat(axis, (3,))
    outs = [np.empty((total, n, 2)), np.empty((total, n), dtype=bool)]
    if return_points:
        outs.append(np.empty((total, n, 3)))
    for i in range(0, total, block):
        sl = slice(i, i + block)
        res = _project_block(camera, center_f[sl], radius_f[sl],
                             lights_f if lights_f.ndim == 2 else lights_f[sl],
                             None if axis_f is None else axis_f[sl], cap_cos_min, solver,
                             return_points)
        for out, r in zip(outs, res):
            out[sl] = r
    return tuple(o.reshape(batch + o.shape[1:]) for o in outs)


_BLOCK_PAIRS = 8192


def _visibility_local(camera: Camera, sol: _Solution, axis_local, cap_cos_min):
    """Pixels (u, v) of the reflection points, 1 / depth, and which glints are seen: on the cap
    (normal · axis >= cap_cos_min), in front of the camera and in the image."""
    ok = sol.ok
    if axis_local is not None:
        ax = _components(axis_local, 1)
        ok = ok & (sol.normal[0] * ax[0] + sol.normal[1] * ax[1] + sol.normal[2] * ax[2] >= cap_cos_min)
    X, Y, Z = sol.point
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = np.where(Z > 0, 1.0 / Z, np.nan)
    u = camera.fx_px * X * iz + camera.cx_px
    v = camera.fy_px * Y * iz + camera.cy_px
    # NaN (behind the camera) compares False.
    visible = ok & (u >= -0.5) & (u <= camera.width_px - 0.5) & (v >= -0.5) & (v <= camera.height_px - 0.5)
    return u, v, iz, visible


def _project_block(camera, center, radius, lights, axis, cap_cos_min, solver, return_points):
    R = camera.rotation
    c_loc, L_loc = _to_local(camera.position_m, R, center, lights)
    sol = _solve_local(c_loc, radius, L_loc, solver)
    u, v, _, visible = _visibility_local(camera, sol, None if axis is None else _apply(R, axis), cap_cos_min)
    out = (_stack((u, v)), np.broadcast_to(visible, sol.ct.shape))
    if return_points:
        return out + (_apply(R.T, _stack(sol.point)) + camera.position_m,)
    return out


def reflect_pixel_rays(camera: Camera, cornea_center, cornea_radius, pixels_px):
    """Back-project pixels to the rays they see reflected off the corneal sphere.

    Parameters
    ----------
    camera : Camera
    cornea_center : (3,) float
    cornea_radius : float
    pixels_px : (..., 2) float

    Returns
    -------
    hit : (...,) bool
        True where the camera ray meets the sphere.
    points_m : (..., 3) float
        First intersection of the camera ray with the sphere (NaN where it misses).
    directions : (..., 3) float
        Unit direction of the reflected ray (NaN where it misses). A light on the ray
        ``points_m + s * directions`` (s > 0) makes a glint at the pixel.
    """
    c = as_points(cornea_center, "cornea_center").reshape(3)
    r = float(cornea_radius)
    d = camera.pixel_rays(pixels_px)
    oc = camera.position_m - c
    b = d @ oc
    disc = b * b - (oc @ oc - r * r)
    hit = disc >= 0
    s = -b - np.sqrt(np.where(hit, disc, 0.0))
    hit &= s > 0
    s = np.where(hit, s, np.nan)
    points = camera.position_m + s[..., None] * d
    n = (points - c) / r
    directions = d - 2 * np.sum(d * n, axis=-1, keepdims=True) * n
    return hit, points, directions
