"""Points inside the eye as the camera sees them through the cornea: exact refraction on the
sphere or the conic, vectorised like :func:`~estimator.geometry.conic.project_glints_conic`.

A point X behind the cornea (the pupil's centre, a point of its edge) is seen along the ray that
leaves X inside the cornea (index n), refracts once at a point P of the anterior corneal surface
and reaches the camera centre O in air. By Fermat's principle P is a stationary point of the
optical path length over the surface,

    f(u, v) = n |P - X| + |P - O|,

with P(u, v) the conic's front half over its transverse coordinates (the graph of
:mod:`~estimator.geometry.conic`, which holds the sphere at Q = 0). Its gradient,

    ∂f/∂u_i = (n ĝ_X + ĝ_O) · P_i,   ĝ_Y = (P - Y) / |P - Y|,

is zero exactly where n ĝ_X + ĝ_O is normal to the surface: the tangential components of the
two unit directions, scaled by the indices, agree, which is Snell's law in vector form
(n (w_in × N) = w_out × N). Its Hessian is the reflection solver's with the weights n and 1:

    ∂²f/∂u_i∂u_j = Σ_Y w_Y P_iᵀ (I - ĝ_Y ĝ_Yᵀ) P_j / |P - Y| + (n ĝ_X + ĝ_O)_z ∂²z/∂u_i∂u_j.

Unlike a convex mirror's, the refraction's stationary point need not be a minimum (the
curvature term has the sign of the outward normal), so Newton solves H δ = -∇f as it stands,
capped in length, from the straight line X -> O's crossing of the surface: the solution when
n = 1, and within ~0.1 R of it for the cornea's n = 1.376. The camera then sees X at the
projection of P: the ray from P to O is straight. Lengths are scaled by R inside.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .conic import _broadcast_inputs, _check_conic, _frame, _local

#: Newton stops when the largest step is below this (units of R), as the conic's reflection
#: solver: float64 rounding of the iterate.
STEP_TOL = 1e-14
#: Iteration cap. From the straight line's crossing the pupil's centre and edge points of
#: paper_sim's poses converge in 4-6 steps (tests/scet_render/test_pupil.py).
MAX_ITERATIONS = 40
#: Largest Newton step (units of R).
MAX_STEP = 0.1
#: A point counts as solved when its last step is below this (units of R: 0.8 nm at 7.8 mm).
CONVERGED_TOL = 1e-10


def _implicit(p, k):
    """The conic (C) of :mod:`~estimator.geometry.conic` in units of R: < 0 inside."""
    return p[..., 0] ** 2 + p[..., 1] ** 2 + k * p[..., 2] ** 2 - 2.0 * p[..., 2]


def _straight_crossing(x, o, k):
    """Transverse coordinates (u, v) where the segment x -> o leaves the conic (x inside)."""
    d = o - x
    A = d[..., 0] ** 2 + d[..., 1] ** 2 + k * d[..., 2] ** 2
    B = 2.0 * (x[..., 0] * d[..., 0] + x[..., 1] * d[..., 1] + k * x[..., 2] * d[..., 2] - d[..., 2])
    C = _implicit(x, k)
    t = (-B + np.sqrt(np.maximum(B * B - 4.0 * A * C, 0.0))) / (2.0 * A)
    p = x + t[..., None] * d
    return p[..., 0], p[..., 1]


def _newton(x, o, u, v, k, n):
    """Newton on the optical path's gradient; (u, v, last step)."""
    step = np.full(u.shape, np.inf)
    for _ in range(MAX_ITERATIONS):
        s = u * u + v * v
        z = s / (1.0 + np.sqrt(np.maximum(1.0 - k * s, 0.0)))
        zp = 0.5 / np.maximum(1.0 - k * z, 1e-12)
        zpp = 2.0 * k * zp ** 3
        Pu = (1.0, 0.0, 2.0 * u * zp)
        Pv = (0.0, 1.0, 2.0 * v * zp)
        P = (u, v, z)
        grad_u = grad_v = h_uu = h_uv = h_vv = w_z = 0.0
        for Y, weight in ((x, n), (o, 1.0)):
            d = tuple(p - Y[..., i] for i, p in enumerate(P))
            inv = 1.0 / np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            gh = tuple(c * inv for c in d)
            gu = gh[0] * Pu[0] + gh[1] * Pu[1] + gh[2] * Pu[2]
            gv = gh[0] * Pv[0] + gh[1] * Pv[1] + gh[2] * Pv[2]
            uu = Pu[0] * Pu[0] + Pu[1] * Pu[1] + Pu[2] * Pu[2]
            uv = Pu[0] * Pv[0] + Pu[1] * Pv[1] + Pu[2] * Pv[2]
            vv = Pv[0] * Pv[0] + Pv[1] * Pv[1] + Pv[2] * Pv[2]
            grad_u = grad_u + weight * gu
            grad_v = grad_v + weight * gv
            h_uu = h_uu + weight * (uu - gu * gu) * inv
            h_uv = h_uv + weight * (uv - gu * gv) * inv
            h_vv = h_vv + weight * (vv - gv * gv) * inv
            w_z = w_z + weight * gh[2]
        h_uu = h_uu + w_z * (2.0 * zp + 4.0 * u * u * zpp)
        h_uv = h_uv + w_z * (4.0 * u * v * zpp)
        h_vv = h_vv + w_z * (2.0 * zp + 4.0 * v * v * zpp)
        det = h_uu * h_vv - h_uv * h_uv
        with np.errstate(divide="ignore", invalid="ignore"):
            du = -(h_vv * grad_u - h_uv * grad_v) / det
            dv = -(h_uu * grad_v - h_uv * grad_u) / det
        length = np.sqrt(du * du + dv * dv)
        ok = np.isfinite(length)
        scale = np.where(length > MAX_STEP, MAX_STEP / np.where(ok & (length > 0), length, 1.0),
                         1.0)
        du, dv = np.where(ok, du * scale, 0.0), np.where(ok, dv * scale, 0.0)
        s_new = (u + du) ** 2 + (v + dv) ** 2
        shrink = np.where(k * s_new > 0.999, 0.5, 1.0)  # stay on the front half (s < 1 / k)
        u, v = u + du * shrink, v + dv * shrink
        step = np.where(ok, length * scale * shrink, np.inf)
        if not (step > STEP_TOL).any():
            break
    return u, v, step


