"""``scet reproduce``: the paper's Section 3 side by side with ours. ``common``
(configuration, context, calibrations), ``paper`` (Fig. 5-8 experiments), ``bands`` (Fig. 9),
``fits`` (the paper's fits), ``run`` (orchestration), ``report``, ``figures``,
``paper_numbers``.
"""

from .bands import (
    PRIOR_MOTION_SD_DEG, SPARSE_STRIDE, LIGHTINGS, METHODS, band_rows, rows_mask, band_trial,
    summarize_bands
)
from .common import (
    RIG_ROTATION_DEG, RIG_ROTATION_AXIS, RIG_TRANSLATION_M, NOISE_PX, EQ1_9_TRUNCATE_RTOL,
    TRANSLATION_HALF_M, DA_DEPTHS_M, ReproductionConfig, config_for, Context, make_context,
    trial_rng, Calibrations, calibrate_all, geometric_calibrations, lighting_calibrations,
    cornea_centers, fit_mapping, stats
)
from .fits import fit_center_radius, orbit_covariance, fit_orbit_prior
from .paper import (
    calibration_trial, MAPPINGS, gaze_trial, solver_check, translated, TRANSLATION_METHODS,
    TRANSLATION_PLANES, translation_trial
)
from .report import write_report, markdown, FIG5_KEYS
from .run import run_experiments, run_reproduction

__all__ = [
    "PRIOR_MOTION_SD_DEG", "SPARSE_STRIDE", "LIGHTINGS", "METHODS", "band_rows", "rows_mask",
    "band_trial", "summarize_bands", "RIG_ROTATION_DEG", "RIG_ROTATION_AXIS",
    "RIG_TRANSLATION_M", "NOISE_PX", "EQ1_9_TRUNCATE_RTOL", "TRANSLATION_HALF_M", "DA_DEPTHS_M",
    "ReproductionConfig", "config_for", "Context", "make_context", "trial_rng", "Calibrations",
    "calibrate_all", "geometric_calibrations", "lighting_calibrations", "cornea_centers",
    "fit_mapping", "stats", "fit_center_radius", "orbit_covariance", "fit_orbit_prior",
    "calibration_trial", "MAPPINGS", "gaze_trial", "solver_check", "translated",
    "TRANSLATION_METHODS", "TRANSLATION_PLANES", "translation_trial", "write_report",
    "markdown", "FIG5_KEYS", "run_experiments", "run_reproduction"
]
