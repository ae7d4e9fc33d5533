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

from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from .camera import Camera
from .geometry import as_points

#: Newton iterations stop once every step is a Newton step below this (radians): convergence
#: is quadratic with |F''/2F'| of order one on the cornea, so the error left after such a step
#: is ~1e-16 rad, the double-precision limit. Saves one iteration over waiting for 1e-15.
_STEP_STOP_RAD = 1e-8
_MAX_NEWTON_ITER = 60


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


def _newton_unit(a, b, cp, sp, ct, st):
    """The root of (R) in [0, φ] as (cos θ, sin θ): two Newton steps from (ct, st) (the
    first-order closed form is within ~1e-4 rad, so the second step is already below the
    stopping size), then a bracketed Newton-bisection for the few pairs that did not settle
    (near-grazing light).

    A Newton step δ = F / F' turns the unit vector by -atan(δ) (a normalised (ct + δ st,
    st - δ ct)): the same fixed point as θ - δ and the same quadratic convergence, as
    atan(δ) = δ + O(δ³), without a trigonometric call."""
    ab = a * b
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(2):
            f, df, s1 = _reflection_condition_unit(a, b, ab, cp, sp, ct, st)
            step = f / df
            q = 1.0 / np.sqrt(1.0 + step * step)
            ct, st = (ct + step * st) * q, (st - step * ct) * q
        # Settled: a small last step and θ inside [0, φ] (sin θ >= 0, sin(φ - θ) >= 0).
        done = (np.abs(step) < _STEP_STOP_RAD) & (st >= 0) & (sp * ct - cp * st >= -1e-15)
    if not done.all():
        i = np.nonzero(~done)
        a, b = (np.broadcast_to(q, done.shape) for q in (a, b))
        p = np.arctan2(sp[i], cp[i])
        theta0 = np.clip(np.arctan2(st[i], ct[i]), 0.0, p)
        theta0 = np.where(np.isfinite(theta0), theta0, 0.5 * p)
        theta = _bracketed_root(a[i], b[i], p, sp[i], cp[i], theta0)
        ct, st = ct.copy(), st.copy()
        ct[i], st[i] = np.cos(theta), np.sin(theta)
    return ct, st


def _reflection_condition_unit(a, b, ab, cp, sp, ct, st):
    """F(θ) of (R), F'(θ) and sin(φ - θ) from the cosines and sines of θ and φ."""
    s1 = sp * ct - cp * st  # sin(φ - θ)
    c1 = cp * ct + sp * st  # cos(φ - θ)
    s2 = s1 * ct - c1 * st  # sin(φ - 2θ)
    c2 = c1 * ct + s1 * st  # cos(φ - 2θ)
    f = ab * s2 + a * st - b * s1
    df = a * ct + b * c1 - 2 * ab * c2
    return f, df, s1


def _reflection_condition(a, b, ab, sp, cp, theta):
    """F(θ) of (R) and F'(θ) at the angle θ (the bracketed fallback works in angles)."""
    f, df, _ = _reflection_condition_unit(a, b, ab, cp, sp, np.cos(theta), np.sin(theta))
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


def _quartic_root(alpha, beta, cp, sp):
    """The bracketed root of (R) from the eigenvalues of the quartic's companion matrix, as
    (cos θ, sin θ) after a Newton polish."""
    phi = np.arctan2(sp, cp)
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
    # Newton polish (also the fallback where the companion matrix was ill-posed).
    return _newton_unit(alpha, beta, cp, sp, np.cos(theta), np.sin(theta))