def refraction_points(camera_position_m, apex_m, cornea_axis, cornea_radius_m: float,
                      asphericity: float, refractive_index: float, points_inside_m, *,
                      limbus_depth_m=None):
    """Where the rays from points inside the cornea to the camera refract (module docstring).

    Parameters
    ----------
    camera_position_m : (3,) float
        Camera centre O.
    apex_m : (..., 3) float
        Corneal apex, a batch of poses.
    cornea_axis : (..., 3) float
        Unit optical axis (outward).
    cornea_radius_m : float
        Apex radius of curvature R.
    asphericity : float
        Conic constant Q in (-1, 1]; 0 is the sphere.
    refractive_index : float
        The cornea's index n (air outside), >= 1.
    points_inside_m : (n, 3) or (..., n, 3) float
        Points behind the corneal surface (inside the conic).
    limbus_depth_m : float, optional
        Refraction points deeper than this behind the apex are off the cap (not seen).

    Returns
    -------
    points_m : (..., n, 3) float
        Refraction points on the surface (NaN where Newton did not converge).
    normals : (..., n, 3) float
        Outward unit normals there.
    ok : (..., n) bool
        The refracted ray exists and is seen: converged, the point inside and the camera
        outside the conic, the camera on the outer side of the tangent plane, and on the cap
        if ``limbus_depth_m`` is given.

    Raises
    ------
    ValueError
        An index below 1, or a conic outside (-1, 1].
    """
    R, Q = _check_conic(cornea_radius_m, asphericity)
    n = float(refractive_index)
    if not (np.isfinite(n) and n >= 1.0):
        raise ValueError(f"refractive_index must be finite and >= 1, got {refractive_index}")
    k = 1.0 + Q
    O, A, ax, X, batch = _broadcast_inputs(camera_position_m, apex_m, cornea_axis,
                                           points_inside_m, "points_inside_m")
    fr = tuple(e[..., None, :] for e in _frame(ax))
    x = _local(X, A[..., None, :], fr, R)
    o = np.broadcast_to(_local(np.broadcast_to(O, batch + (3,)), A, _frame(ax), R)[..., None, :],
                        x.shape)
    u0, v0 = _straight_crossing(x, o, k)
    u, v, step = _newton(x, o, u0, v0, k, n)
    s = u * u + v * v
    z = s / (1.0 + np.sqrt(np.maximum(1.0 - k * s, 0.0)))
    grad_F = np.stack([u, v, k * z - 1.0], axis=-1)  # outward normal of (C)
    normal_loc = grad_F / np.linalg.norm(grad_F, axis=-1, keepdims=True)
    P_loc = np.stack([u, v, z], axis=-1)
    converged = step < CONVERGED_TOL
    ok = (converged & (k * s < 1.0) & (_implicit(x, k) < 0) & (_implicit(o, k) > 0)
          & (np.einsum("...i,...i->...", o - P_loc, normal_loc) > 0))
    if limbus_depth_m is not None:
        ok &= z * R <= float(limbus_depth_m)
    to_world = lambda w: sum(w[..., i, None] * fr[i] for i in range(3))  # noqa: E731
    points = A[..., None, :] + R * to_world(P_loc)
    points = np.where(converged[..., None], points, np.nan)
    return points, to_world(normal_loc), ok


