"""Exact corneal reflections on a conic (aspheric) cornea, vectorised like :func:`project_glints`.

A conic of revolution about the optical axis with apex radius R and conic constant
(asphericity) Q: with z measured from the apex along the axis into the eye and r the distance
from the axis,

    r² + (1 + Q) z² - 2 R z = 0.                                                      (C)

For Q > -1 it is an ellipsoid with semi-axis a = R / (1 + Q) along the axis and
b = R / sqrt(1 + Q) across it, centred a behind the apex (prolate for Q < 0, as real corneas
are; Q = 0 is the sphere of radius R). The front half (z < a) is the graph

    z(s) = s / (R + sqrt(R² - (1 + Q) s)),   s = u² + v²,

over the disk s < b² of transverse coordinates (u, v) (the stable root of (C), exact at Q = 0).

There is no closed form for the reflection point on a conic: with the surface point P(u, v),
Fermat's principle makes it the stationary point of the optical path length

    f(u, v) = |P - O| + |P - G|,

a minimum for a convex mirror. We find it by Newton's method on the gradient of f with its
exact Hessian (below), started from the closed-form solution on the sphere of the apex's
curvature (:func:`reflection_points`), which is ~0.1 R away at most for |Q| <= 1 over the
corneal cap. The gradient is zero exactly where the sum of the unit vectors from P toward O
and G is normal to the surface: the law of reflection. Lengths are scaled by R inside.

With w = ĝ_O + ĝ_G (ĝ_X = (P - X) / |P - X|), P_u = (1, 0, 2u z'), P_v = (0, 1, 2v z') in the
(e1, e2, into-the-eye) frame, z' = dz/ds = 1 / (2 (R - (1 + Q) z)) and z'' = 2 (1 + Q) z'³:

    ∂f/∂u_i = w · P_i,
    ∂²f/∂u_i∂u_j = P_iᵀ (M_O + M_G) P_j + w_z ∂²z/∂u_i∂u_j,   M_X = (I - ĝ_X ĝ_Xᵀ) / |P - X|.
"""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .reflection import reflection_points
from .rigid import as_points

#: Newton stops when the largest step is below this (in units of R): 1e-14 R is 1e-16 m at
#: R = 7.8 mm, float64 rounding of the iterate; the law of reflection then holds to ~1e-15 rad.
STEP_TOL = 1e-14
#: Iteration cap: from the sphere's solution every visible glint of paper_sim's 24 x 15 grid
#: converges in 5 steps for Q in [-0.95, -0.25], 6 at Q = 0.3 and 23 at Q = 1 (the oblate
#: limit, where the sphere's start is far and steps are capped); pairs still moving after this
#: many are reported not visible.
MAX_ITERATIONS = 40
#: Largest Newton step (units of R): keeps the iterate on the front half of the conic when the
#: sphere's start is far from the solution (oblique glints of strongly aspheric corneas).
MAX_STEP = 0.25
#: A pair counts as converged when its last step is below this (units of R; 1e-10 R is
#: 0.8 nm, 5e-6 px at 1300 px focal length and 20 cm).
CONVERGED_TOL = 1e-10


def _check_conic(radius_m: float, asphericity: float) -> tuple[float, float]:
    R, Q = float(radius_m), float(asphericity)
    if not (R > 0 and np.isfinite(R)):
        raise ValueError(f"cornea_radius_m must be positive and finite, got {radius_m}")
    if not (-1.0 < Q <= 1.0):
        raise ValueError(f"asphericity Q must lie in (-1, 1] (an ellipsoid), got {asphericity}")
    return R, Q


def conic_sag(s, radius_m: float, asphericity: float) -> np.ndarray:
    """Depth z behind the apex of the conic's front half at squared distance ``s`` (m²) from
    the axis (the stable root of (C)); NaN beyond its equator (s > b²)."""
    s = np.asarray(s, dtype=np.float64)
    k = 1.0 + asphericity
    disc = radius_m * radius_m - k * s
    with np.errstate(invalid="ignore"):
        return np.where(disc >= 0, s / (radius_m + np.sqrt(np.maximum(disc, 0.0))), np.nan)


def _broadcast_inputs(camera_position_m, apex_m, cornea_axis, points, name: str):
    """The conic solvers' inputs checked and broadcast: the camera (3,), the apex and axis
    (batch..., 3), the points (batch..., n, 3) (one point (3,) is n = 1), and batch."""
    O = as_points(camera_position_m, "camera_position_m").reshape(3)
    A = as_points(apex_m, "apex_m")
    ax = as_points(cornea_axis, "cornea_axis")
    P = as_points(points, name)
    if P.ndim == 1:
        P = P[None, :]
    batch = np.broadcast_shapes(A.shape[:-1], ax.shape[:-1], P.shape[:-2])
    n = P.shape[-2]
    return (O, np.broadcast_to(A, batch + (3,)), np.broadcast_to(ax, batch + (3,)),
            np.broadcast_to(P, batch + (n, 3)), batch)


