"""The glint projection of one cornea pose, compiled with Numba (optional): the tracker's
cheap path predicts a band's glints from one pose and fits a few of them, where numpy's
cost is the overhead of ~100 calls on arrays of 5-40 elements, not the arithmetic.

:func:`glints_one_pose` is :func:`estimator.geometry.project_glints` for one cornea centre:
the same plane of reflection, first-order start, two Newton steps on (R) and bracketed
Newton-bisection for the pairs that do not settle (:mod:`estimator.geometry.reflection`,
:mod:`estimator.geometry.roots`), the same cap, facing and image tests, written one light at
a time. Both give the same glints to ~1e-12 px and the same visibility (tested). Without Numba
(or with ``NUMBA_DISABLE_JIT=1``) :func:`glints_one_pose` calls the numpy function instead:
same answers, slower (:data:`ENABLED` says which runs).
"""

from __future__ import annotations

import math

import numpy as np

from .camera import Camera
from .jacobians import glint_jacobians
from .reflection import project_glints

try:
    import numba
except ImportError:  # the numpy projection runs instead
    numba = None

#: Whether :func:`glints_one_pose` runs compiled (Numba imports and its JIT is on).
ENABLED = numba is not None and not numba.config.DISABLE_JIT

_STEP_STOP_RAD = 1e-8  # as estimator.geometry.roots
#: The ``jac`` argument of :func:`glints_kernel` when no Jacobian is wanted.
NO_JACOBIAN = np.empty((0, 2, 3))
_MAX_NEWTON_ITER = 60


def _condition(a, b, ab, cp, sp, ct, st):
    """F(θ), F'(θ) of (R) from the cosines and sines of θ and φ (roots._reflection_condition_unit)."""
    s1 = sp * ct - cp * st
    c1 = cp * ct + sp * st
    s2 = s1 * ct - c1 * st
    c2 = c1 * ct + s1 * st
    return ab * s2 + a * st - b * s1, a * ct + b * c1 - 2 * ab * c2


def _root(a, b, cp, sp):
    """(cos θ, sin θ) of the bracketed root of (R) for one (pose, light) pair."""
    ch = math.sqrt(max(0.5 * (1 + cp), 0.0))
    sh = math.sqrt(max(0.5 * (1 - cp), 0.0))
    den = 2 * a * b - (a + b) * ch
    d = (a - b) * sh / den if den != 0.0 else 0.0
    if not abs(d) < 1.0:
        d = 0.0
    q = 1.0 / math.sqrt(1.0 + d * d)
    ct, st = (ch - d * sh) * q, (sh + d * ch) * q
    ab = a * b
    step = math.inf
    for _ in range(2):
        f, df = _condition(a, b, ab, cp, sp, ct, st)
        step = f / df if df != 0.0 else math.nan
        q = 1.0 / math.sqrt(1.0 + step * step)
        ct, st = (ct + step * st) * q, (st - step * ct) * q
    if abs(step) < _STEP_STOP_RAD and st >= 0 and sp * ct - cp * st >= -1e-15:
        return ct, st
    # Near-grazing pair: safeguarded Newton on [0, φ] (roots._bracketed_root).
    p = math.atan2(sp, cp)
    theta = math.atan2(st, ct)
    theta = min(max(theta, 0.0), p) if math.isfinite(theta) else 0.5 * p
    lo, hi = 0.0, p
    for _ in range(_MAX_NEWTON_ITER):
        f, df = _condition(a, b, ab, cp, sp, math.cos(theta), math.sin(theta))
        if f > 0:
            lo = theta
        else:
            hi = theta
        step = f / df if df != 0.0 else math.nan
        new = theta - step
        bad = not (lo <= new <= hi)
        if bad:
            new = 0.5 * (lo + hi)
        theta = new
        if not bad and abs(step) < _STEP_STOP_RAD:
            break
    return math.cos(theta), math.sin(theta)


