"""The lighting designer: its objective on a hand-countable case, the region, the scene it
writes, bad budgets and regions, and determinism for a seed."""

from pathlib import Path

import numpy as np
import pytest

from estimator.scene import load_scene, parse_scene
from scet_render.cli import main
from scet_render.design import (Arc, BandModel, Budget, DesignPoses, Region, SearchSettings,
                                admissible, band_counts, counted_share, design_lights,
                                layout_glints)
from scet_render.design.objective import MIN_SEPARATION_PX


@pytest.fixture(scope="module")
def paper():
    return load_scene("paper_sim")


def _model():
    # Two bands: rows 0-9 and 10-19; band 0 is a sliver (10 % visible), band 1 a design band.
    row_band = np.array([0] * 10 + [1] * 10)
    return BandModel(np.array([0, 10]), np.array([9, 19]), np.array([0, 1]),
                     np.array([0.1, 1.0]), row_band)


def test_band_counts_by_hand():
    model = _model()
    # Pose 0: 2 glints in band 0, 5 in band 1, one unusable, one outside the frame.
    g = np.array([[[1, 2.0], [5, 8.4], [1, 10.0], [3, 12], [5, 14], [7, 16], [9, 19.4],
                   [2, 15], [4, -3]]], dtype=float)
    usable = np.array([[True] * 7 + [False, True]])
    counts = band_counts(model, g, usable)
    assert counts.tolist() == [[2, 5]]
    # Only band 1 is a design band: it holds 5, so the share is 1 at need 5 and 0 at need 6.
    assert counted_share(model, counts, 5) == 1.0
    assert counted_share(model, counts, 6) == 0.0


def test_blended_glints_do_not_count(paper):
    # Two lights 0.01 mm apart make glints far closer than MIN_SEPARATION_PX: neither counts.
    pair = np.array([[0.0, 0.02, -0.025], [0.00001, 0.02, -0.025], [0.015, 0.0, -0.03]])
    poses = DesignPoses(np.zeros(1), np.zeros(1), ("primary",))
    g, usable = layout_glints(paper, pair, poses)
    assert np.linalg.norm(g[0, 0] - g[0, 1]) < MIN_SEPARATION_PX
    assert not usable[0, 0] and not usable[0, 1]


def test_region(paper):
    region = Region()
    assert admissible(paper, region, paper.lights_world_m).all()  # the paper's arc is legal
    in_view = np.array([0.0, 0.0, -0.040])  # straight ahead: hides the screen's centre
    too_close = np.array([0.0, 0.012, -0.012])  # 17 mm from the rotation centre
    behind = np.array([0.03, 0.0, 0.01])  # behind the face plane
    assert not admissible(paper, region, np.stack([in_view, too_close, behind])).any()


def test_arc_scene_table_round_trip(paper):
    arc = Arc(azimuth_deg=20.0, elevation_deg=10.0, beta_deg=40.0, phi0_deg=30.0,
              span_deg=120.0, rho_m=0.03, count=9)
    ring = Arc(azimuth_deg=0.0, elevation_deg=0.0, beta_deg=50.0, phi0_deg=0.0, span_deg=360.0,
               rho_m=0.03, count=12)
    text = _scene_text_without_lights(paper) + arc.scene_table(paper.eye.rotation_center_m, "a", 0.4) \
        + ring.scene_table(paper.eye.rotation_center_m, "r", 0.4)
    loaded = parse_scene(text, "<test>")
    c = paper.eye.rotation_center_m
    np.testing.assert_allclose(loaded.lights_world_m,
                               np.concatenate([arc.positions(c), ring.positions(c)]), atol=1e-9)
    # A closed ring does not double its first light.
    p = ring.positions(c)
    assert np.linalg.norm(p[0] - p[-1]) > 0.5 * ring.spacing_m


def _scene_text_without_lights(setup):
    from scet_render.design.report import scene_without_lights

    return scene_without_lights(Path(setup.source).read_text())


@pytest.mark.parametrize("kwargs, word", [({"lights": 3}, "lights"),
                                          ({"lights": 10, "arcs": 3, "free": 0}, "arcs"),
                                          ({"free": 80}, "free"),
                                          ({"style": "wire", "free": 4}, "free")])
def test_bad_budgets_name_the_parameter(kwargs, word):
    with pytest.raises(ValueError, match=word):
        Budget(**kwargs)


TINY = SearchSettings(seed=3, maxiter=2, popsize=2, grid=(4, 3), motion=4, search_step=1,
                      candidates=150, evaluate=False)


def test_region_that_sees_no_cornea(paper):
    # Lights 45-50 mm from the eye and 46 mm or more in front of it lie within 23 deg of the
    # optical axis: all in the eye's view of the screen, so no position is left.
    region = Region(min_eye_distance_m=0.045, max_eye_distance_m=0.050, max_z_m=-0.046)
    with pytest.raises(ValueError, match="region"):
        design_lights(paper, Budget(lights=20, arcs=1, free=4), region, TINY)


def test_cli_bad_input_exits_2(capsys):
    assert main(["design-lights", "paper_sim", "--lights", "3"]) == 2
    err = capsys.readouterr().err
    assert "lights" in err and err.count("\n") == 1


def test_search_is_deterministic(paper):
    budget = Budget(lights=24, arcs=2, free=4)
    a = design_lights(paper, budget, Region(), TINY)
    b = design_lights(paper, budget, Region(), TINY)
    np.testing.assert_array_equal(a.setup.lights_world_m, b.setup.lights_world_m)
    assert a.counted_after == b.counted_after
    assert admissible(paper, Region(), a.setup.lights_world_m).all()
    assert a.lights <= budget.lights
