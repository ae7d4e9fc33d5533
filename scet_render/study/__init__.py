"""Studies beyond the validation: event-level measurements on rendered sequences, and the
spherical tracker on aspheric corneas.

:mod:`.events` (pymovements' detectors on gaze samples, scored against the motion model),
:mod:`.events_run` (``scet study events``: render, track, detect) and :mod:`.events_report`;
:mod:`.aspheric` (``scet study aspheric``) and :mod:`.aspheric_report`.
"""

from .events import (DETECTORS, EventScores, Saccades, Series, detect_saccades, score_saccades,
                     true_saccades, uniform_series, velocity)
from .events_report import RATE_60, Condition, summary_row
from .events_run import FULL, QUICK, EventConfig, run_event_study
from .aspheric import (AsphericCondition, aspheric_scene, feature_level_model_error,
                       parse_asphericities, run_aspheric_study)

__all__ = ["DETECTORS", "EventScores", "Saccades", "Series", "detect_saccades", "score_saccades",
           "true_saccades", "uniform_series", "velocity", "FULL", "QUICK", "Condition",
           "EventConfig", "run_event_study", "summary_row", "RATE_60", "AsphericCondition",
           "aspheric_scene", "feature_level_model_error", "parse_asphericities",
           "run_aspheric_study"]
