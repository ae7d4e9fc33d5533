"""``scet reproduce``: the paper's Section 3 side by side with ours. ``common``
(configuration, context, calibrations), ``paper`` (Fig. 5-8 experiments), ``bands`` (Fig. 9),
``fits`` (the paper's fits), ``run`` (orchestration), ``report``, ``figures``,
``paper_numbers``.
"""

from .bands import (
    LIGHTINGS,
    METHODS,
    PRIOR_MOTION_SD_DEG,
    SPARSE_STRIDE,
    band_rows,
    band_trial,
    rows_mask,
    summarize_bands,
)
from .common import (
    DA_DEPTHS_M,
    EQ1_9_TRUNCATE_RTOL,
    NOISE_PX,
    RIG_ROTATION_AXIS,
    RIG_ROTATION_DEG,
    RIG_TRANSLATION_M,
    TRANSLATION_HALF_M,
    Calibrations,
    Context,
    ReproductionConfig,
    calibrate_all,
    config_for,
    cornea_centers,
    fit_mapping,
    geometric_calibrations,
    lighting_calibrations,
    make_context,
    stats,
    trial_rng,
)
from .fits import fit_center_radius, fit_orbit_prior, orbit_covariance
from .paper import (
    MAPPINGS,
    TRANSLATION_METHODS,
    TRANSLATION_PLANES,
    calibration_trial,
    gaze_trial,
    solver_check,
    translated,
    translation_trial,
)
from .report import FIG5_KEYS, markdown, write_report
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
