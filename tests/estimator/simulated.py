"""Simulated glints for the estimator's tests, built from the estimator alone.

The feature-level simulator (:mod:`scet_render.simulate`) sits a layer above the estimator, so
the estimator's tests do not use it: they run on the base install (numpy, scipy, OpenCV). These
helpers compute the same thing from the same parts, the closed-form glints of
:func:`estimator.geometry.project_glints` on the eye of :mod:`estimator.eye` with Böhme et al.'s
feature position error e_f, drawing the noise in the same order, so a test gets the very
numbers it got from the simulator. ``tests/scet_render/test_simulate.py`` holds the simulator
to these helpers, bit for bit.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from estimator.setup import Setup


@dataclass(frozen=True, slots=True)
class SimulatedGlints:
    """Glints of every light for a batch of gaze targets.

    Attributes
    ----------
    targets_m : (m, 3) float
        Gaze targets, world frame.
    yaw_rad, pitch_rad : (m,) float
        Eye rotation (Fick angles) that points the optical axis at each target.
    cornea_center_m : (m, 3) float
    glints_true_px : (m, n, 2) float
        Noise-free glints (NaN where the reflection is behind the camera).
    glints_px : (m, n, 2) float
        With the feature position error.
    visible : (m, n) bool
        Noise-free glint on the corneal cap, lit, seen and inside the image.
    """

    targets_m: np.ndarray
    yaw_rad: np.ndarray
    pitch_rad: np.ndarray
    cornea_center_m: np.ndarray
    glints_true_px: np.ndarray
    glints_px: np.ndarray
    visible: np.ndarray


def ground_truth_glints(setup: Setup, yaw_rad, pitch_rad, *, lights_world_m=None,
                        cornea_radius_m: float | None = None):
    """Noise-free glints for eye rotations (Fick angles, any batch shape).

    Returns ``(glints_px (..., n, 2), visible (..., n), cornea_center_m (..., 3))``.
    """
    lights = setup.lights_world_m if lights_world_m is None else lights_world_m
    return setup.eye.glints(setup.camera, lights, yaw_rad, pitch_rad,
                            cornea_radius_m=cornea_radius_m)


def simulate_glints(setup: Setup, targets_m, *, noise_px: float = 0.0,
                    noise_model: str = "uniform", rng=None, lights_world_m=None,
                    cornea_radius_m: float | None = None) -> SimulatedGlints:
    """Glints of every light for every target (m, 3), with e_f = ``noise_px``: uniform in
    [-e_f, e_f] per axis, or ``noise_model="gaussian"`` with SD e_f. ``rng`` is a Generator or
    a seed; ``lights_world_m`` and ``cornea_radius_m`` override the setup's (a perturbed rig)."""
    targets = np.asarray(targets_m, dtype=np.float64)
    yaw, pitch = setup.eye.angles_toward(targets)
    glints, visible, center = ground_truth_glints(setup, yaw, pitch, lights_world_m=lights_world_m,
                                                  cornea_radius_m=cornea_radius_m)
    noisy = glints.copy()
    if noise_px > 0:
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        if noise_model == "uniform":
            noisy = glints + gen.uniform(-noise_px, noise_px, size=glints.shape)
        elif noise_model == "gaussian":
            noisy = glints + gen.normal(0.0, noise_px, size=glints.shape)
        else:
            raise ValueError(f"noise_model must be 'uniform' or 'gaussian', got {noise_model!r}")
    return SimulatedGlints(targets, yaw, pitch, center, glints, noisy, visible)


_TARGETS = re.compile(r"^(grid|calib):(\d+)x(\d+)$")


def screen_targets(spec: str, setup: Setup) -> np.ndarray:
    """Targets on the setup's screen, (m, 3): ``grid:COLSxROWS`` gives cell centres (the
    paper's 24 x 15 accuracy grid), ``calib:COLSxROWS`` edge to edge (its 3 x 3 and 5 x 5
    calibration patterns), as the ``scet simulate --targets`` specs do."""
    m = _TARGETS.match(spec)
    if m is None:
        raise ValueError(f"bad target spec {spec!r}: expected grid:COLSxROWS or calib:COLSxROWS")
    cols, rows = int(m.group(2)), int(m.group(3))
    if m.group(1) == "calib":
        return setup.screen.grid(cols, rows, margin=0.0)
    return setup.screen.grid(cols, rows)


def ground_truth_calibration(setup: Setup):
    """The calibration a perfect procedure gives (nominal lighting, the eye's own c_e and r_co),
    with the Eq. (1) mapping ``eq1_25`` fitted to the noise-free cornea centres of the 5 x 5
    calibration pattern: what the tracker tests and bench_tracker track with."""
    from estimator.calibration import Calibration, fit_gaze_mapping
    from estimator.gaze import fit_cornea_centers

    targets = setup.screen.grid(5, 5, margin=0.0)
    yaw, pitch = setup.eye.angles_toward(targets)
    g, vis, _ = ground_truth_glints(setup, yaw, pitch)
    cal = Calibration.ground_truth(setup)
    c = fit_cornea_centers(setup, cal, np.where(vis[..., None], g, np.nan)).center_m
    return cal.with_mappings(eq1_25=fit_gaze_mapping(c, targets, "eq1", degenerate="min_norm"))
