"""``scet validate``: render, calibrate, track and compare with the ground truth and
the feature-level simulator. ``run`` (the run), ``report`` (``validation.md``).
"""

from .config import (
    FULL,
    IDENTITY_RADIUS_PX,
    QUICK,
    SIM_REPEATS,
    ValidationConfig,
    ValidationResult,
    ValidationRow,
)
from .report import prior_table_markdown, table_markdown
from .run import geometric_from, run_validation

__all__ = [
    "IDENTITY_RADIUS_PX", "ValidationConfig", "QUICK", "FULL", "ValidationRow",
    "ValidationResult", "SIM_REPEATS", "table_markdown", "prior_table_markdown",
    "geometric_from", "run_validation"
]
