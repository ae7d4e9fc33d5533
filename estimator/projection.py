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

import numpy as np

from .camera import Camera
from .geometry import as_points

#: Newton iterations stop once every step is a Newton step below this (radians): convergence
#: is quadratic with |F''/2F'| of order one on the cornea, so the error left after such a step
#: is ~1e-16 rad, the double-precision limit. Saves one iteration over waiting for 1e-15.
_STEP_STOP_RAD = 1e-8
_MAX_NEWTON_ITER = 60


def _plane_frame(camera_position_m, cornea_center_m, cornea_radius_m, lights_world_m):
    """Scaled in-plane quantities for every (pose, light) pair, broadcast to (..., n).

    Works on x, y, z component arrays: reductions over a length-3 axis are several times
    slower in numpy than the same arithmetic written out.
    """
    O = as_points(camera_position_m, "camera_position_m")
    c = as_points(cornea_center_m, "cornea_center_m")
    L = as_points(lights_world_m, "lights_world_m")
    if L.ndim == 1:
        L = L[None, :]
    r = np.asarray(cornea_radius_m, dtype=np.float64)
    if np.any(~(r > 0)) or np.any(~np.isfinite(r)):
        raise ValueError(f"cornea_radius_m must be positive and finite, got {cornea_radius_m}")
    o = O - c  # (..., 3)
    o_norm = np.sqrt(o[..., 0] ** 2 + o[..., 1] ** 2 + o[..., 2] ** 2)
    e1 = o / np.where(o_norm > 0, o_norm, 1.0)[..., None]
    # Per pose, a fixed unit vector perpendicular to e1 for the degenerate plane (a light on
    # the line through O and c, where θ = 0 or π and any plane through the line will do).
    fb = np.cross(e1, np.array([0.0, 0.0, 1.0]))
    fb = np.where(np.linalg.norm(fb, axis=-1, keepdims=True) > 1e-6, fb,
                  np.cross(e1, np.array([1.0, 0.0, 0.0])))
    fb = fb / np.linalg.norm(fb, axis=-1, keepdims=True)
    e1x, e1y, e1z = (e1[..., i][..., None] for i in range(3))
    lx = L[..., 0] - c[..., 0][..., None]
    ly = L[..., 1] - c[..., 1][..., None]
    lz = L[..., 2] - c[..., 2][..., None]
    l_par = lx * e1x + ly * e1y + lz * e1z
    px, py, pz = lx - l_par * e1x, ly - l_par * e1y, lz - l_par * e1z
    l_perp = np.sqrt(px * px + py * py + pz * pz)
    l_norm = np.sqrt(l_par * l_par + l_perp * l_perp)
    degenerate = l_perp <= 1e-12 * l_norm
    inv = 1.0 / np.where(degenerate, 1.0, l_perp)
    e2 = [np.where(degenerate, fb[..., i][..., None], q * inv) for i, q in enumerate((px, py, pz))]
    r_b = r[..., None] if r.ndim else r
    alpha = o_norm[..., None] / r_b
    beta = l_norm / r_b
    phi = np.arctan2(l_perp, l_par)
    alpha, beta, phi = np.broadcast_arrays(alpha, beta, phi)
    return c, r, (e1x, e1y, e1z), e2, alpha, beta, phi


def _newton_root(alpha, beta, phi, theta0):
    """The root of (R) in [0, φ]: two plain Newton steps from ``theta0`` (the first-order closed
    form is within ~1e-4 rad, so the second step is already below the stopping size), then a
    bracketed Newton-bisection for the few pairs that did not settle (near-grazing light)."""
    shape = phi.shape
    a, b, p = (np.ravel(x) for x in (alpha, beta, phi))
    theta = np.clip(np.ravel(theta0), 0.0, p)
    sp, cp = np.sin(p), np.cos(p)
    ab = a * b
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(2):
            f, df = _reflection_condition(a, b, ab, sp, cp, theta)
            step = f / df
            theta = theta - step
    done = (np.abs(step) < _STEP_STOP_RAD) & (theta >= 0) & (theta <= p)  # NaN -> False
    if not done.all():
        i = np.flatnonzero(~done)
        theta[i] = _bracketed_root(a[i], b[i], p[i], sp[i], cp[i], np.clip(np.ravel(theta0)[i], 0, p[i]))
    return theta.reshape(shape)


