"""Step 2 of :mod:`estimator.glints.detector`: the top-hat's noise model, and the fast search for the
pixels above a threshold.

The model is measured on a 1-in-64 subsample of the frame (:data:`_NOISE_STEP`); its bins,
medians and the reasons for them are in :class:`_NoiseModel`. Private to the detector: the
names carry a leading underscore and may change with it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from .params import DetectionParams


#: The noise model's subsample: every 8th pixel of every 8th row (4,800 at VGA).
_NOISE_STEP = 8



@lru_cache(maxsize=8)
def _line_kernel(length: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_RECT, (length, 1))


def _flat_true(mask: np.ndarray) -> np.ndarray:
    """Sorted flat indices of the true pixels of a bool image: where it is sparse, the 8-byte
    words that hold any first (numpy's nonzero is fast on bool, not on wider types), then
    within them, 2x faster than ``np.flatnonzero`` on a VGA frame; where more than
    :data:`_DENSE_WORDS` of the words hold one, ``np.flatnonzero`` itself (the prototype's
    16-spp renders put 27 % of their pixels above the lowest threshold: 1.31 against
    0.24 ms)."""
    flat = mask.reshape(-1)
    if flat.size % 8:
        return np.flatnonzero(flat)
    words = np.flatnonzero(flat.view(np.uint64) != 0)
    if words.size > _DENSE_WORDS * (flat.size // 8):
        return np.flatnonzero(flat)
    k = np.flatnonzero(flat.reshape(-1, 8)[words])
    return words[k >> 3] * 8 + (k & 7)


#: Share of a bool image's 8-byte words holding a true pixel above which :func:`_flat_true`
#: takes ``np.flatnonzero`` (measured on a VGA mask: the word path wins below ~10 %).
_DENSE_WORDS = 0.1


@dataclass(frozen=True, slots=True)
class _NoiseModel:
    """Robust noise of the top-hat against the local background level L (the opening), as a
    table over level bins: the floor (median) and σ (1.4826 MAD) of the top-hat in each bin,
    interpolated in L. Shot noise makes σ grow with L (σ² = read² + L / gain for a sensor; a
    low-spp render's Monte Carlo noise grows like L itself), so one global σ would set the
    threshold by the dark pupil and let the bright sclera's noise through. σ is made
    non-decreasing in L (noise does not fall with brightness; a bin's MAD can dip by chance).
    Beyond the brightest bin σ keeps the slope of the last two bins (``slope``, per DN of L);
    a shift of every level by a constant shifts nothing else."""

    levels: np.ndarray  # (B,) bin centres, increasing
    floors: np.ndarray  # (B,)
    sigmas: np.ndarray  # (B,)
    k: float
    slope: float
    lowest_threshold: float
    typical_sigma: float  # at the median level
    typical_threshold: float
    _tables: dict = field(default_factory=dict, repr=False, compare=False)

    #: Level bins, between quantiles of the subsample: finer toward the bright end, where a
    #: small bright area (sclera, skin under the strobe) must still get its own σ (the top bin
    #: holds the brightest 2 %, ~100 pixels at VGA: MAD to ~10 %).
    QUANTILES = (0.0, 0.25, 0.5, 0.7, 0.85, 0.93, 0.98, 1.0)

    @classmethod
    def measure(cls, t: np.ndarray, level: np.ndarray, params: DetectionParams) -> "_NoiseModel":
        """From the top-hat ``t`` (>= 0) and level of a pixel subsample, (m,) int64 (integer
        frames) or float32.

        A pixel falls in the bin between the quantiles of level around it (one whose level
        equals a quantile, in the bin above). Integers are counted, floats sorted; both take
        the element of rank size // 2 as the median, so an integer-valued float frame gives
        the same model as the integer frame."""
        ranks = (np.array(cls.QUANTILES[1:-1]) * level.size).astype(int)
        stats = _bin_medians_counted if t.dtype.kind in "iu" else _bin_medians_sorted
        floors, mads, levels, full, typical = stats(t, level, ranks)
        floors, sigmas, levels = floors[full], 1.4826 * mads[full], levels[full]
        sigmas = np.maximum.accumulate(np.maximum(sigmas, params.min_noise_dn))
        # Bins of one level (a large flat dark area) collapse into one point, the worst.
        keep = np.append(levels[1:] > levels[:-1] + 1e-6, True)
        levels, floors, sigmas = levels[keep], floors[keep], sigmas[keep]
        slope = 0.0
        if levels.size > 1:
            slope = max(float((sigmas[-1] - sigmas[-2]) / (levels[-1] - levels[-2])), 0.0)
        k = params.threshold_sigma
        extra = slope * max(typical - levels[-1], 0.0)
        return cls(levels, floors, sigmas, k, slope, float((floors + k * sigmas).min()),
                   float(np.interp(typical, levels, sigmas)) + extra,
                   float(np.interp(typical, levels, floors + k * sigmas)) + k * extra)

    @classmethod
    def of_frame(cls, img: np.ndarray, params: DetectionParams) -> "_NoiseModel":
        """From a frame, on the :data:`_NOISE_STEP` subsample. The top-hat works along rows,
        so that of every 8th row alone is the frame's on those rows (1/8 of the cost)."""
        rows = img[::_NOISE_STEP]
        top = cv2.morphologyEx(rows, cv2.MORPH_TOPHAT, _line_kernel(params.background_kernel_px))
        sample = np.float32 if img.dtype.kind == "f" else np.int64
        t = top[:, ::_NOISE_STEP].astype(sample).ravel()
        return cls.measure(t, rows[:, ::_NOISE_STEP].astype(sample).ravel() - t, params)

    def tables(self, top_level: int, centroid_floor_sigma: float) -> np.ndarray:
        """(3, m) rows floor, floor + ``centroid_floor_sigma`` σ and threshold at the integer
        levels 0 .. m - 1 > ``top_level``, computed once per model (and again, longer, when a
        frame reaches beyond them): on integer frames a look-up replaces the interpolations,
        with the same values."""
        key = float(centroid_floor_sigma)
        found = self._tables.get(key)
        if found is None or found.shape[1] <= top_level:
            level = np.arange(1 << max(int(top_level), 255).bit_length(), dtype=np.float64)
            floor = self.floor(level)
            found = np.stack([floor, floor + key * self.sigma(level), self.threshold(level)])
            found.setflags(write=False)
            self._tables[key] = found
        return found

    def _extra(self, level):
        return self.slope * np.maximum(level - self.levels[-1], 0.0) if self.slope else 0.0

    def sigma(self, level):
        return np.interp(level, self.levels, self.sigmas) + self._extra(level)

    def floor(self, level):
        return np.interp(level, self.levels, self.floors)

    def threshold(self, level):
        return (np.interp(level, self.levels, self.floors + self.k * self.sigmas)
                + self.k * self._extra(level))


def _bin_medians_sorted(t, level, ranks):
    """Per level bin (``ranks``: the ranks of level that bound the bins): median of t, median
    of |t - that median| and median level, whether the bin holds any pixel, and the median
    level overall. One sort of keys bin * scale + value, scale above every value, orders by
    bin then value (np.median's overhead is 5x the work)."""
    sorted_level = np.sort(level)
    b = np.searchsorted(sorted_level[ranks], level, side="right")
    size = np.bincount(b, minlength=ranks.size + 1)
    mid = np.cumsum(size) - size + size // 2
    bins = np.arange(size.size)
    b_sorted = np.repeat(bins, size)
    scale = 2.0 * (float(t.max()) + 1.0)
    x = np.sort(b * scale + t) - b_sorted * scale
    floors = x[mid]
    dev = np.abs(x - floors[b_sorted])
    scale = 2.0 * (float(dev.max()) + 1.0)
    mads = np.sort(b_sorted * scale + dev)[mid] - bins * scale
    return (floors, mads, sorted_level[mid].astype(np.float64), size > 0,
            float(sorted_level[level.size // 2]))


#: Histogram length of :func:`_bin_medians_counted` (DN): the noise floor and MAD of the
#: top-hat sit far below it at any gain.
_MEDIAN_CAP = 255


def _bin_medians_counted(t, level, ranks):
    """:func:`_bin_medians_sorted` for integers, by histograms: the value of rank r is the
    first whose cumulative count exceeds r."""
    low = int(level.min())
    counts = np.cumsum(np.bincount(level - low))
    at_rank = lambda r: np.searchsorted(counts, r, side="right")  # noqa: E731
    bin_of_level = np.searchsorted(at_rank(ranks), np.arange(counts.size), side="right")
    b = bin_of_level[level - low]
    n_bins = ranks.size + 1
    size = np.bincount(b, minlength=n_bins)
    mid = np.cumsum(size) - size + size // 2  # rank of each bin's median, all bins in a row
    full = size > 0
    bins = np.arange(n_bins)
    t_max = int(t.max())  # |t - floor| <= max(t) too

    def medians(x):
        # One histogram per bin, side by side: the median of bin i is the value of rank
        # mid[i] in all of them. Values above the cap (glint pixels caught by the subsample)
        # are counted at the cap: a median below it is unchanged, and one at it is redone
        # uncapped.
        width, clip = min(t_max, _MEDIAN_CAP) + 1, t_max > _MEDIAN_CAP
        while True:
            counts = np.bincount(b * width + (np.minimum(x, width - 1) if clip else x),
                                 minlength=n_bins * width)
            med = np.searchsorted(np.cumsum(counts), mid, side="right") - bins * width
            if not clip or (med[full] < _MEDIAN_CAP).all():
                return med
            width, clip = int(x.max()) + 1, False

    floors = medians(t)
    mads = medians(np.abs(t - floors[b]))
    levels = at_rank(mid) + low
    return (floors.astype(np.float64), mads.astype(np.float64), levels.astype(np.float64),
            full, float(at_rank(level.size // 2) + low))
