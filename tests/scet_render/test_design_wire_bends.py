"""The wire's bends round the strip's edges (scet_render.render.wire_mirror.wire_bend_mesh):
geometry only, drawn on request. The wire lies on the strip everywhere, meets the inner
stretch's analytic cylinder end to end, and the default scene does not draw it."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.geometry.wire import setup_wire_mirrors
from estimator.scene import load_scene
from scet_render.render.wire_mirror import (TUBE_SEGMENTS, wire_bend_mesh, wire_mirror_objects,
                                            wire_turn_path_m)

#: Positions from the same formulas by two routes (m).
EXACT_M = 1e-12
#: The tube's chords sag d/2 (1 - cos(pi / TUBE_SEGMENTS)) inside the wire's surface (m).
SAG_M = 0.4e-3 * (1 - np.cos(np.pi / TUBE_SEGMENTS)) + 1e-12


@pytest.fixture(scope="module")
def mirror():
    ((_, _, m),) = setup_wire_mirrors(load_scene("prototype_ov5647_wire"))
    return m


def _cross_section(mirror, pts):
    """(radius from the arc's axis, position along the normal) of points (..., 3)."""
    rel = pts - mirror.center_m
    return np.hypot(rel @ mirror.u, rel @ mirror.v), rel @ mirror.normal


def test_path_meets_the_inner_stretch(mirror):
    hw = 0.5 * mirror.width_m
    for k in (0, mirror.turns // 2, mirror.turns - 1):
        path = wire_turn_path_m(mirror, k)
        axis = mirror.wire_axes_m[k]
        np.testing.assert_allclose(path[0], axis + hw * mirror.normal, atol=EXACT_M)
        np.testing.assert_allclose(path[-1], axis - hw * mirror.normal, atol=EXACT_M)


def test_wire_lies_on_the_strip_all_round(mirror):
    """Every centreline point is one wire radius from the strip's rectangular cross-section
    (R..R+t by -w/2..w/2), in the turn's own plane."""
    path = wire_turn_path_m(mirror, 7)
    r, z = _cross_section(mirror, path)
    lo, hi = mirror.radius_m, mirror.radius_m + mirror.thickness_m
    hw = 0.5 * mirror.width_m
    dr = np.maximum(np.maximum(lo - r, r - hi), 0.0)
    dz = np.maximum(np.abs(z) - hw, 0.0)
    np.testing.assert_allclose(np.hypot(dr, dz), mirror.wire_radius_m, atol=EXACT_M)
    # In the plane of the turn's radial direction and the normal.
    rel = path - mirror.center_m
    side = np.cross(mirror.normal, mirror.radial[7])
    np.testing.assert_allclose(rel @ side, 0.0, atol=EXACT_M)


def test_tube_surrounds_the_path(mirror):
    m = wire_bend_mesh(mirror)
    assert m.vertices.shape[0] == mirror.turns * wire_turn_path_m(mirror, 0).shape[0] * TUBE_SEGMENTS
    # Each vertex is one wire radius from its ring's centre (the path point it was built on).
    path = np.concatenate([wire_turn_path_m(mirror, k) for k in range(mirror.turns)])
    d = np.linalg.norm(m.vertices.reshape(-1, TUBE_SEGMENTS, 3) - path[:, None, :], axis=-1)
    np.testing.assert_allclose(d, mirror.wire_radius_m, atol=EXACT_M)
    # No vertex inside the strip (the tube touches it along the corners at most).
    r, z = _cross_section(mirror, m.vertices)
    inside = ((r > mirror.radius_m + SAG_M) & (r < mirror.radius_m + mirror.thickness_m - SAG_M)
              & (np.abs(z) < 0.5 * mirror.width_m - SAG_M))
    assert not inside.any()


def test_bends_drawn_only_when_asked(mirror):
    plain, meshes = wire_mirror_objects(mirror, "w", radiance=1.0, split=False)
    assert "w_bends" not in plain and "w_bends" not in meshes
    objs, meshes = wire_mirror_objects(mirror, "w", radiance=1.0, split=False, bends=True)
    assert objs["w_bends"]["bsdf"] == objs["w_turn_000"]["bsdf"]
    assert meshes["w_bends"].faces.shape[0] > 0