def _sphere_reflection(radius, cx, cy, cz, o_norm, e1x, e1y, e1z, lx, ly, lz):
    """One light's reflection on the sphere of ``radius`` about the centre (cx, cy, cz), in
    camera axes: ``o_norm`` = |c|, e1 the unit from the centre toward the camera, l = (lx, ly,
    lz) the light's offset from the centre. Returns (outside, a, b, cos θ, sin θ, c1, e2 (3),
    normal n (3), point (X, Y, Z)): ``outside`` whether camera and light are both outside the
    sphere (else a = b = 2, the root still defined). What :func:`glints_kernel` and the
    scalar float path (:mod:`estimator.cornea.scalar`) compute for every light."""
    l_par = lx * e1x + ly * e1y + lz * e1z
    px, py, pz = lx - l_par * e1x, ly - l_par * e1y, lz - l_par * e1z
    l_perp = math.sqrt(px * px + py * py + pz * pz)
    l_norm = math.sqrt(l_par * l_par + l_perp * l_perp)
    inv_n = 1.0 / l_norm if l_norm > 0 else 1.0
    if l_perp <= 1e-12 * l_norm:  # light on the camera-centre line: any plane through it
        fx, fy, fz = e1y, -e1x, 0.0  # e1 x (0, 0, 1)
        if math.sqrt(fx * fx + fy * fy) <= 1e-6:
            fx, fy, fz = 0.0, e1z, -e1y  # e1 x (1, 0, 0)
        fn = math.sqrt(fx * fx + fy * fy + fz * fz)
        e2x, e2y, e2z = fx / fn, fy / fn, fz / fn
    else:
        inv = 1.0 / l_perp
        e2x, e2y, e2z = px * inv, py * inv, pz * inv
    alpha, beta = o_norm / radius, l_norm / radius
    cp, sp = l_par * inv_n, l_perp * inv_n
    outside = alpha > 1 and beta > 1
    a, b = (alpha, beta) if outside else (2.0, 2.0)
    ct, st = _root(a, b, cp, sp)
    nx, ny, nz = ct * e1x + st * e2x, ct * e1y + st * e2y, ct * e1z + st * e2z
    X, Y, Z = cx + radius * nx, cy + radius * ny, cz + radius * nz
    c1 = cp * ct + sp * st
    return outside, a, b, ct, st, c1, e2x, e2y, e2z, nx, ny, nz, X, Y, Z


def glints_kernel(R, O, intr, size, center, radius, lights, axis, cap_cos_min, use_cap,
                   out, visible, with_jacobian, jac):
    """Glints (n, 2) and visibility (n,) of ``lights`` (n, 3) for one cornea ``center`` (3,),
    world frame in, pixels out (``intr`` = fx, fy, cx, cy; ``size`` = width, height). With
    ``with_jacobian``, also d glint / d centre (n, 2, 3) (px per metre, world frame) into
    ``jac`` (:data:`NO_JACOBIAN` otherwise): the closed form of
    :func:`estimator.geometry.jacobians.jacobian_terms`."""
    d0, d1, d2 = center[0] - O[0], center[1] - O[1], center[2] - O[2]
    cx = R[0, 0] * d0 + R[0, 1] * d1 + R[0, 2] * d2
    cy = R[1, 0] * d0 + R[1, 1] * d1 + R[1, 2] * d2
    cz = R[2, 0] * d0 + R[2, 1] * d1 + R[2, 2] * d2
    ax = R[0, 0] * axis[0] + R[0, 1] * axis[1] + R[0, 2] * axis[2]
    ay = R[1, 0] * axis[0] + R[1, 1] * axis[1] + R[1, 2] * axis[2]
    az = R[2, 0] * axis[0] + R[2, 1] * axis[1] + R[2, 2] * axis[2]
    o_norm = math.sqrt(cx * cx + cy * cy + cz * cz)
    inv_o = 1.0 / o_norm if o_norm > 0 else 1.0
    e1x, e1y, e1z = -cx * inv_o, -cy * inv_o, -cz * inv_o
    for i in range(lights.shape[0]):
        q0, q1, q2 = lights[i, 0] - O[0], lights[i, 1] - O[1], lights[i, 2] - O[2]
        lx = R[0, 0] * q0 + R[0, 1] * q1 + R[0, 2] * q2 - cx
        ly = R[1, 0] * q0 + R[1, 1] * q1 + R[1, 2] * q2 - cy
        lz = R[2, 0] * q0 + R[2, 1] * q1 + R[2, 2] * q2 - cz
        (outside, a, b, ct, st, c1, e2x, e2y, e2z, nx, ny, nz, X, Y, Z) = _sphere_reflection(
            radius, cx, cy, cz, o_norm, e1x, e1y, e1z, lx, ly, lz)
        ok = outside and a * ct > 1 and b * c1 > 1
        if use_cap:
            ok = ok and nx * ax + ny * ay + nz * az >= cap_cos_min
        if Z > 0:
            iz = 1.0 / Z
            u = intr[0] * X * iz + intr[2]
            v = intr[1] * Y * iz + intr[3]
        else:
            u = v = math.nan
        out[i, 0], out[i, 1] = u, v
        visible[i] = ok and -0.5 <= u <= size[0] - 0.5 and -0.5 <= v <= size[1] - 0.5
        if with_jacobian:
            _jacobian_rows(R, intr, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y, e2z,
                           nx, ny, nz, X, Y, Z, jac, i)