def _reflection_condition(a, b, ab, sp, cp, theta):
    """F(θ) of (R) and F'(θ), from sin θ and cos θ and the angle-sum identities."""
    st, ct = np.sin(theta), np.cos(theta)
    s2, c2 = 2 * st * ct, ct * ct - st * st
    s_pt = sp * ct - cp * st  # sin(φ - θ)
    c_pt = cp * ct + sp * st  # cos(φ - θ)
    f = ab * (sp * c2 - cp * s2) + a * st - b * s_pt
    df = -2 * ab * (cp * c2 + sp * s2) + a * ct + b * c_pt
    return f, df


def _bracketed_root(a, b, p, sp, cp, theta):
    """Safeguarded Newton on [0, φ]: F(0) > 0 > F(φ) and F decreases through the root; a step
    that leaves the bracket is replaced by bisection. Converged pairs drop out."""
    out = theta.copy()
    idx = np.arange(theta.size)
    lo, hi = np.zeros_like(p), p.copy()
    for _ in range(_MAX_NEWTON_ITER):
        f, df = _reflection_condition(a, b, a * b, sp, cp, theta)
        pos = f > 0
        np.copyto(lo, theta, where=pos)
        np.copyto(hi, theta, where=~pos)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = f / df
        new = theta - step
        bad = ~((new >= lo) & (new <= hi))  # also catches NaN from df == 0
        np.copyto(new, 0.5 * (lo + hi), where=bad)
        out[idx] = new
        active = bad | (np.abs(step) >= _STEP_STOP_RAD)
        if not active.any():
            break
        idx = idx[active]
        a, b, p, sp, cp = a[active], b[active], p[active], sp[active], cp[active]
        lo, hi, theta = lo[active], hi[active], new[active]
    return out


def reflection_quartic(alpha, beta, phi) -> np.ndarray:
    """(..., 5) coefficients, highest power first, of the reflection quartic in t = tan(θ/2)."""
    alpha, beta, phi = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (alpha, beta, phi)))
    s, c = np.sin(phi), np.cos(phi)
    ab = alpha * beta
    return np.stack(
        [
            beta * s * (alpha + 1),
            2 * (2 * ab * c + alpha + beta * c),
            -6 * ab * s,
            2 * (alpha + beta * c - 2 * ab * c),
            beta * s * (alpha - 1),
        ],
        axis=-1,
    )


def _quartic_root(alpha, beta, phi):
    """The bracketed root of (R) from the eigenvalues of the quartic's companion matrix."""
    coeffs = reflection_quartic(alpha, beta, phi)
    lead = coeffs[..., 0]
    ok = np.abs(lead) > 1e-300
    norm = coeffs[..., 1:] / np.where(ok, lead, 1.0)[..., None]
    shape = coeffs.shape[:-1]
    comp = np.zeros(shape + (4, 4))
    comp[..., 0, :] = -norm
    comp[..., 1, 0] = comp[..., 2, 1] = comp[..., 3, 2] = 1.0
    roots = np.linalg.eigvals(comp.reshape(-1, 4, 4)).reshape(shape + (4,))
    t_max = np.tan(np.minimum(phi, np.pi * (1 - 1e-12)) / 2)[..., None]
    real = roots.real
    # Closest root to the real segment [0, tan(φ/2)], in the complex plane.
    dist = np.abs(roots.imag) + np.maximum(0.0, -real) + np.maximum(0.0, real - t_max)
    best = np.take_along_axis(real, np.argmin(dist, axis=-1)[..., None], axis=-1)[..., 0]
    theta = 2 * np.arctan(np.clip(best, 0.0, t_max[..., 0]))
    theta = np.where(ok, theta, phi / 2)
    # Newton polish in θ (also the fallback where the companion matrix was ill-posed).
    return _newton_root(alpha, beta, phi, theta)