def snell_residual_rad(points_inside_m, surface_m, normals, camera_position_m,
                       refractive_index: float) -> np.ndarray:
    """(...) how far each refraction is from Snell's law: |n (w_in x N) - (w_out x N)|, the
    difference of the two sides' tangential components (radians, to first order), for the
    rays from the inside points through the surface points to the camera."""
    X = np.asarray(points_inside_m, dtype=np.float64)
    P = np.asarray(surface_m, dtype=np.float64)
    w_in = P - X
    w_in = w_in / np.linalg.norm(w_in, axis=-1, keepdims=True)
    w_out = np.asarray(camera_position_m, dtype=np.float64) - P
    w_out = w_out / np.linalg.norm(w_out, axis=-1, keepdims=True)
    N = np.asarray(normals, dtype=np.float64)
    diff = refractive_index * np.cross(w_in, N) - np.cross(w_out, N)
    return np.linalg.norm(diff, axis=-1)


def project_through_cornea(camera: Camera, apex, cornea_axis, cornea_radius: float,
                           asphericity: float, refractive_index: float, points_inside, *,
                           limbus_depth_m=None, return_points: bool = False):
    """Where points inside the cornea appear in the image, seen through it (one refraction
    at the anterior surface; :func:`refraction_points`), projected by ``camera.project``.

    Returns
    -------
    pixels_px : (..., n, 2) float64
        Image positions (pixel-centre convention); NaN where no refracted ray was found.
    visible : (..., n) bool
        The refracted ray exists, crosses the cap, and lands in the image.
    points_m : (..., n, 3) float64
        The refraction points (only with ``return_points``).
    """
    points, _, ok = refraction_points(camera.position_m, apex, cornea_axis, cornea_radius,
                                      asphericity, refractive_index, points_inside,
                                      limbus_depth_m=limbus_depth_m)
    px, _ = camera.project(points)
    visible = ok & camera.in_image(px)
    return (px, visible, points) if return_points else (px, visible)
