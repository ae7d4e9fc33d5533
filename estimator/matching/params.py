"""The matcher's value types: :class:`MatchParams` (every default with the
measurement that chose it) and :class:`GlintMatch` (one band's identities).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..reasons import Reason

#: Reason codes of a :class:`GlintMatch` (:class:`estimator.reasons.Reason`).
OK, TOO_FEW_GLINTS, NO_HYPOTHESIS, FIT_FAILED, AMBIGUOUS = (
    Reason.OK, Reason.TOO_FEW_GLINTS, Reason.NO_HYPOTHESIS, Reason.FIT_FAILED, Reason.AMBIGUOUS)




@dataclass(frozen=True, slots=True)
class MatchParams:
    """Settings of :class:`GlintMatcher`, each with the reason for its default.

    Attributes
    ----------
    gate_px : float
        Largest detection-prediction distance of a match once the fit has locked on. Detected
        glints carry 0.3-0.5 px of noise per axis: a 2D residual beyond 2.5 px has probability
        exp(-2.5² / (2 0.5²)) = 4e-6 for a true glint, while the closest glints of one arc are
        5.7 px apart (``paper_sim``).
    coarse_gate_px : float
        Gate of the first assignment from a grid pose: the grid node nearest the truth is up to
        half a step off in each angle (0.5° x 3 px/° x sqrt 2 = 2.1 px at 1°), plus the noise.
    prior_gate_px : float
        Gate of the first assignment from a prior: the eye turns up to ~0.7° in the 1 ms
        between two bands in a saccade (700°/s), ~2 px of glint motion, plus the noise.
    noise_px : float
        σ of the likelihood score (px): the upper end of the detector's error.
    missing_cost : float
        Score of a glint predicted well inside the band but not detected: -2 log(0.1), a
        dropout rate of 5-10 %. Much less than an unmatched detection, enough that a pose
        predicting a dense pattern over an empty band loses to one predicting nothing.
    band_margin_px : float
        Predicted glints up to this far outside the band's rows are still candidates (their
        detection may sit inside), and only those this far inside count as missing.
    model : {"orbit", "center"}
        Cornea fit: 2 unknowns on the orbit (robust, needs the eye calibration) or the free
        centre (3 unknowns).
    max_iter : int
        Match-refit rounds per hypothesis; the assignment is stable after 2-3.
    hypotheses : int
        Local minima of the coarse score refined on a cold start.
    shift_sources : int
        Leading hypotheses whose identities are also tried shifted by ±1 and ±2 lights
        along their arcs. One suffices: the leader is the one a shifted chain competes with
        (measured: 2 changed nothing on 300 bands).
    prior_hypotheses, prior_window_deg : int, float
        With a prior, the local minima of the coarse score within ±window of it refined
        beside the prior itself (the chain shifted by one light is ~2-3° away).
    grid_step_deg, grid_yaw_deg, grid_pitch_deg : float
        Coarse grid of eye rotations: step, and half-ranges in yaw and pitch. The paper's
        screen (48 x 30 cm at 70 cm) spans ±19° yaw and -16°..+8° pitch; ±35° covers it with
        room for a larger screen or a poor prior.
    unmatched_cost : float
        Score of a detection left unmatched. 2 log(A / (2π σ²)) = 18, the log-odds of clutter
        uniform over a band's ~50 x 300 px against a glint at the noise σ, rounded up to
        (gate / σ)² = 25: a detection is always better matched inside the gate than not.
    prior_sigma_deg : float
        With a prior, each hypothesis also scores its distance from the prior over this, per
        angle: a saccade turns the eye by up to ~0.5° in the 1 ms between bands, and the chain
        shifted by one light lies 1.5-3° away.
    min_margin : float
        A best hypothesis that beats a rival with other identities by less than this is
        "ambiguous" and no identity is returned: exp(-ΔS / 2) is their likelihood ratio, and 6
        asks for 20:1. Measured on 150 cold bands: 4 claimed 0.5 % wrong identities
        (paper_sim), 6 claimed 0-0.1 %, at the price of refusing 4-6 % of the detections.
    min_matches, min_matches_prior : int
        Fewer matched glints than this after the refit is "too_few_glints" (no identities
        are returned): one glint fits an orbit pose through it exactly, whatever its light,
        and two rarely pin the identity on a cold start; with a prior, two do (the prior
        already places each glint within the prior gate).
    """

    gate_px: float = 2.5
    coarse_gate_px: float = 4.0
    prior_gate_px: float = 5.0
    noise_px: float = 0.5
    missing_cost: float = 4.0
    unmatched_cost: float = 25.0
    prior_sigma_deg: float = 0.5
    min_margin: float = 6.0
    band_margin_px: float = 2.0
    model: str = "orbit"
    max_iter: int = 8
    hypotheses: int = 6
    prior_hypotheses: int = 3
    shift_sources: int = 1
    prior_window_deg: float = 3.0
    grid_step_deg: float = 1.0
    grid_yaw_deg: float = 35.0
    grid_pitch_deg: float = 35.0
    min_matches: int = 3
    min_matches_prior: int = 2

    def __post_init__(self):
        if self.model not in ("orbit", "center"):
            raise ValueError(f"model must be 'orbit' or 'center', got {self.model!r}")
        for name in ("gate_px", "coarse_gate_px", "prior_gate_px", "noise_px", "grid_step_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if min(self.max_iter, self.hypotheses, self.min_matches, self.min_matches_prior) < 1:
            raise ValueError("max_iter, hypotheses and min_matches(_prior) must be >= 1")


@dataclass(frozen=True, slots=True)
class GlintMatch:
    """Identities of the k detections of one band.

    Attributes
    ----------
    light_index : (k,) int64
        Light that made each detection; -1 where unmatched (spurious or unexplained).
    confidence : (k,) float
        In [0, 1]; 0 where unmatched (see the module docstring).
    residual_px : (k,) float
        Distance to the light's predicted glint after the refit; NaN where unmatched.
    cornea_center_m : (3,) float
        Refit cornea centre; NaN when the match failed.
    angles_rad : (2,) float
        Fick (yaw, pitch) of the cornea centre about the eye centre.
    rms_px : float
        RMS residual of the matched glints.
    score : float
        Negative log-likelihood S of the chosen hypothesis.
    hypothesis_margin : float
        S of the runner-up hypothesis minus S of the chosen one (inf with a single hypothesis).
    iterations : int
        Match-refit rounds of the chosen hypothesis.
    reason : str
        ``"ok"``, or why no identity is returned: ``"too_few_glints"``, ``"ambiguous"`` (a
        rival hypothesis within ``min_margin``), ``"no_hypothesis"`` or ``"fit_failed"``.
    """

    light_index: np.ndarray
    confidence: np.ndarray
    residual_px: np.ndarray
    cornea_center_m: np.ndarray
    angles_rad: np.ndarray
    rms_px: float
    score: float
    hypothesis_margin: float
    iterations: int
    reason: str

    @property
    def ok(self) -> bool:
        return self.reason == OK

    @property
    def matched(self) -> np.ndarray:
        """(k,) bool: detections given a light."""
        return self.light_index >= 0
