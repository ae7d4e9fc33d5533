"""The tracker's value types: :class:`GazeSample` (one band's estimate) and :class:`BandPrior`
(the motion model of the prior a sparse band borrows from the previous sample),
:func:`estimated_sample` and :func:`failed_sample` (the one way each is built), the samples
CSV (format ``scet-samples``, version 3) and :class:`TrackerInputError`. Reason codes:
:class:`estimator.reasons.Reason`.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import TrackerInputError
from ..eye import EYE_SPEED_MAX_DEG_S
from ..formats import SAMPLES_FORMAT, SAMPLES_READABLE, SAMPLES_VERSION, atomic_write
from ..reasons import Reason

__all__ = ["GazeSample", "BandPrior", "estimated_sample", "failed_sample", "inverse_2x2",
           "SAMPLE_COLUMNS", "samples_csv", "write_samples_csv", "read_samples_csv",
           "TrackerInputError"]


def inverse_2x2(A, rcond: float = 1e-12):
    """The inverse of a symmetric positive semi-definite 2 x 2 matrix (a JᵀJ, a covariance) in
    closed form, or None where its determinant is not above ``rcond`` a₀₀ a₁₁, i.e. where it is
    (nearly) singular (np.linalg.inv and det cost ~15 us a call on a 2 x 2, and every sample
    inverts a few)."""
    a, b, c, d = float(A[0, 0]), float(A[0, 1]), float(A[1, 0]), float(A[1, 1])
    det = a * d - b * c
    if not det > rcond * a * d:
        return None
    return np.array([[d, -b], [-c, a]]) / det


@dataclass(frozen=True, slots=True)
class BandPrior:
    """Motion model of the prior a sparse band borrows from the previous sample.

    The previous sample's Fick angles θ_k (covariance Σ_k: its fit's, σ² (JᵀJ)⁻¹, or the
    posterior of its own prior-assisted fit) predict the eye rotation at time t as a Gaussian of
    mean θ_k and covariance Σ_k + (v_max (t - t_k))² I: the eye may have turned at up to
    ``eye_speed_max_deg_s`` on each axis since. The speed bound enters as one SD, so a saccade
    at full speed costs 1 in the squared Mahalanobis distance: the prior does not pull it back,
    it only tells identities apart (at 16 pulses per frame, 1.04 ms between bands, SD 0.62°,
    against the ~2° between neighbouring glints of an arc in ``paper_sim``).

    Attributes
    ----------
    eye_speed_max_deg_s : float
        Per-axis eye speed bound (:data:`estimator.eye.EYE_SPEED_MAX_DEG_S`).
    max_sd_deg : float
        A prior whose SD (largest axis) exceeds this is not used. The wider the prior, the
        likelier a sparse band's chain shifted by one light (~2° away) or a blob passes for the
        right identities: measured on 150 simulated bands of 1-3 glints with clutter
        (paper_sim), 99.6 % of the claimed identities were right at 0.62° SD, 98.5 % at 0.8°,
        97 % at 1.25°. In practice this is the prior's age limit: 1.25 ms at 600°/s, one band
        period at 16 pulses per frame (1.04 ms), not at 8 (2.08 ms).
    noise_px : float
        Glint noise σ (px per axis) that weighs the prior against the glints and sizes the
        samples' covariances: the matcher's (the upper end of the detector's error), which
        errs on the side of a wider posterior.
    """

    eye_speed_max_deg_s: float = EYE_SPEED_MAX_DEG_S
    max_sd_deg: float = 0.75
    noise_px: float = 0.5

    def __post_init__(self):
        for name in ("eye_speed_max_deg_s", "max_sd_deg", "noise_px"):
            if not getattr(self, name) > 0:
                raise ValueError(f"BandPrior.{name} must be positive, got {getattr(self, name)!r}")

    def predict(self, cov_rad2, elapsed_s: float):
        """Covariance (2, 2) rad² after ``elapsed_s``, or None when its SD exceeds the limit."""
        if not elapsed_s >= 0:
            return None
        grown = np.asarray(cov_rad2) + (math.radians(self.eye_speed_max_deg_s) * elapsed_s) ** 2 * np.eye(2)
        if not np.isfinite(grown).all():
            return None
        # The largest eigenvalue of the symmetric 2 x 2, in closed form (np.linalg.eigvalsh
        # costs ~20 us a call, and every band with a prior asks).
        a, b, c = float(grown[0, 0]), 0.5 * float(grown[0, 1] + grown[1, 0]), float(grown[1, 1])
        if 0.5 * (a + c) + math.hypot(0.5 * (a - c), b) > math.radians(self.max_sd_deg) ** 2:
            return None
        return grown


@dataclass(frozen=True, slots=True)
class GazeSample:
    """One gaze sample: one strobe pulse (one band) of one frame.

    Attributes
    ----------
    frame_index, strobe_index : int
    time_s : float
        Strobe instant s_j + Δs / 2 (s), on the sequence clock.
    screen_xy_m : (2,) float
        Gaze point on the screen plane (NaN when failed).
    cornea_center_m : (3,) float
    glints_px : (k, 2) float
        The band's detections that were identified and used.
    light_index : (k,) int
        Their lights.
    confidence : (k,) float
        The matcher's confidence in each identity (:class:`estimator.matching.GlintMatch`).
    residual_px : float
        RMS residual of the cornea fit (NaN when failed).
    reason : str
        "ok" or why the sample is NaN.
    prior_assisted : bool
        The band borrowed the previous sample's estimate as a prior (:class:`BandPrior`): its
        few glints were identified and fitted with it.
    flux_flagged : (f,) int
        Lights whose glints were flagged as cut by a lash (``estimator.tracking.cut_glints``) and
        dropped (a prior-assisted sample only records them); empty when not checked.
    """

    frame_index: int
    strobe_index: int
    time_s: float
    screen_xy_m: np.ndarray
    cornea_center_m: np.ndarray
    glints_px: np.ndarray
    light_index: np.ndarray
    residual_px: float
    reason: str
    confidence: np.ndarray
    prior_assisted: bool = False
    flux_flagged: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def ok(self) -> bool:
        return self.reason == Reason.OK

    @property
    def n_glints(self) -> int:
        return int(self.light_index.shape[0])


def estimated_sample(frame_index: int, strobe_index: int, time_s: float, *, screen_xy_m,
                     cornea_center_m, glints_px, light_index, residual_px: float, confidence,
                     prior_assisted: bool = False) -> GazeSample:
    """An accepted sample of band ``strobe_index`` of frame ``frame_index``: screen point (2,),
    cornea centre (3,) and confidence (k,) copied (the caller's arrays stay its own), the
    identified detections ``glints_px`` (k, 2) of lights ``light_index`` (k,), its fit's RMS
    ``residual_px``."""
    return GazeSample(frame_index, strobe_index, time_s, screen_xy_m.copy(),
                      cornea_center_m.copy(), glints_px, light_index, float(residual_px),
                      Reason.OK, confidence.copy(), prior_assisted=prior_assisted)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


#: The arrays every failed sample shares (read-only: a sample is immutable, and half the
#: bands of a stream fail, most without a glint; building these per sample was ~a tenth of
#: such a band's cost).
_NAN2, _NAN3 = _frozen(np.full(2, np.nan)), _frozen(np.full(3, np.nan))
_NO_GLINTS, _NO_LIGHTS = _frozen(np.zeros((0, 2))), _frozen(np.zeros(0, dtype=np.int64))
_NO_CONFIDENCE = _frozen(np.zeros(0))


def failed_sample(frame_index: int, strobe_index: int, time_s: float, reason: str,
                  glints_px=None, light_index=None) -> GazeSample:
    """A NaN sample of band ``strobe_index`` of frame ``frame_index`` failed for ``reason``
    (with the detections and lights it had, if any). Its NaN screen point and centre, and
    its empty arrays, are read-only arrays shared by all failed samples."""
    g = _NO_GLINTS if glints_px is None else np.asarray(glints_px, dtype=np.float64)
    if light_index is None:
        li, conf = _NO_LIGHTS, _NO_CONFIDENCE
    else:
        li = np.asarray(light_index, np.int64)
        conf = np.zeros(li.shape[0]) if li.shape[0] else _NO_CONFIDENCE
    return GazeSample(frame_index, strobe_index, time_s, _NAN2, _NAN3, g, li, math.nan,
                      reason, conf)


SAMPLE_COLUMNS = ("frame", "strobe", "time_s", "screen_x_m", "screen_y_m", "cornea_x_m",
                  "cornea_y_m", "cornea_z_m", "n_glints", "lights", "residual_px", "reason",
                  "prior", "flux_flagged")


def samples_csv(samples) -> str:
    """CSV text of samples: a ``# scet-samples 3`` line, the header, one row per sample
    (``prior``: 1 for a prior-assisted sample, else 0; ``flux_flagged``: the lights whose glints
    were dropped as cut by a lash, ``;``-separated)."""
    buf = io.StringIO()
    buf.write(f"# {SAMPLES_FORMAT} {SAMPLES_VERSION}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(SAMPLE_COLUMNS)
    for s in samples:
        w.writerow([s.frame_index, s.strobe_index, repr(float(s.time_s)),
                    *(repr(float(v)) for v in s.screen_xy_m),
                    *(repr(float(v)) for v in s.cornea_center_m), s.n_glints,
                    ";".join(str(int(i)) for i in s.light_index), repr(float(s.residual_px)),
                    s.reason, int(s.prior_assisted),
                    ";".join(str(int(i)) for i in s.flux_flagged)])
    return buf.getvalue()


def write_samples_csv(path, samples) -> Path:
    """Write :func:`samples_csv` of ``samples`` to ``path`` atomically; returns the path."""
    return atomic_write(Path(path), samples_csv(samples))


def read_samples_csv(path) -> list[dict]:
    """Rows of a ``samples.csv`` (values as strings), after checking its format line.

    Reads versions 1-3 (:data:`SAMPLES_READABLE`); rows of version 1, written before prior
    assistance existed, get ``prior`` "0", rows of versions 1-2 ``flux_flagged`` "" (none)."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise TrackerInputError(f"cannot read the samples ({exc.strerror or exc})",
                                path=path) from None
    except UnicodeDecodeError as exc:
        raise TrackerInputError(f"not UTF-8 text ({exc.reason} at byte {exc.start})",
                                path=path) from None
    first, _, rest = text.partition("\n")
    known = {f"# {SAMPLES_FORMAT} {v}": v for v in SAMPLES_READABLE}
    version = known.get(first.strip())
    if version is None:
        raise TrackerInputError(f"{path}: expected first line '# {SAMPLES_FORMAT} <version>' "
                                f"with version in {SAMPLES_READABLE}, got {first[:60]!r}")
    try:
        rows = list(csv.DictReader(io.StringIO(rest)))
    except csv.Error as exc:  # a field over csv's size limit, a NUL byte
        raise TrackerInputError(f"not a samples CSV ({exc})", path=path) from None
    for r in rows:  # columns added by later versions: prior (2), flux_flagged (3)
        if version < 2:
            r["prior"] = "0"
        if version < 3:
            r["flux_flagged"] = ""
    return rows
