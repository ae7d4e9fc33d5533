"""Glint identities: which light made each glint of a band.

Modules: ``params`` (:class:`MatchParams`, :class:`GlintMatch`), ``model`` (the calibrated
eye, priors, hypotheses), ``matcher`` (:class:`GlintMatcher`), ``follow`` (:class:`BandFollower`: the cheap path from
a recent sample).
"""

from .follow import BandFollower, FollowParams, Followed
from .matcher import GlintMatcher, match_glints
from .model import calibrated_eye
from .params import (
    AMBIGUOUS,
    FIT_FAILED,
    NO_HYPOTHESIS,
    OK,
    TOO_FEW_GLINTS,
    GlintMatch,
    MatchParams,
)
from .search import HypothesisSearch

__all__ = [
    "GlintMatcher", "match_glints", "calibrated_eye", "OK", "TOO_FEW_GLINTS", "NO_HYPOTHESIS",
    "FIT_FAILED", "AMBIGUOUS", "MatchParams", "GlintMatch", "HypothesisSearch", "BandFollower",
    "FollowParams", "Followed"
]