def _jacobian_rows(R, intr, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y, e2z, nx, ny,
                   nz, X, Y, Z, jac, i):
    """Row i of d glint / d centre (2, 3), world frame, from one pair's plane and root (the
    implicit derivative of the law of reflection, :mod:`estimator.geometry.jacobians`):
    :func:`_jacobian_camera`'s rows turned into the world frame."""
    u0, u1, u2, v0, v1, v2 = _jacobian_camera(intr[0], intr[1], radius, a, b, ct, st, c1, e1x,
                                              e1y, e1z, e2x, e2y, e2z, nx, ny, nz, X, Y, Z)
    for j in range(3):
        jac[i, 0, j] = u0 * R[0, j] + u1 * R[1, j] + u2 * R[2, j]
        jac[i, 1, j] = v0 * R[0, j] + v1 * R[1, j] + v2 * R[2, j]


def _jacobian_camera(fx, fy, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y, e2z, nx, ny,
                     nz, X, Y, Z):
    """d u / d c and d v / d c (6 floats, px per m) in the camera's axes of one pair's glint,
    from its plane (e1, e2), root (cos θ, sin θ, c1 = cos(φ - θ)), normal n and reflection
    point (X, Y, Z), a = |c| / r, b = |l| / r, focal lengths fx, fy (px)."""
    inv_qa = 1.0 / math.sqrt(max(a * a - 2 * a * ct + 1, 1e-300))
    qb = math.sqrt(max(b * b - 2 * b * c1 + 1, 1e-300))
    cos_i = (a * ct - 1) * inv_qa
    sin_i = a * st * inv_qa
    inv_du, inv_dw = inv_qa / radius, 1.0 / (radius * qb)
    rH, rD = radius * (inv_du + inv_dw), radius * (inv_dw - inv_du)
    inv_g = 1.0 / (2 + rH * cos_i)
    inv_qk = 1.0 / (2 * cos_i + rH)
    b_tn = rD * sin_i * inv_g
    tx, ty, tz = st * e1x - ct * e2x, st * e1y - ct * e2y, st * e1z - ct * e2z
    kx, ky, kz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    iz = 1.0 / Z
    xz, yz = X * iz, Y * iz
    fxz, fyz = fx * iz, fy * iz
    pt_x, pt_y = tx - xz * tz, ty - yz * tz
    pk_x, pk_y = kx - xz * kz, ky - yz * kz
    m_t, m_k = 1 - 2 * inv_g, 1 - 2 * cos_i * inv_qk
    wx, wy, wz = m_t * tx + b_tn * nx, m_t * ty + b_tn * ny, m_t * tz + b_tn * nz
    qx, qy = m_k * pk_x, m_k * pk_y
    u0 = fxz * (1 - pt_x * wx - qx * kx)
    u1 = fxz * -(pt_x * wy + qx * ky)
    u2 = fxz * -(xz + pt_x * wz + qx * kz)
    v0 = fyz * -(pt_y * wx + qy * kx)
    v1 = fyz * (1 - pt_y * wy - qy * ky)
    v2 = fyz * -(yz + pt_y * wz + qy * kz)
    return u0, u1, u2, v0, v1, v2


