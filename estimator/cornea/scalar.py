"""One band's small fit in Python floats: :func:`estimator.cornea.fit_small` where Numba is
not installed (or its JIT is off), the same Levenberg-Marquardt as the compiled one
(:func:`estimator.cornea.small.lm_kernel`) written for CPython.

A band's fit has 2-3 unknowns and 5-15 glints. Numpy's cost there is per call, not per
element: :func:`estimator.cornea.fit_cornea`'s batched machinery for one sample makes ~40
array passes a Jacobian (measured ~2 ms a fit on paper_sim's bands), where the same arithmetic
on Python floats, one glint at a time, costs a few microseconds a glint. So this module
evaluates the glint projection (:func:`estimator.geometry.compiled.glints_kernel`: plane of
reflection, the root of (R), the implicit Jacobian) with :mod:`math` on floats, one light at a
time, and runs the compiled fit's damping schedule and stopping rule on them.

The operations are the compiled kernels', in the same order (IEEE double arithmetic either
way, no fused multiply-add in Numba's default mode), so the two give the same parameters,
residual and JᵀJ to the last bit (``tests/estimator/test_cheap_path.py`` compares them where
Numba is installed). Two things differ in the work done, not in the numbers: each light's
position in camera axes is rotated once a fit (the kernels rotate it at every evaluation, the
same products), and an evaluation of a trial point computes its Jacobian too, which the next
iteration then takes instead of projecting the same point again.

Python raises where Numba's ``error_model="numpy"`` gives inf or NaN (a division by zero, the
cosine of an infinite angle); an evaluation that raises counts as a non-finite cost: the trial
step is rejected, or at the start the fit fails (where Numba's arithmetic may carry an
infinity on to a finite cost; measured only on inputs no calibration gives, a zero radius).
"""

from __future__ import annotations

import math

from ..geometry.compiled import jacobian_in_camera as _jacobian_in_camera
from ..geometry.compiled import sphere_reflection as _reflection

__all__ = ["camera_floats", "lights_in_camera", "lm_floats", "glints_floats"]


def camera_floats(R, O, intr, size) -> tuple:
    """The camera of :func:`estimator.geometry.compiled.camera_arrays` as one flat tuple of
    18 Python floats: rotation (row-major 9), centre (3), fx, fy, cx, cy, width, height."""
    return (*(float(v) for v in R.ravel()), *(float(v) for v in O), *(float(v) for v in intr),
            *(float(v) for v in size))


