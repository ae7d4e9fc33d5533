"""Glint detection in a banded rolling-shutter frame, with OpenCV.

A glint is the corneal reflection of one strobed point light: a small bright spot (1-4 px in
radius at 640x480) on an eye image whose sclera, iris, skin and eyelids sit at low to moderate
levels. Each strobe pulse lights only a band of rows (Sec. 2.3 of the SCET paper, Fig. 2), so
every glint also carries the instant of the pulse that lit it. The pipeline is lean (it runs on
a Raspberry Pi, one frame per 16.6 ms). Steps 2-6 after the top-hat run compiled with Numba
when it is installed (:mod:`estimator.glints.kernels`, one call per step), and otherwise as
numpy and OpenCV (:mod:`estimator.glints.spots`: components labelled by
``cv2.connectedComponents`` on the frame with the rows and columns that hold no pixel above
threshold squeezed out; small spots measured as one stack of equal patches with moments as
matrix products, large ones pixel by pixel with ``np.add.reduceat``), at about half the frame
rate; every path weighs the same pixels alike and gives the same detections (tested to
1e-9 px):

1. Background: a morphological white top-hat, the image minus its opening by a horizontal line
   of ``background_kernel_px`` pixels (OpenCV, on the frame's own 8/16-bit or float32 type,
   no float64 frame-sized temporary). The opening erases every bright structure narrower than
   the line (glints) and keeps everything wider: skin, sclera, iris, pupil and lid edges, linear
   gradients exactly, and the band structure. A horizontal line rather than a square because
   the bands are constant along rows: the V-shaped dips at band edges (Eq. (5)) cut the sclera
   and skin into bright horizontal ridges a few rows high wherever a dip runs near a lid or
   iris edge; a square does not fit in them and would leave them in the top-hat, a line does.
2. Threshold: the top-hat floor plus ``threshold_sigma`` robust standard deviations (1.4826
   MAD), both from a 1-in-64 pixel subsample (the glints are too sparse to move them), in 7
   bins of the local background level L (the opening) between quantiles of L, interpolated
   in L: noise grows with brightness (shot noise), and a single global σ set by the dark
   pupil or the dark gaps between bands would let the bright sclera's noise cross the
   threshold. The medians are counted (histograms) for integer frames and sorted for float
   ones, with the same result. Pixels above the lowest threshold are found word by word,
   then kept where the top-hat exceeds the threshold at their own level.
   The top-hat works along rows, so the subsample's top-hat is that of every 8th row alone.
   :class:`GlintDetector` measures this model only now and then over the frames of one
   sequence (it is the sensor's, not the scene's; see there when it is measured again), and
   between whole-frame searches searches only a window around the glints it found, with the
   same result for every glint inside it.
3. Connected components (8-connected) of the pixels above threshold, with each one's area
   and box.
4. Per component, over its box grown by ``centroid_margin_px``, the intensity-weighted
   centroid of the top-hat above its floor (pixel-centre convention: (0, 0)
   is the centre of the top-left pixel), with each row divided by the light it collected from
   the strobes, Σ_j w_j(y) of :func:`estimator.banding.row_pulse_weights`, clamped below at
   ``band_weight_floor``. A static glint is recorded as I(x, y) Σ_j w_j(y), so the division
   undoes the cut a band edge makes in the spot (uncorrected, a spot on the ramp of Eq. (5)
   moves toward the band's plateau by up to half a pixel).
5. Filters (a failing component is not a glint and is not returned): area, elongation of the
   intensity-weighted second moments, and the ratio of the brightest 4-neighbour to the peak
   (an optical spot is never a single pixel; a noise spike or hot pixel is). Elongated
   components with two or three clearly separated maxima (neighbouring glints whose skirts
   touch, common where the arc's glints crowd) are first split among their maxima and flagged
   :data:`BLENDED`. Thresholds and their reasons are in :class:`DetectionParams`.
6. Band and time: the light of a spot is shared among the pulses in proportion to
   Σ_pixels I(x, y) w_j(y); the largest share names the strobe, and the time stamp is that
   pulse's centre s_j + Δs / 2 (as in :func:`estimator.banding.row_strobe`). The row weights,
   and per pulse the running count of rows below its plateau (for :data:`CUT_BY_BAND_EDGE`),
   are computed once per strobe phase and cached.

Flags (bits of :attr:`GlintDetections.flags`): :data:`SATURATED` (a pixel of the spot reached
full scale: the centroid is that of the flat top and its skirt, the intensity a lower bound),
:data:`CUT_BY_BAND_EDGE` (the spot reaches a row where its pulse's weight falls below the
plateau: the centroid was corrected as above and is less certain), :data:`TWO_PULSES` (a second
pulse contributes a share of the spot's light: the spot may hold two images of the same glint,
Δ_clk apart; they are not split, the strobe and time are those of the larger share),
:data:`IMAGE_EDGE` (the spot's box touches the image border: the centroid may be truncated),
:data:`NO_BAND` (the spot lies on rows no pulse lights: not a strobe glint; strobe index
:data:`estimator.banding.NO_PULSE`, time NaN) and :data:`BLENDED` (split from a neighbour: the
centroid is pulled toward it by up to ~0.1 px). Flagged glints are kept: what to do with them
is the caller's decision.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

import estimator.glints.kernels as glint_kernels
import estimator.glints.spots as glint_spots

from ..banding import NO_PULSE, strobe_instant
from ..setup import Sensor, Setup
from .noise import _flat_true, _line_kernel, _NoiseModel
from .params import (
    BLENDED,
    CUT_BY_BAND_EDGE,
    IMAGE_EDGE,
    NO_BAND,
    SATURATED,
    TWO_PULSES,
    DetectionParams,
    GlintDetections,
    _empty,
)
from .spots import (
    _Boxes,
    _blend_maxima,
    _deblend,
    _frame_timing,
    _gather,
    _Labels,
    _measure_patches,
    _measure_pixels,
    _Spots,
    _weights,
)

# --------------------------------------------------------------------------- input checks


def _check_frame(frame, setup: Setup) -> np.ndarray:
    a = np.asarray(frame)
    if a.size == 0:
        raise ValueError(f"frame is empty (shape {a.shape})")
    want = (setup.camera.height_px, setup.camera.width_px)
    if a.ndim != 2 or a.shape != want:
        raise ValueError(f"frame must have shape {want} (height, width of setup {setup.name!r}'s "
                         f"camera), got {a.shape}")
    if a.dtype == np.bool_ or not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise ValueError(f"frame must be uint8, uint16 or float sensor DN, got dtype {a.dtype}")
    if a.dtype in (np.uint8, np.uint16):
        return np.ascontiguousarray(a)
    if np.issubdtype(a.dtype, np.floating) and not np.isfinite(a).all():
        raise ValueError("frame contains NaN or infinite values")
    return np.ascontiguousarray(a, dtype=np.float32)


# --------------------------------------------------------------------------- detection


def detect_glints(frame, setup: Setup, frame_index: int = 0,
                  params: DetectionParams = DetectionParams()) -> GlintDetections:
    """Find the glints in one banded frame and time-stamp each with its strobe.

    Parameters
    ----------
    frame : (H, W) uint8, uint16 or float
        Sensor output in DN (black level included), H x W the setup camera's size. uint8 is
        taken as 8-bit output (full scale 255, black level scaled by 2^(8 - bit depth)).
    setup : Setup
        Sensor and strobe timing (the bands), bit depth and black level.
    frame_index : int
        Frame f of the sequence; its row 0 is read at f Δt (Eq. (2)).
    params : DetectionParams

    Returns
    -------
    GlintDetections
        Empty arrays when the frame holds no glint.

    Raises
    ------
    ValueError
        Empty frame, wrong shape or dtype, NaN or infinite values, non-integer frame index.
    """
    img, frame_index = _prepare(frame, setup, frame_index)
    return _detect(img, setup, frame_index, params, None)[0]


def _prepare(frame, setup: Setup, frame_index) -> tuple[np.ndarray, int]:
    """The checked frame (uint8, uint16 or float32, C-contiguous) and frame index."""
    if isinstance(frame_index, bool) or not isinstance(frame_index, (int, np.integer)):
        raise ValueError(f"frame_index must be an integer, got {frame_index!r}")
    img = _check_frame(frame, setup)
    if setup.sensor.visible_lines != img.shape[0]:
        raise ValueError(f"setup {setup.name!r}: sensor.visible_lines = "
                         f"{setup.sensor.visible_lines} but its camera image has "
                         f"{img.shape[0]} rows")
    return img, int(frame_index)


def _full_scale_and_black(img: np.ndarray, sensor: Sensor, params: DetectionParams):
    """Full scale and black level (DN) of a checked frame."""
    if img.dtype == np.uint8:
        full_scale, black = 255.0, sensor.black_level_dn * 2.0 ** (8 - sensor.bit_depth)
    else:
        full_scale, black = float(2 ** sensor.bit_depth - 1), float(sensor.black_level_dn)
    if params.saturation_dn is not None:
        full_scale = float(params.saturation_dn)
    return full_scale, black


def _detect(img: np.ndarray, setup: Setup, frame_index: int, params: DetectionParams,
            noise: _NoiseModel | None, roi: tuple[int, int, int, int] | None = None,
            drop_cut: bool = False) -> tuple[GlintDetections | None, _NoiseModel]:
    """:func:`detect_glints` on a checked frame, with ``noise`` as its noise model (measured
    on the frame when None). Returns the detections and the model used.

    With ``roi`` = (y0, y1, x0, x1), only the window of rows y0 .. y1 - 1 and columns
    x0 .. x1 - 1 is searched, and every glint found is exactly what the whole frame gives
    for it: the top-hat is taken over the window widened by the line kernel's reach (it works
    along rows only), the noise model (when measured) on the whole frame, the band timing on
    the window's rows, and a component whose grown box touches a side of the window that is
    not the frame's border (it may reach beyond, or join another there) voids the window:
    the detections are then None; with ``drop_cut`` such components are dropped instead (the
    others are still exactly the whole frame's)."""
    sensor = setup.sensor
    full_scale, black = _full_scale_and_black(img, sensor, params)
    kernel = _line_kernel(params.background_kernel_px)
    if noise is None:
        noise = _NoiseModel.of_frame(img, params)

    # 1-2: background and threshold (shot noise: the threshold rises with the background).
    if roi is None:
        y0 = x0 = 0
        top = cv2.morphologyEx(img, cv2.MORPH_TOPHAT, kernel)
    else:
        y0, y1, x0, x1 = roi
        reach = params.background_kernel_px - 1  # the opening at x reads x ± (length - 1)
        wx0, wx1 = max(x0 - reach, 0), min(x1 + reach, img.shape[1])
        top = cv2.morphologyEx(img[y0:y1, wx0:wx1], cv2.MORPH_TOPHAT, kernel)
        top, frame_shape, img = top[:, x0 - wx0:x1 - wx0], img.shape, img[y0:y1, x0:x1]
        if not glint_kernels.ENABLED:  # the numpy path reads the window by flat indices
            top, img = np.ascontiguousarray(top), np.ascontiguousarray(img)
    height, width = img.shape
    found = _components(top, img, noise, params)
    if found is None:
        return _empty(frame_index, noise.typical_sigma, noise.typical_threshold), noise
    labels, area, box_y0, box_y1, box_x0, box_x1 = found
    keep = (area >= params.min_area_px) & (area <= params.max_area_px)
    if roi is not None:
        cut = _inner_side(box_y0, box_y1, box_x0, box_x1, params.centroid_margin_px, roi,
                          frame_shape)
        if cut.any():
            if not drop_cut:
                return None, noise
            keep &= ~cut
    comp = np.flatnonzero(keep)
    if comp.size == 0:
        return _empty(frame_index, noise.typical_sigma, noise.typical_threshold), noise

    # 4: centroid, shape and light of every component over its box grown by the margin.
    table, m_off = _frame_timing(sensor, setup.strobe, frame_index, params.cut_tolerance,
                                 params.band_weight_floor)
    if roi is not None:
        table = table.rows(y0, y0 + height)
    if comp.size < area.size:
        box_y0, box_y1, box_x0, box_x1 = box_y0[comp], box_y1[comp], box_x0[comp], box_x1[comp]
    box = _Boxes.grown(comp + 1, box_y0, box_y1, box_x0, box_x1, params.centroid_margin_px,
                       height, width)
    spots = _measure(box, img, top, labels, noise, table, params)

    # 5: split blended neighbours, then filter.
    area_out, row0, row1, edge = area[comp], box.y0, box.y1, box.edge
    blended = np.zeros(comp.size, dtype=bool)
    replaced = np.zeros(comp.size, dtype=bool)
    elongated = np.flatnonzero(spots.elong > params.blend_elongation)
    if elongated.size:
        px = _gather(box.take(elongated), labels)
        value = _weights(px, img, top, noise, table, params)[1]
        if glint_kernels.ENABLED:
            px2, split = glint_kernels.deblend(px, value, top, params)
        else:
            px2, split = _deblend(px, value, np.arange(px.n), top, params, _blend_maxima)
        if px2 is not None:
            replaced[elongated[split]] = True
            spots = _Spots.concat([spots, _measure_pixels(px2, img, top, noise, table,
                                                          params)[0]])
            replaced = np.concatenate([replaced, np.zeros(px2.n, dtype=bool)])
            blended = np.concatenate([blended, np.ones(px2.n, dtype=bool)])
            area_out = np.concatenate([area_out, np.bincount(px2.seg, px2.own, px2.n)
                                       .astype(np.int64)])
            row0, row1, edge = (np.concatenate([a, b]) for a, b in (
                (row0, px2.row0), (row1, px2.row1), (edge, px2.edge)))
    finish = glint_kernels.finish if glint_kernels.ENABLED else _finish
    u, v, flux, area_out, peak, j_global, time_s, flags = finish(
        spots, area_out, row0, row1, edge, blended, replaced, table, m_off, setup.strobe,
        full_scale, params)
    if u.size == 0:
        return _empty(frame_index, noise.typical_sigma, noise.typical_threshold), noise
    return GlintDetections(
        u_px=u + x0, v_px=v + y0, intensity=flux, area_px=area_out, peak=peak - black,
        strobe_index=j_global, time_s=time_s, flags=flags, frame_index=frame_index,
        noise_dn=noise.typical_sigma, threshold_dn=noise.typical_threshold), noise


def _finish(spots: _Spots, area, row0, row1, edge, blended, replaced, table, m_off: int,
            strobe, full_scale: float, params: DetectionParams):
    """The end of step 5 and step 6 (numpy; :func:`estimator.glints.kernels.finish` when
    compiled): the spots that pass the filters, ordered by row, as (u, v, flux, area, peak,
    strobe index, time, flags), the peak with the black level."""
    saturated = spots.raw_peak.astype(np.float64) >= full_scale
    good = (~replaced & (spots.flux > 0) & (spots.elong <= params.max_elongation)
            & ((spots.neighbour >= params.min_neighbour_ratio) | saturated))
    sel = np.flatnonzero(good)
    sel = sel[np.argsort(spots.v[sel], kind="stable")]
    spots = spots.take(sel)
    # 6: band and time, from the pulse at the centroid row and its two neighbours (the only
    # ones a spot a few rows high can see): spots.light holds each spot's light and its
    # sums weighted by those three pulses' row weights.
    shares = spots.light[1:] / np.where(spots.light[0] > 0, spots.light[0], 1.0)  # (3, n)
    ranked = np.sort(shares, axis=0)
    lit = ranked[2] > 0
    col = spots.dom + np.argmax(shares, axis=0) - 1  # the table column of the largest share
    j_global = np.where(lit, table.local_index[np.where(lit, col - 1, 0)] - m_off, NO_PULSE)
    time_s = np.where(lit, strobe_instant(strobe.phase_s + j_global * strobe.period_s, strobe.pulse_s),
                      np.nan)
    # Cut by a band edge: the pulse's weight on a row of the spot (±1) is below its plateau.
    below = table.below_plateau
    cut = lit & (below[row1[sel] + 3, col] > below[row0[sel], col])
    flags = (saturated[sel] * SATURATED | cut * CUT_BY_BAND_EDGE
             | (lit & (ranked[1] >= params.two_pulse_share)) * TWO_PULSES
             | edge[sel] * IMAGE_EDGE | ~lit * NO_BAND | blended[sel] * BLENDED)
    return (spots.u, spots.v, spots.flux, area[sel], spots.raw_peak.astype(np.float64),
            j_global.astype(np.int64), time_s, flags.astype(np.int64))


def _components(top, img, noise: _NoiseModel, params: DetectionParams):
    """Steps 2-3 on the top-hat ``top`` of ``img``: the components of the pixels above
    threshold as (labels, area, y0, y1, x0, x1), the boxes inclusive and labels 1, 2, ...
    the components in order; None when no pixel is above threshold. Compiled when
    :data:`estimator.glints.kernels.ENABLED`, else numpy and OpenCV (C-contiguous frames)."""
    height, width = img.shape
    # Compare in the image's own type: a Python float would cast the whole frame to float64.
    low = noise.lowest_threshold
    idx = _flat_true(top > (math.floor(low) if top.dtype.kind == "u" else np.float32(low)))
    if idx.size == 0:
        return None
    if glint_kernels.ENABLED:
        image, *found = glint_kernels.components(idx, top, img, noise, params)
        return (_Labels.whole(image, found[0].size + 1), *found) if found[0].size else None
    if top.dtype.kind == "u":
        t = top.ravel().take(idx)
        level = img.ravel().take(idx) - t  # the opening
        idx = idx[t > noise.tables(int(level.max()), params.centroid_floor_sigma)[2].take(level)]
    else:
        t = top.ravel()[idx].astype(np.float64)
        idx = idx[t > noise.threshold(img.ravel()[idx] - t)]  # level: the opening
    if idx.size == 0:
        return None
    # Labelled with the empty rows and columns between them squeezed to one (8-connectivity
    # is unchanged; ~4x fewer pixels to label than their bounding rectangle); the boxes from
    # the labels of those pixels (OpenCV's per-component statistics cost 4x the labelling).
    rows, cols = np.divmod(idx, width)
    labels = _Labels.of(rows, cols, height, width)
    lab = labels.at(rows, cols)
    area = np.bincount(lab, minlength=labels.n)[1:]
    order = np.argsort(lab, kind="stable")  # rows ascend within a component
    first = np.cumsum(area) - area
    rows, cols = rows[order], cols[order]
    return (labels, area, rows[first], rows[first + area - 1],
            np.minimum.reduceat(cols, first), np.maximum.reduceat(cols, first))


def _measure(box: _Boxes, img, top, labels: _Labels, noise: _NoiseModel, table,
             params: DetectionParams) -> _Spots:
    """Step 4 on the components of ``box``: compiled when
    :data:`estimator.glints.kernels.ENABLED`; else small boxes as one stack of equal patches,
    the rare large ones pixel by pixel."""
    if glint_kernels.ENABLED:
        return glint_kernels.measure(box, img, top, labels.image, noise, table, params)
    small = ((box.gy1 - box.gy0 <= glint_spots._PATCH_PX)
             & (box.gx1 - box.gx0 <= glint_spots._PATCH_PX))
    if small.all():
        return _measure_patches(box, img, top, labels, noise, table, params)
    patch, pixel = np.flatnonzero(small), np.flatnonzero(~small)
    parts = [_measure_pixels(_gather(box.take(pixel), labels), img, top, noise, table,
                             params)[0]]
    if patch.size:
        parts.insert(0, _measure_patches(box.take(patch), img, top, labels, noise, table,
                                         params))
    return _Spots.concat(parts).take(np.argsort(np.concatenate([patch, pixel])))


def _inner_side(y0, y1, x0, x1, margin: int, roi, frame_shape) -> np.ndarray:
    """(c,) bool: which of the boxes (window coordinates, inclusive ends), grown by
    ``margin``, reach a side of the window ``roi`` that is not the frame's border."""
    r0, r1, c0, c1 = roi
    height, width = frame_shape
    out = np.zeros(np.shape(y0), dtype=bool)
    if r0 > 0:
        out |= y0 <= margin
    if r1 < height:
        out |= y1 + margin >= r1 - r0 - 1
    if c0 > 0:
        out |= x0 <= margin
    if c1 < width:
        out |= x1 + margin >= c1 - c0 - 1
    return out
