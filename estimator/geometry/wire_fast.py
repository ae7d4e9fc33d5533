"""The wire mirror's virtual sources for the tracker's fits (issue 35 c): each turn's glint is
the LED's highlight on that turn, which moves with the cornea.

The point-source model puts each turn's light at a fixed point (its axis at mid-width). The
glint of turn k is really the corneal image of the highlight W_k on the wire, the point of the
turn where light from the LED reflects toward the cornea's reflection point P_k
(:mod:`estimator.geometry.wire`): W_k depends on the cornea centre c (and radius r). This
module gives the fits that dependence:

* :meth:`WireLights.sources` -- W_k(c, r) for a batch of cornea centres: the two-bounce
  alternation of :mod:`estimator.geometry.wire` (cornea reflection with W as the source,
  cylinder reflection with P as the viewer), warm-started from the caller's previous W. A fit
  moves c by micrometres between evaluations, so from the previous W the alternation needs a
  few rounds instead of the ~13 from the turn's axis (the error shrinks ~6x a round). No
  occlusion, strip-width or cap test: the caller knows which glints were seen.
* :func:`wire_glints_jacobian` -- the glints of the virtual sources and their total derivative
  with respect to the cornea centre, d g / d c = ∂g/∂c + ∂g/∂L · dW/dc: ∂g/∂c and ∂g/∂L in
  closed form (:func:`estimator.geometry.glint_jacobians`, the point-source fit's own rows),
  dW/dc by forward differences of :data:`JACOBIAN_ROUNDS` rounds of the alternation started
  from the converged W. The alternation is a contraction of gain q ~ 1/6 (W -> P -> W), so k
  rounds give dW/dc = (1 + A + ... + A^(k-1)) B h with A the round's gain: the fixed point's
  derivative (I - A)^-1 B to a relative q^k (~0.5 % at k = 3) of a term that is itself 5-9 %
  of ∂g/∂c on prototype_ov5647_wire's grid (median 5.2 %, max 8.9 %). An approximate
  Jacobian slows Gauss-Newton a little and does not move its noise-free answer (zero
  residual). Leaving dW/dc out altogether (a fixed point over frozen sources) converges
  linearly at that 5-9 % a round.

Other light groups of the rig stay points. numpy, with an optional Numba kernel for the
alternation and the glints' rows (:mod:`estimator.geometry.wire_kernel`, the default where Numba
is: a band's few glints cost numpy's per-call overhead, not arithmetic; ``compiled=False``
forces numpy, which gives the same answers to the sources' tolerance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import wire_kernel
from .camera import Camera
from .jacobians import glint_jacobians
from .reflection import reflection_points
from .rigid import RigidPose, as_points
from .wire import cylinder_reflection, setup_wire_mirrors
from .wire_model import WireMirror

__all__ = ["WireLights", "wire_glints_jacobian", "SOURCE_TOL_M", "SOURCE_MAX_ROUNDS",
           "SOURCE_STEP_M", "JACOBIAN_ROUNDS"]

#: The alternation stops when no highlight moves more than this (m) in a round: 1e-13 m is, via
#: the cornea's ~0.13x image and 643-1300 px at ~30 mm, ~1e-9 px, and leaves the forward
#: differences below (step 1e-6 m) a relative error of ~1e-7.
SOURCE_TOL_M = 1e-13
#: Rounds of the alternation; a pair still moving after this many is flagged (not converged).
#: From the turn's axis 13 rounds reach the tolerance on prototype_ov5647_wire's grid.
SOURCE_MAX_ROUNDS = 40
#: Forward-difference step of dW/dc (m): 1 um of cornea moves W by < 1 um, where the solve's
#: 1e-13 m tolerance is 1e-7 of the difference and the curvature's share (~h / 8 mm) ~1e-4.
SOURCE_STEP_M = 1e-6
#: Rounds of the alternation behind each forward difference (module docstring): 3 rounds from
#: the converged sources leave ~q^3 ~ 0.5 % of the highlight's motion out, against 8-9 rounds
#: to the full tolerance (measured: a Jacobian of 360 poses x 35 turns in 0.93 s with full
#: solves).
JACOBIAN_ROUNDS = 3


@dataclass(frozen=True, slots=True)
class WireLights:
    """The rig's lights with each wire mirror's turns as virtual sources.

    Attributes
    ----------
    camera_position_m : (3,) float
    points_m : (n, 3) float
        Every light as a point (the wire turns' entries are replaced by their highlights).
    mirrors : tuple of (int, WireMirror)
        Index of each mirror's first turn in the rig, and the mirror in the world frame.
    """

    camera_position_m: np.ndarray
    points_m: np.ndarray
    mirrors: tuple

    @classmethod
    def from_setup(cls, setup, correction: RigidPose | None = None) -> "WireLights":
        """The lights of ``setup`` moved by a lighting ``correction`` (world frame; default
        none): the calibrated lighting pose moves the mirror and its LED as it moves the
        points."""
        corr = RigidPose() if correction is None else correction
        mirrors = tuple((first, m.posed(corr)) for _, first, m in setup_wire_mirrors(setup))
        if not mirrors:
            raise ValueError(f"light_model 'wire_mirror' needs a wire_mirror light group; scene "
                             f"{setup.name!r} has none")
        return cls(setup.camera.position_m, corr.apply(setup.lights_world_m), mirrors)

    def posed(self, correction: RigidPose) -> "WireLights":
        """These lights moved rigidly by ``correction``."""
        return WireLights(self.camera_position_m, correction.apply(self.points_m),
                          tuple((f, m.posed(correction)) for f, m in self.mirrors))

    @property
    def count(self) -> int:
        return int(self.points_m.shape[0])

    def sources(self, centers_m, radius_m, start=None, *, tol_m: float = SOURCE_TOL_M,
                rounds: int | None = None):
        """Virtual sources for cornea centres ``centers_m`` (B, 3) and radius ``radius_m``.

        Parameters
        ----------
        centers_m : (B, 3) float
        radius_m : float
        start : (B, n, 3) float, optional
            The sources of nearby centres (a warm start); default each turn's highlight
            start of :mod:`estimator.geometry.wire` (its axis moved onto the wire's surface).
        tol_m : float
        rounds : int, optional
            Run exactly this many rounds from ``start`` (the Jacobian's differences).

        Returns
        -------
        sources_m : (B, n, 3) float
            The point lights, with each turn's highlight in its place.
        converged : (B, n) bool
            False where a turn's alternation did not settle (or its reflection does not exist).
        """
        c = as_points(centers_m, "centers_m").reshape(-1, 3)
        every = np.broadcast_to(np.arange(self.count), (c.shape[0], self.count))
        return self.sources_of(c, radius_m, every, start, tol_m=tol_m, rounds=rounds)

    def sources_of(self, centers_m, radius_m, light_index, start=None, *,
                   tol_m: float = SOURCE_TOL_M, rounds: int | None = None,
                   compiled: bool | None = None):
        """:meth:`sources` of the lights ``light_index`` (B, k) only (a band's few glints: the
        alternation then costs per glint seen, not per light). ``compiled``: run the Numba
        kernel (:mod:`estimator.geometry.wire_kernel`, the default where Numba is) or numpy
        (False); both agree to ``tol_m``.

        Returns
        -------
        sources_m : (B, k, 3) float
        converged : (B, k) bool
        """
        c = as_points(centers_m, "centers_m").reshape(-1, 3)
        idx = np.asarray(light_index)
        out = self.points_m[idx]
        ok = np.ones(idx.shape, dtype=bool)
        for first, m in self.mirrors:
            turn = idx - first
            on = (turn >= 0) & (turn < m.turns)
            if not on.any():
                continue
            turn = np.clip(turn, 0, m.turns - 1)
            W0 = None if start is None else np.asarray(start, dtype=np.float64)
            W, okm = _highlights(self.camera_position_m, m, c, radius_m, W0, tol_m, rounds, turn,
                                 compiled)
            out = np.where(on[..., None], W, out)
            ok = np.where(on, okm, ok)
        return out, ok


def _highlights(O, m: WireMirror, c, r, W, tol_m, rounds, turn, compiled=None):
    """(B, k, 3) highlights of the turns ``turn`` (B, k) and (B, k) converged: the alternation
    of :mod:`estimator.geometry.wire` from ``W`` (or each turn's default start, its axis moved
    onto the wire); exactly ``rounds`` rounds when given. ``compiled``: the Numba kernel
    (:mod:`estimator.geometry.wire_kernel`; default where it is enabled) or numpy."""
    axes, rho, L = m.wire_axes_m[turn], m.wire_radius_m, m.led_position_m
    W = np.array(axes - rho * m.radial[turn] if W is None else W, dtype=np.float64)
    if wire_kernel.ENABLED if compiled is None else compiled:
        if not wire_kernel.ENABLED:
            raise ValueError("compiled=True needs Numba (estimator.geometry.wire_kernel.ENABLED)")
        W, step = wire_kernel.highlights(O, c, r, W, axes, m.normal, rho, L, tol_m=tol_m,
                                         max_rounds=SOURCE_MAX_ROUNDS, rounds=rounds)
        return W, (step <= tol_m) if rounds is None else np.isfinite(step)
    step = np.full(W.shape[:2], np.inf)
    for _ in range(SOURCE_MAX_ROUNDS if rounds is None else rounds):
        P, _, _ = reflection_points(O, c, r, W)
        P = np.where(np.isfinite(P), P, 0.5 * (W + O))
        W_new, _, _, _ = cylinder_reflection(axes, m.normal, rho, L, P)
        moved = np.linalg.norm(W_new - W, axis=-1)
        step = np.where(np.isfinite(moved), moved, np.inf)
        W = np.where(np.isfinite(W_new), W_new, W)
        if rounds is None and not (step > tol_m).any():
            break
    return W, (step <= tol_m) if rounds is None else np.isfinite(step)


def wire_glints_jacobian(camera: Camera, lights: WireLights, centers_m, radius_m, start=None, *,
                         d_sources=None, tol_m: float = SOURCE_TOL_M, light_index=None,
                         compiled: bool | None = None):
    """Glints of the virtual sources and their total derivative with respect to the cornea
    centre (module docstring).

    Parameters
    ----------
    camera : Camera
    lights : WireLights
    centers_m : (B, 3) float
    radius_m : float
    start : (B, n, 3) float, optional
        Warm start of the sources.
    d_sources : (B, n, 3, 3) float, optional
        dW/dc to use instead of differencing (a chord: the fits hold the first one, since the
        highlight's share of the Jacobian changes little over their steps).
    tol_m : float
        The sources' tolerance.
    light_index : (B, k) int, optional
        Only these lights (their glints (B, k, 2) come back); default every light.
    compiled : bool, optional
        The Numba kernels of :mod:`estimator.geometry.wire_kernel` (default where Numba is) or
        numpy (False): the same answers to the sources' ``tol_m``.

    Returns
    -------
    glints_px : (B, n, 2) float
    d_center : (B, n, 2, 3) float
        d glint / d cornea centre (px per m), the highlight's motion included.
    sources_m : (B, n, 3) float
        The virtual sources (the next call's warm start).
    converged : (B, n) bool
    d_sources : (B, n, 3, 3) float
        dW/dc (the one given, or the differences).
    """
    c = as_points(centers_m, "centers_m").reshape(-1, 3)
    if light_index is None:
        light_index = np.broadcast_to(np.arange(lights.count), (c.shape[0], lights.count))
    W, ok = lights.sources_of(c, radius_m, light_index, start, tol_m=tol_m, compiled=compiled)
    if wire_kernel.ENABLED if compiled is None else compiled:
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            g, d_c, d_l = wire_kernel.glints_and_rows(camera, c, radius_m, W)
    else:
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            g, _, d_c, _, d_l = glint_jacobians(camera, c, radius_m, W)
    dW = d_sources
    if dW is None:
        dW = np.empty(W.shape + (3,))
        for k in range(3):
            ck = c.copy()
            ck[:, k] += SOURCE_STEP_M
            Wk, _ = lights.sources_of(ck, radius_m, light_index, W, rounds=JACOBIAN_ROUNDS,
                                      compiled=compiled)
            dW[..., k] = (Wk - W) / SOURCE_STEP_M
    return g, d_c + d_l @ dW, W, ok, dW
