"""Eye motion over time: ``saccades`` (main sequence, fixational noise),
``trajectory`` (:class:`Trajectory`, the pose at any instant), ``sequences`` (fixations,
saccades, pursuit).
"""

from .saccades import (
    CARPENTER_SLOPE_S_PER_DEG, CARPENTER_INTERCEPT_S, BALOH_V_MAX_DEG_S, BALOH_C_DEG,
    main_sequence, SaccadeModel, FixationalNoise
)
from .sequences import fixation_sequence, saccade_sequence, grid_sequence, pursuit, concatenate
from .trajectory import SAME_DIRECTION_RAD, NOISE_COMPONENTS, SegmentKind, Trajectory

__all__ = [
    "CARPENTER_SLOPE_S_PER_DEG", "CARPENTER_INTERCEPT_S", "BALOH_V_MAX_DEG_S", "BALOH_C_DEG",
    "main_sequence", "SaccadeModel", "FixationalNoise", "fixation_sequence", "saccade_sequence",
    "grid_sequence", "pursuit", "concatenate", "SAME_DIRECTION_RAD", "NOISE_COMPONENTS",
    "SegmentKind", "Trajectory"
]
