"""Steps 4 and 6 of :mod:`estimator.glints.detector`: each component's centroid, shape and light, and
the per-row pulse weights that correct its centroid and name its strobe.

Components are measured on one stack of equal patches when their boxes are small
(:func:`_measure_patches`), pixel by pixel otherwise (:func:`_measure_pixels`); both weigh the
same pixels alike. That is the numpy path, which runs when the compiled kernels of
:mod:`estimator.glints.kernels` are not available; on both paths blended neighbours are split by
:func:`_deblend` and the pieces measured pixel by pixel, and the row table serves both. Private to the detector:
the names carry a leading underscore and may change with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np

from ..banding import row_pulse_weights
from ..setup import Sensor, Strobe

if TYPE_CHECKING:
    from .noise import _NoiseModel
    from .params import DetectionParams


#: The frame-local strobe phase is rounded to this (s) to key the cache of per-row pulse
#: weights: a strobe locked to the frame (P Δ_clk = Δt) then finds the same entry every frame
#: despite the float rounding of s_j - t0_f. 1e-10 s changes a weight by 1e-6 of a 100 µs pulse.
_PHASE_QUANTUM_S = 1e-10


@dataclass(frozen=True, slots=True)
class _RowTable:
    """Per-row pulse weights of one frame-local strobe phase (read-only arrays). Rows are
    padded: index y + 1 is row y, for y = -1..N. Columns are padded too: column c + 1 is pulse
    c, and columns 0, P + 1.. are zero, so that the pulses either side of any pulse, or of
    none, can be looked up without bounds checks."""

    local_index: np.ndarray  # (P,) pulse indices relative to the cached phase
    weights: np.ndarray  # (N + 2, P + 4)
    gain: np.ndarray  # (N + 2,) 1 / max(Σ_j w_j(y), band_weight_floor): the centroid's row gain
    dominant: np.ndarray  # (N + 2,) column of the largest weight (P + 1 for a dark row)
    below_plateau: np.ndarray  # (N + 3, P + 4) rows < k where a pulse's weight is below its
    # (1 - cut_tolerance) plateau, counted from the top

    def rows(self, y0: int, y1: int) -> "_RowTable":
        """The table of the window of rows y0 .. y1 - 1, indexed as its own frame (row y0 is
        row 0; padded as before). Views: differences of ``below_plateau``'s running counts
        are unchanged."""
        return _RowTable(self.local_index, self.weights[y0:y1 + 2], self.gain[y0:y1 + 2],
                         self.dominant[y0:y1 + 2], self.below_plateau[y0:y1 + 3])


@lru_cache(maxsize=64)
def _row_table(sensor: Sensor, strobe: Strobe, phase_s: float, cut_tolerance: float,
               band_weight_floor: float) -> _RowTable:
    """The table of ``strobe`` with its phase set to ``phase_s`` (a key, not a new strobe per
    frame: building one costs more than the rest of the look-up)."""
    j, _, w = row_pulse_weights(sensor, replace(strobe, phase_s=phase_s), 0)
    n, p = w.shape
    padded = np.zeros((n + 2, p + 4))
    padded[1:-1, 1:p + 1] = w
    total = padded.sum(axis=1)
    dominant = np.where(total > 0, np.argmax(padded, axis=1), p + 2)
    below = np.zeros((n + 3, p + 4), dtype=np.int64)
    np.cumsum(padded < (1.0 - cut_tolerance) * padded.max(axis=0), axis=0, out=below[1:])
    gain = 1.0 / np.maximum(total, band_weight_floor)
    for a in (padded, gain, dominant, below, j):
        a.setflags(write=False)
    return _RowTable(j, padded, gain, dominant, below)


def _frame_timing(sensor: Sensor, strobe: Strobe, frame_index: int, cut_tolerance: float,
                  band_weight_floor: float) -> tuple[_RowTable, int]:
    """(row table, m): column c + 1 of the table is the global pulse ``local_index[c] - m``.

    Frame f sees pulse j start at s_j - t0_f = (phase - f Δt) + j Δ_clk. Writing
    phase - f Δt = δ + m Δ_clk with δ in [0, Δ_clk), frame f looks like frame 0 of a strobe of
    phase δ whose pulse j' is the global pulse j' - m; tables are cached per δ, so a strobe
    locked to the frame computes one table for a whole sequence.
    """
    period = strobe.period_s
    local = strobe.phase_s - frame_index * sensor.frame_period_s
    m = math.floor(local / period)
    delta = round((local - m * period) / _PHASE_QUANTUM_S) * _PHASE_QUANTUM_S
    if delta >= period:
        delta, m = delta - period, m + 1
    return _row_table(sensor, strobe, delta, cut_tolerance, band_weight_floor), m


def _weights(px, img, top, noise: _NoiseModel, table: _RowTable, params: DetectionParams):
    """Per pixel: raw value, value above the top-hat floor, centroid weight (value less
    ``centroid_floor_sigma`` σ, clipped, divided by the row's light) and that row gain."""
    raw = img[px.ys, px.xs]
    t = top[px.ys, px.xs].astype(np.float64)
    level = raw - t
    value = t - noise.floor(level)
    gain = table.gain[px.ys + 1]
    weight = np.maximum(value - params.centroid_floor_sigma * noise.sigma(level), 0.0) * gain
    return raw, value, weight, gain


@dataclass(frozen=True, slots=True)
class _Pixels:
    """Pixels of n spots, spot after spot (segments start at ``starts``)."""

    n: int
    seg: np.ndarray  # (q,) spot of each pixel
    starts: np.ndarray  # (n,) first pixel of each spot
    ys: np.ndarray
    xs: np.ndarray
    own: np.ndarray  # (q,) bool: above threshold and in the spot's component
    usable: np.ndarray  # (q,) bool: own or background (not another component's)
    row0: np.ndarray  # (n,) first and last row of the spot's own pixels
    row1: np.ndarray
    edge: np.ndarray  # (n,) bool: the grown box touches the image border


@dataclass(frozen=True, slots=True)
class _Boxes:
    """Boxes of k components: their labels, own rows and columns (inclusive), the box grown
    by the centroid margin and clipped to the frame (exclusive ends), and whether the grown
    box touches the frame's border."""

    ids: np.ndarray
    y0: np.ndarray
    y1: np.ndarray
    x0: np.ndarray
    x1: np.ndarray
    gy0: np.ndarray
    gy1: np.ndarray
    gx0: np.ndarray
    gx1: np.ndarray
    edge: np.ndarray

    @classmethod
    def grown(cls, ids, y0, y1, x0, x1, margin: int, height: int, width: int) -> "_Boxes":
        gy0, gy1 = np.maximum(y0 - margin, 0), np.minimum(y1 + margin + 1, height)
        gx0, gx1 = np.maximum(x0 - margin, 0), np.minimum(x1 + margin + 1, width)
        edge = (gx0 == 0) | (gy0 == 0) | (gx1 == width) | (gy1 == height)
        return cls(ids, y0, y1, x0, x1, gy0, gy1, gx0, gx1, edge)

    def take(self, sel) -> "_Boxes":
        return _Boxes(*(getattr(self, name)[sel] for name in self.__slots__))


@dataclass(frozen=True, slots=True)
class _Labels:
    """Component labels (0: background) of the pixels above threshold, on the frame with its
    rows and columns that hold none squeezed out, but one between runs of rows (columns) that
    hold some: pixel (y, x) of the frame is pixel (row_at[y], col_at[x]) of ``image``. Rows
    and columns without such pixels, including those past the frame's last (up to
    :data:`_PATCH_PX` of them), map to an empty row or column."""

    image: np.ndarray
    n: int  # labels, background included
    row_at: np.ndarray
    col_at: np.ndarray

    @classmethod
    def of(cls, rows, cols, height: int, width: int) -> "_Labels":
        row_at, col_at = _squeeze(rows, height), _squeeze(cols, width)
        image = np.zeros((int(row_at.max()) + 2, int(col_at.max()) + 2), dtype=np.uint8)
        image[row_at[rows], col_at[cols]] = 1
        n, image = cv2.connectedComponentsWithAlgorithm(image, 8, cv2.CV_32S, cv2.CCL_BOLELLI)
        return cls(image, n, row_at, col_at)

    @classmethod
    def whole(cls, image: np.ndarray, n: int) -> "_Labels":
        """``n`` labels (background included) already on the frame's own grid."""
        height, width = image.shape
        return cls(image, n, np.arange(height), np.arange(width))

    def at(self, ys, xs) -> np.ndarray:
        """Labels of the pixels (ys, xs)."""
        return self.image[self.row_at[ys], self.col_at[xs]]


def _squeeze(v: np.ndarray, n: int) -> np.ndarray:
    """(n + _PATCH_PX,) int: for each position 0..n - 1 + _PATCH_PX, its index once the
    positions not in ``v`` are squeezed out but one between runs (0 for those left out:
    index 0 is empty)."""
    kept = np.flatnonzero(np.bincount(v, minlength=n))
    step = np.empty(kept.size, dtype=np.intp)  # 1 within a run, 2 across a gap
    step[0] = 2
    np.minimum(kept[1:] - kept[:-1], 2, out=step[1:])
    at = np.zeros(n + _PATCH_PX, dtype=np.intp)
    at[kept] = np.cumsum(step)
    return at


def _gather(box: _Boxes, labels: _Labels) -> _Pixels:
    """The pixels of the grown boxes, box after box, row by row."""
    n = box.ids.size
    bw = box.gx1 - box.gx0
    counts = bw * (box.gy1 - box.gy0)
    starts = np.cumsum(counts) - counts
    seg = np.repeat(np.arange(n), counts)
    dy, dx = np.divmod(np.arange(int(counts.sum())) - starts[seg], bw[seg])
    ys, xs = box.gy0[seg] + dy, box.gx0[seg] + dx
    lab = labels.at(ys, xs)
    own = lab == box.ids[seg]
    return _Pixels(n, seg, starts, ys, xs, own, own | (lab == 0), box.y0, box.y1, box.edge)


@dataclass(frozen=True, slots=True)
class _Spots:
    """What step 4 measures on n spots (arrays over the last axis)."""

    u: np.ndarray
    v: np.ndarray
    flux: np.ndarray
    elong: np.ndarray
    neighbour: np.ndarray  # brightest 4-neighbour of the peak pixel over the peak
    raw_peak: np.ndarray  # brightest own pixel of the frame (DN, black level included)
    dom: np.ndarray  # row-table column of the dominant pulse of the centroid's row
    light: np.ndarray  # (4, n) light, and its sums weighted by pulses dom - 1, dom, dom + 1

    def take(self, sel) -> "_Spots":
        return _Spots(*(getattr(self, name)[..., sel] for name in self.__slots__))

    @staticmethod
    def concat(parts) -> "_Spots":
        return _Spots(*(np.concatenate([getattr(p, name) for p in parts], axis=-1)
                        for name in _Spots.__slots__))


def _shape(sums, u0, v0):
    """Centroid, flux and elongation from the moment sums (9, n) of a spot's weights: over
    usable pixels Σw, Σwx, Σwy; over own pixels Σw, Σwx, Σwy, Σwx², Σwy², Σwxy, with x, y
    relative to (u0, v0)."""
    den = sums[0:4:3]  # Σw over usable and over own pixels
    den = np.where(den > 0, den, 1.0)
    u = sums[1] / den[0] + u0
    v = sums[2] / den[0] + v0
    mx, my, mxx, myy, mxy = sums[4:] / den[1]  # mean x, y, x², y², xy over own pixels
    sxx, syy, sxy = mxx - mx * mx, myy - my * my, mxy - mx * my
    half_tr = 0.5 * (sxx + syy)
    disc = np.hypot(0.5 * (sxx - syy), sxy)  # sqrt(half_tr² - det), never negative
    # + 1/12 px²: the second moment of one pixel, so that a one-pixel-wide spot stays finite.
    elong = np.sqrt((half_tr + disc + 1 / 12) / (np.maximum(half_tr - disc, 0.0) + 1 / 12))
    return u, v, sums[0], elong


def _neighbour_ratio(top, py, px, peak):
    """Brightest 4-neighbour of the peak pixels (py, px) over their value ``peak`` above the
    top-hat floor."""
    h, w = top.shape
    ny = np.stack([np.maximum(py - 1, 0), np.minimum(py + 1, h - 1), py, py])
    nx = np.stack([px, px, np.maximum(px - 1, 0), np.minimum(px + 1, w - 1)])
    nb = top.ravel().take(ny * w + nx).max(axis=0)
    floor = top.ravel().take(py * w + px) - peak  # the top-hat floor under the peak
    return (nb.astype(np.float64) - floor) / np.where(peak > 0, peak, 1.0)


def _measure_pixels(px: _Pixels, img, top, noise, table, params):
    """Centroids, flux, elongation, peak sharpness and pulse light of every spot, pixel by
    pixel (pixels are contiguous per spot, so one ``np.add.reduceat`` sums all the moments).
    Returns the spots and each pixel's value above the top-hat floor."""
    raw, value, weight, gain = _weights(px, img, top, noise, table, params)
    seg, starts = px.seg, px.starts
    w = weight * px.usable
    wo = weight * px.own  # second moments: own pixels only (the skirt's noise has no shape)
    x = (px.xs - px.xs[starts][seg]).astype(np.float64)  # box-local coordinates: no cancellation
    y = (px.ys - px.ys[starts][seg]).astype(np.float64)
    sums = np.add.reduceat(np.stack([w, w * x, w * y, wo, wo * x, wo * y, wo * x * x, wo * y * y,
                                     wo * x * y]), starts, axis=1)
    u, v, flux, elong = _shape(sums, px.xs[starts], px.ys[starts])
    # Peak pixel (the first of a spot's maxima) and its brightest 4-neighbour.
    vo = np.where(px.own, value, -np.inf)
    peak = np.maximum.reduceat(vo, starts)
    at = np.flatnonzero(vo == peak[seg])
    first = at[np.concatenate([[True], seg[at][1:] != seg[at][:-1]])]
    neighbour = _neighbour_ratio(top, px.ys[first], px.xs[first], peak)
    raw_peak = np.maximum.reduceat(np.where(px.own, raw, 0), starts)
    dom = table.dominant[np.rint(v).astype(np.intp) + 1]
    cols = dom[:, None] + np.arange(-1, 2)  # (n, 3) table columns, zero beyond the pulses
    light = np.maximum(value, 0.0) * gain * px.usable
    light = np.add.reduceat(np.concatenate([light[None], table.weights[px.ys + 1, cols[seg].T]
                                            * light]), starts, axis=1)
    return _Spots(u, v, flux, elong, neighbour, raw_peak, dom, light), value


#: Components whose grown box fits in this many pixels each way are measured on one stack of
#: equal patches (a few dozen numpy calls for all of them, against ~150 calls' worth of
#: per-pixel passes); larger ones (saturated blooms, blends, clutter) pixel by pixel. An
#: unsaturated glint of σ <= 1.5 px is at most 11 px across with its margin.
_PATCH_PX = 13


@dataclass(frozen=True, slots=True)
class _PatchLayout:
    """A (ph, pw) patch, its pixels row by row (read-only arrays)."""

    offsets: np.ndarray  # (ph pw,) flat offsets in an image ``width`` wide
    row: np.ndarray  # (ph pw,) row in the patch
    inside: np.ndarray  # (ph + 1, pw + 1, ph pw) bool: in the top-left (h, w) box of the patch
    basis: np.ndarray  # (ph pw, 6 + ph) 1, x, y, x², y², xy, then 1 on the pixels of each row


@lru_cache(maxsize=64)
def _patch_layout(ph: int, pw: int, width: int) -> _PatchLayout:
    y, x = np.divmod(np.arange(ph * pw), pw)
    inside = ((y < np.arange(ph + 1)[:, None, None, None])
              & (x < np.arange(pw + 1)[None, :, None, None]))[:, :, 0, :]
    yf, xf = y.astype(np.float64), x.astype(np.float64)
    basis = np.concatenate([np.stack([np.ones(ph * pw), xf, yf, xf * xf, yf * yf, xf * yf], axis=1),
                            (y[:, None] == np.arange(ph)).astype(np.float64)], axis=1)
    out = _PatchLayout(y * width + x, y, inside, basis)
    for name in out.__slots__:
        getattr(out, name).setflags(write=False)
    return out


def _measure_patches(box: _Boxes, img, top, labels: _Labels, noise, table, params) -> _Spots:
    """:func:`_measure_pixels` for spots whose grown boxes are small, on a (k, ph pw) stack
    of patches, ph x pw the largest grown box: the same pixels with the same weights (the
    patch beyond a spot's box is masked out), summed in another order."""
    height, width = img.shape
    k = box.ids.size
    bh, bw = box.gy1 - box.gy0, box.gx1 - box.gx0
    ph, pw = int(bh.max()), int(bw.max())
    lay = _patch_layout(ph, pw, width)
    # Patch pixels beyond the frame's last row are clipped to its last pixel, and those beyond
    # its last column run into the next row: all lie outside the box and are masked out.
    flat = (box.gy0 * width + box.gx0)[:, None] + lay.offsets
    raw = img.ravel().take(flat, mode="clip")
    t_raw = top.ravel().take(flat, mode="clip")
    t = t_raw.astype(np.float64)
    rows = box.gy0[:, None] + np.arange(ph)  # (k, ph), up to ph - 1 past the frame
    lab = labels.image.ravel().take(
        ((labels.row_at.take(rows) * labels.image.shape[1])[:, :, None]
         + labels.col_at.take(box.gx0[:, None] + np.arange(pw))[:, None, :]).reshape(k, -1))
    own = lab == box.ids[:, None]  # a component's pixels all lie in its box
    usable = (own | (lab == 0)) & lay.inside[bh, bw]
    # As in _weights, element by element (on integer frames the level is an integer, and the
    # noise model's tables hold its interpolation at every integer level).
    if raw.dtype.kind == "u":
        level = raw - t_raw  # the opening: no wrap-around
        floors, centroid_floors, _ = noise.tables(int(level.max()), params.centroid_floor_sigma)
        value = t - floors.take(level)
        weight = t - centroid_floors.take(level)
    else:
        level = raw - t
        value = t - noise.floor(level)
        weight = value - params.centroid_floor_sigma * noise.sigma(level)
    rows = np.minimum(rows, height - 1)
    gain = table.gain.take(rows + 1)
    weight = np.maximum(weight, 0.0, out=weight) * gain.take(lay.row, axis=1)
    # One product for the moments of the usable and own pixels' weights and each row's light.
    prod = np.concatenate([weight * usable, weight * own, np.maximum(value, 0.0) * usable]
                          ) @ lay.basis
    sums = np.concatenate([prod[:k, :3].T, prod[k:2 * k, :6].T])
    row_light = prod[2 * k:, 6:] * gain  # (k, ph)
    u, v, flux, elong = _shape(sums, box.gx0, box.gy0)
    # Own pixels stand above the threshold, hence above the floor: value > 0 there, and the
    # largest of value * own is the peak, its first pixel row by row as in _gather.
    n = lay.offsets.size
    at = np.arange(0, k * n, n) + (value * own).argmax(axis=1)
    peak = value.ravel().take(at)
    if params.centroid_margin_px >= 1 and not box.edge.any():
        # The peak's 4-neighbours lie inside its grown box, hence inside the patch.
        near = t.ravel().take(at[:, None] + np.array([0, -pw, pw, -1, 1]))
        floor = near[:, 0] - peak  # the top-hat floor under the peak
        neighbour = (near[:, 1:].max(axis=1) - floor) / np.where(peak > 0, peak, 1.0)
    else:
        fy, fx = np.divmod(at % n, pw)
        neighbour = _neighbour_ratio(top, box.gy0 + fy, box.gx0 + fx, peak)
    raw_peak = (raw * own).max(axis=1)
    dom = table.dominant[np.rint(v).astype(np.intp) + 1]
    pulse_weights = table.weights[(rows + 1)[:, :, None], dom[:, None, None] + np.arange(-1, 2)]
    light = np.concatenate([row_light.sum(axis=1)[None],
                            np.einsum("kr,krj->jk", row_light, pulse_weights)])
    return _Spots(u, v, flux, elong, neighbour, raw_peak, dom, light)


def _blend_maxima(ys, xs, own, val, top, params: DetectionParams) -> np.ndarray:
    """Indices of the separated maxima of one elongated spot (its pixels ``ys``, ``xs``, own
    flags and values), or an empty array where it does not split: 2..max_blend 8-neighbour
    local maxima among its own pixels, each pair's straight path dipping below
    ``blend_saddle`` of the lower peak (:func:`estimator.glints.kernels.blend_maxima` is the
    compiled form)."""
    h, w = top.shape
    none = np.zeros(0, dtype=np.int64)
    floor = float(np.median(top[ys, xs] - val))
    # 8-neighbour local maxima among the spot's own pixels (the neighbours' rows and
    # columns clamped to the image once per offset: np.clip costs ~14 us a call).
    nb = np.full(ys.size, -np.inf)
    near_y = [np.minimum(np.maximum(ys + d, 0), h - 1) for d in (-1, 0, 1)]
    near_x = [np.minimum(np.maximum(xs + d, 0), w - 1) for d in (-1, 0, 1)]
    for iy in range(3):
        for ix in range(3):
            if iy != 1 or ix != 1:
                nb = np.maximum(nb, top[near_y[iy], near_x[ix]].astype(np.float64) - floor)
    cand = np.flatnonzero(own & (val > nb))
    if not 2 <= cand.size <= params.max_blend:
        return none
    cy, cx, cv = ys[cand].astype(float), xs[cand].astype(float), val[cand]
    for a in range(cand.size):
        for b in range(a + 1, cand.size):
            t = np.linspace(0.0, 1.0, 2 + 2 * int(np.hypot(cy[a] - cy[b], cx[a] - cx[b])))
            ly = np.rint(cy[a] + t * (cy[b] - cy[a])).astype(int)
            lx = np.rint(cx[a] + t * (cx[b] - cx[a])).astype(int)
            saddle = top[ly, lx].astype(np.float64).min() - floor
            if not saddle < params.blend_saddle * min(cv[a], cv[b]):
                return none
    return cand


def _deblend(px: _Pixels, value, spots_idx, top, params: DetectionParams, maxima=_blend_maxima):
    """Split elongated spots with 2..max_blend separated maxima among their maxima (each pixel
    to its nearest maximum; ``maxima``: :func:`_blend_maxima` or its compiled form). Returns
    the new spots' pixels and the spots split, or (None, []) when none splits."""
    parts = []
    split = []
    for s in spots_idx:
        sl = slice(px.starts[s], px.starts[s + 1] if s + 1 < px.n else px.seg.size)
        ys, xs, own, usable, val = px.ys[sl], px.xs[sl], px.own[sl], px.usable[sl], value[sl]
        cand = maxima(ys, xs, own, val, top, params)
        if cand.size == 0:
            continue
        cy, cx = ys[cand].astype(float), xs[cand].astype(float)
        nearest = np.argmin((ys[:, None] - cy) ** 2 + (xs[:, None] - cx) ** 2, axis=1)
        split.append(s)
        for k in range(cand.size):
            mine = nearest == k
            rows = ys[mine & own]
            parts.append((ys[mine], xs[mine], own[mine], usable[mine], rows.min(), rows.max(),
                          px.edge[s]))
    if not parts:
        return None, []
    counts = np.array([p[0].size for p in parts])
    starts = np.zeros(len(parts), dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    cat = lambda i: np.concatenate([p[i] for p in parts])  # noqa: E731
    return _Pixels(len(parts), np.repeat(np.arange(len(parts)), counts), starts, cat(0), cat(1),
                   cat(2), cat(3), np.array([p[4] for p in parts]),
                   np.array([p[5] for p in parts]), np.array([p[6] for p in parts])), split
