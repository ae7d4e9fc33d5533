"""The tracking wing: banded frames in, one gaze sample per lit band out.

:class:`Tracker` (:mod:`.tracker`) runs a stream of frames: per frame it detects the glints,
groups them by strobe and takes one band step per lit band (:func:`band_sample`,
:mod:`.bands`). A band step takes the stream's :class:`StreamState` (:mod:`.state`: prior
angles, start, last estimate, velocity; immutable) and the stream's fixed
:class:`BandContext` (:mod:`.context`: setup, calibration, fit problems, matcher, follower,
prior; the one switch between the gaze methods), and returns the :class:`GazeSample` and the
next state. A sparse band borrows the last estimate as a prior (:mod:`.assisted`); identified
glints are fitted by the compiled small fit where it applies (:mod:`.estimates`); with Numba
a cheap band and a prior-assisted band each take one compiled call (:mod:`.kernel`,
:mod:`.prior_kernel`: the same samples bit for bit); glints cut by a lash are flagged by their
flux (:mod:`.cut_glints`). Samples and their CSV:
:mod:`.samples`; reason codes: :class:`estimator.reasons.Reason`.
"""

from ..reasons import IDENTITY_FAILURES, Reason
from .assisted import assisted_sample
from .bands import band_sample, cheap_sample, dense_sample, searched_sample
from .context import MAX_RESIDUAL_PX, METHODS, MIN_GLINTS, BandContext
from .cut_glints import flagged, kept_detections, same_points
from .estimates import assisted_estimate, searched_estimate
from .samples import (SAMPLE_COLUMNS, BandPrior, GazeSample, TrackerInputError,
                      estimated_sample, failed_sample, inverse_2x2, read_samples_csv,
                      samples_csv, write_samples_csv)
from .state import JUMP_AGE_S, JUMP_SLACK_DEG, VELOCITY_AGE_S, LastEstimate, StreamState
from .tracker import SATURATED_FRAME_SHARE, Tracker

__all__ = [
    "Tracker", "SATURATED_FRAME_SHARE",
    "BandContext", "METHODS", "MIN_GLINTS", "MAX_RESIDUAL_PX",
    "StreamState", "LastEstimate", "JUMP_AGE_S", "JUMP_SLACK_DEG", "VELOCITY_AGE_S",
    "band_sample", "dense_sample", "cheap_sample", "searched_sample", "assisted_sample",
    "searched_estimate", "assisted_estimate",
    "flagged", "kept_detections", "same_points",
    "GazeSample", "BandPrior", "estimated_sample", "failed_sample", "inverse_2x2",
    "SAMPLE_COLUMNS", "samples_csv", "write_samples_csv", "read_samples_csv",
    "TrackerInputError", "Reason", "IDENTITY_FAILURES",
]
