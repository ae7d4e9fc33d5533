"""Fixtures shared by the cornea-fit tests: the paper_sim scene and its fit problem."""

import pytest

from estimator.cornea import FitProblem
from estimator.scene import load_scene


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def problem(setup):
    return FitProblem(setup.camera, setup.lights_world_m, setup.eye.cornea_radius_m,
                      setup.eye.rotation_center_m, setup.eye.cornea_offset_m)
