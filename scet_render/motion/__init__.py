"""Eye motion over time: ``saccades`` (main sequence, fixational noise), ``blinks`` (the
upper lid's closure over time), ``pupil`` (the pupil's size: light reflex and hippus),
``trajectory`` (:class:`Trajectory`, the pose, lid closure and pupil size at any instant),
``sequences`` (fixations, saccades, pursuit).
"""

from .blinks import BLINK_DURATION_RANGE_S, BlinkModel, Blinks, blink_schedule
from .saccades import (
    BALOH_C_DEG,
    BALOH_V_MAX_DEG_S,
    CARPENTER_INTERCEPT_S,
    CARPENTER_SLOPE_S_PER_DEG,
    FixationalNoise,
    SaccadeModel,
    main_sequence,
)
from .pupil import PupilModel, PupilTrace, pupil_diameters, pupil_schedule
from .sequences import concatenate, fixation_sequence, grid_sequence, pursuit, saccade_sequence
from .trajectory import (
    NOISE_COMPONENTS,
    SAME_DIRECTION_RAD,
    SegmentKind,
    Trajectory,
    with_blinks,
    with_pupil,
)

__all__ = [
    "CARPENTER_SLOPE_S_PER_DEG", "CARPENTER_INTERCEPT_S", "BALOH_V_MAX_DEG_S", "BALOH_C_DEG",
    "main_sequence", "SaccadeModel", "FixationalNoise", "fixation_sequence", "saccade_sequence",
    "grid_sequence", "pursuit", "concatenate", "SAME_DIRECTION_RAD", "NOISE_COMPONENTS",
    "SegmentKind", "Trajectory", "BLINK_DURATION_RANGE_S", "BlinkModel", "Blinks",
    "blink_schedule", "with_blinks", "PupilModel", "PupilTrace", "pupil_schedule",
    "pupil_diameters", "with_pupil"
]
