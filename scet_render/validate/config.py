"""The validation's settings and results: :class:`ValidationConfig` (quick and full
modes), the rows of its table and :class:`ValidationResult`, and the constants that define an
identity and the simulation it is compared with.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator.calibration import Calibration

#: A detection is the glint of the light it was matched to when that light's ground-truth glint
#: is the labelled glint nearest to it and lies within this distance (px at full size, 640 x
#: 480; halved at half size): identity, not centroid accuracy. The closest neighbouring glints
#: of paper_sim are 5.7 px apart; rendered centroids sit within ~0.3 px of their glint on a
#: conductor cornea or the default dielectric; Mitsuba's own dielectric (plain_dielectric) at
#: 16 spp renders each glint as a few clipped Monte Carlo pixels (a 2.5 % reflection sampled
#: per camera ray; :mod:`scet_render.render.sensor`) whose centroid is up to ~2 px off (median
#: 0.9 px, measured on the full validation before the default cornea sampled its glints).
IDENTITY_RADIUS_PX = 3.0


@dataclass(frozen=True, slots=True)
class ValidationConfig:
    scale: int
    spp: int
    cornea: str
    frames: int
    calib_grid: tuple = (5, 5)
    #: Strobe settings (pulses per frame); ``frames`` test frames are rendered for each.
    pulses_per_frame: tuple = (16,)


QUICK = ValidationConfig(scale=2, spp=4, cornea="conductor", frames=30, pulses_per_frame=(8, 16))
FULL = ValidationConfig(scale=1, spp=16, cornea="dielectric", frames=90,
                        pulses_per_frame=(4, 8, 16))


@dataclass(frozen=True, slots=True)
class ValidationRow:
    """One line of the table: a source ("rendered" or "simulated"), a band count (strobe
    pulses per frame) and a gaze method."""

    source: str
    pulses_per_frame: int
    method: str
    n: int
    valid: float
    mean_deg: float
    sd_deg: float
    median_deg: float
    p95_deg: float
    robustness: float
    identity_rate: float

    def as_dict(self) -> dict:
        return {name: getattr(self, name) for name in self.__slots__}


@dataclass(frozen=True, slots=True)
class ValidationResult:
    """Everything :func:`run_validation` measured.

    Attributes
    ----------
    rows : list of ValidationRow
    feature_noise_px : float
        RMS per-axis error of the rendered detections against the labels (px), over all
        strobe settings.
    feature_noise_by_ppf : dict
        pulses per frame -> that setting's RMS per-axis error (px): the e_f of its matching
        feature-level simulation (Gaussian).
    identity_rate : float
        Share of identified detections whose light is right (that light's ground-truth glint
        is the nearest to the detection, within :data:`IDENTITY_RADIUS_PX` at full size).
    n_identified : int
    calibration : Calibration
    errors_deg : dict
        (source, pulses_per_frame, method) -> (m,) per-sample errors (NaN = failed).
    reasons : dict
        (pulses_per_frame, method) -> {reason: count}.
    assisted : dict
        (pulses_per_frame, method) -> (m,) bool: prior-assisted samples
        (:attr:`estimator.tracker.GazeSample.prior_assisted`).
    assisted_identities : (int, int)
        Right and all identified glints of the prior-assisted samples (included in
        ``identity_rate``).
    timings_s : dict
        Wall time of each stage.
    report : Path
    """

    rows: list
    feature_noise_px: float
    identity_rate: float
    n_identified: int
    calibration: Calibration
    errors_deg: dict
    reasons: dict
    timings_s: dict
    report: Path
    config: ValidationConfig = field(default=QUICK)
    feature_noise_by_ppf: dict = field(default_factory=dict)
    assisted: dict = field(default_factory=dict)
    assisted_identities: tuple = (0, 0)

    def own_errors(self, method: str, pulses_per_frame: int) -> np.ndarray:
        """Rendered errors of the samples estimated from their own glints alone (the others
        NaN): what the feature-level simulation reproduces."""
        err = self.errors_deg[("rendered", pulses_per_frame, method)]
        return np.where(self.assisted[(pulses_per_frame, method)], np.nan, err)

    def row(self, source: str, method: str, pulses_per_frame: int | None = None) -> ValidationRow:
        """The row of ``source`` and ``method`` at ``pulses_per_frame`` (may be left out when
        only one strobe setting was run)."""
        found = [r for r in self.rows if r.source == source and r.method == method
                 and (pulses_per_frame is None or r.pulses_per_frame == pulses_per_frame)]
        if len(found) != 1:
            raise KeyError(f"{len(found)} rows for {(source, method, pulses_per_frame)}")
        return found[0]

    def errors(self, source: str, method: str, pulses_per_frame: int | None = None) -> np.ndarray:
        """Per-sample errors of ``source`` and ``method``: of one strobe setting, or of all
        of them concatenated."""
        return np.concatenate([e for (s, p, m), e in sorted(self.errors_deg.items())
                               if s == source and m == method
                               and (pulses_per_frame is None or p == pulses_per_frame)])


@dataclass(frozen=True, slots=True)
class ValidationRun:
    """What :func:`scet_render.validate.validate_setup` measured on one setup, before any
    report: the inputs of ``validation.md`` and of the studies built on it.

    Attributes
    ----------
    settings : dict
        pulses per frame -> (setup of that strobe setting, test dataset folder).
    rows, errors_deg, reasons, assisted, assisted_identities, feature_noise_by_ppf,
    feature_noise_px, calibration, timings_s
        As :class:`ValidationResult`'s (``errors`` keyed (source, ppf, method); the simulated
        errors are ``SIM_REPEATS`` realisations of the samples, realisation-major).
    tracked : dict
        (pulses_per_frame, method) -> list of :class:`estimator.tracker.GazeSample`.
    labels : dict
        pulses per frame -> {(frame, strobe): label} of its test dataset.
    correct, total : int
        Right and all identified glints.
    mapping : str
        The polynomial mapping used (``eq1_<m>``).
    """

    settings: dict
    rows: list
    errors: dict
    reasons: dict
    tracked: dict
    assisted: dict
    assisted_ids: tuple
    labels: dict
    noise_by_ppf: dict
    noise_px: float
    correct: int
    total: int
    calibration: Calibration
    mapping: str
    timings: dict


#: Noise realisations of the feature-level simulation per sample: one realisation of ~20
#: samples (the fast test) leaves the median of polynomial gaze, whose cornea-centre fit
#: amplifies feature noise, uncertain to ~0.3 deg; ten bring it to ~0.1 deg.
SIM_REPEATS = 10
