"""The tracker's names where callers have always imported them: a face of
:mod:`estimator.tracking` (the tracking wing), with the reason codes under their old constant
names (members of :class:`estimator.reasons.Reason`, the one vocabulary; they compare and
write as the same strings).
"""

from .reasons import IDENTITY_FAILURES, PRIOR_PREFIX, Reason
from .tracking import (JUMP_AGE_S, JUMP_SLACK_DEG, MAX_RESIDUAL_PX, METHODS, MIN_GLINTS,
                       SATURATED_FRAME_SHARE, VELOCITY_AGE_S, BandPrior, GazeSample, Tracker,
                       TrackerInputError, failed_sample, inverse_2x2)

__all__ = ["Tracker", "GazeSample", "BandPrior", "TrackerInputError", "failed_sample",
           "inverse_2x2", "METHODS", "MIN_GLINTS", "MAX_RESIDUAL_PX", "JUMP_AGE_S",
           "JUMP_SLACK_DEG", "VELOCITY_AGE_S", "SATURATED_FRAME_SHARE", "IDENTITY_FAILURES",
           "PRIOR_PREFIX", "UNREADABLE_FRAME", "WRONG_FRAME_SIZE", "SATURATED_FRAME",
           "MISSING_FRAME", "INTERNAL_ERROR", "RESIDUAL_TOO_LARGE", "IMPLAUSIBLE_JUMP",
           "OUT_OF_REACH", "FLUX_CUT_GLINTS"]

UNREADABLE_FRAME = Reason.UNREADABLE_FRAME
WRONG_FRAME_SIZE = Reason.WRONG_FRAME_SIZE
SATURATED_FRAME = Reason.SATURATED_FRAME
MISSING_FRAME = Reason.MISSING_FRAME
INTERNAL_ERROR = Reason.INTERNAL_ERROR
RESIDUAL_TOO_LARGE = Reason.RESIDUAL_TOO_LARGE
IMPLAUSIBLE_JUMP = Reason.IMPLAUSIBLE_JUMP
OUT_OF_REACH = Reason.OUT_OF_REACH
FLUX_CUT_GLINTS = Reason.FLUX_CUT_GLINTS
