"""The wire option's highlight alternation compiled with Numba (optional): the virtual sources of
:mod:`estimator.geometry.wire_fast` one (sample, glint) pair at a time.

A band of the ``light_model = "wire_mirror"`` fit holds a few glints, and each evaluation of
its Levenberg-Marquardt step solves their highlights by the two-bounce alternation
(:mod:`estimator.geometry.wire`): ~4 rounds of a sphere reflection (the cornea, W as the
source) and a cylinder reflection (the turn, P as the viewer). In numpy each round is ~60 calls
on arrays of a few elements; profiled on prototype_ov5647_wire with 4 glints a band, one band a
call, the alternation was 72 % of the band step (5.2 of 7.2 s over 60 bands). Here the same
arithmetic runs as one loop:

* the sphere: the plane through the centre, camera and source, the first-order root, two
  Newton steps and the bracketed fallback (:func:`estimator.geometry.compiled._root`, the
  compiled projection's own root);
* the cylinder: the same planar problem in the cross-section and the axial coordinate of the
  unfolded path, Eq. (A) of :mod:`estimator.geometry.wire`.

Each pair stops when its own highlight moves less than the tolerance (numpy stops when every
pair has), so the two agree to the tolerance, not to the last bit (tested: 1e-12 m of highlight
at the fits' 1e-11 m tolerance). With ``rounds`` given both run exactly that many rounds.
Without Numba (or with ``NUMBA_DISABLE_JIT=1``) :data:`ENABLED` is False and the caller runs
the numpy alternation.
"""

from __future__ import annotations

import math

import numpy as np

from .compiled import ENABLED as _COMPILED
from .compiled import _jacobian_rows, _root, camera_arrays

try:
    import numba
except ImportError:  # the numpy alternation runs instead
    numba = None

#: Whether :func:`highlights` runs compiled (Numba imports and its JIT is on).
ENABLED = bool(_COMPILED) and numba is not None

__all__ = ["ENABLED", "highlights", "glints_and_rows"]


def _plane_basis(lx, ly, lz, e1x, e1y, e1z):
    """The plane of reflection spanned by unit ``e1`` (toward the viewpoint) and the source
    offset ``l`` from the sphere's centre: l's components along e1 and normal to it, |l|,
    1 / |l| (1 where l = 0) and the unit e2 normal to e1 in the plane (any plane through e1
    where l lies on its line)."""
    l_par = lx * e1x + ly * e1y + lz * e1z
    px, py, pz = lx - l_par * e1x, ly - l_par * e1y, lz - l_par * e1z
    l_perp = math.sqrt(px * px + py * py + pz * pz)
    l_norm = math.sqrt(l_par * l_par + l_perp * l_perp)
    inv_n = 1.0 / l_norm if l_norm > 0 else 1.0
    if l_perp <= 1e-12 * l_norm:  # source on the line through the viewpoint and the centre
        fx, fy, fz = e1y, -e1x, 0.0
        if math.sqrt(fx * fx + fy * fy) <= 1e-6:
            fx, fy, fz = 0.0, e1z, -e1y
        fn = math.sqrt(fx * fx + fy * fy + fz * fz)
        return l_par, l_perp, l_norm, inv_n, fx / fn, fy / fn, fz / fn
    return l_par, l_perp, l_norm, inv_n, px / l_perp, py / l_perp, pz / l_perp


def _sphere_point(O, c, r, W, out):
    """Reflection point on the sphere (centre ``c``, radius ``r``) of light from ``W`` toward
    ``O`` into ``out`` (3,) (world frame; :func:`estimator.geometry.reflection_points`, whose
    point it returns whether or not the reflection faces both ends)."""
    dx, dy, dz = O[0] - c[0], O[1] - c[1], O[2] - c[2]
    o_norm = math.sqrt(dx * dx + dy * dy + dz * dz)
    inv_o = 1.0 / o_norm if o_norm > 0 else 1.0
    e1x, e1y, e1z = dx * inv_o, dy * inv_o, dz * inv_o
    lx, ly, lz = W[0] - c[0], W[1] - c[1], W[2] - c[2]
    l_par, l_perp, l_norm, inv_n, e2x, e2y, e2z = _plane_basis(lx, ly, lz, e1x, e1y, e1z)
    a, b = o_norm / r, l_norm / r
    if not (a > 1 and b > 1):
        a, b = 2.0, 2.0
    ct, st = _root(a, b, l_par * inv_n, l_perp * inv_n)
    out[0] = c[0] + r * (ct * e1x + st * e2x)
    out[1] = c[1] + r * (ct * e1y + st * e2y)
    out[2] = c[2] + r * (ct * e1z + st * e2z)


