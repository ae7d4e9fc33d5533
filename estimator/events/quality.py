"""The band samples the event detector leaves out: the tracker's poor fits.

The tracker writes, beside each band's gaze, how it got it (the samples CSV's ``n_glints``,
``prior`` and ``residual_px`` columns, :mod:`estimator.tracking`). On the events study's rendered
sub-sequence (issue 34; ``reports/events.md``: 570 frames, the designed lighting, 16 pulses,
7,635 valid bands) the errors are not alike across them:

- bands identified with the help of the prior from **one or two glints** have an RMS gaze error
  of 41-49 mdeg against 11-22 mdeg for the rest, and 8.6 % / 16 % of them are further than
  5 noise SDs from the truth against 0.4-2.9 % of the bands identified alone: their pose rests
  on the prior's guess of which light made the glint, and a wrong guess still fits;
- bands whose fit **residual** is far above the stream's own: a misidentified light or a glint
  merged with clutter leaves one; of the bands with the top 1 % of residuals, 36 % (identified
  alone) and 74 % (prior-assisted) are further than 5 SDs from the truth, against 2.2 % of all.

A one-band error of a tenth of a degree is, to the detector, a speed spike of ~100 deg/s; a few
close together make a false microsaccade, and one beside a saccade moves its onset or offset.
With the renders' own errors drawn into the study's goal setting (1,000 saccades) such bands
made 2.37 false events a minute against the goal of 1. But most such bands are right (84 % of
the flagged rendered bands are within 5 SDs), and leaving all of them out thins the samples
around onsets. So the gate leaves out a band only when both hold (:func:`left_out`):

1. :func:`poor_fits` flags it by how the tracker got it (the two kinds above), and
2. its gaze disagrees with its neighbours': further than ``neighbour_outlier_sd`` robust SDs
   from a local quadratic through the valid samples within ``neighbour_window_s`` on each side,
   itself left out (:func:`estimator.events.velocity.leave_one_out_residual`), or no such
   fit can be made.

The callers set the gaze of what is left out to NaN before detection, as a band the tracker
could not estimate; the samples themselves are not changed (the CSV keeps every estimate).
On the goal setting with the renders' errors the two conditions together gave 1.00 / 0.99 ms
onset / offset mean abs error and no false event on five trajectories nothing had been tried
on, against 1.01 / 1.05 ms and 0.42 a minute leaving out every flagged band and 1.08 / 1.01 ms
and 1.39 a minute with no gate (seeds 11-15, a one-off measurement of issue 34's sixth
round: ``docs/results/events.md``; the report's table pools seeds 0-4).

Both bounds are the stream's own (Hampel's identifier: the median plus 3 times 1.4826 median
absolute deviations, the SD of a Gaussian; Hampel 1974, Pearson 2002 "Outliers in process
modeling and identification", 3 the usual choice), so that no pixel or degree figure of one
camera or lighting is built in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .velocity import leave_one_out_residual

#: Fewest valid samples with a finite residual for the stream's residual scale: below this
#: the median absolute deviation says little, and no band is flagged by its residual.
MIN_RESIDUALS = 20


@dataclass(frozen=True, slots=True)
class SampleGate:
    """Which samples :func:`left_out` leaves out (every default with its reason).

    Attributes
    ----------
    min_prior_glints : int
        A prior-assisted band with fewer glints than this is flagged: 3, since the rendered
        bands of one or two glints have 2-4x the error of those of three or more (module
        docstring); 0 flags none.
    residual_outlier_sd : float
        A band whose fit residual exceeds the stream's median by more than this many robust
        SDs is flagged: 3, Hampel's identifier; ``inf`` flags none.
    neighbour_window_s : float
        Half window of the local quadratic a flagged band's gaze is checked against (s): 4 ms
        holds ~4 bands on each side at 16 pulses per frame, so one or two more poor fits
        among them do not carry the fit, and a quadratic follows a saccade's acceleration
        over it (:func:`estimator.events.velocity.leave_one_out_residual`).
    neighbour_outlier_sd : float
        A flagged band further than this many robust SDs (per axis, of every valid sample's
        distance from its own local fit) from its local fit is left out: 3, Hampel's
        identifier; ``inf``: every flagged band stays.
    neighbour_check : bool
        False: every flagged band is left out, whatever its neighbours say.
    """

    min_prior_glints: int = 3
    residual_outlier_sd: float = 3.0
    neighbour_window_s: float = 0.004
    neighbour_outlier_sd: float = 3.0
    neighbour_check: bool = True

    def __post_init__(self):
        if isinstance(self.min_prior_glints, bool) or not isinstance(self.min_prior_glints, int) \
                or self.min_prior_glints < 0:
            raise ValueError("SampleGate.min_prior_glints must be an integer >= 0, got "
                             f"{self.min_prior_glints!r}")
        for name in ("residual_outlier_sd", "neighbour_outlier_sd", "neighbour_window_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or v <= 0 \
                    or (name == "neighbour_window_s" and math.isinf(v)):
                raise ValueError(f"SampleGate.{name} must be > 0"
                                 f"{'' if name == 'neighbour_window_s' else ' (inf: off)'}, "
                                 f"got {v!r}")


#: No sample flagged: what detection was before the gate.
NO_GATE = SampleGate(min_prior_glints=0, residual_outlier_sd=math.inf)


def residual_bound(residual_px, valid, gate: SampleGate = SampleGate()) -> float:
    """The residual above which a band is flagged (px): the median of the ``valid`` (n,) bool
    samples' finite residuals plus ``gate.residual_outlier_sd`` robust SDs; ``inf`` with fewer
    than :data:`MIN_RESIDUALS` of them or no spread."""
    r = np.asarray(residual_px, dtype=np.float64)
    use = r[np.asarray(valid, dtype=bool) & np.isfinite(r)]
    if use.size < MIN_RESIDUALS or math.isinf(gate.residual_outlier_sd):
        return math.inf
    med = float(np.median(use))
    sd = 1.4826 * float(np.median(np.abs(use - med)))
    return med + gate.residual_outlier_sd * sd if sd > 0 else math.inf


def poor_fits(n_glints, prior, residual_px, valid, gate: SampleGate = SampleGate(), *,
              bound_px: float | None = None, source: str = "samples") -> np.ndarray:
    """(n,) bool: the ``valid`` samples the event detector should leave out (module docstring).

    Parameters
    ----------
    n_glints : (n,) int
        Glints each band's fit used.
    prior : (n,) bool
        Whether the prior assisted the band's identification.
    residual_px : (n,) float
        RMS residual of each band's fit (px; NaN where there was no fit).
    valid : (n,) bool
        Samples with a gaze estimate; only these can be flagged, and only their residuals set
        the bound.
    gate : SampleGate
    bound_px : float, optional
        The residual bound to use instead of the one of these samples (:func:`residual_bound`;
        the streaming form passes that of its history).
    source : str
        Names the input in error messages.

    Raises
    ------
    ValueError
        Naming ``source``: arrays of different lengths, or a glint count that is negative or
        not a whole number.
    """
    g = np.asarray(n_glints, dtype=np.float64).reshape(-1)
    p = np.asarray(prior, dtype=bool).reshape(-1)
    r = np.asarray(residual_px, dtype=np.float64).reshape(-1)
    v = np.asarray(valid, dtype=bool).reshape(-1)
    if not g.size == p.size == r.size == v.size:
        raise ValueError(f"{source}: n_glints, prior, residual_px and valid must have one entry "
                         f"per sample, got {g.size}, {p.size}, {r.size}, {v.size}")
    bad = np.flatnonzero(~np.isfinite(g) | (g < 0) | (g != np.round(g)))
    if bad.size:
        raise ValueError(f"{source}: sample {int(bad[0])} has n_glints {float(g[bad[0]]):g}: a glint "
                         "count is a whole number >= 0")
    bound = residual_bound(r, v, gate) if bound_px is None else float(bound_px)
    with np.errstate(invalid="ignore"):
        flagged = (p & (g < gate.min_prior_glints)) | (np.isfinite(r) & (r > bound))
    return flagged & v


def disagree_with_neighbours(time_s, position_deg, candidates,
                             gate: SampleGate = SampleGate()) -> np.ndarray:
    """(n,) bool: the ``candidates`` (n,) whose gaze ``position_deg`` (n, 2) deg at
    ``time_s`` (n,) s lies further than ``gate.neighbour_outlier_sd`` robust SDs from the
    local quadratic through their neighbours, or has no such fit (module docstring, step 2).
    The robust SD is per axis, over every valid sample's distance from its own fit."""
    c = np.asarray(candidates, dtype=bool)
    if not c.any():
        return c.copy()
    r = leave_one_out_residual(time_s, position_deg, gate.neighbour_window_s)
    fit = np.isfinite(r).all(axis=1)
    if fit.sum() < MIN_RESIDUALS:
        return c.copy()
    med = np.median(r[fit], axis=0)
    sd = 1.4826 * np.median(np.abs(r[fit] - med), axis=0)
    axes = sd > 0  # an axis without spread (a gaze that never moves on it) says nothing
    if not axes.any():
        return c & ~fit
    with np.errstate(invalid="ignore"):
        z = np.sqrt(np.sum(((r[:, axes] - med[axes]) / sd[axes]) ** 2, axis=1))
        return c & np.where(fit, z > gate.neighbour_outlier_sd, True)


def left_out(time_s, position_deg, n_glints, prior, residual_px,
             gate: SampleGate = SampleGate(), *, bound_px: float | None = None,
             source: str = "samples") -> np.ndarray:
    """(n,) bool: the samples the event detector leaves out (module docstring): the valid
    samples (finite ``position_deg`` (n, 2)) that :func:`poor_fits` flags and, with
    ``gate.neighbour_check``, whose gaze also :func:`disagree_with_neighbours`. Arguments as
    those two take them; raises ``ValueError`` naming ``source`` as :func:`poor_fits`."""
    x = np.asarray(position_deg, dtype=np.float64)
    valid = np.isfinite(x).all(axis=1) if x.ndim == 2 else np.zeros(0, dtype=bool)
    flagged = poor_fits(n_glints, prior, residual_px, valid, gate, bound_px=bound_px,
                        source=source)
    if not gate.neighbour_check:
        return flagged
    return disagree_with_neighbours(time_s, x, flagged, gate)