def _solve(camera_position_m, cornea_center_m, cornea_radius_m, lights_world_m, solver):
    """Reflection points and the in-plane quantities the Jacobians reuse."""
    c, r, e1, e2, alpha, beta, phi = _plane_frame(
        camera_position_m, cornea_center_m, cornea_radius_m, lights_world_m)
    outside = (alpha > 1) & (beta > 1)
    # With the camera or a light inside the sphere there is no reflection; solve a harmless
    # stand-in problem there so that the iteration's stopping test only sees real ones.
    alpha = np.where(outside, alpha, 2.0)
    beta = np.where(outside, beta, 2.0)
    if solver == "newton":
        # First-order closed form around the bisector (exact for a distant camera and light).
        half = phi / 2
        denom = 2 * alpha * beta - (alpha + beta) * np.cos(half)
        with np.errstate(divide="ignore", invalid="ignore"):
            theta0 = half + (alpha - beta) * np.sin(half) / denom
        theta0 = np.where(np.isfinite(theta0), theta0, half)
        theta = _newton_root(alpha, beta, phi, theta0)
    elif solver == "quartic":
        theta = _quartic_root(alpha, beta, phi)
    else:
        raise ValueError(f"solver must be 'newton' or 'quartic', got {solver!r}")
    ct, st = np.cos(theta), np.sin(theta)
    normals = np.stack([ct * a + st * b for a, b in zip(e1, e2)], axis=-1)
    r_b = r[..., None, None] if r.ndim else r
    points = c[..., None, :] + r_b * normals
    ok = outside & (alpha * ct > 1) & (beta * np.cos(phi - theta) > 1)
    return points, normals, ok, (e1, e2, ct, st, alpha, beta, phi, r)


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
    points, normals, ok, _ = _solve(camera_position_m, cornea_center_m, cornea_radius_m,
                                    lights_world_m, solver)
    return points, normals, ok


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


def _visibility(camera, points, normals, ok, axis, cap_cos_min):
    """Pixels of reflection points, and which glints are seen: on the cap, in the image."""
    if axis is not None:
        ok = ok & (np.einsum("...nk,...k->...n", normals, axis) >= cap_cos_min)
    glints, depth = camera.project(points)
    visible = ok & (depth > 0) & camera.in_image(np.nan_to_num(glints, nan=-1e9))
    return glints, visible


def _project_block(camera, center, radius, lights, axis, cap_cos_min, solver, return_points):
    points, normals, ok, _ = _solve(camera.position_m, center, radius, lights, solver)
    glints, visible = _visibility(camera, points, normals, ok, axis, cap_cos_min)
    if return_points:
        return glints, visible, points
    return glints, visible


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



