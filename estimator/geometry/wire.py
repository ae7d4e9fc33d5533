"""Glints of the wire-wound mirror: camera -> cornea -> wire turn -> LED, two specular bounces.

The prototype's lighting (SCET paper Sec. 4.1) is one near-IR LED whose light reflects off
``turns`` turns of enamelled wire wound on a printed circular strip; each glint on the cornea
is the LED seen in one wire turn seen in the cornea. On the strip's inner face (the face toward
the arc's centre, which the eye sees) each turn is a straight stretch of wire across the
strip's width: a circular cylinder of radius ρ = d/2 whose axis runs along the arc plane's
normal n̂, at radius R - ρ from the arc's axis (the wire lies on the face) and at the turn's
angle on the arc. Every turn's axis is parallel to n̂.

**Two-bounce glint (Fermat).** With the camera centre O, the corneal reflection point P and
the wire highlight W, the light's path O -> P -> W -> L is stationary in P (the law of
reflection at the cornea, the existing one-bounce solvers :func:`reflection_points` and
:func:`conic_reflection_points` with W as the source) and stationary in W (the law of
reflection on the cylinder with P as the viewer). We solve the pair by alternating the two
exact one-bounce solutions from the point-source model's position (the turn's axis at mid-width):

    P_k = cornea_reflection(O, W_k),     W_{k+1} = cylinder_reflection(L, P_k).

The map is a contraction with a small gain: the cornea images the wire at ~f / D = 3.9 mm / 30 mm
~ 0.13 (P moves 0.13 mm when W moves 1 mm) and W follows P along the axis by at most
D_L / (D_L + D_P) < 1 (the plane-mirror share below), so the error shrinks several times per
round; the iteration stops when W moves less than :data:`STEP_TOL_M` (prototype_ov5647_wire's
24 x 15 grid: 13 rounds from the mid-width start, sphere and conic Q = -0.25 alike). At the fixed point both laws
of reflection hold at once, i.e. the optical path is stationary in both vertices.

**Reflection on a cylinder** (axis point A, unit axis â, radius ρ; source L, viewer X). The
surface normal ⊥ â, so the reflection keeps each ray's component along â: the cross-section
(projection along â) obeys the law of reflection on the circle of radius ρ, the sphere's
planar problem (Sec. 2.1 of the paper; :mod:`~estimator.geometry.roots`) with
α = |x⊥| / ρ, β = |l⊥| / ρ. Along the axis the mirror is a plane: with D_L, D_X the
cross-section distances from the highlight to L and X, the unfolded path is straight, so

    s = (l_a D_X + x_a D_L) / (D_L + D_X)                                             (A)

for the axial coordinates s, l_a, x_a of W, L, X (the Keller cone: the two rays make equal
angles with the axis).

**Visibility.** A glint is labelled visible when: both one-bounce solutions exist and face
their endpoints (the corneal cap, as in :func:`project_glints`); the highlight lies on the
turn's stretch across the strip, |s| <= w/2 (a highlight beyond it is on the bend round the
strip's edge, which the model does not hold: the glint is labelled lost); both rays leave the
wire into the arc's inside (not through the strip) and pass no other turn nor the strip;
the LED emits toward W; the iteration converged; the pixel is in the image.

**Brightness.** The glint's power relative to the other turns: the LED's radiant intensity
toward W (its datasheet beam, :class:`LedBeam`), the wire's reflectance (enamel over copper,
:func:`enamelled_copper_reflectance`), the cornea's Fresnel reflectance, and the two mirrors'
demagnification of the LED's area (|det ∂px/∂L⊥|, by finite differences in
:func:`wire_glint_flux`).

Everything is vectorised over a batch of cornea poses and the turns, numpy only (the
estimator's Raspberry Pi budget).
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

import numpy as np

from .camera import Camera
from .conic import conic_reflection_points
from .reflection import reflection_points
from .rigid import as_points
from .roots import _first_order_root, _newton_unit
from .wire_model import (
    COPPER_INDEX_850NM,
    ENAMEL_INDEX,
    LedBeam,
    WireGeometryError,
    WireMirror,
    enamelled_copper_reflectance,
    fresnel_unpolarized,
)

__all__ = ["LedBeam", "WireMirror", "WireGeometryError", "WireGlints", "cylinder_reflection",
           "project_wire_glints", "project_wire_glints_conic", "wire_glint_flux",
           "enamelled_copper_reflectance", "fresnel_unpolarized", "COPPER_INDEX_850NM",
           "eye_wire_glints", "setup_wire_mirrors", "led_disk_glints",
           "ENAMEL_INDEX"]

#: The alternation stops when the highlight moves less than this (m): 1e-13 m is 1e-10 of a
#: wire radius; through the cornea's ~0.13x and 643-1300 px at ~30 mm, ~1e-9 px.
STEP_TOL_M = 1e-13
#: Rounds of the alternation: 13 reach STEP_TOL_M from the mid-width start on the prototype's
#: grid (the error falls ~6x a round); pairs still moving after this many are labelled not
#: visible.
MAX_ROUNDS = 40


# -- one bounce on a cylinder ------------------------------------------------------------------
def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def cylinder_reflection(axis_point_m, axis_dir, radius_m: float, source_m, viewer_m):
    """Where light from ``source_m`` reflects off an infinite circular cylinder toward
    ``viewer_m`` (module docstring: the cross-section's circle problem and (A)).

    Parameters
    ----------
    axis_point_m : (..., 3) float
        A point on the axis (axial coordinates are measured from it).
    axis_dir : (..., 3) float
        Unit axis direction.
    radius_m : float
    source_m, viewer_m : (..., 3) float
        All arguments broadcast together.

    Returns
    -------
    point_m : (..., 3) float
        The highlight W.
    normal : (..., 3) float
        Outward unit normal there.
    axial_m : (...,) float
        W's coordinate along the axis from ``axis_point_m``.
    ok : (...,) bool
        Source and viewer outside the cylinder and in front of the tangent plane at W.
    """
    A = np.asarray(axis_point_m, dtype=np.float64)
    a = np.asarray(axis_dir, dtype=np.float64)
    Lr = np.asarray(source_m, dtype=np.float64) - A
    Xr = np.asarray(viewer_m, dtype=np.float64) - A
    la, xa = _dot(Lr, a), _dot(Xr, a)
    lp = Lr - la[..., None] * a
    xp = Xr - xa[..., None] * a
    x_norm = np.linalg.norm(xp, axis=-1)
    e1 = xp / np.where(x_norm > 0, x_norm, 1.0)[..., None]
    l_par = _dot(lp, e1)
    q = lp - l_par[..., None] * e1
    l_perp = np.linalg.norm(q, axis=-1)
    l_norm = np.hypot(l_par, l_perp)
    # A source on the viewer's line through the axis: any in-plane e2 serves (θ = 0).
    fallback = np.cross(a, e1)
    e2 = np.where((l_perp > 1e-15 * np.maximum(l_norm, 1e-300))[..., None],
                  q / np.where(l_perp > 0, l_perp, 1.0)[..., None], fallback)
    alpha = x_norm / radius_m
    beta = l_norm / radius_m
    cp = l_par / np.where(l_norm > 0, l_norm, 1.0)
    sp = l_perp / np.where(l_norm > 0, l_norm, 1.0)
    outside = (alpha > 1) & (beta > 1)
    al = np.where(outside, alpha, 2.0)
    be = np.where(outside, beta, 2.0)
    ct, st = _newton_unit(al, be, cp, sp, *_first_order_root(al, be, cp, sp))
    n = ct[..., None] * e1 + st[..., None] * e2
    wp = radius_m * n  # the highlight in the cross-section, from the axis
    d_x = np.linalg.norm(xp - wp, axis=-1)
    d_l = np.linalg.norm(lp - wp, axis=-1)
    s = (la * d_x + xa * d_l) / np.where(d_l + d_x > 0, d_l + d_x, 1.0)
    point = A + wp + s[..., None] * a
    c1 = cp * ct + sp * st
    ok = outside & (al * ct > 1) & (be * c1 > 1)
    return point, n, s, ok


# -- the two-bounce solve --------------------------------------------------------------------
class WireGlints(NamedTuple):
    """The glint of every turn for a batch of cornea poses: arrays (..., turns[, k]).

    ``glints_px`` (..., T, 2), ``visible`` (..., T), ``highlight_m`` (..., T, 3) the wire
    highlight W, ``wire_normal`` (..., T, 3), ``axial_m`` (..., T) W's offset along the turn
    from mid-width, ``on_segment`` (..., T) |axial| <= w/2, ``cornea_point_m`` (..., T, 3),
    ``cornea_normal`` (..., T, 3), ``converged`` (..., T), ``led_relative`` (..., T) the LED's
    I(θ) / I_max toward W, ``wire_reflectance`` and ``cornea_reflectance`` (..., T).
    """

    glints_px: np.ndarray
    visible: np.ndarray
    highlight_m: np.ndarray
    wire_normal: np.ndarray
    axial_m: np.ndarray
    on_segment: np.ndarray
    cornea_point_m: np.ndarray
    cornea_normal: np.ndarray
    converged: np.ndarray
    led_relative: np.ndarray
    wire_reflectance: np.ndarray
    cornea_reflectance: np.ndarray


def _two_bounce(camera: Camera, mirror: WireMirror, batch: tuple, cornea_reflect, cornea_index,
                occlusion: bool) -> WireGlints:
    T = mirror.turns
    O = camera.position_m
    axes = mirror.wire_axes_m  # (T, 3)
    L = mirror.led_position_m
    rho = mirror.wire_radius_m
    # Start: the point-source model's light, moved onto the wire's inner surface.
    W = np.broadcast_to(axes - rho * mirror.radial, batch + (T, 3)).copy()
    step = np.full(batch + (T,), np.inf)
    for _ in range(MAX_ROUNDS):
        P, _, _ = cornea_reflect(W)
        P_safe = np.where(np.isfinite(P), P, W + (O - W) * 0.5)
        W_new, _, _, _ = cylinder_reflection(axes, mirror.normal, rho, L, P_safe)
        moved = np.linalg.norm(W_new - W, axis=-1)
        step = np.where(np.isfinite(moved), moved, np.inf)
        W = np.where(np.isfinite(W_new), W_new, W)
        if not (step > STEP_TOL_M).any():
            break
    converged = step <= STEP_TOL_M
    P, nP, okP = cornea_reflect(W)
    W, nW, s, okW = cylinder_reflection(axes, mirror.normal, rho, L,
                                        np.where(np.isfinite(P), P, W))
    on_segment = np.abs(s) <= 0.5 * mirror.width_m
    radial = mirror.radial
    to_led = L - W
    to_eye = P - W
    # Both rays leave the wire into the arc's inside, not through the strip it lies on.
    inward = (_dot(to_led, radial) < 0) & (_dot(to_eye, radial) < 0)
    led_cos = _dot(-to_led, mirror.led_aim) / np.linalg.norm(to_led, axis=-1)
    led_rel = mirror.beam(led_cos)
    cos_w = _dot(to_led, nW) / np.linalg.norm(to_led, axis=-1)
    cam_dir = O - P
    cos_c = _dot(cam_dir, nP) / np.linalg.norm(cam_dir, axis=-1)
    px, _ = camera.project(P)
    visible = (converged & okP & okW & on_segment & inward & (led_rel > 0)
               & camera.in_image(px))
    if occlusion and visible.any():
        visible &= ~_occluded(mirror, W, L) & ~_occluded(mirror, W, P)
    return WireGlints(px, visible, W, nW, s, on_segment, P, nP, converged, led_rel,
                      enamelled_copper_reflectance(cos_w),
                      fresnel_unpolarized(cos_c, 1.0, cornea_index))


def _occluded(mirror: WireMirror, W, X) -> np.ndarray:
    """(..., T) whether the segment from each highlight W (..., T, 3) to X (..., T, 3) passes
    through another turn or the strip. Every turn's axis is parallel to the arc normal, so the
    test runs in the arc plane (coordinates along u, v) and checks the axial coordinate at the
    crossing."""
    c, n = mirror.center_m, mirror.normal
    w2 = np.stack([_dot(W - c, mirror.u), _dot(W - c, mirror.v)], -1)  # (..., T, 2)
    x2 = np.stack([_dot(X - c, mirror.u), _dot(X - c, mirror.v)], -1)
    wz, xz = _dot(W - c, n), _dot(X - c, n)
    d2 = x2 - w2
    dz = xz - wz
    hw = 0.5 * mirror.width_m
    # Other turns: circles of radius ρ at the axes, (..., T [segment], T [turn]).
    ang = mirror.turn_angles_rad
    axes2 = (mirror.radius_m - mirror.wire_radius_m) * np.stack([np.cos(ang), np.sin(ang)], -1)
    f = w2[..., :, None, :] - axes2  # (..., T, T, 2)
    dd = _dot(d2, d2)[..., :, None]
    b = _dot(f, d2[..., :, None, :])
    cc = _dot(f, f) - mirror.wire_radius_m ** 2
    disc = b * b - dd * cc
    with np.errstate(invalid="ignore", divide="ignore"):
        t1 = (-b - np.sqrt(np.maximum(disc, 0.0))) / dd
    z_hit = wz[..., :, None] + t1 * dz[..., :, None]
    T = mirror.turns
    other = ~np.eye(T, dtype=bool)
    hit_turn = ((disc > 0) & (t1 > 1e-9) & (t1 < 1.0) & (np.abs(z_hit) <= hw) & other).any(-1)
    # The strip's inner face: the circle of radius R, within its angular extent and width.
    R = mirror.radius_m
    b0 = _dot(w2, d2)
    c0 = _dot(w2, w2) - R * R  # < 0: W lies inside the circle
    dd0 = _dot(d2, d2)
    with np.errstate(invalid="ignore", divide="ignore"):
        t_exit = (-b0 + np.sqrt(np.maximum(b0 * b0 - dd0 * c0, 0.0))) / dd0
    exit_pt = w2 + t_exit[..., None] * d2
    a_exit = np.arctan2(exit_pt[..., 1], exit_pt[..., 0])
    lo, hi = mirror.strip_angles_rad
    # Angles measured from u, unwrapped into [lo, lo + 2π).
    a_exit = lo + np.mod(a_exit - lo, 2 * np.pi)
    z_exit = wz + t_exit * dz
    hit_strip = (t_exit < 1.0) & (a_exit <= hi) & (np.abs(z_exit) <= hw)
    return hit_turn | hit_strip


def project_wire_glints(camera: Camera, mirror: WireMirror, cornea_center, cornea_radius, *,
                        cornea_axis=None, cap_cos_min: float | None = None,
                        refractive_index: float = 1.376, occlusion: bool = True) -> WireGlints:
    """Glints of every wire turn on a spherical cornea (module docstring).

    Parameters
    ----------
    camera : Camera
    mirror : WireMirror
        In the world frame (:meth:`WireMirror.posed` with the scene group's pose).
    cornea_center : (..., 3) float
        Cornea centres (m), a batch of poses.
    cornea_radius : float
    cornea_axis : (..., 3) float, optional
        With ``cap_cos_min``: glints off the corneal cap are not visible (as
        :func:`project_glints`).
    cap_cos_min : float, optional
    refractive_index : float
        The cornea's, for its Fresnel reflectance.
    occlusion : bool
        Test the rays against the other turns and the strip.

    Returns
    -------
    WireGlints
        Arrays of shape (..., turns[, k]).
    """
    c = as_points(cornea_center, "cornea_center")
    batch = c.shape[:-1]
    if (cornea_axis is None) != (cap_cos_min is None):
        raise ValueError("cornea_axis and cap_cos_min must be given together")
    ax = None if cornea_axis is None else np.broadcast_to(as_points(cornea_axis, "cornea_axis"), batch + (3,))
    r = float(cornea_radius)

    def reflect(W):
        P, nP, ok = reflection_points(camera.position_m, c, r, W)
        if ax is not None:
            ok = ok & (_dot(nP, ax[..., None, :]) >= cap_cos_min)
        return P, nP, ok

    return _two_bounce(camera, mirror, batch, reflect, refractive_index, occlusion)


def project_wire_glints_conic(camera: Camera, mirror: WireMirror, apex, cornea_axis,
                              cornea_radius: float, asphericity: float, *,
                              limbus_depth_m=None, refractive_index: float = 1.376,
                              occlusion: bool = True) -> WireGlints:
    """Glints of every wire turn on a conic cornea (:func:`conic_reflection_points` at the
    corneal vertex; otherwise as :func:`project_wire_glints`).

    Parameters
    ----------
    apex : (..., 3) float
        Corneal apex, a batch of poses.
    cornea_axis : (..., 3) float
        Unit optical axis (outward).
    cornea_radius : float
        Apex radius of curvature.
    asphericity : float
        Conic constant Q in (-1, 1].
    limbus_depth_m : float, optional
        Reflection points deeper than this behind the apex are off the cap.
    """
    A = as_points(apex, "apex")
    axis = as_points(cornea_axis, "cornea_axis")
    batch = np.broadcast_shapes(A.shape[:-1], axis.shape[:-1])

    def reflect(W):
        return conic_reflection_points(camera.position_m, A, axis, cornea_radius, asphericity, W,
                                       limbus_depth_m=limbus_depth_m)

    return _two_bounce(camera, mirror, batch, reflect, refractive_index, occlusion)


def wire_glint_flux(camera: Camera, mirror: WireMirror, cornea_center, cornea_radius, *,
                    step_m: float = 2e-6, **kwargs) -> tuple[WireGlints, np.ndarray]:
    """Each glint's power on the sensor, relative: I(θ)/I_max x wire reflectance x cornea
    reflectance x |det ∂px/∂L⊥| (px² per m² of LED area across the ray toward W: the two
    mirrors' demagnification, by central differences of the whole solve with the LED moved by
    ``step_m`` across the ray).

    Returns
    -------
    glints : WireGlints
    flux : (..., turns) float
        Relative power (0 where not visible); px² m⁻² units of the LED's area.
    """
    g = project_wire_glints(camera, mirror, cornea_center, cornea_radius, **kwargs)
    ray = g.highlight_m - mirror.led_position_m
    ray = ray / np.linalg.norm(ray, axis=-1, keepdims=True)
    helper = np.where(np.abs(ray[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = np.cross(ray, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(ray, e1)
    # The LED is one point for all turns, so move it along fixed axes and project the
    # per-turn Jacobian onto each turn's transverse plane: ∂px/∂L is (2, 3) per turn.
    J = np.zeros(g.glints_px.shape[:-1] + (2, 3))
    for i, e in enumerate(np.eye(3)):
        px = []
        for sgn in (1.0, -1.0):
            moved = replace(mirror, led_position_m=mirror.led_position_m + sgn * step_m * e)
            px.append(project_wire_glints(camera, moved, cornea_center, cornea_radius, **kwargs).glints_px)
        J[..., :, i] = (px[0] - px[1]) / (2 * step_m)
    Jt = np.stack([np.einsum("...ij,...j->...i", J, e1), np.einsum("...ij,...j->...i", J, e2)], -1)
    det = np.abs(np.linalg.det(Jt))
    flux = g.led_relative * g.wire_reflectance * g.cornea_reflectance * det
    return g, np.where(g.visible, flux, 0.0)


def eye_wire_glints(eye, camera: Camera, mirror: WireMirror, yaw_rad, pitch_rad, *,
                    occlusion: bool = True) -> WireGlints:
    """Glints of every turn for an :class:`~estimator.eye.Eye` rotated to (yaw, pitch) (Fick
    angles, any batch shape): the sphere with the corneal cap test, or for Q != 0 the conic
    with the cap ending at the limbus plane (as :meth:`Eye.glints`)."""
    center = eye.cornea_center(yaw_rad, pitch_rad)
    axis = eye.apex(yaw_rad, pitch_rad) - center  # the gaze direction (geometry sits below eye)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    if eye.cornea_asphericity != 0:
        return project_wire_glints_conic(camera, mirror, center + eye.cornea_radius_m * axis, axis,
                                         eye.cornea_radius_m, eye.cornea_asphericity,
                                         limbus_depth_m=eye.limbus_depth_m,
                                         refractive_index=eye.refractive_index, occlusion=occlusion)
    return project_wire_glints(camera, mirror, center, eye.cornea_radius_m, cornea_axis=axis,
                               cap_cos_min=eye.cap_cos_min, refractive_index=eye.refractive_index,
                               occlusion=occlusion)


def setup_wire_mirrors(setup) -> list[tuple[int, int, WireMirror]]:
    """The wire mirrors of a :class:`~estimator.setup.Setup`: (group index, index of the
    group's first light in the rig, the mirror in the world frame) for each ``wire_mirror``
    group."""
    out, first = [], 0
    for i, g in enumerate(setup.lights.groups):
        if isinstance(g.emitter, WireMirror):
            out.append((i, first, g.emitter.posed(g.pose)))
        first += g.count
    return out


def led_disk_glints(eye, camera: Camera, mirror: WireMirror, yaw_rad, pitch_rad, *,
                    rings: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Centroids of the glints of an LED of finite size: each turn's glint averaged over points
    spread evenly over the LED's emitting disk (``mirror.led_diameter_m``, facing its aim),
    each point counted where its own glint is visible. A constant-radiance disk's glint is the
    image of its area, so to first order its centroid is this uniform average (the two mirrors'
    demagnification varies little across a 1 mm LED); it differs from the centre's glint where
    the mapping curves or part of the disk's highlight leaves the strip.

    Returns
    -------
    glints_px : (..., turns, 2) float
        NaN where no point of the disk makes a visible glint.
    share : (..., turns) float
        The share of the disk's area whose glint is visible.
    """
    z = mirror.led_aim
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = 0.5 * mirror.led_diameter_m
    acc = wsum = total = 0.0
    for i in range(rings):
        rho = (i + 0.5) / rings
        n = max(1, int(round(2 * np.pi * rho * rings)))
        for a in np.arange(n) * 2 * np.pi / n:
            p = mirror.led_position_m + r * rho * (np.cos(a) * x + np.sin(a) * y)
            g = eye_wire_glints(eye, camera, replace(mirror, led_position_m=p), yaw_rad, pitch_rad)
            w = (rho / n) * g.visible
            acc = acc + w[..., None] * np.where(g.visible[..., None], g.glints_px, 0.0)
            wsum = wsum + w
            total = total + rho / n
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where((wsum > 0)[..., None], acc / wsum[..., None], np.nan), wsum / total