def _cylinder_point(A, ax, rho, L, X, out):
    """Highlight on the cylinder (axis point ``A``, unit axis ``ax``, radius ``rho``) of light
    from ``L`` toward ``X`` into ``out`` (3,): :func:`estimator.geometry.wire.cylinder_reflection`'s
    point."""
    lr0, lr1, lr2 = L[0] - A[0], L[1] - A[1], L[2] - A[2]
    xr0, xr1, xr2 = X[0] - A[0], X[1] - A[1], X[2] - A[2]
    la = lr0 * ax[0] + lr1 * ax[1] + lr2 * ax[2]
    xa = xr0 * ax[0] + xr1 * ax[1] + xr2 * ax[2]
    lp0, lp1, lp2 = lr0 - la * ax[0], lr1 - la * ax[1], lr2 - la * ax[2]
    xp0, xp1, xp2 = xr0 - xa * ax[0], xr1 - xa * ax[1], xr2 - xa * ax[2]
    x_norm = math.sqrt(xp0 * xp0 + xp1 * xp1 + xp2 * xp2)
    inv_x = 1.0 / x_norm if x_norm > 0 else 1.0
    e10, e11, e12 = xp0 * inv_x, xp1 * inv_x, xp2 * inv_x
    l_par = lp0 * e10 + lp1 * e11 + lp2 * e12
    q0, q1, q2 = lp0 - l_par * e10, lp1 - l_par * e11, lp2 - l_par * e12
    l_perp = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    l_norm = math.hypot(l_par, l_perp)
    if l_perp > 1e-15 * max(l_norm, 1e-300):
        e20, e21, e22 = q0 / l_perp, q1 / l_perp, q2 / l_perp
    else:  # the source on the viewer's line through the axis (θ = 0)
        e20 = ax[1] * e12 - ax[2] * e11
        e21 = ax[2] * e10 - ax[0] * e12
        e22 = ax[0] * e11 - ax[1] * e10
    inv_n = 1.0 / l_norm if l_norm > 0 else 1.0
    a, b = x_norm / rho, l_norm / rho
    if not (a > 1 and b > 1):
        a, b = 2.0, 2.0
    ct, st = _root(a, b, l_par * inv_n, l_perp * inv_n)
    w0 = rho * (ct * e10 + st * e20)
    w1 = rho * (ct * e11 + st * e21)
    w2 = rho * (ct * e12 + st * e22)
    d_x = math.sqrt((xp0 - w0) ** 2 + (xp1 - w1) ** 2 + (xp2 - w2) ** 2)
    d_l = math.sqrt((lp0 - w0) ** 2 + (lp1 - w1) ** 2 + (lp2 - w2) ** 2)
    den = d_l + d_x
    s = (la * d_x + xa * d_l) / (den if den > 0 else 1.0)
    out[0] = A[0] + w0 + s * ax[0]
    out[1] = A[1] + w1 + s * ax[1]
    out[2] = A[2] + w2 + s * ax[2]


def _highlights_kernel(O, c, r, W, axes, ax, rho, L, tol, max_rounds, fixed, step_out):
    """The alternation of every pair (b, j) of ``W`` (B, k, 3), in place; ``step_out`` (B, k)
    its last move (m; inf where a round gave no finite point)."""
    P = np.empty(3)
    Wn = np.empty(3)
    for bi in range(W.shape[0]):
        for j in range(W.shape[1]):
            step = math.inf
            for _ in range(max_rounds):
                _sphere_point(O, c[bi], r, W[bi, j], P)
                if not (math.isfinite(P[0]) and math.isfinite(P[1]) and math.isfinite(P[2])):
                    for i in range(3):
                        P[i] = 0.5 * (W[bi, j, i] + O[i])
                _cylinder_point(axes[bi, j], ax, rho, L, P, Wn)
                moved = math.sqrt((Wn[0] - W[bi, j, 0]) ** 2 + (Wn[1] - W[bi, j, 1]) ** 2
                                  + (Wn[2] - W[bi, j, 2]) ** 2)
                step = moved if math.isfinite(moved) else math.inf
                if math.isfinite(Wn[0]) and math.isfinite(Wn[1]) and math.isfinite(Wn[2]):
                    for i in range(3):
                        W[bi, j, i] = Wn[i]
                if not fixed and step <= tol:
                    break
            step_out[bi, j] = step


