"""Eye motion over time: ``saccades`` (main sequence, fixational noise),
``trajectory`` (:class:`Trajectory`, the pose at any instant), ``sequences`` (fixations,
saccades, pursuit).
"""

from .saccades import (
    BALOH_C_DEG,
    BALOH_V_MAX_DEG_S,
    CARPENTER_INTERCEPT_S,
    CARPENTER_SLOPE_S_PER_DEG,
    FixationalNoise,
    SaccadeModel,
    main_sequence,
)
from .sequences import concatenate, fixation_sequence, grid_sequence, pursuit, saccade_sequence
from .trajectory import NOISE_COMPONENTS, SAME_DIRECTION_RAD, SegmentKind, Trajectory

__all__ = [
    "CARPENTER_SLOPE_S_PER_DEG", "CARPENTER_INTERCEPT_S", "BALOH_V_MAX_DEG_S", "BALOH_C_DEG",
    "main_sequence", "SaccadeModel", "FixationalNoise", "fixation_sequence", "saccade_sequence",
    "grid_sequence", "pursuit", "concatenate", "SAME_DIRECTION_RAD", "NOISE_COMPONENTS",
    "SegmentKind", "Trajectory"
]
