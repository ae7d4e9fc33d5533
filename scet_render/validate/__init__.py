"""``scet validate``: render, calibrate, track and compare with the ground truth and
the feature-level simulator; ``scet score``: samples against a dataset's labels.

Modules: ``config`` (modes, rows, results), ``run`` (the run), ``report`` (``validation.md``),
``score`` (the metrics per method, band position and reason code).
"""

from .config import (
    FULL,
    IDENTITY_RADIUS_PX,
    QUICK,
    SIM_REPEATS,
    ValidationConfig,
    ValidationResult,
    ValidationRow,
    ValidationRun,
)
from .report import prior_table_markdown, table_markdown
from .run import geometric_from, run_validation, validate_setup
from .score import (
    POSITIONS,
    Score,
    ScoreRow,
    band_position,
    error_statistics,
    reasons_table,
    score_samples,
    score_table,
    true_gaze_points,
    write_score_report,
)

__all__ = [
    "IDENTITY_RADIUS_PX", "ValidationConfig", "QUICK", "FULL", "ValidationRow",
    "ValidationResult", "ValidationRun", "validate_setup", "SIM_REPEATS", "table_markdown",
    "prior_table_markdown",
    "geometric_from", "run_validation", "POSITIONS", "true_gaze_points", "band_position",
    "error_statistics",
    "ScoreRow", "Score", "score_samples", "score_table", "reasons_table", "write_score_report"
]