def _frame(axis):
    """(..., 3) unit axes e1, e2 perpendicular to the unit optical axis and e3 = -axis (into
    the eye)."""
    d = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    helper = np.where(np.abs(d[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(d, e1)
    return e1, e2, -d


def _local(points, apex, frame, R):
    """World points (..., [n,] 3) -> the conic's (u, v, z) frame in units of R."""
    rel = points - apex
    return np.stack([np.einsum("...j,...j->...", rel, e) for e in frame], axis=-1) / R


def _newton(o, g, u, v, k):
    """Newton on the optical path's gradient; (u, v, moved) with ``moved`` the last step."""
    step = np.full(u.shape, np.inf)
    for _ in range(MAX_ITERATIONS):
        s = u * u + v * v
        disc = np.maximum(1.0 - k * s, 0.0)
        z = s / (1.0 + np.sqrt(disc))
        zp = 0.5 / np.maximum(1.0 - k * z, 1e-12)
        zpp = 2.0 * k * zp ** 3
        Pu = (1.0, 0.0, 2.0 * u * zp)
        Pv = (0.0, 1.0, 2.0 * v * zp)
        P = (u, v, z)
        grad_u = grad_v = h_uu = h_uv = h_vv = 0.0
        w_z = 0.0
        for X in (o, g):
            d = tuple(p - x for p, x in zip(P, X))
            dist = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            inv = 1.0 / dist
            gh = tuple(c * inv for c in d)
            gu = gh[0] * Pu[0] + gh[1] * Pu[1] + gh[2] * Pu[2]
            gv = gh[0] * Pv[0] + gh[1] * Pv[1] + gh[2] * Pv[2]
            uu = Pu[0] * Pu[0] + Pu[1] * Pu[1] + Pu[2] * Pu[2]
            uv = Pu[0] * Pv[0] + Pu[1] * Pv[1] + Pu[2] * Pv[2]
            vv = Pv[0] * Pv[0] + Pv[1] * Pv[1] + Pv[2] * Pv[2]
            grad_u = grad_u + gu
            grad_v = grad_v + gv
            h_uu = h_uu + (uu - gu * gu) * inv
            h_uv = h_uv + (uv - gu * gv) * inv
            h_vv = h_vv + (vv - gv * gv) * inv
            w_z = w_z + gh[2]
        h_uu = h_uu + w_z * (2.0 * zp + 4.0 * u * u * zpp)
        h_uv = h_uv + w_z * (4.0 * u * v * zpp)
        h_vv = h_vv + w_z * (2.0 * zp + 4.0 * v * v * zpp)
        det = h_uu * h_vv - h_uv * h_uv
        good = det > 0  # convex mirror: the path length is a minimum; else a gradient step
        with np.errstate(divide="ignore", invalid="ignore"):
            du = np.where(good, -(h_vv * grad_u - h_uv * grad_v) / det, -grad_u)
            dv = np.where(good, -(h_uu * grad_v - h_uv * grad_u) / det, -grad_v)
        length = np.sqrt(du * du + dv * dv)
        scale = np.where(length > MAX_STEP, MAX_STEP / np.where(length > 0, length, 1.0), 1.0)
        du, dv = du * scale, dv * scale
        # Stay inside the front half (s < b² = 1 / k in units of R).
        s_new = (u + du) ** 2 + (v + dv) ** 2
        shrink = np.where(k * s_new > 0.999, 0.5, 1.0)
        u, v = u + du * shrink, v + dv * shrink
        step = np.where(np.isfinite(length), length * scale * shrink, np.inf)
        if not (step > STEP_TOL).any():
            break
    return u, v, step


def conic_reflection_points(camera_position_m, apex_m, cornea_axis, cornea_radius_m: float,
                            asphericity: float, lights_world_m, *, limbus_depth_m=None):
    """3D reflection points of lights on a conic cornea (see the module docstring).

    Parameters
    ----------
    camera_position_m : (3,) float
        Camera centre O.
    apex_m : (..., 3) float
        Corneal apex, a batch of poses.
    cornea_axis : (..., 3) float
        Unit optical axis (outward, from the eye toward the apex).
    cornea_radius_m : float
        Apex radius of curvature R.
    asphericity : float
        Conic constant Q in (-1, 1].
    lights_world_m : (n, 3) or (..., n, 3) float
    limbus_depth_m : float, optional
        Depth of the limbus behind the apex: reflection points deeper than it are off the cap.

    Returns
    -------
    points_m : (..., n, 3) float
        Reflection points (NaN where Newton did not converge).
    normals : (..., n, 3) float
        Outward unit normals there.
    ok : (..., n) bool
        True where the reflection exists and is seen: converged, camera and light outside the
        conic and on the outer side of the tangent plane, on the cap if ``limbus_depth_m``.
    """
    R, Q = _check_conic(cornea_radius_m, asphericity)
    k = 1.0 + Q
    O, A, ax, L, batch = _broadcast_inputs(camera_position_m, apex_m, cornea_axis,
                                           lights_world_m, "lights_world_m")
    frame = _frame(ax)
    # Start: the sphere of the apex's curvature (centre R behind the apex).
    start, _, _ = reflection_points(O, A - R * ax / np.linalg.norm(ax, axis=-1, keepdims=True), R, L)
    fr = tuple(e[..., None, :] for e in frame)
    s0 = _local(start, A[..., None, :], fr, R)
    u0 = np.where(np.isfinite(s0[..., 0]), s0[..., 0], 0.0)
    v0 = np.where(np.isfinite(s0[..., 1]), s0[..., 1], 0.0)
    o = _local(np.broadcast_to(O, batch + (3,)), A, frame, R)[..., None, :]
    g = _local(L, A[..., None, :], fr, R)
    u, v, step = _newton(tuple(o[..., i] for i in range(3)), tuple(g[..., i] for i in range(3)),
                         u0, v0, k)
    s = u * u + v * v
    z = s / (1.0 + np.sqrt(np.maximum(1.0 - k * s, 0.0)))
    grad_F = np.stack([u, v, k * z - 1.0], axis=-1)  # outward normal of (C)
    normal_loc = grad_F / np.linalg.norm(grad_F, axis=-1, keepdims=True)
    P_loc = np.stack([u, v, z], axis=-1)
    implicit = lambda p: p[..., 0] ** 2 + p[..., 1] ** 2 + k * p[..., 2] ** 2 - 2.0 * p[..., 2]  # noqa: E731
    ok = ((step < CONVERGED_TOL) & (k * s < 1.0) & (implicit(o) > 0) & (implicit(g) > 0)
          & (np.einsum("...i,...i->...", o - P_loc, normal_loc) > 0)
          & (np.einsum("...i,...i->...", g - P_loc, normal_loc) > 0))
    if limbus_depth_m is not None:
        ok &= z * R <= float(limbus_depth_m)
    to_world = lambda x: sum(x[..., i, None] * fr[i] for i in range(3))  # noqa: E731
    points = A[..., None, :] + R * to_world(P_loc)
    points = np.where((step < CONVERGED_TOL)[..., None], points, np.nan)
    return points, to_world(normal_loc), ok


def project_glints_conic(camera: Camera, apex, cornea_axis, cornea_radius: float,
                         asphericity: float, lights_world, *, limbus_depth_m=None,
                         return_points: bool = False):
    """Where each light's reflection on a conic cornea lands in the image (the conic
    counterpart of :func:`project_glints`).

    Parameters
    ----------
    camera : Camera
    apex : (..., 3) float
        Corneal apex in metres; a batch of poses.
    cornea_axis : (..., 3) float
        Unit optical axis of each pose (outward).
    cornea_radius : float
        Apex radius of curvature R (m).
    asphericity : float
        Conic constant Q in (-1, 1]; 0 is the sphere.
    lights_world : (n, 3) or (..., n, 3) float
    limbus_depth_m : float, optional
        The cap: reflection points deeper than this behind the apex are not visible.
    return_points : bool
        Also return the 3D reflection points (..., n, 3).

    Returns
    -------
    glints_px : (..., n, 2) float64
        Image positions (pixel-centre convention); NaN behind the camera or unconverged.
    visible : (..., n) bool
        The reflection exists, lies on the cap, faces camera and light, and is in the image.
    points_m : (..., n, 3) float64
        Only with ``return_points``.
    """
    points, _, ok = conic_reflection_points(camera.position_m, apex, cornea_axis, cornea_radius,
                                            asphericity, lights_world, limbus_depth_m=limbus_depth_m)
    px, _ = camera.project(points)
    visible = ok & camera.in_image(px)
    return (px, visible, points) if return_points else (px, visible)
