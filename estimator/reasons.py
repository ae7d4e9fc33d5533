"""Why a gaze sample is NaN: the one vocabulary of reason codes (:class:`Reason`).

Each code is a :class:`enum.StrEnum` whose value is the string the samples CSV has always
carried in its ``reason`` column (``estimator.tracking.samples_csv``), so a member compares,
hashes, formats and writes as that string and files stay byte for byte the same.

A few reasons are composed from others:

- a matcher's failure, seen by the tracker: :func:`match_failure` (``match_<reason>``);
- a sparse band whose prior-assisted estimate failed too: :func:`prior_failure`
  (``prior_<reason>``, e.g. ``prior_ambiguous``, ``prior_residual_too_large``);
- a band done again without the glints a lash cuts that failed: :func:`flux_cut_failure`
  (``flux_cut_glints_<reason>``);
- a frame whose processing raised (a bug, logged with its traceback): :func:`internal_error`
  (``internal_error:<exception type>``).
"""

from __future__ import annotations

from enum import StrEnum

__all__ = ["Reason", "IDENTITY_FAILURES", "PRIOR_PREFIX", "FLUX_CUT_PREFIX", "match_failure",
           "prior_failure", "flux_cut_failure", "internal_error"]


class Reason(StrEnum):
    """Reason codes of fits, matches and gaze samples (values: the CSV strings)."""

    #: An accepted estimate.
    OK = "ok"
    # A cornea fit's (estimator.cornea) and the matcher's (estimator.matching).
    TOO_FEW_GLINTS = "too_few_glints"
    NOT_CONVERGED = "not_converged"
    NON_FINITE = "non_finite"
    NO_HYPOTHESIS = "no_hypothesis"
    FIT_FAILED = "fit_failed"
    AMBIGUOUS = "ambiguous"
    #: The optical axis does not reach the screen plane (estimator.gaze).
    MISSES_SCREEN = "misses_screen"
    # The matcher's failures as the tracker names them (match_failure).
    MATCH_TOO_FEW_GLINTS = "match_too_few_glints"
    MATCH_AMBIGUOUS = "match_ambiguous"
    MATCH_NO_HYPOTHESIS = "match_no_hypothesis"
    MATCH_FIT_FAILED = "match_fit_failed"
    # A frame the tracker cannot read: every band of it is NaN.
    UNREADABLE_FRAME = "unreadable_frame"
    WRONG_FRAME_SIZE = "wrong_frame_size"
    SATURATED_FRAME = "saturated_frame"
    MISSING_FRAME = "missing_frame"
    #: A frame whose index is not after the last one the tracker took (it came late, out of
    #: order, or twice): its bands are NaN and the stream goes on from the newer frame.
    FRAME_OUT_OF_ORDER = "frame_out_of_order"
    #: Prefix of :func:`internal_error`.
    INTERNAL_ERROR = "internal_error"
    #: A fit on identified glints whose RMS residual is above the tracker's limit.
    RESIDUAL_TOO_LARGE = "residual_too_large"
    #: A band's own identification puts the eye further from the previous sample than it can
    #: turn in the time between them (``estimator.tracking.JUMP_AGE_S``, ``JUMP_SLACK_DEG``).
    IMPLAUSIBLE_JUMP = "implausible_jump"
    #: No eye rotation within that turn of a sample under ``JUMP_AGE_S`` old can have
    #: ``MIN_GLINTS`` of the band's detections matched (its glints fall elsewhere: the top rows
    #: of a frame while the eye looks down, a band of lid clutter): the band is not searched (a
    #: search could match it only at a rotation IMPLAUSIBLE_JUMP rejects) and is left to the
    #: prior.
    OUT_OF_REACH = "band_out_of_reach"
    #: Prefix of :func:`flux_cut_failure`.
    FLUX_CUT_GLINTS = "flux_cut_glints"


PRIOR_PREFIX = "prior_"
FLUX_CUT_PREFIX = f"{Reason.FLUX_CUT_GLINTS}_"

#: Failures of a band's own identification, after which the band may still be identified with
#: the prior (not a fit that failed on identified glints: those glints were the trouble).
IDENTITY_FAILURES = frozenset({Reason.OUT_OF_REACH, Reason.MATCH_TOO_FEW_GLINTS,
                               Reason.MATCH_AMBIGUOUS, Reason.MATCH_NO_HYPOTHESIS,
                               Reason.MATCH_FIT_FAILED, Reason.TOO_FEW_GLINTS})


def match_failure(reason: str) -> str:
    """The tracker's reason (``match_<reason>``) for a matcher's failure ``reason``."""
    return f"match_{reason}"


def prior_failure(reason: str) -> str:
    """``prior_<reason>``: a prior was there, it did not rescue the band."""
    return PRIOR_PREFIX + reason


def flux_cut_failure(reason: str) -> str:
    """``flux_cut_glints_<reason>``: the band failed once done without its cut glints."""
    return FLUX_CUT_PREFIX + reason


def internal_error(exc: BaseException) -> str:
    """``internal_error:<exception type>``: the frame's processing raised."""
    return f"{Reason.INTERNAL_ERROR}:{type(exc).__name__}"