def _light_rows(R, intr, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz,
                X, Y, Z, jac, i):
    """Row i of d glint / d light (2, 3), world frame: dP/dL = (r / d_w) [t w'ᵀ / g + k kᵀ /
    (2 cos i + r H)] through the pinhole (:func:`estimator.geometry.glint_jacobians`)."""
    inv_qa = 1.0 / math.sqrt(max(a * a - 2 * a * ct + 1, 1e-300))
    qb = math.sqrt(max(b * b - 2 * b * c1 + 1, 1e-300))
    cos_i = (a * ct - 1) * inv_qa
    sin_i = a * st * inv_qa
    inv_du, inv_dw = inv_qa / radius, 1.0 / (radius * qb)
    rH = radius * (inv_du + inv_dw)
    inv_g = 1.0 / (2 + rH * cos_i)
    inv_qk = 1.0 / (2 * cos_i + rH)
    tx, ty, tz = st * e1x - ct * e2x, st * e1y - ct * e2y, st * e1z - ct * e2z
    kx, ky, kz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    iz = 1.0 / Z
    xz, yz = X * iz, Y * iz
    l_t, l_k = radius * inv_dw * inv_g, radius * inv_dw * inv_qk
    wx, wy, wz = sin_i * nx + cos_i * tx, sin_i * ny + cos_i * ty, sin_i * nz + cos_i * tz
    pt_x, pt_y = tx - xz * tz, ty - yz * tz
    pk_x, pk_y = kx - xz * kz, ky - yz * kz
    for row in range(2):
        f = intr[row] * iz
        s_t = f * l_t * (pt_x if row == 0 else pt_y)
        s_k = f * l_k * (pk_x if row == 0 else pk_y)
        r0, r1, r2 = s_t * wx + s_k * kx, s_t * wy + s_k * ky, s_t * wz + s_k * kz
        for j in range(3):
            jac[i, row, j] = r0 * R[0, j] + r1 * R[1, j] + r2 * R[2, j]


def _glints_rows_kernel(R, O, intr, c, radius, W, g, d_c, d_l):
    """Glints (B, k, 2), d glint / d centre and d glint / d light (B, k, 2, 3) of sources ``W``
    (B, k, 3) on the spheres ``c`` (B, 3): :func:`estimator.geometry.glint_jacobians` without
    the visibility (NaN behind the camera)."""
    for bi in range(W.shape[0]):
        d0, d1, d2 = c[bi, 0] - O[0], c[bi, 1] - O[1], c[bi, 2] - O[2]
        cx = R[0, 0] * d0 + R[0, 1] * d1 + R[0, 2] * d2
        cy = R[1, 0] * d0 + R[1, 1] * d1 + R[1, 2] * d2
        cz = R[2, 0] * d0 + R[2, 1] * d1 + R[2, 2] * d2
        o_norm = math.sqrt(cx * cx + cy * cy + cz * cz)
        inv_o = 1.0 / o_norm if o_norm > 0 else 1.0
        e1x, e1y, e1z = -cx * inv_o, -cy * inv_o, -cz * inv_o
        for j in range(W.shape[1]):
            q0, q1, q2 = W[bi, j, 0] - O[0], W[bi, j, 1] - O[1], W[bi, j, 2] - O[2]
            lx = R[0, 0] * q0 + R[0, 1] * q1 + R[0, 2] * q2 - cx
            ly = R[1, 0] * q0 + R[1, 1] * q1 + R[1, 2] * q2 - cy
            lz = R[2, 0] * q0 + R[2, 1] * q1 + R[2, 2] * q2 - cz
            l_par, l_perp, l_norm, inv_n, e2x, e2y, e2z = _plane_basis(lx, ly, lz,
                                                                       e1x, e1y, e1z)
            a, b = o_norm / radius, l_norm / radius
            if not (a > 1 and b > 1):
                a, b = 2.0, 2.0
            cp, sp = l_par * inv_n, l_perp * inv_n
            ct, st = _root(a, b, cp, sp)
            nx, ny, nz = ct * e1x + st * e2x, ct * e1y + st * e2y, ct * e1z + st * e2z
            X, Y, Z = cx + radius * nx, cy + radius * ny, cz + radius * nz
            if not Z > 0:
                for row in range(2):
                    g[bi, j, row] = math.nan
                    for m in range(3):
                        d_c[bi, j, row, m] = math.nan
                        d_l[bi, j, row, m] = math.nan
                continue
            g[bi, j, 0] = intr[0] * X / Z + intr[2]
            g[bi, j, 1] = intr[1] * Y / Z + intr[3]
            c1 = cp * ct + sp * st
            _jacobian_rows(R, intr, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y, e2z,
                           nx, ny, nz, X, Y, Z, d_c[bi], j)
            _light_rows(R, intr, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y, e2z,
                        nx, ny, nz, X, Y, Z, d_l[bi], j)


