"""The wire-wound mirror's two-bounce glints (estimator.geometry.wire): the law of reflection at
the cornea and at the wire, the highlight on the wire's surface, an independent minimisation of
the optical path, the thin-wire limit, the highlight following the cornea, and the labels of
glints whose highlight leaves the strip."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest
from scipy.optimize import minimize

from estimator.eye import gaze_direction
from estimator.geometry import project_glints
from estimator.geometry.wire import (
    cylinder_reflection,
    enamelled_copper_reflectance,
    eye_wire_glints,
    project_wire_glints,
    project_wire_glints_conic,
    setup_wire_mirrors,
)
from estimator.scene import load_scene


@dataclass(frozen=True)
class WireTol:
    #: Law of reflection at both vertices (rad): each one-bounce solver ends on a Newton polish
    #: (~1e-15 rad); the alternation stops when W moves < 1e-13 m, which tilts the cornea's
    #: incoming ray by < 1e-13 m / 30 mm ~ 3e-12 rad. 1e-9 rad: tests/tolerances.py's bound.
    reflection_rad: float = 1e-9
    #: The highlight's distance from the wire's axis minus ρ (m): float64 rounding of ~3 cm
    #: coordinates (7e-18 m ulp times a few operations).
    on_surface_m: float = 1e-12
    #: Against scipy's BFGS minimum of the path length (m): BFGS stops at gtol 1e-12 of a
    #: path measured in mm, ~1e-10 m along flat directions; 1e-8 m is 4e-5 px at 643 px / 30 mm
    #: through the cornea's 0.13x.
    brute_force_m: float = 1e-8
    #: Glint pixels of the conic solver at Q = 0 against the sphere's (px): the conic's Newton
    #: stops at 1e-14 R; both well below 1e-6 px.
    conic_sphere_px: float = 1e-6


TOL = WireTol()


@pytest.fixture(scope="module")
def setup():
    return load_scene("prototype_ov5647_wire")


@pytest.fixture(scope="module")
def mirror(setup):
    ((_, _, m),) = setup_wire_mirrors(setup)
    return m


@pytest.fixture(scope="module")
def grid(setup):
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(8, 5))
    return yaw, pitch


@pytest.fixture(scope="module")
def glints(setup, mirror, grid):
    return eye_wire_glints(setup.eye, setup.camera, mirror, *grid)


def _reflection_residual(p, n, a, b):
    """Angle (rad) between the mirror image of the ray a -> p and the ray p -> b."""
    d_in = (p - a) / np.linalg.norm(p - a, axis=-1, keepdims=True)
    d_out = (b - p) / np.linalg.norm(b - p, axis=-1, keepdims=True)
    refl = d_in - 2 * np.sum(d_in * n, -1, keepdims=True) * n
    return np.arccos(np.clip(np.sum(refl * d_out, -1), -1, 1)) + 0 * np.linalg.norm(np.cross(refl, d_out), axis=-1)


def test_enough_glints_to_test(glints):
    # The prototype scene's LED lights the turns facing the eye: a third of 40 poses x 35 turns.
    assert glints.converged.all()
    assert glints.visible.sum() > 300


def test_law_of_reflection_at_both_vertices(setup, mirror, glints):
    v = glints.visible
    O = setup.camera.position_m
    W, P = glints.highlight_m, glints.cornea_point_m
    L = mirror.led_position_m
    cross_w = np.linalg.norm(np.cross(
        (L - W) / np.linalg.norm(L - W, axis=-1, keepdims=True)
        + (P - W) / np.linalg.norm(P - W, axis=-1, keepdims=True), glints.wire_normal), axis=-1)
    cross_p = np.linalg.norm(np.cross(
        (W - P) / np.linalg.norm(W - P, axis=-1, keepdims=True)
        + (O - P) / np.linalg.norm(O - P, axis=-1, keepdims=True), glints.cornea_normal), axis=-1)
    # The bisector of the two unit rays is the normal: its cross product with the normal is
    # the sine of the residual (times the bisector's length, ~2 cos(incidence) >= 0.1).
    assert cross_w[v].max() < TOL.reflection_rad
    assert cross_p[v].max() < TOL.reflection_rad
    # The incoming ray's mirror image leaves toward the next vertex.
    assert _reflection_residual(W, glints.wire_normal, L, P)[v].max() < 1e-7
    assert _reflection_residual(P, glints.cornea_normal, W, O)[v].max() < 1e-7


def test_highlight_on_the_wire_surface(mirror, glints):
    rel = glints.highlight_m - mirror.wire_axes_m
    across = rel - np.sum(rel * mirror.normal, -1, keepdims=True) * mirror.normal
    dist = np.linalg.norm(across, axis=-1)
    assert np.abs(dist - mirror.wire_radius_m).max() < TOL.on_surface_m
    axial = np.sum(rel * mirror.normal, -1)
    np.testing.assert_allclose(axial, glints.axial_m, atol=1e-15)
    assert np.array_equal(glints.on_segment, np.abs(glints.axial_m) <= 0.5 * mirror.width_m)


def test_cylinder_reflection_is_the_path_length_minimum():
    """Against scipy's minimum of |L - W| + |W - X| over the cylinder's surface (ψ, s)."""
    rng = np.random.default_rng(7)
    A, a, rho = np.array([0.01, -0.02, 0.005]), np.array([0.0, 0.6, 0.8]), 0.4e-3
    e1 = np.cross(a, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    for _ in range(20):
        # Source and viewer 10-40 mm from the axis on the same side, up to 20 mm along it.
        def point(ang):
            r = rng.uniform(10e-3, 40e-3)
            return A + r * (math.cos(ang) * e1 + math.sin(ang) * e2) + rng.uniform(-20e-3, 20e-3) * a
        L, X = point(rng.uniform(-1.0, 1.0)), point(rng.uniform(-1.0, 1.0))
        W, n, s, ok = cylinder_reflection(A, a, rho, L, X)
        assert ok

        def path(q):
            # The length (mm) and its exact gradient: BFGS's stopping test on a finite-difference
            # gradient would leave ~1e-8 m along the axis.
            p = A + rho * (math.cos(q[0]) * e1 + math.sin(q[0]) * e2) + q[1] * 1e-3 * a
            dp = np.stack([rho * (-math.sin(q[0]) * e1 + math.cos(q[0]) * e2), 1e-3 * a])
            g = (p - L) / np.linalg.norm(p - L) + (p - X) / np.linalg.norm(p - X)
            return (np.linalg.norm(L - p) + np.linalg.norm(p - X)) * 1e3, dp @ g * 1e3

        psi0 = math.atan2((W - A) @ e2, (W - A) @ e1) + 0.05
        best = minimize(path, [psi0, s * 1e3 + 0.3], jac=True, method="BFGS", options={"gtol": 1e-13})
        q = best.x
        p = A + rho * (math.cos(q[0]) * e1 + math.sin(q[0]) * e2) + q[1] * 1e-3 * a
        assert np.linalg.norm(p - W) < TOL.brute_force_m


def test_two_bounce_glint_is_the_stationary_optical_path(setup, mirror, glints):
    """Fermat, independently: minimise |O - P| + |P - W| + |W - L| over P on the corneal sphere
    (2 angles) and W on the wire (ψ, s) with scipy, and compare the glints."""
    eye, cam = setup.eye, setup.camera
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(8, 5))
    i_pose, i_turn = np.argwhere(glints.visible)[[0, len(np.argwhere(glints.visible)) // 2, -1]].T
    e_n = mirror.normal
    for ip, k in zip(i_pose, i_turn):
        c = eye.cornea_center(yaw.ravel()[ip], pitch.ravel()[ip])
        r = eye.cornea_radius_m
        A = mirror.wire_axes_m[k]
        e1 = -mirror.radial[k]
        e2 = np.cross(e_n, e1)
        O, L = cam.position_m, mirror.led_position_m

        def vertices(q):
            th, ph, psi, s = q
            P = c + r * np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
            W = A + mirror.wire_radius_m * (math.cos(psi) * e1 + math.sin(psi) * e2) + s * 1e-3 * e_n
            return P, W

        def path(q):
            th, ph, psi, s = q
            P, W = vertices(q)
            dP = r * np.array([[math.cos(th) * math.cos(ph), math.cos(th) * math.sin(ph), -math.sin(th)],
                               [-math.sin(th) * math.sin(ph), math.sin(th) * math.cos(ph), 0.0]])
            dW = np.stack([mirror.wire_radius_m * (-math.sin(psi) * e1 + math.cos(psi) * e2), 1e-3 * e_n])
            u = lambda x: x / np.linalg.norm(x)  # noqa: E731
            gP, gW = u(P - O) + u(P - W), u(W - P) + u(W - L)
            length = np.linalg.norm(O - P) + np.linalg.norm(P - W) + np.linalg.norm(W - L)
            return length * 1e3, np.concatenate([dP @ gP, dW @ gW]) * 1e3

        P0 = glints.cornea_point_m.reshape(-1, mirror.turns, 3)[ip, k] - c
        W0 = glints.highlight_m.reshape(-1, mirror.turns, 3)[ip, k] - A
        q0 = [math.acos(P0[2] / r) + 0.02, math.atan2(P0[1], P0[0]) - 0.02,
              math.atan2(W0 @ e2, W0 @ e1) + 0.1, W0 @ e_n * 1e3 + 0.2]
        best = minimize(path, q0, jac=True, method="BFGS", options={"gtol": 1e-13})
        P, W = vertices(best.x)
        assert np.linalg.norm(W - glints.highlight_m.reshape(-1, mirror.turns, 3)[ip, k]) < TOL.brute_force_m
        px, _ = cam.project(P)
        assert np.linalg.norm(px - glints.glints_px.reshape(-1, mirror.turns, 2)[ip, k]) < 1e-4


def test_thin_wire_limit(setup, mirror, grid):
    """As d -> 0 the highlight closes on the wire's axis: the glint's offset from the thin-wire
    glint is proportional to d (the cornea images the d/2 step at ~0.13x)."""
    yaw, pitch = grid
    thin = eye_wire_glints(setup.eye, setup.camera, replace(mirror, wire_diameter_m=1e-9), yaw, pitch)
    offsets = []
    for d in (0.4e-3, 0.2e-3, 0.1e-3):
        g = eye_wire_glints(setup.eye, setup.camera, replace(mirror, wire_diameter_m=d), yaw, pitch)
        both = g.visible & thin.visible
        offsets.append(np.linalg.norm(g.glints_px - thin.glints_px, axis=-1)[both])
    assert offsets[0].size > 50
    # Linear in d: halving d halves the offset (to 5 %, the curvature of the path in d).
    for big, small in zip(offsets, offsets[1:]):
        n = min(big.size, small.size)
        ratio = np.median(big[:n]) / np.median(small[:n])
        assert 1.9 < ratio < 2.1
    # and the thin wire's glint is the point source on its axis at the highlight's height.
    thin_mirror = replace(mirror, wire_diameter_m=1e-9)
    pts = thin_mirror.wire_axes_m + thin.axial_m[..., None] * mirror.normal
    c = setup.eye.cornea_center(yaw, pitch)
    px, _ = project_glints(setup.camera, c.reshape(-1, 3)[:, None, :], setup.eye.cornea_radius_m,
                           pts.reshape(-1, mirror.turns, 1, 3))
    v = thin.visible.reshape(-1, mirror.turns)
    assert np.abs(px[..., 0, :] - thin.glints_px.reshape(-1, mirror.turns, 2))[v].max() < 1e-3


def test_highlight_moves_with_the_cornea(setup, mirror):
    """Moving the cornea along the arc normal slides each highlight along its wire by the plane
    mirror's share D_L / (D_L + D_P) of the cornea point's move (equal angles with the axis)."""
    c0 = setup.eye.cornea_center(0.0, 0.0)
    delta = 0.2e-3
    g0 = project_wire_glints(setup.camera, mirror, c0, setup.eye.cornea_radius_m)
    g1 = project_wire_glints(setup.camera, mirror, c0 + delta * mirror.normal, setup.eye.cornea_radius_m)
    both = g0.visible & g1.visible
    assert both.sum() >= 5
    ds = g1.axial_m - g0.axial_m
    dp = (g1.cornea_point_m - g0.cornea_point_m) @ mirror.normal
    across = lambda x: x - np.sum(x * mirror.normal, -1, keepdims=True) * mirror.normal  # noqa: E731
    D_L = np.linalg.norm(across(mirror.led_position_m - g0.highlight_m), axis=-1)
    D_P = np.linalg.norm(across(g0.cornea_point_m - g0.highlight_m), axis=-1)
    D_P1 = np.linalg.norm(across(g1.cornea_point_m - g1.highlight_m), axis=-1)
    D_L1 = np.linalg.norm(across(mirror.led_position_m - g1.highlight_m), axis=-1)
    l_a = (mirror.led_position_m - mirror.wire_axes_m) @ mirror.normal
    p_a = (g0.cornea_point_m - mirror.wire_axes_m) @ mirror.normal
    s = g0.axial_m
    # (A) differentiated: the cornea point's own move along the axis (the plane mirror's
    # share) plus the change of the cross-section distances.
    predicted = (D_L * dp + (l_a - s) * (D_P1 - D_P) + (p_a - s) * (D_L1 - D_L)) / (D_L + D_P)
    assert np.all(np.abs(ds[both]) > 0.05e-3)  # tens of µm: the virtual source is not fixed
    np.testing.assert_allclose(ds[both], predicted[both], rtol=0.02)
    # and the glint moves differently from the point-source model's.
    pts0, _ = project_glints(setup.camera, c0, setup.eye.cornea_radius_m, mirror.wire_axes_m)
    pts1, _ = project_glints(setup.camera, c0 + delta * mirror.normal, setup.eye.cornea_radius_m,
                             mirror.wire_axes_m)
    diff = np.linalg.norm((g1.glints_px - g0.glints_px) - (pts1 - pts0), axis=-1)
    assert np.median(diff[both]) > 0.01


def test_highlight_off_the_strip_is_not_visible(setup, mirror):
    """An LED far below the arc plane pushes every highlight off the 2 mm strip."""
    led = mirror.led_position_m + 0.08 * mirror.normal
    aim = mirror.wire_axes_m[17] - led
    moved = replace(mirror, led_position_m=led, led_aim=aim / np.linalg.norm(aim))
    g = project_wire_glints(setup.camera, moved, setup.eye.cornea_center(0.0, 0.0),
                            setup.eye.cornea_radius_m)
    assert not g.on_segment.any() and not g.visible.any()
    assert np.all(np.abs(g.axial_m) > 0.5 * mirror.width_m)


def test_conic_solver_matches_the_sphere_at_q0(setup, mirror, grid):
    yaw, pitch = grid
    axis = gaze_direction(yaw, pitch)
    c = setup.eye.cornea_center(yaw, pitch)
    r = setup.eye.cornea_radius_m
    s = project_wire_glints(setup.camera, mirror, c, r)
    q = project_wire_glints_conic(setup.camera, mirror, c + r * axis, axis, r, 0.0)
    v = s.visible & q.visible
    assert v.sum() > 300 and np.array_equal(s.visible, q.visible)
    assert np.abs(s.glints_px - q.glints_px)[v].max() < TOL.conic_sphere_px


def test_conic_cornea_obeys_the_law_of_reflection(setup, mirror, grid):
    yaw, pitch = grid
    eye = replace(setup.eye, cornea_asphericity=-0.25)
    g = eye_wire_glints(eye, setup.camera, mirror, yaw, pitch)
    v = g.visible
    assert v.sum() > 200
    O, W, P = setup.camera.position_m, g.highlight_m, g.cornea_point_m
    bis = (W - P) / np.linalg.norm(W - P, axis=-1, keepdims=True) + (O - P) / np.linalg.norm(O - P, axis=-1, keepdims=True)
    assert np.linalg.norm(np.cross(bis, g.cornea_normal), axis=-1)[v].max() < TOL.reflection_rad


def test_enamelled_copper_reflectance():
    """Normal incidence: the film's 4.7 % plus copper's 0.965 through it (less its losses),
    0.948, below the bare metal's 0.965; near 1 at grazing incidence."""
    r = enamelled_copper_reflectance(np.array([1.0, 0.5, 1e-6]))
    assert 0.94 < r[0] < 0.965
    assert 0.9 < r[1] < 1.0 and r[-1] > 0.99


def test_rays_through_another_turn_or_the_strip_are_blocked(mirror):
    """A ray from a highlight along the inner face, low enough to hit the next turn, is blocked;
    the same ray lifted clear of the wire, or one straight toward the arc's centre, is not; a
    ray out through the strip is blocked."""
    from estimator.geometry import wire

    k = 10
    rho = mirror.wire_radius_m
    inward = -mirror.radial[k]
    tangent = np.cross(mirror.normal, mirror.radial[k])  # toward turn k + 1
    W = mirror.wire_axes_m[k] + rho * inward
    low = W + 5e-3 * tangent  # passes at the wire axes' height: through turn k + 1
    high = W + 5e-3 * tangent + 3 * mirror.wire_diameter_m * inward
    centre = mirror.center_m + 0.2e-3 * mirror.normal
    out = mirror.wire_axes_m[k] + 10e-3 * mirror.radial[k]
    T = mirror.turns
    Ws = np.broadcast_to(W, (T, 3)).copy()
    for X, blocked in ((low, True), (high, False), (centre, False), (out, True)):
        got = wire._occluded(mirror, Ws, np.broadcast_to(X, (T, 3)))
        assert got[k] == blocked
