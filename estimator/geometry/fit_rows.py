"""The cornea-centre fit's Jacobian rows, packed for the normal equations: the fast path of
:func:`estimator.cornea.solve.normal_equations` for the ``"center"`` and ``"orbit"`` models.

The geometry is that of :func:`estimator.geometry.jacobian_terms` (the general path, which
handles every configuration and stays the reference), computed with about half the
elementwise passes: in a basis per sample, with the reflection's root found on a quartic in
tan(ψ/2), and with the residuals and the rows written side by side so that one matrix product
per sample gives JᵀJ, Jᵀr and the cost. Samples it does not handle are flagged for the general
path; ``tests/estimator/test_cornea_fast_path.py`` holds the two paths to 1e-11 of each other.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from .camera import Camera
from .reflection import _apply
from .roots import _STEP_STOP_RAD

#: The fast centre-fit path's root has settled when its last Newton step on τ = tan(ψ/2) is
#: below this: the :data:`_STEP_STOP_RAD` of the general path, as dψ = 2 dτ / (1 + τ²).
_TAU_STOP = 0.5 * _STEP_STOP_RAD
#: Largest block (samples x lights) whose work arrays are kept between calls: the LM's
#: largest block of 40 lights (1.5 x estimator.cornea.solve._BLOCK samples), ~7 MB per thread.
_SCRATCH_PAIRS = 30000


class _Scratch(threading.local):
    """Work arrays of :func:`centre_fit_rows`, kept between calls, one set per thread.

    A fit evaluates its glints a few times per block of samples, each time through some forty
    (samples, lights) arrays. Fresh ones come from memory that the allocator has just handed
    back to the system, and touching it again costs a page fault per 4 KiB: measured ~370
    faults, about a third of the time, per evaluation of 100 samples x 40 lights."""

    def __init__(self):
        self.arrays = {}

    def get(self, name: str, shape: tuple) -> np.ndarray:
        """An uninitialised array of ``shape`` (samples first), the same memory on every call
        of this thread while the trailing dimensions stay the same and the samples fit."""
        if math.prod(shape) > 8 * _SCRATCH_PAIRS:
            return np.empty(shape)
        key = (name,) + shape[1:]
        a = self.arrays.get(key)
        if a is None or a.shape[0] < shape[0]:
            if len(self.arrays) > 64:  # many light counts (gathered bands): start afresh
                self.arrays.clear()
            a = self.arrays[key] = np.empty(shape)
        return a[:shape[0]]


_scratch = _Scratch()


def centre_fit_rows(camera: Camera, center, radius: float, lights, glints, mask):
    """Residuals and rows of d glint / d centre of a cornea-centre fit, packed so that one
    matrix product per sample gives its normal equations.

    The same geometry as :func:`jacobian_terms` with half the elementwise passes. Vectors are
    written in an orthonormal basis per sample, (e1, f2, f3) with e1 from the cornea centre
    toward the camera: a light's plane of reflection is spanned by e1 and e2 = cos ζ f2 +
    sin ζ f3, its normal is k = (0, -sin ζ, cos ζ), and the lights' coordinates, the
    reflection points' camera coordinates and the pinhole rows are matrix products. The root
    of (R) is taken around the bisector, θ = φ/2 + ψ: with τ = tan(ψ/2), (R) times
    (1 + τ²)² / 2 is the quartic

        Q(τ) = a + τ (τ² (E - a τ) - D),
        a = (α - β) sin(φ/2) / 2,  D = 2αβ - (α + β) cos(φ/2),  E = 2αβ + (α + β) cos(φ/2),

    on which a Newton step takes no square root. From the first-order root τ₀ = a / D (that of
    :func:`_first_order_root`) two steps settle to double precision. The light's distance
    follows from the law of sines, |P - L| sin i = |L - c| sin(φ - θ). Work arrays are reused
    between calls (:class:`_Scratch`) and written in place.

    Parameters
    ----------
    center : (B, 3) float
        Cornea centres in the world frame.
    radius : float
    lights : (n, 3) or (B, n, 3) float
    glints : (B, n, 2) float
        Observed glints (px); only those in ``mask`` count.
    mask : (B, n) bool

    Returns
    -------
    G : (B, 4, 2n) float
        Rows 0-2: d (u, v) / d c_b of the glints in ``mask`` (zero elsewhere), c_b the centre
        in the basis in units of r; row 3: the residuals (u, v) - glints (px). G Gᵀ holds JᵀJ,
        Jᵀr and the cost Σ r². Overwritten by the thread's next call.
    N : (B, 3, 3) float
        d c_b / d c_world (per metre): the world Jacobian is J_b N.
    fast : (B,) bool
        False for a sample with a pair this path does not handle (a light on the line through
        the camera and the centre, a camera or light inside the sphere, a root that did not
        settle or left [0, φ]): take that sample from :func:`jacobian_terms`.
    """
    R = camera.rotation
    c = _apply(R, center - camera.position_m) / radius  # units of r from here on
    L = _apply(R, lights - camera.position_m) / radius
    B, n = mask.shape
    get = _scratch.get
    alpha = np.sqrt(np.einsum("bi,bi->b", c, c))[:, None]
    e1 = -c / alpha
    # Duff et al. (2017), "Building an orthonormal basis, revisited": f2 ⟂ e1 without a branch.
    sgn = np.copysign(1.0, e1[:, 2])
    h = -1.0 / (sgn + e1[:, 2])
    M = np.empty((B, 3, 3))  # rows e1, f2, f3 = e1 x f2
    M[:, 0] = e1
    M[:, 1, 0] = 1.0 + sgn * e1[:, 0] * e1[:, 0] * h
    M[:, 1, 1] = sgn * e1[:, 0] * e1[:, 1] * h
    M[:, 1, 2] = -sgn * e1[:, 0]
    f2 = M[:, 1]
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        M[:, 2, i] = e1[:, j] * f2[:, k] - e1[:, k] * f2[:, j]
    # Light coordinates L · (e1, f2, f3); (L - c) · e1 = L · e1 + α.
    lc = np.matmul(M, np.ascontiguousarray(np.swapaxes(L, -1, -2)), out=get("lc", (B, 3, n)))
    cp, cz, sz = lc[:, 0], lc[:, 1], lc[:, 2]
    cp += alpha
    w = [get(f"w{i}", (B, n)) for i in range(12)]
    fast = alpha[:, 0] > 1
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        # β = |L - c| / r, cos φ, sin φ, the light's azimuth (cos ζ, sin ζ) and the half angle.
        beta, sp, ch, sh, tmp = w[0], w[1], w[2], w[3], w[4]
        np.multiply(cz, cz, out=beta)
        np.multiply(sz, sz, out=tmp)
        beta += tmp
        np.sqrt(beta, out=sp)
        cz /= sp
        sz /= sp
        np.multiply(cp, cp, out=tmp)
        beta += tmp
        np.sqrt(beta, out=beta)
        sp /= beta
        cp /= beta
        np.multiply(cp, 0.5, out=ch)
        ch += 0.5
        np.sqrt(ch, out=ch)  # cos(φ/2)
        np.multiply(sp, 0.5, out=sh)
        sh /= ch  # sin(φ/2) = sin φ / (2 cos(φ/2))
        if not (sp.min() > 1e-12 and beta.min() > 1):
            fast &= _rows_all(sp > 1e-12) & _rows_all(beta > 1)
        # The quartic's coefficients and two Newton steps from τ₀ = a / D.
        a, E, D, tau, t2, u, v, step = w[1], w[4], w[5], w[6], w[7], w[8], w[9], w[10]
        np.add(alpha, beta, out=u)
        u *= ch
        np.multiply(alpha + alpha, beta, out=E)
        np.subtract(E, u, out=D)
        E += u
        np.subtract(alpha, beta, out=a)
        a *= sh
        a *= 0.5
        np.divide(a, D, out=tau)
        for _ in range(2):
            np.multiply(tau, tau, out=t2)
            np.multiply(a, tau, out=u)
            np.subtract(E, u, out=v)
            np.multiply(v, t2, out=step)
            step -= D
            step *= tau
            step += a  # Q(τ)
            v *= 3.0
            v -= u
            v *= t2
            v -= D  # Q'(τ) = τ² (3E - 4aτ) - D
            step /= v
            tau -= step
        if not (step.max() < _TAU_STOP and step.min() > -_TAU_STOP):
            fast &= _rows_all(np.abs(step) < _TAU_STOP)
        # cos ψ, sin ψ; then cos θ (into the reflection points' array), sin θ and sin(φ - θ).
        P = get("P", (B, 4, n))
        ct, cpsi, spsi, st, s1 = P[:, 0], w[7], w[6], w[1], w[4]
        np.multiply(tau, tau, out=cpsi)
        np.add(cpsi, 1.0, out=u)
        np.divide(1.0, u, out=u)
        np.subtract(1.0, cpsi, out=cpsi)
        cpsi *= u
        spsi += spsi
        spsi *= u
        np.multiply(ch, cpsi, out=ct)
        np.multiply(sh, spsi, out=u)
        ct -= u
        cpsi *= sh
        spsi *= ch
        np.add(cpsi, spsi, out=st)
        np.subtract(cpsi, spsi, out=s1)
        if not (st.min() >= 0 and s1.min() >= -1e-15):
            fast &= _rows_all(st >= 0) & _rows_all(s1 >= -1e-15)
        # Reflection points P = c + r n in the camera frame (units of r).
        np.multiply(st, cz, out=P[:, 1])
        np.multiply(st, sz, out=P[:, 2])
        P[:, 3] = 1.0
        Mc = np.concatenate([np.swapaxes(M, 1, 2), c[:, :, None]], axis=2)
        XYZ = np.matmul(Mc, P, out=get("XYZ", (B, 3, n)))
        xz, yz, iz = XYZ[:, 0], XYZ[:, 1], XYZ[:, 2]
        np.divide(1.0, iz, out=iz)
        xz *= iz
        yz *= iz
        # Residuals (u, v) - glints where masked; H = (f_x / z) (1, x/z, y/z) where masked.
        G = get("G", (B, 4, 2, n))
        H = get("H", (B, 3, n))
        fm, tmp = w[11], w[10]
        pinhole = ((xz, camera.fx_px, camera.cx_px), (yz, camera.fy_px, camera.cy_px))
        for row, (proj, f_px, c_px) in enumerate(pinhole):
            np.multiply(mask, f_px, out=fm)
            if row == 0:
                np.multiply(fm, iz, out=H[:, 0])
            np.subtract(glints[..., row], c_px, out=tmp)
            tmp *= 1.0 / f_px
            res = G[:, 3, row]
            np.subtract(proj, tmp, out=res)
            res *= fm
        np.multiply(H[:, 0], xz, out=H[:, 1])
        np.multiply(H[:, 0], yz, out=H[:, 2])
        # Distances to camera and light over r, incidence angle and the terms of dP/dc of
        # jacobian_terms: rH = r (1/d_u + 1/d_w), rD = r (1/d_w - 1/d_u), g, m_k, m_t, b_tn.
        cos_i, inv_qa, sin_i, rH, inv_g, m_k = w[2], w[3], w[5], w[6], w[7], w[8]
        np.multiply(alpha, ct, out=cos_i)
        np.add(cos_i, cos_i, out=inv_qa)
        np.subtract(alpha * alpha + 1.0, inv_qa, out=inv_qa)
        np.sqrt(inv_qa, out=inv_qa)
        np.divide(1.0, inv_qa, out=inv_qa)
        cos_i -= 1.0
        cos_i *= inv_qa
        np.multiply(alpha, st, out=sin_i)
        sin_i *= inv_qa
        beta *= s1
        np.divide(sin_i, beta, out=beta)  # r / d_w = sin i / (β sin(φ - θ))
        np.add(inv_qa, beta, out=rH)
        beta -= inv_qa  # rD
        np.multiply(rH, cos_i, out=inv_g)
        inv_g += 2.0
        np.divide(1.0, inv_g, out=inv_g)
        np.add(cos_i, cos_i, out=m_k)
        m_k += rH
        np.divide(rH, m_k, out=m_k)
        b_tn, m_t = beta, inv_g
        b_tn *= sin_i
        b_tn *= inv_g
        m_t *= -2.0
        m_t += 1.0
        # dP/dc = I - t wᵀ - m_k k kᵀ with t = (sin θ, -cos θ e2), w = m_t t + b_tn n,
        # n = (cos θ, sin θ e2) in the basis: w = (w1, wq cos ζ, wq sin ζ).
        w1, w2, w3 = w[2], w[3], w[5]
        np.multiply(m_t, st, out=w1)
        np.multiply(b_tn, ct, out=tmp)
        w1 += tmp
        np.multiply(b_tn, st, out=w3)
        np.multiply(m_t, ct, out=tmp)
        w3 -= tmp
        np.multiply(w3, cz, out=w2)
        w3 *= sz
    # π: the pinhole rows (1, 0, -x/z) and (0, 1, -y/z) in the basis, times f / z, as Mp H
    # (the v rows' coefficients carry f_y / f_x).
    Mp = np.zeros((B, 6, 3))
    Mp[:, :3, 0], Mp[:, :3, 1] = M[:, :, 0], -M[:, :, 2]
    Mp[:, 3:, 0], Mp[:, 3:, 2] = M[:, :, 1], -M[:, :, 2]
    Mp[:, 3:] *= camera.fy_px / camera.fx_px
    pi = np.matmul(Mp, H, out=get("pi", (B, 6, n)))
    T, K, tmp = w[9], w[10], w[4]
    for row in range(2):
        p1, p2, p3 = pi[:, 3 * row], pi[:, 3 * row + 1], pi[:, 3 * row + 2]
        # T = π · t, K = m_k π · k; the row is π - T w - K k.
        np.multiply(p2, cz, out=T)
        np.multiply(p3, sz, out=tmp)
        T += tmp
        T *= ct
        np.multiply(p1, st, out=tmp)
        np.subtract(tmp, T, out=T)
        np.multiply(p3, cz, out=K)
        np.multiply(p2, sz, out=tmp)
        K -= tmp
        K *= m_k
        np.multiply(T, w1, out=tmp)
        np.subtract(p1, tmp, out=G[:, 0, row])
        np.multiply(T, w2, out=tmp)
        p2 -= tmp
        np.multiply(K, sz, out=tmp)
        np.add(p2, tmp, out=G[:, 1, row])
        np.multiply(T, w3, out=tmp)
        p3 -= tmp
        np.multiply(K, cz, out=tmp)
        np.subtract(p3, tmp, out=G[:, 2, row])
    return G.reshape(B, 4, 2 * n), (M @ R) * (1.0 / radius), fast


def _rows_all(a):
    return np.logical_and.reduce(a, axis=1)
