"""The wire option's compiled highlight alternation (:mod:`estimator.geometry.wire_kernel`)
against the numpy alternation it replaces: the same virtual sources over the paper's grid, the
same fixed-round differences the Jacobian takes, and the same verdicts."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from estimator.geometry import wire_kernel
from estimator.geometry.wire_fast import JACOBIAN_ROUNDS, SOURCE_TOL_M, WireLights
from estimator.scene import load_scene

pytestmark = pytest.mark.skipif(not wire_kernel.ENABLED,
                                reason="Numba not installed or NUMBA_DISABLE_JIT set: nothing compiled to compare")


@dataclass(frozen=True)
class KernelTol:
    #: Converged sources, kernel against numpy, as a share of the stopping tolerance: each pair
    #: of the kernel stops at its own first move below tol, numpy when every pair's has; the
    #: contraction (gain ~1/6 a round) leaves < tol / 5 after such a move, so the two differ by
    #: less than tol (measured 0.13 tol at 1e-11 m and 1e-13 m).
    converged_share: float = 1.0
    #: Fixed rounds (the Jacobian's differences), kernel against numpy (m): the same arithmetic
    #: in another order; measured 1.1e-17 m, ~1e-15 of the ~10 mm coordinates.
    rounds_m: float = 1e-15


TOL = KernelTol()


@pytest.fixture(scope="module")
def grid():
    setup = load_scene("prototype_ov5647_wire")
    lights = WireLights.from_setup(setup)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(8, 5))
    c = setup.eye.cornea_center(yaw, pitch)
    idx = np.broadcast_to(np.arange(lights.count), (len(c), lights.count))
    return lights, c, setup.eye.cornea_radius_m, idx


@pytest.mark.parametrize("tol_m", [SOURCE_TOL_M, 1e-11])
def test_kernel_sources_match_numpy(grid, tol_m):
    lights, c, r, idx = grid
    W_np, ok_np = lights.sources_of(c, r, idx, tol_m=tol_m, compiled=False)
    W_k, ok_k = lights.sources_of(c, r, idx, tol_m=tol_m, compiled=True)
    assert ok_np.all() and (ok_k == ok_np).all()
    assert np.abs(W_k - W_np).max() <= TOL.converged_share * tol_m


def test_kernel_fixed_rounds_match_numpy(grid):
    """The forward differences of dW/dc run exactly JACOBIAN_ROUNDS rounds from the converged
    sources: the kernel must run the same rounds, not stop early."""
    lights, c, r, idx = grid
    W, _ = lights.sources_of(c, r, idx, compiled=False)
    moved = c + np.array([1e-6, 0.0, 0.0])
    W_np, ok_np = lights.sources_of(moved, r, idx, W, rounds=JACOBIAN_ROUNDS, compiled=False)
    W_k, ok_k = lights.sources_of(moved, r, idx, W, rounds=JACOBIAN_ROUNDS, compiled=True)
    assert (ok_k == ok_np).all()
    assert np.abs(W_k - W_np).max() <= TOL.rounds_m
    # and the rounds did move the sources (a kernel that returned its start would fail here)
    assert np.linalg.norm(W_k - W, axis=-1).min() > 1e-9


def test_kernel_takes_a_subset_of_turns(grid):
    """A band's few glints (light_index (B, k)) give the same sources as the full solve's."""
    lights, c, r, idx = grid
    W_all, _ = lights.sources_of(c, r, idx, compiled=True)
    pick = np.array([[3, 17, 30, 34]] * len(c))
    W_few, ok = lights.sources_of(c, r, pick, compiled=True)
    assert ok.all()
    assert np.abs(W_few - np.take_along_axis(W_all, pick[..., None], axis=1)).max() <= SOURCE_TOL_M


def test_kernel_glints_and_jacobian_match_numpy(grid):
    """The fit's evaluation (virtual sources, their glints, the total Jacobian with the
    highlight's motion) through the kernels and through numpy."""
    from estimator.geometry import glint_jacobians
    from estimator.geometry.wire_fast import wire_glints_jacobian

    lights, c, r, idx = grid
    camera = load_scene("prototype_ov5647_wire").camera
    g_np, J_np, W_np, ok_np, dW_np = wire_glints_jacobian(camera, lights, c, r, compiled=False)
    g_k, J_k, W_k, ok_k, dW_k = wire_glints_jacobian(camera, lights, c, r, compiled=True)
    assert (ok_k == ok_np).all() and np.abs(W_k - W_np).max() <= SOURCE_TOL_M
    # Sources within 1e-13 m: through the cornea's ~0.13x at 643 px / 30 mm ~1e-9 px; the
    # forward differences of dW/dc (step 1e-6 m) carry that 1e-13 m as 1e-7 of their value.
    assert np.abs(g_k - g_np).max() < 1e-8
    assert np.abs(J_k - J_np).max() <= 1e-6 * np.abs(J_np).max()
    # On the same sources the compiled glints and rows are the closed form's, to rounding.
    g, _, d_c, _, d_l = glint_jacobians(camera, c, r, W_np)
    g2, d_c2, d_l2 = wire_kernel.glints_and_rows(camera, c, r, W_np)
    assert np.abs(g2 - g).max() < 1e-9
    assert np.abs(d_c2 - d_c).max() <= 1e-12 * np.abs(d_c).max()
    assert np.abs(d_l2 - d_l).max() <= 1e-12 * np.abs(d_l).max()