if ENABLED:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _plane_basis = _jit(_plane_basis)
    _sphere_point = _jit(_sphere_point)
    _cylinder_point = _jit(_cylinder_point)
    _highlights_kernel = _jit(_highlights_kernel)
    _light_rows = _jit(_light_rows)
    _glints_rows_kernel = _jit(_glints_rows_kernel)


def glints_and_rows(camera, centers_m, radius_m: float, sources_m):
    """Glints of the sources and their derivatives, compiled: ``(glints_px (B, k, 2),
    d_center (B, k, 2, 3), d_light (B, k, 2, 3))`` as :func:`estimator.geometry.glint_jacobians`
    gives them (its visibility aside; NaN behind the camera).

    Parameters
    ----------
    camera : Camera
    centers_m : (B, 3) float
    radius_m : float
    sources_m : (B, k, 3) float
    """
    W = np.ascontiguousarray(sources_m, dtype=np.float64)
    B, k = W.shape[:2]
    R, O, intr, _ = camera_arrays(camera)
    g = np.empty((B, k, 2))
    d_c, d_l = np.empty((B, k, 2, 3)), np.empty((B, k, 2, 3))
    _glints_rows_kernel(R, O, intr, np.ascontiguousarray(centers_m, dtype=np.float64).reshape(B, 3),
                        float(radius_m), W, g, d_c, d_l)
    return g, d_c, d_l


def highlights(camera_position_m, centers_m, radius_m: float, start_m, axes_m, axis_dir,
               wire_radius_m: float, led_m, *, tol_m: float, max_rounds: int,
               rounds: int | None = None):
    """The highlights of the turns whose axis points are ``axes_m``, by the compiled
    alternation (module docstring).

    Parameters
    ----------
    camera_position_m : (3,) float
    centers_m : (B, 3) float
        Cornea centres.
    radius_m : float
    start_m : (B, k, 3) float
        Where each pair's alternation starts.
    axes_m : (B, k, 3) float
        Each pair's turn axis point (mid-width).
    axis_dir : (3,) float
        The turns' unit axis (the arc plane's normal).
    wire_radius_m : float
    led_m : (3,) float
    tol_m : float
        A pair stops when its highlight moves less than this in a round.
    max_rounds : int
    rounds : int, optional
        Run exactly this many rounds.

    Returns
    -------
    sources_m : (B, k, 3) float
    step_m : (B, k) float
        Each pair's last move (inf where no finite point came).
    """
    W = np.array(start_m, dtype=np.float64, order="C")
    B, k = W.shape[:2]
    step = np.empty((B, k))
    _highlights_kernel(np.ascontiguousarray(camera_position_m, dtype=np.float64).reshape(3),
                       np.ascontiguousarray(centers_m, dtype=np.float64).reshape(B, 3), float(radius_m),
                       W, np.ascontiguousarray(np.broadcast_to(axes_m, W.shape), dtype=np.float64),
                       np.ascontiguousarray(axis_dir, dtype=np.float64).reshape(3), float(wire_radius_m),
                       np.ascontiguousarray(led_m, dtype=np.float64).reshape(3), float(tol_m),
                       int(max_rounds if rounds is None else rounds), rounds is not None, step)
    return W, step
