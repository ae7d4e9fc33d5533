"""Independent references for :mod:`scet_render.render.mnee` (numpy, float64): the irradiance
a point light refracted by the cornea puts at a point behind it, computed from the light's side
by power through a ray tube, and Gaussian optics on the axis of a refracting sphere. The tests
hold the manifold solve to both (tests/scet_render/test_mnee.py).
"""

from __future__ import annotations

import math

import numpy as np

from .cornea_bsdf import fresnel_dielectric


def reference_irradiance(state: dict, x, light, eta: float, *, step: float = 1e-6) -> float:
    """Irradiance at ``x`` (normal to the ray arriving there) from a unit-intensity point light
    at ``light`` refracted into the cornea: the light's side of :func:`~scet_render.render.mnee.connect`, by power.

    A ray tube of solid angle dOmega leaving the light carries dOmega W (unit intensity); after
    refraction (transmittance 1 - F) it crosses an area dA normal to the ray at x, so the
    irradiance there is (1 - F) dOmega / dA. The tube is traced in float64 numpy from the light
    through the cornea's quadric to the plane through x normal to the refracted ray; nothing is
    shared with :func:`~scet_render.render.mnee.connect` but the surface. Returns NaN when no ray reaches x.
    """
    x = np.asarray(x, dtype=np.float64)
    L = np.asarray(light, dtype=np.float64)
    minv, tinv = np.asarray(state["minv"]), np.asarray(state["tinv"])

    def enter(u):
        """Ray from the light along unit u: where it crosses the plane through x (normal m)."""
        o, dl = minv @ L + tinv, minv @ u
        A, B, C = dl @ dl, o @ dl, o @ o - 1.0
        disc = B * B - A * C
        if disc <= 0:
            return None
        t = (-B - math.sqrt(disc)) / A
        y = L + t * u
        n = minv.T @ (o + t * dl)
        n /= np.linalg.norm(n)
        ci = -u @ n
        st2 = (1.0 - ci * ci) / (eta * eta)
        ct = math.sqrt(1.0 - st2)
        d = u / eta + n * (ci / eta - ct)
        return y, d / np.linalg.norm(d), ci

    # The ray from the light that reaches x: Newton on the direction from the light.
    w = (x - L) / np.linalg.norm(x - L)
    e1 = np.cross(w, [0.0, 0.0, 1.0] if abs(w[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(w, e1)

    def hit(ab):
        u = w + ab[0] * e1 + ab[1] * e2
        u = u / np.linalg.norm(u)
        r = enter(u)
        if r is None:
            return None
        y, d, ci = r
        s = ((x - y) @ m) / (d @ m)
        return y + s * d, d, ci, u

    def residual(ab):
        h = hit(ab)
        if h is None:
            return None
        p = h[0] - x
        return np.array([p @ e1, p @ e2])

    # Damped Newton: a step is halved until the ray still meets the cornea and the miss shrinks.
    m = w.copy()
    ab = np.zeros(2)
    r = residual(ab)
    if r is None:
        return math.nan
    for _ in range(60):
        if np.linalg.norm(r) < 1e-12:
            break
        J = np.empty((2, 2))
        for j in range(2):
            dab = ab.copy()
            dab[j] += step
            rj = residual(dab)
            if rj is None:
                return math.nan
            J[:, j] = (rj - r) / step
        delta = np.linalg.solve(J, r)
        for _ in range(30):
            r_new = residual(ab - delta)
            if r_new is not None and np.linalg.norm(r_new) < np.linalg.norm(r):
                break
            delta = delta / 2
        else:
            return math.nan
        ab, r = ab - delta, r_new
    if np.linalg.norm(r) > 1e-9:
        return math.nan
    # The converged ray's direction at x is the tube's axis: measure the tube normal to it.
    m = hit(ab)[1]
    _, _, ci, u0 = hit(ab)
    # Solid angle of a parameter patch at the light, and its area normal to the ray at x
    # (central differences: the ratio is good to ~step^2).
    cols, dirs = [], []
    for j in range(2):
        up, down = ab.copy(), ab.copy()
        up[j] += step
        down[j] -= step
        p_up, _, _, u_up = hit(up)
        p_down, _, _, u_down = hit(down)
        cols.append(p_up - p_down)
        dirs.append(u_up - u_down)
    area = abs(np.cross(cols[0], cols[1]) @ m)
    omega = abs(np.cross(dirs[0], dirs[1]) @ u0)
    F = float(fresnel_dielectric(ci, eta))
    return (1.0 - F) * omega / area


def axial_irradiance(source_distance: float, depth: float, radius: float, eta: float) -> float:
    """Irradiance on the axis at ``depth`` behind the apex of a refracting sphere (index
    ``eta``, air outside) from a unit-intensity point source ``source_distance`` in front of it.

    Gaussian optics is exact for the on-axis ray tube: the refracted wavefront converges toward
    (or diverges from) the image point s' with eta / s' = (eta - 1) / R - 1 / s, so a tube of
    solid angle dOmega (area s^2 dOmega at the apex) has area s^2 dOmega (1 - t / s')^2 at
    depth t, and the transmittance at normal incidence is 1 - ((eta - 1) / (eta + 1))^2.
    """
    s, t, R = float(source_distance), float(depth), float(radius)
    power = (eta - 1.0) / R - 1.0 / s
    scale = 1.0 - t * power / eta  # 1 - t / s' with 1 / s' = power / eta
    F0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    return (1.0 - F0) / (s * s * scale * scale)


__all__ = ["reference_irradiance", "axial_irradiance"]