#: One light's reflection on the sphere in camera axes (:func:`_sphere_reflection`), for
#: callers outside this package: :mod:`estimator.cornea.scalar`'s float fit runs where the JIT
#: is off, and takes this plain-Python form (the same lines as the compiled kernels'; Python's
#: arithmetic raises where Numba's carries infinities).
sphere_reflection = _sphere_reflection

if ENABLED:
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _condition = _jit(_condition)
    _root = _jit(_root)
    _sphere_reflection = _jit(_sphere_reflection)
    _jacobian_camera = _jit(_jacobian_camera)
    _jacobian_rows = _jit(_jacobian_rows)
    glints_kernel = _jit(glints_kernel)

#: One pair's d glint / d centre rows in camera axes, for the same callers.
jacobian_in_camera = _jacobian_camera


def camera_arrays(camera: Camera):
    """The camera as the kernels take it: rotation (3, 3), centre (3,), intrinsics (4,) and
    size (2,)."""
    return (np.ascontiguousarray(camera.rotation, dtype=np.float64),
            np.ascontiguousarray(camera.position_m, dtype=np.float64),
            np.array([camera.fx_px, camera.fy_px, camera.cx_px, camera.cy_px]),
            np.array([float(camera.width_px), float(camera.height_px)]))


def glints_and_rows_one_pose(camera: Camera, center_m, radius_m: float, lights_world_m, *,
                             cornea_axis=None, cap_cos_min: float | None = None, arrays=None):
    """:func:`glints_one_pose` and d glint / d cornea centre (n, 2, 3) (px per metre), the
    closed form of :func:`estimator.geometry.glint_jacobians` (compiled where Numba is)."""
    if not ENABLED:
        g, vis, d_center, _, _ = glint_jacobians(camera, center_m, radius_m, lights_world_m,
                                                 cornea_axis=cornea_axis,
                                                 cap_cos_min=cap_cos_min,
                                                 radius_and_lights=False)
        return g, vis, d_center
    center = np.asarray(center_m, dtype=np.float64).reshape(3)
    lights = np.ascontiguousarray(lights_world_m, dtype=np.float64)
    if (cornea_axis is None) != (cap_cos_min is None):
        raise ValueError("cornea_axis and cap_cos_min must be given together")
    R, O, intr, size = camera_arrays(camera) if arrays is None else arrays
    out = np.empty((lights.shape[0], 2))
    vis = np.empty(lights.shape[0], dtype=np.bool_)
    jac = np.empty((lights.shape[0], 2, 3))
    use_cap = cornea_axis is not None
    axis = np.asarray(cornea_axis, dtype=np.float64).reshape(3) if use_cap else np.zeros(3)
    glints_kernel(R, O, intr, size, center, float(radius_m), lights, axis,
                  float(cap_cos_min) if use_cap else 0.0, use_cap, out, vis, True, jac)
    return out, vis, jac


def glints_one_pose(camera: Camera, center_m, radius_m: float, lights_world_m, *,
                    cornea_axis=None, cap_cos_min: float | None = None, arrays=None):
    """Glints (n, 2) and visibility (n,) of every light for one cornea centre (3,):
    :func:`estimator.geometry.project_glints` of one pose (compiled where Numba is).

    ``arrays`` is :func:`camera_arrays` of ``camera`` when the caller keeps it."""
    center = np.asarray(center_m, dtype=np.float64).reshape(3)
    lights = np.asarray(lights_world_m, dtype=np.float64)
    if (cornea_axis is None) != (cap_cos_min is None):
        raise ValueError("cornea_axis and cap_cos_min must be given together")
    if not ENABLED:
        g, vis = project_glints(camera, center, radius_m, lights, cornea_axis=cornea_axis,
                                cap_cos_min=cap_cos_min)
        return g, vis
    R, O, intr, size = camera_arrays(camera) if arrays is None else arrays
    out = np.empty((lights.shape[0], 2))
    vis = np.empty(lights.shape[0], dtype=np.bool_)
    use_cap = cornea_axis is not None
    axis = np.asarray(cornea_axis, dtype=np.float64).reshape(3) if use_cap else np.zeros(3)
    glints_kernel(R, O, intr, size, center, float(radius_m), np.ascontiguousarray(lights),
                   axis, float(cap_cos_min) if use_cap else 0.0, use_cap, out, vis, False,
                   NO_JACOBIAN)
    return out, vis