def _first_order_root(alpha, beta, cp, sp):
    """(cos θ₀, sin θ₀): the first-order closed form around the bisector φ / 2, exact for a
    distant camera and light, θ₀ = φ/2 + (α - β) sin(φ/2) / (2αβ - (α + β) cos(φ/2))."""
    ch = np.sqrt(np.maximum(0.5 * (1 + cp), 0.0))  # cos(φ/2), φ in [0, π]
    sh = np.sqrt(np.maximum(0.5 * (1 - cp), 0.0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        d = (alpha - beta) * sh / (2 * alpha * beta - (alpha + beta) * ch)
    d = np.where(np.abs(d) < 1.0, d, 0.0)  # also NaN; the bisector is a safe start
    q = 1.0 / np.sqrt(1.0 + d * d)
    return (ch - d * sh) * q, (sh + d * ch) * q


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



def glint_jacobians(camera: Camera, cornea_center, cornea_radius, lights_world, *,
                    cornea_axis=None, cap_cos_min: float | None = None,
                    radius_and_lights: bool = True, frame: str = "world"):
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
    d_center is computed (the other two are None), which is what a centre fit needs. With
    ``frame="camera"`` d_center and d_light are derivatives with respect to camera-frame
    coordinates (world ones are those times ``camera.rotation``), which saves rotating every
    glint's rows when only sums over glints are needed (JᵀJ rotates as Rᵀ JᵀJ R).

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
    center = as_points(cornea_center, "cornea_center")
    lights = as_points(lights_world, "lights_world")
    if lights.ndim == 1:
        lights = lights[None, :]
    axis = None if cornea_axis is None else as_points(cornea_axis, "cornea_axis")
    if (axis is None) != (cap_cos_min is None):
        raise ValueError("cornea_axis and cap_cos_min must be given together")
    if frame not in ("world", "camera"):
        raise ValueError(f"frame must be 'world' or 'camera', got {frame!r}")
    R = camera.rotation
    T = _jacobian_terms(camera, center, cornea_radius, lights, axis, cap_cos_min)
    shape = T.shape
    glints = _stack((T.u, T.v))
    visible = np.broadcast_to(T.visible, shape)
    R_out = R if frame == "world" else None
    d_center = _rows_to_world(shape, R_out, T.row_u, T.row_v)
    if not radius_and_lights:
        return glints, visible, d_center, None, None
    d_radius = _stack(_radius_rows(T))
    l_t, l_k = T.rr * T.inv_dw * T.inv_g, T.rr * T.inv_dw * T.inv_qk
    n, t, k = (T.nx, T.ny, T.nz), T.t, T.k
    w_perp = [T.sin_i * a + T.cos_i * b for a, b in zip(n, t)]
    rows = []
    for f, p_t, p_k in ((T.fxz, T.pt_x, T.pk_x), (T.fyz, T.pt_y, T.pk_y)):
        s_t, s_k = f * l_t * p_t, f * l_k * p_k
        rows.append(tuple(s_t * a + s_k * b for a, b in zip(w_perp, k)))
    return glints, visible, d_center, d_radius, _rows_to_world(shape, R_out, *rows)


def _radius_rows(T: SimpleNamespace):
    """d u / d r and d v / d r from :func:`_jacobian_terms` (dP/dr = n - (r D sin i / g) t)."""
    return (T.fxz * (T.nx - T.xz * T.nz - T.b_tn * T.pt_x),
            T.fyz * (T.ny - T.yz * T.nz - T.b_tn * T.pt_y))


def _jacobian_terms(camera: Camera, center, radius, lights, axis=None, cap_cos_min=None,
                    with_visibility: bool = True) -> SimpleNamespace:
    """Glints and the camera-frame rows of d glint / d centre, as component arrays (...,  n),
    with the intermediate terms the radius and light derivatives reuse.

    Everything is in the camera frame, where the pinhole Jacobian rows are f/Z (1, 0, -X/Z) and
    f/Z (0, 1, -Y/Z); derivatives with respect to world positions are those times R. A cornea
    fit needs only these rows' sums over glints, so it takes them from here unassembled."""
    R = camera.rotation
    c_loc, L_loc = _to_local(camera.position_m, R, center, lights)
    sol = _solve_local(c_loc, radius, L_loc, "newton")
    if with_visibility:
        u, v, iz, visible = _visibility_local(camera, sol, None if axis is None else _apply(R, axis), cap_cos_min)
    else:
        X, Y, Z = sol.point
        with np.errstate(divide="ignore", invalid="ignore"):
            iz = 1.0 / Z
        u, v, visible = camera.fx_px * X * iz + camera.cx_px, camera.fy_px * Y * iz + camera.cy_px, None
    a, b, ct, st, c1, rr = sol.alpha, sol.beta, sol.ct, sol.st, sol.c1, sol.plane.r
    # Distances and incidence angle from the in-plane solution (scaled by r).
    inv_qa = 1.0 / np.sqrt(np.maximum(a * a - 2 * a * ct + 1, 1e-300))
    qb = np.sqrt(np.maximum(b * b - 2 * b * c1 + 1, 1e-300))
    cos_i = (a * ct - 1) * inv_qa
    sin_i = a * st * inv_qa
    inv_du, inv_dw = inv_qa / rr, 1.0 / (rr * qb)
    rH, rD = rr * (inv_du + inv_dw), rr * (inv_dw - inv_du)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_g = 1.0 / (2 + rH * cos_i)
        inv_qk = 1.0 / (2 * cos_i + rH)
    b_tn = rD * sin_i * inv_g
    (e1x, e1y, e1z), (e2x, e2y, e2z) = sol.plane.e1, sol.plane.e2
    nx, ny, nz = sol.normal
    tx, ty, tz = st * e1x - ct * e2x, st * e1y - ct * e2y, st * e1z - ct * e2z
    kx, ky, kz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    X, Y, _ = sol.point
    xz, yz = X * iz, Y * iz
    fxz, fyz = camera.fx_px * iz, camera.fy_px * iz
    # Pinhole rows applied to t and k (the J_pi t and J_pi k of the docstring, over f/Z).
    pt_x, pt_y = tx - xz * tz, ty - yz * tz
    pk_x, pk_y = kx - xz * kz, ky - yz * kz
    # dP/dc = I - t ((1 - a_t) t + b n)ᵀ - (1 - a_k) k kᵀ, since n nᵀ + t tᵀ + k kᵀ = I.
    m_t, m_k = 1 - 2 * inv_g, 1 - 2 * cos_i * inv_qk
    wx, wy, wz = m_t * tx + b_tn * nx, m_t * ty + b_tn * ny, m_t * tz + b_tn * nz
    qx, qy = m_k * pk_x, m_k * pk_y
    row_u = (fxz * (1 - pt_x * wx - qx * kx), fxz * -(pt_x * wy + qx * ky), fxz * -(xz + pt_x * wz + qx * kz))
    row_v = (fyz * -(pt_y * wx + qy * kx), fyz * (1 - pt_y * wy - qy * ky), fyz * -(yz + pt_y * wz + qy * kz))
    return SimpleNamespace(
        shape=sol.ct.shape, u=u, v=v, visible=visible, row_u=row_u, row_v=row_v, rr=rr,
        nx=nx, ny=ny, nz=nz, t=(tx, ty, tz), k=(kx, ky, kz), xz=xz, yz=yz, fxz=fxz, fyz=fyz,
        pt_x=pt_x, pt_y=pt_y, pk_x=pk_x, pk_y=pk_y, b_tn=b_tn, sin_i=sin_i, cos_i=cos_i,
        inv_dw=inv_dw, inv_g=inv_g, inv_qk=inv_qk)


def _rows_to_world(shape, R, row_u, row_v):
    """(..., 2, 3) derivatives from their camera-frame rows (3 component arrays each): with
    respect to world positions, d/dX_world = d/dX_camera R, written out per element; with
    respect to camera-frame positions if ``R`` is None."""
    out = np.empty(shape + (2, 3))
    for i, (a0, a1, a2) in enumerate((row_u, row_v)):
        for j in range(3):
            out[..., i, j] = (a0, a1, a2)[j] if R is None else a0 * R[0, j] + a1 * R[1, j] + a2 * R[2, j]
    return out