def glint_jacobians(camera: Camera, cornea_center, cornea_radius, lights_world, *,
                    cornea_axis=None, cap_cos_min: float | None = None,
                    radius_and_lights: bool = True):
    """Glints and their derivatives with respect to the cornea centre, the corneal radius and
    the light positions, in closed form.

    Implicit differentiation of the law of reflection at P = c + r n: with u, w the unit vectors
    from P to the camera and to the light (distances d_u, d_w), i the angle of incidence, t the
    in-plane tangent toward the camera (u = cos i n + sin i t, w = cos i n - sin i t) and k the
    normal of the plane of reflection, the tangential part of u + w must stay zero. In the
    (n, t, k) frame the linearised condition is diagonal, which gives, with H = 1/d_u + 1/d_w,
    D = 1/d_w - 1/d_u, g = 2 + r H cos i and w' = sin i n + cos i t,

        dP/dc = n nᵀ + (2/g) t tᵀ - (r D sin i / g) t nᵀ + (2 cos i / (2 cos i + r H)) k kᵀ
        dP/dr = n - (r D sin i / g) t
        dP/dL = (r / d_w) [ t w'ᵀ / g + k kᵀ / (2 cos i + r H) ]

    followed by the pinhole Jacobian. About five times cheaper than general 3x3 algebra, and
    checked against finite differences in the tests. With ``radius_and_lights=False`` only
    d_center is computed (the other two are None), which is what a centre fit needs.

    Returns
    -------
    glints_px : (..., n, 2)
    visible : (..., n) bool
    d_center : (..., n, 2, 3)
        d glint / d cornea centre (px per metre).
    d_radius : (..., n, 2)
        d glint / d corneal radius (px per metre).
    d_light : (..., n, 2, 3)
        d glint / d light position (px per metre).
    """
    axis = None if cornea_axis is None else as_points(cornea_axis, "cornea_axis")
    if (axis is None) != (cap_cos_min is None):
        raise ValueError("cornea_axis and cap_cos_min must be given together")
    points, n, ok, (e1, e2, ct, st, alpha, beta, phi, r) = _solve(
        camera.position_m, cornea_center, cornea_radius, lights_world, "newton")
    glints, visible = _visibility(camera, points, n, ok, axis, cap_cos_min)
    rr = r[..., None] if r.ndim else r
    # Distances and incidence angle from the in-plane solution (scaled by r).
    qa = np.sqrt(np.maximum(alpha * alpha - 2 * alpha * ct + 1, 1e-300))
    cpt = np.cos(phi) * ct + np.sin(phi) * st  # cos(φ - θ)
    qb = np.sqrt(np.maximum(beta * beta - 2 * beta * cpt + 1, 1e-300))
    cos_i = (alpha * ct - 1) / qa
    sin_i = alpha * st / qa
    inv_du, inv_dw = 1 / (rr * qa), 1 / (rr * qb)
    H, D = inv_du + inv_dw, inv_dw - inv_du
    g = 2 + rr * H * cos_i
    qk = 2 * cos_i + rr * H
    with np.errstate(divide="ignore", invalid="ignore"):
        a_t, b_tn, a_k = 2 / g, rr * D * sin_i / g, 2 * cos_i / qk
        l_t, l_k = rr * inv_dw / g, rr * inv_dw / qk
    t = np.stack([st * x - ct * y for x, y in zip(e1, e2)], axis=-1)
    k = np.stack([e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                  e1[0] * e2[1] - e1[1] * e2[0]], axis=-1)
    # Pinhole Jacobian J_pi (2x3 per glint): rows f (R_x - (X/Z) R_z) / Z and f (R_y - (Y/Z) R_z) / Z.
    R = camera.rotation
    pc = (points - camera.position_m) @ R.T
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = 1 / pc[..., 2]
    xz, yz = pc[..., 0] * iz, pc[..., 1] * iz
    fxz, fyz = camera.fx_px * iz, camera.fy_px * iz
    Jpi = np.stack([np.stack([fxz * (R[0, j] - xz * R[2, j]) for j in range(3)], -1),
                    np.stack([fyz * (R[1, j] - yz * R[2, j]) for j in range(3)], -1)], -2)
    Pt = (Jpi @ t[..., None])[..., 0]
    Pk = (Jpi @ k[..., None])[..., 0]
    outer = lambda p, v: p[..., :, None] * v[..., None, :]  # noqa: E731
    # dP/dc = I - t ((1 - a_t) t + b n)ᵀ - (1 - a_k) k kᵀ, since n nᵀ + t tᵀ + k kᵀ = I.
    d_center = Jpi - outer(Pt, (1 - a_t)[..., None] * t + b_tn[..., None] * n) \
        - outer((1 - a_k)[..., None] * Pk, k)
    if not radius_and_lights:
        return glints, visible, d_center, None, None
    d_radius = np.einsum("...ij,...j->...i", Jpi, n) - b_tn[..., None] * Pt
    w_perp = sin_i[..., None] * n + cos_i[..., None] * t
    d_light = outer(l_t[..., None] * Pt, w_perp) + outer(l_k[..., None] * Pk, k)
    return glints, visible, d_center, d_radius, d_light