def _rotate(cam, v0, v1, v2):
    """R v (3 floats): a world vector in the camera's axes (the kernels' products and sums)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = cam[:9]
    return (r00 * v0 + r01 * v1 + r02 * v2, r10 * v0 + r11 * v1 + r12 * v2,
            r20 * v0 + r21 * v1 + r22 * v2)


def lights_in_camera(cam, lights):
    """R (L - O) of each light (k, 3): the part of the kernels' per-light rotation that does
    not depend on the cornea (the same products and sums)."""
    o0, o1, o2 = cam[9:12]
    return [_rotate(cam, float(L[0]) - o0, float(L[1]) - o1, float(L[2]) - o2) for L in lights]


def _toward_camera(cam, c0, c1, c2):
    """The cornea centre (world, 3 floats) in the camera's axes, its distance from the camera
    and the unit e1 from it toward the camera: (cx, cy, cz, |c|, e1x, e1y, e1z)."""
    cx, cy, cz = _rotate(cam, c0 - cam[9], c1 - cam[10], c2 - cam[11])
    o_norm = math.sqrt(cx * cx + cy * cy + cz * cz)
    inv_o = 1.0 / o_norm if o_norm > 0 else 1.0
    return cx, cy, cz, o_norm, -cx * inv_o, -cy * inv_o, -cz * inv_o


def _centre(model, x, ce, rco):
    """The cornea centre (3 floats) of parameters x: the centre itself, or on the orbit."""
    if model == 0:
        return x[0], x[1], x[2]
    cp = math.cos(x[1])
    return (ce[0] + rco * (cp * math.sin(x[0])), ce[1] + rco * math.sin(x[1]),
            ce[2] + rco * (-cp * math.cos(x[0])))


def _glint(cam, radius, cx, cy, cz, o_norm, e1x, e1y, e1z, q):
    """One light's reflection (``q``: R (L - O), :func:`lights_in_camera`) on the sphere of
    ``radius`` about the centre (cx, cy, cz) in camera axes, o_norm and e1 from
    :func:`_toward_camera`: (outside, a, b, cos θ, sin θ, c1, e2 (3), normal n (3), point
    (X, Y, Z), pixel (u, v)), ``outside`` whether camera and light are both outside the
    sphere (else a = b = 2, the root still defined), u = v = NaN behind the camera."""
    outside, a, b, ct, st, c1, e2x, e2y, e2z, nx, ny, nz, X, Y, Z = _reflection(
        radius, cx, cy, cz, o_norm, e1x, e1y, e1z, q[0] - cx, q[1] - cy, q[2] - cz)
    if Z > 0:
        iz = 1.0 / Z
        u = cam[12] * X * iz + cam[14]
        v = cam[13] * Y * iz + cam[15]
    else:
        u = v = math.nan
    return outside, a, b, ct, st, c1, e2x, e2y, e2z, nx, ny, nz, X, Y, Z, u, v


def _evaluate(cam, model, x, ce, rco, radius, rq, glints):
    """The glints' squared residual at x (px²), JᵀJ (p lists of p) and Jᵀr (p) of their
    residuals r and Jacobian J = d r / d x: ``_residuals_rows`` and ``_normal_sums`` of
    :mod:`estimator.cornea.small`, with :func:`estimator.geometry.compiled.glints_kernel`'s
    projection and ``_jacobian_rows`` written out for one light at a time, and the sums taken
    as each light's two rows come (the rows' order: the same sums)."""
    cx, cy, cz, o_norm, e1x, e1y, e1z = _toward_camera(cam, *_centre(model, x, ce, rco))
    if model == 1:
        cyw, syw, cpt, spt = math.cos(x[0]), math.sin(x[0]), math.cos(x[1]), math.sin(x[1])
        dy0, dy2 = rco * cpt * cyw, rco * cpt * syw
        dp0, dp1, dp2 = -rco * spt * syw, rco * cpt, rco * spt * cyw
    cost = t0 = t1 = t2 = a00 = a01 = a02 = a11 = a12 = a22 = 0.0
    for i, q in enumerate(rq):
        _, a, b, ct, st, c1, e2x, e2y, e2z, nx, ny, nz, X, Y, Z, u, v = _glint(
            cam, radius, cx, cy, cz, o_norm, e1x, e1y, e1z, q)
        du, dv = u - glints[i][0], v - glints[i][1]
        cost += du * du + dv * dv
        (ju0, ju1, ju2), (jv0, jv1, jv2) = _jacobian_rows(
            cam, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz, X, Y, Z)
        if model == 0:
            j0, j1, j2 = ju0, ju1, ju2
            k0, k1, k2 = jv0, jv1, jv2
            t0 += j0 * du
            t0 += k0 * dv
            t1 += j1 * du
            t1 += k1 * dv
            t2 += j2 * du
            t2 += k2 * dv
            a00 += j0 * j0
            a00 += k0 * k0
            a01 += j0 * j1
            a01 += k0 * k1
            a02 += j0 * j2
            a02 += k0 * k2
            a11 += j1 * j1
            a11 += k1 * k1
            a12 += j1 * j2
            a12 += k1 * k2
            a22 += j2 * j2
            a22 += k2 * k2
        else:
            j0, j1 = ju0 * dy0 + ju2 * dy2, ju0 * dp0 + ju1 * dp1 + ju2 * dp2
            k0, k1 = jv0 * dy0 + jv2 * dy2, jv0 * dp0 + jv1 * dp1 + jv2 * dp2
            t0 += j0 * du
            t0 += k0 * dv
            t1 += j1 * du
            t1 += k1 * dv
            a00 += j0 * j0
            a00 += k0 * k0
            a01 += j0 * j1
            a01 += k0 * k1
            a11 += j1 * j1
            a11 += k1 * k1
    if model == 0:
        return cost, [[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]], [t0, t1, t2]
    return cost, [[a00, a01], [a01, a11]], [t0, t1]


def _safe_evaluate(*args):
    """:func:`_evaluate`, or a NaN cost where Python raises on what Numba's
    ``error_model="numpy"`` carries as inf or NaN (module docstring)."""
    try:
        return _evaluate(*args)
    except (ZeroDivisionError, ValueError, OverflowError):
        return math.nan, None, None


def _solve(A, y, p):
    """A⁻¹ y by Gaussian elimination with partial pivoting (``small._solve``), or None where
    a pivot is zero."""
    M = [row[:] for row in A]
    y = y[:]
    for k in range(p):
        piv = k
        for i in range(k + 1, p):
            if abs(M[i][k]) > abs(M[piv][k]):
                piv = i
        if not abs(M[piv][k]) > 0:
            return None
        M[k], M[piv] = M[piv], M[k]
        y[k], y[piv] = y[piv], y[k]
        for i in range(k + 1, p):
            f = M[i][k] / M[k][k]
            for j in range(k, p):
                M[i][j] -= f * M[k][j]
            y[i] -= f * y[k]
    out = [0.0] * p
    for k in range(p - 1, -1, -1):
        s = y[k]
        for j in range(k + 1, p):
            s -= M[k][j] * out[j]
        out[k] = s / M[k][k]
    return out


def _prior_cost(x, pm, P, p):
    """(x - μ)ᵀ Λ (x - μ) (px²)."""
    cost = 0.0
    for a in range(p):
        for b in range(p):
            cost += (x[a] - pm[a]) * P[a][b] * (x[b] - pm[b])
    return cost


def lm_floats(cam, model, x0, ce, rco, radius, lights, glints, max_iter, xtol, gn_stop, pm,
              P):
    """The compiled fit's Levenberg-Marquardt (``small._lm``) on Python floats, with the
    batched fit's Gauss-Newton stop (module docstring).

    Parameters
    ----------
    cam : tuple of 18 float
        :func:`camera_floats`.
    model : int
        0: the centre (p = 3, m); 1: the orbit's Fick angles (p = 2, rad).
    x0 : (p,) float
    ce : (3,) float
        The eye centre (model 1).
    rco, radius : float
        The orbit's and the cornea's radius (m).
    lights : (k, 3) float
    glints : (k, 2) float
    max_iter : int
    xtol : float
        Stopping step in x's units (relative above 1).
    gn_stop : float
        A step below this in every unknown (x's units, relative above 1) while the damping is
        at most 1e-3 is taken and ends the fit, its cost to second order
        (:data:`estimator.cornea.solve._GN_STOP`); 0: never.
    pm : (p,) float
    P : (p, p) float
        The prior's mean and information (zeros: none).

    Returns
    -------
    x : list of p float
    JtJ : list of p lists of p float
        The glints' JᵀJ at the last point whose Jacobian was taken.
    cost : float
        The glints' share of the cost at x (px²).
    iterations : int
    converged : bool
    """
    p = len(x0)
    rq = lights_in_camera(cam, lights)
    glints = [(float(g[0]), float(g[1])) for g in glints]
    ce = (float(ce[0]), float(ce[1]), float(ce[2])) if model == 1 else ce
    pm = [float(v) for v in pm]
    P = [[float(v) for v in row] for row in P]
    x = [float(v) for v in x0]
    JtJ = [[0.0] * p for _ in range(p)]
    cost, JtJ_x, Jtr_x = _safe_evaluate(cam, model, x, ce, rco, radius, rq, glints)
    cost += _prior_cost(x, pm, P, p)
    lam = 1e-6
    iters = 0
    converged = False
    for _ in range(max_iter):
        if not math.isfinite(cost):
            break
        JtJ, Jtr = JtJ_x, Jtr_x
        for a in range(p):
            for b in range(p):
                Jtr[a] += P[a][b] * (x[b] - pm[b])
        iters += 1
        accepted = False
        while lam <= 1e12:
            A = [[JtJ[a][b] + P[a][b] for b in range(p)] for a in range(p)]
            for a in range(p):
                A[a][a] += lam * max(JtJ[a][a] + P[a][a], 1e-30)
            step = _solve(A, Jtr, p)
            if step is not None:
                x_new = [x[j] - step[j] for j in range(p)]
                if lam <= 1e-3 and all(abs(step[j]) <= gn_stop * max(1.0, abs(x[j]))
                                       for j in range(p)):
                    # The batched fit's stop: the step leaves an error far below the noise.
                    # Its cost to second order: r² - 2 sᵀ Jᵀr + sᵀ (JᵀJ + Λ) s.
                    quad = 0.0
                    for a in range(p):
                        for b in range(p):
                            quad += step[a] * (JtJ[a][b] + P[a][b]) * step[b]
                    lin = 0.0
                    for a in range(p):
                        lin += step[a] * Jtr[a]
                    x, cost = x_new, max(cost - 2 * lin + quad, 0.0)
                    return x, JtJ, cost - _prior_cost(x, pm, P, p), iters, True
                cost_new, JtJ_n, Jtr_n = _safe_evaluate(cam, model, x_new, ce, rco, radius,
                                                        rq, glints)
                cost_new += _prior_cost(x_new, pm, P, p)
                if math.isfinite(cost_new) and cost_new <= cost:
                    accepted = True
                    break
            lam *= 10
        if not accepted:
            converged = True  # no step lowers the cost: a minimum to machine precision
            break
        small = True
        for j in range(p):
            small = small and abs(step[j]) <= xtol * max(1.0, abs(x[j]))
        x, cost, JtJ_x, Jtr_x = x_new, cost_new, JtJ_n, Jtr_n
        lam = max(lam / 10, 1e-12)
        if small:
            converged = True
            break
    return x, JtJ, cost - _prior_cost(x, pm, P, p), iters, converged


def glints_floats(cam, center, radius, rq, axis, cap_cos_min, with_jacobian):
    """Glints, visibility and (``with_jacobian``) d glint / d centre of every light for one
    cornea ``center`` (3 floats, m), with the cap test about the optical ``axis`` (3 floats,
    world) at ``cap_cos_min``: :func:`estimator.geometry.compiled.glints_kernel` with
    ``use_cap``, on floats (its operations in its order; ``rq``: :func:`lights_in_camera`).

    Returns
    -------
    glints : list of n (u, v) float
    visible : list of n bool
    jac : list of n ((3 float), (3 float)) or None
        The rows d u / d c and d v / d c (px per m, world frame).
    """
    cx, cy, cz, o_norm, e1x, e1y, e1z = _toward_camera(cam, center[0], center[1], center[2])
    ax, ay, az = _rotate(cam, axis[0], axis[1], axis[2])
    glints, visible, jac = [], [], [] if with_jacobian else None
    u_hi, v_hi = cam[16] - 0.5, cam[17] - 0.5
    for q in rq:
        outside, a, b, ct, st, c1, e2x, e2y, e2z, nx, ny, nz, X, Y, Z, u, v = _glint(
            cam, radius, cx, cy, cz, o_norm, e1x, e1y, e1z, q)
        ok = outside and a * ct > 1 and b * c1 > 1
        ok = ok and nx * ax + ny * ay + nz * az >= cap_cos_min
        glints.append((u, v))
        visible.append(ok and -0.5 <= u <= u_hi and -0.5 <= v <= v_hi)
        if with_jacobian:
            jac.append(_jacobian_rows(cam, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y,
                                      e2z, nx, ny, nz, X, Y, Z))
    return glints, visible, jac


def _jacobian_rows(cam, radius, a, b, ct, st, c1, e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz, X,
                   Y, Z):
    """One light's d glint / d centre rows ((3 float), (3 float)), world frame
    (``compiled._jacobian_rows``: its rows in camera axes, turned by the same operations)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = cam[:9]
    u0, u1, u2, v0, v1, v2 = _jacobian_in_camera(cam[12], cam[13], radius, a, b, ct, st, c1,
                                                 e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz,
                                                 X, Y, Z)
    return ((u0 * r00 + u1 * r10 + u2 * r20, u0 * r01 + u1 * r11 + u2 * r21,
             u0 * r02 + u1 * r12 + u2 * r22),
            (v0 * r00 + v1 * r10 + v2 * r20, v0 * r01 + v1 * r11 + v2 * r21,
             v0 * r02 + v1 * r12 + v2 * r22))
