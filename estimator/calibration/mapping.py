"""Gaze mappings: polynomials from the cornea centre (and the distance reading) to the screen.

Sec. 2.2.2 and 3.3.1 of the SCET paper: Eq. (1) (8 terms, from 9 or 25 calibration points), the
full second-order polynomial in the cornea centre (25 points), and the 15-term second-order
polynomial in (x, y, z, d_a) with the distance sensor (27 points: 9 at 3 depths). Inputs are
centred and scaled before the least-squares fit: cornea coordinates are ~1e-3 m and their
products ~1e-9, which would otherwise ruin the conditioning.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from ..checks import Doc
from ..errors import InputError
from ..formats import MAPPING_FORMAT, MAPPING_VERSION
from ..setup import DistanceSensor


def _monomials(n_vars: int, max_degree: int, multilinear: bool):
    terms = [e for e in itertools.product(range(max_degree + 1), repeat=n_vars)
             if (max(e) <= 1 if multilinear else sum(e) <= max_degree)]
    return tuple(sorted(terms, key=lambda e: (sum(e), [-k for k in e])))


#: Mapping kinds: number of input features and the exponent of each feature in each term.
#: ``eq1``: Eq. (1) of the paper, 1, x, y, z, xy, xz, yz, xyz (8 terms, 9 or 25 points);
#: ``quadratic``: the full second-order polynomial in the cornea centre (10 terms, Sec. 3.2);
#: ``quadratic_da``: second order in (x, y, z, d_a), 1 + 4 + 10 = 15 terms (Sec. 2.5, 3.3.1).
MAPPING_TERMS = {
    "eq1": _monomials(3, 3, multilinear=True),
    "quadratic": _monomials(3, 2, multilinear=False),
    "quadratic_da": _monomials(4, 2, multilinear=False),
}
#: Rank tolerance of the centred and scaled design matrix: singular values below this share of
#: the largest are taken as zero. Cornea centres fitted to exact glints carry ~1e-10 m of
#: solver error on a ~2e-3 m spread (5e-8 relative), and 0.5 px of glint noise ~1e-5 m (5e-3):
#: 1e-6 separates an exactly degenerate pattern that only solver error makes "full rank" from
#: one that a real measurement determines.
RANK_RTOL = 1e-6
#: Bounds of a mapping file's feature offsets and scales (m, or the distance reading's unit):
#: a cornea centre lies within centimetres of the eye, a distance reading within metres; a
#: scale is a spread of calibration points and positive.
MAX_FEATURE = 1e3
MIN_SCALE = 1e-12


@dataclass(frozen=True, slots=True)
class GazeMapping:
    """Polynomial from eye features (cornea centre (x, y, z) in metres, and for
    ``quadratic_da`` the distance reading d_a) to screen (x, y) in metres.

    Features are centred and scaled (``(f - offset_m) / scale_m``) before the monomials are
    formed: raw cornea coordinates are ~1e-3 m and their triple products ~1e-9 m³, which
    would make the design matrix hopeless. All three monomial sets are closed under shifts and
    scalings of the inputs, so this changes the conditioning, not the model. ``rank`` is the
    rank of the fit (the number of terms unless it was fitted with ``degenerate="min_norm"``).
    """

    kind: str
    coefficients: np.ndarray  # (k, 2)
    offset_m: np.ndarray  # (d,)
    scale_m: np.ndarray  # (d,)
    n_points: int
    rms_m: float
    rank: int = -1

    def __post_init__(self):
        if self.rank == -1:
            object.__setattr__(self, "rank", len(MAPPING_TERMS.get(self.kind, ())))
        if self.kind not in MAPPING_TERMS:
            raise ValueError(f"mapping kind must be one of {sorted(MAPPING_TERMS)}, got {self.kind!r}")
        k, d = len(MAPPING_TERMS[self.kind]), len(MAPPING_TERMS[self.kind][0])
        for name, shape in (("coefficients", (k, 2)), ("offset_m", (d,)), ("scale_m", (d,))):
            a = np.asarray(getattr(self, name), dtype=np.float64).copy()
            if a.shape != shape:
                raise ValueError(f"GazeMapping.{name} must have shape {shape} for {self.kind!r}, got {a.shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def n_features(self) -> int:
        return self.offset_m.size

    def predict(self, features) -> np.ndarray:
        """(m, 2) screen (x, y) in metres for (m, d) features; NaN rows stay NaN."""
        f = np.asarray(features, dtype=np.float64)
        if f.ndim == 1:
            f = f[None]
        if f.ndim != 2 or f.shape[1] != self.n_features:
            raise ValueError(f"features must have shape (m, {self.n_features}) for {self.kind!r}, got {f.shape}")
        return _design(self.kind, (f - self.offset_m) / self.scale_m) @ self.coefficients

    def predict_one(self, feature) -> tuple[float, float]:
        """:meth:`predict` of one feature vector (d,) in plain floats: a tracker's sample,
        where the batch form's array set-up costs ~30 us and the arithmetic ~1 us (the same
        monomials and products, summed term by term: equal to rounding)."""
        z = [(v - o) / s for v, o, s in zip(np.asarray(feature, dtype=np.float64).tolist(),
                                            self.offset_m.tolist(), self.scale_m.tolist())]
        x = y = 0.0
        for term, (cx, cy) in zip(MAPPING_TERMS[self.kind], self.coefficients.tolist()):
            t = 1.0
            for zi, e in zip(z, term):
                t *= zi ** e
            x += cx * t
            y += cy * t
        return x, y

    def to_dict(self) -> dict:
        return {"format": MAPPING_FORMAT, "version": MAPPING_VERSION, "kind": self.kind,
                "coefficients": self.coefficients.tolist(), "offset_m": self.offset_m.tolist(),
                "scale_m": self.scale_m.tolist(), "n_points": self.n_points, "rms_m": self.rms_m,
                "rank": self.rank}

    @classmethod
    def from_dict(cls, data: dict, *, path="gaze mapping", key: str = "",
                  error: type[InputError] = InputError) -> "GazeMapping":
        """A mapping from its JSON document, every field typed and ranged (errors of type
        ``error`` name ``path`` and the dotted key under ``key``)."""
        doc = Doc(data, path, key, error)
        doc.string("format", choices=(MAPPING_FORMAT,))
        version = doc.integer("version")
        if version != MAPPING_VERSION:
            raise doc.error("version", f"this SCET reads {MAPPING_FORMAT} version "
                                       f"{MAPPING_VERSION}, the file says {version}")
        kind = doc.string("kind", choices=tuple(MAPPING_TERMS))
        k, d = len(MAPPING_TERMS[kind]), len(MAPPING_TERMS[kind][0])
        return cls(kind, doc.array("coefficients", (k, 2)),
                   doc.array("offset_m", (d,), lo=-MAX_FEATURE, hi=MAX_FEATURE),
                   doc.array("scale_m", (d,), lo=MIN_SCALE, hi=MAX_FEATURE),
                   doc.integer("n_points", lo=1, hi=10_000_000),
                   doc.number("rms_m", lo=0.0, hi=MAX_FEATURE, allow_nan=True),
                   doc.integer("rank", lo=0, hi=k))


def _design(kind, z):
    E = np.array(MAPPING_TERMS[kind], dtype=float)  # (k, d)
    return np.prod(z[:, None, :] ** E[None], axis=-1)


def fit_gaze_mapping(features, screen_xy_m, kind: str = "eq1", *, degenerate: str = "raise",
                     rank_rtol: float = RANK_RTOL) -> GazeMapping:
    """Least-squares polynomial from features to screen points (Eq. (1) and Sec. 3.2, 3.3.1).

    Parameters
    ----------
    features : (m, 3) or (m, 4) float
        Cornea centres (m) of the calibration frames, plus the distance reading d_a for
        ``quadratic_da``.
    screen_xy_m : (m, 2) or (m, 3) float
        The fixated targets (only x and y are used).
    kind : {"eq1", "quadratic", "quadratic_da"}
    degenerate : {"raise", "min_norm"}
        What to do when the points do not determine every term (a rank-deficient design):
        raise, or return the minimum-norm least-squares solution (in centred and scaled
        features) over the determined directions. Note that Eq. (1) from a 3x3 grid is
        rank-deficient whenever the grid is mirror-symmetric about the eye's vertical plane (the
        paper's setup): x enters Eq. (1) only linearly, and mirror pairs of cornea centres then
        determine only three of the four coefficients of x, xy, xz and xyz.
    rank_rtol : float
        Singular values below ``rank_rtol`` times the largest count as zero (:data:`RANK_RTOL`).

    Raises
    ------
    ValueError
        Non-finite inputs, fewer points than terms, or (with ``degenerate="raise"``) points that
        do not determine the polynomial: duplicates, too few distinct rows or columns, or a
        symmetric pattern.
    """
    if kind not in MAPPING_TERMS:
        raise ValueError(f"mapping kind must be one of {sorted(MAPPING_TERMS)}, got {kind!r}")
    if degenerate not in ("raise", "min_norm"):
        raise ValueError(f"degenerate must be 'raise' or 'min_norm', got {degenerate!r}")
    terms = MAPPING_TERMS[kind]
    k, d = len(terms), len(terms[0])
    f = np.asarray(features, dtype=np.float64)
    s = np.asarray(screen_xy_m, dtype=np.float64)
    if f.ndim != 2 or f.shape[1] != d:
        raise ValueError(f"features must have shape (m, {d}) for {kind!r}, got {f.shape}")
    if s.ndim != 2 or s.shape[0] != f.shape[0] or s.shape[1] not in (2, 3):
        raise ValueError(f"screen_xy_m must have shape ({f.shape[0]}, 2), got {s.shape}")
    s = s[:, :2]
    bad = ~(np.isfinite(f).all(axis=1) & np.isfinite(s).all(axis=1))
    if bad.any():
        raise ValueError(f"calibration points {np.flatnonzero(bad).tolist()} are not finite (failed fits?)")
    m = f.shape[0]
    if m < k:
        raise ValueError(f"{kind!r} mapping has {k} terms and needs at least {k} calibration points, got {m}")
    offset = f.mean(axis=0)
    scale = f.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    A = _design(kind, (f - offset) / scale)
    U, sv, Vt = np.linalg.svd(A, full_matrices=False)
    keep = sv > rank_rtol * sv[0]
    rank = int(keep.sum())
    if rank < k and degenerate == "raise":
        distinct = np.unique(f, axis=0).shape[0]
        raise ValueError(f"degenerate calibration for the {kind!r} mapping: the {m} points ({distinct} distinct) "
                         f"determine only {rank} of its {k} terms (rank-deficient design, singular value "
                         f"ratio {sv[-1] / sv[0]:.1e} < {rank_rtol:.0e}); use more or less symmetric points, "
                         "or degenerate='min_norm'")
    coef = Vt[keep].T @ ((U[:, keep].T @ s) / sv[keep, None])
    rms = float(np.sqrt(np.mean(np.sum((A @ coef - s) ** 2, axis=1))))
    return GazeMapping(kind, coef, offset, scale, m, rms, rank)


def distance_reading(translation_z_m, sensor: DistanceSensor, rng: np.random.Generator) -> np.ndarray:
    """Distance-sensor output of Sec. 3.3.1: d_a = c t + v, v uniform with zero mean and SD
    ``sensor.noise_sd`` (half-width sqrt(3) SD), t the translation of camera and lights along z."""
    t = np.asarray(translation_z_m, dtype=np.float64)
    half = np.sqrt(3.0) * sensor.noise_sd
    return sensor.gain_per_m * t + rng.uniform(-half, half, size=t.shape)
