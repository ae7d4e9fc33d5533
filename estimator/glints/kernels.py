"""Steps 2-6 of :mod:`estimator.glints.detector` after the top-hat, compiled with Numba (optional): the
exact threshold and the connected components (:func:`components`), each component's centroid,
shape and light (:func:`measure`), and the filters, strobe, time and flags of the spots that
pass (:func:`finish`), one call each, and in between the split of every elongated spot into
its separated maxima (:func:`deblend`, :func:`estimator.glints.spots._deblend` in one call;
Monte Carlo clutter of a 4-spp render makes ~20 elongated spots a frame, 2.2 of its 3 ms in
numpy, the prototype's 16-spp renders ~120).

Without Numba (``pip install scet`` without the ``fast`` extra, a platform with no Numba wheel,
or ``NUMBA_DISABLE_JIT=1``) the detector runs its numpy and OpenCV path
(:mod:`estimator.glints.spots`, :func:`estimator.glints.detector._finish`): the estimator needs nothing
beyond numpy, scipy and OpenCV. Both give the same detections (tested to 1e-9 px and equal
flags, strobes and times); the numpy path runs at about half the frame rate, its cost being
the overhead of ~300 numpy calls per frame on a few hundred pixels, not the pixels.

:data:`ENABLED` says which path runs; tests and the benchmark set it to False to run the numpy
path. The kernels are compiled on first use per frame type (8-bit, 16-bit, float; whole frame
or window), ~7 s for a 16-bit stream, and cached next to this file (``__pycache__``, or
Numba's user-wide cache when that is read-only), so once per installation.
"""

from __future__ import annotations

import logging
import math
import threading

import numpy as np

from ..banding import NO_PULSE, strobe_instant

try:
    import numba
    from numba.core import types
    from numba.extending import overload
except ImportError:  # the numpy path of estimator.glints.spots runs instead
    numba = None

#: Whether :mod:`estimator.glints` uses these kernels: Numba imports and its JIT is on
#: (``NUMBA_DISABLE_JIT=1`` would run them as Python, far slower than the numpy path).
ENABLED = numba is not None and not numba.config.DISABLE_JIT
if not ENABLED:
    logging.getLogger(__name__).info(
        "glint detection runs its numpy path (about half the frame rate): %s",
        "Numba is not installed (pip install 'scet[fast]')" if numba is None
        else "NUMBA_DISABLE_JIT is set")


def _noise_at(raw, t, tables, levels, floors, sigmas, threshold_nodes, slope, c, k):
    """At one pixel of value ``raw`` and top-hat ``t`` (background level L = raw - t), the
    noise model of :class:`estimator.glints.noise._NoiseModel`: the top-hat's floor, floor +
    c σ and the threshold floor + k σ. Integer frames look them up in ``tables`` (3, levels),
    float ones interpolate the model in float64, as the numpy path does. The last value is
    the level L when the tables stop short of it, -1 otherwise (always on float frames).
    Compiled only (dispatched on the pixel's type)."""
    raise NotImplementedError("compiled only")


if numba is not None:

    @overload(_noise_at)
    def _noise_at_typed(raw, t, tables, levels, floors, sigmas, threshold_nodes, slope, c, k):
        if isinstance(raw, types.Integer):
            def lookup(raw, t, tables, levels, floors, sigmas, threshold_nodes, slope, c, k):
                level = np.int64(raw) - np.int64(t)
                if level >= tables.shape[1]:
                    return 0.0, 0.0, 0.0, level
                return tables[0, level], tables[1, level], tables[2, level], np.int64(-1)
            return lookup

        def interpolate(raw, t, tables, levels, floors, sigmas, threshold_nodes, slope, c, k):
            level = np.float64(raw) - np.float64(t)
            floor = np.interp(level, levels, floors)
            extra = slope * max(level - levels[-1], 0.0) if slope != 0.0 else 0.0
            sigma = np.interp(level, levels, sigmas) + extra
            threshold = np.interp(level, levels, threshold_nodes) + k * extra
            return floor, floor + c * sigma, threshold, np.int64(-1)
        return interpolate

    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _strobe_instant = _jit(strobe_instant)

    @_jit
    def _root(parent, i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    @_jit
    def _union(parent, a, b):
        ra, rb = _root(parent, a), _root(parent, b)
        if ra < rb:
            parent[rb] = ra
        elif rb < ra:
            parent[ra] = rb

    @_jit
    def _components_kernel(image, idx, top, img, tables, levels, floors, sigmas,
                           threshold_nodes, slope, c, k):
        height, width = top.shape
        # Step 2's exact test on the candidates (top-hat above the lowest threshold).
        rows = np.empty(idx.size, np.int64)
        cols = np.empty(idx.size, np.int64)
        n, short = 0, np.int64(-1)
        for i in range(idx.size):
            y, x = idx[i] // width, idx[i] % width
            t = top[y, x]
            threshold, need = _noise_at(img[y, x], t, tables, levels, floors, sigmas,
                                        threshold_nodes, slope, c, k)[2:]
            if need >= 0:
                short = max(short, need)
            elif np.float64(t) > threshold:
                rows[n], cols[n] = y, x
                n += 1
        if short >= 0:
            n = 0
        # Step 3: union-find over the pixels in raster order.
        parent = np.empty(n, np.int64)
        for i in range(n):
            y, x = rows[i], cols[i]
            parent[i] = i
            image[y, x] = i + 1
            if x > 0 and image[y, x - 1] != 0:
                _union(parent, i, image[y, x - 1] - 1)
            if y > 0:
                for xx in range(max(x - 1, 0), min(x + 2, width)):
                    if image[y - 1, xx] != 0:
                        _union(parent, i, image[y - 1, xx] - 1)
        # Roots are each component's first pixel (unions keep the smaller index): labels
        # 1, 2, ... in the order of the components' first pixels, row by row.
        label_of = np.zeros(n, np.int32)
        count = 0
        for i in range(n):
            r = _root(parent, i)
            if label_of[r] == 0:
                count += 1
                label_of[r] = count
            label_of[i] = label_of[r]
        area = np.zeros(count, np.int64)
        y0 = np.empty(count, np.int64)
        y1 = np.empty(count, np.int64)
        x0 = np.full(count, width, np.int64)
        x1 = np.full(count, -1, np.int64)
        for i in range(n):
            s = label_of[i] - 1
            y, x = rows[i], cols[i]
            image[y, x] = s + 1
            if area[s] == 0:
                y0[s] = y
            area[s] += 1
            y1[s] = y
            x0[s] = min(x0[s], x)
            x1[s] = max(x1[s], x)
        return short, rows[:n], cols[:n], area, y0, y1, x0, x1

    @_jit
    def _measure_kernel(img, top, labels, ids, gy0, gy1, gx0, gx1, tables, levels, floors,
                        sigmas, threshold_nodes, slope, c, k, gain, dominant, pulse_weights):
        height, width = top.shape
        n = ids.size
        u = np.empty(n)
        v = np.empty(n)
        flux = np.empty(n)
        elong = np.empty(n)
        neighbour = np.empty(n)
        raw_peak = np.zeros(n)
        dom = np.empty(n, np.int64)
        light = np.zeros((4, n))
        row_light = np.empty(int((gy1 - gy0).max()) if n else 0)
        short = np.int64(-1)
        for s in range(n):
            own_id = ids[s]
            sw = swx = swy = 0.0  # usable pixels: own and background
            ow = owx = owy = owxx = owyy = owxy = 0.0  # own pixels
            peak, py, px = -np.inf, gy0[s], gx0[s]
            for yy in range(gy0[s], gy1[s]):
                g = gain[yy + 1]
                y = np.float64(yy - gy0[s])
                lit = 0.0
                for xx in range(gx0[s], gx1[s]):
                    lab = labels[yy, xx]
                    own = lab == own_id
                    if not own and lab != 0:
                        continue  # another component's pixel
                    raw, t = img[yy, xx], top[yy, xx]
                    floor, centroid_floor, _, need = _noise_at(
                        raw, t, tables, levels, floors, sigmas, threshold_nodes, slope, c, k)
                    if need >= 0:
                        short = max(short, need)
                        continue
                    value = np.float64(t) - floor
                    w = max(np.float64(t) - centroid_floor, 0.0) * g
                    x = np.float64(xx - gx0[s])
                    sw += w
                    swx += w * x
                    swy += w * y
                    if own:
                        ow += w
                        owx += w * x
                        owy += w * y
                        owxx += w * x * x
                        owyy += w * y * y
                        owxy += w * x * y
                        if value > peak:  # the first of the maxima, row by row
                            peak, py, px = value, yy, xx
                        if np.float64(raw) > raw_peak[s]:
                            raw_peak[s] = np.float64(raw)
                    if value > 0.0:
                        lit += value
                row_light[yy - gy0[s]] = lit * g
            # As glint_spots._shape: the centroid over usable pixels, the shape over own ones.
            den = sw if sw > 0.0 else 1.0
            u[s] = swx / den + gx0[s]
            v[s] = swy / den + gy0[s]
            flux[s] = sw
            den = ow if ow > 0.0 else 1.0
            mx, my = owx / den, owy / den
            sxx, syy, sxy = owxx / den - mx * mx, owyy / den - my * my, owxy / den - mx * my
            half_tr = 0.5 * (sxx + syy)
            disc = math.hypot(0.5 * (sxx - syy), sxy)
            elong[s] = math.sqrt((half_tr + disc + 1 / 12) / (max(half_tr - disc, 0.0) + 1 / 12))
            # As glint_spots._neighbour_ratio: the brightest 4-neighbour of the peak over it.
            nb = max(top[max(py - 1, 0), px], top[min(py + 1, height - 1), px],
                     top[py, max(px - 1, 0)], top[py, min(px + 1, width - 1)])
            floor_at_peak = np.float64(top[py, px]) - peak
            neighbour[s] = (np.float64(nb) - floor_at_peak) / (peak if peak > 0.0 else 1.0)
            d = dominant[int(np.rint(v[s])) + 1]
            dom[s] = d
            for r in range(gy1[s] - gy0[s]):
                lit = row_light[r]
                light[0, s] += lit
                for j in range(3):
                    light[1 + j, s] += lit * pulse_weights[gy0[s] + r + 1, d - 1 + j]
        return short, (u, v, flux, elong, neighbour, raw_peak, dom, light)


    @_jit
    def _finish_kernel(u, v, flux, elong, neighbour, raw_peak, dom, light, area, row0, row1,
                       edge, blended, replaced, local_index, below, m_off, phase_s, period_s,
                       pulse_s, full_scale, max_elongation, min_neighbour_ratio,
                       two_pulse_share, no_pulse, flag_bits):
        saturated_bit, cut_bit, two_bit, edge_bit, no_band_bit, blended_bit = flag_bits
        good = np.empty(u.size, np.int64)
        n = 0
        for s in range(u.size):
            saturated = raw_peak[s] >= full_scale
            if (not replaced[s] and flux[s] > 0 and elong[s] <= max_elongation
                    and (neighbour[s] >= min_neighbour_ratio or saturated)):
                good[n] = s
                n += 1
        # By row, stably: an insertion sort, linear here (the components come in the order of
        # their first rows, so their centroids are nearly sorted already).
        sel = good[:n]
        for i in range(1, n):
            s, j = sel[i], i
            while j > 0 and v[sel[j - 1]] > v[s]:
                sel[j] = sel[j - 1]
                j -= 1
            sel[j] = s
        out_peak = np.empty(n)
        strobe = np.empty(n, np.int64)
        time_s = np.empty(n)
        flags = np.zeros(n, np.int64)
        for i in range(n):
            s = sel[i]
            out_peak[i] = raw_peak[s]
            # Step 6: the shares of the pulses dom - 1, dom, dom + 1; the largest (the first
            # of equal ones) names the strobe, the second largest flags two pulses.
            total = light[0, s] if light[0, s] > 0 else 1.0
            best, second, arg = -np.inf, -np.inf, 0
            for j in range(3):
                share = light[1 + j, s] / total
                if share > best:
                    best, second, arg = share, best, j
                elif share > second:
                    second = share
            lit = best > 0
            col = dom[s] + arg - 1
            if lit:
                strobe[i] = local_index[col - 1] - m_off
                time_s[i] = _strobe_instant(phase_s + strobe[i] * period_s, pulse_s)
                if below[row1[s] + 3, col] > below[row0[s], col]:
                    flags[i] |= cut_bit
                if second >= two_pulse_share:
                    flags[i] |= two_bit
            else:
                strobe[i] = no_pulse
                time_s[i] = np.nan
                flags[i] |= no_band_bit
            if out_peak[i] >= full_scale:
                flags[i] |= saturated_bit
            if edge[s]:
                flags[i] |= edge_bit
            if blended[s]:
                flags[i] |= blended_bit
        return (u[sel], v[sel], flux[sel], area[sel], out_peak, strobe, time_s, flags)

    @_jit
    def _blend_maxima_kernel(ys, xs, own, val, top, max_blend, blend_saddle):
        """:func:`estimator.glints.spots._blend_maxima`, element by element in its order."""
        h, w = top.shape
        n = ys.size
        diff = np.empty(n)
        for i in range(n):
            diff[i] = float(top[ys[i], xs[i]]) - val[i]
        floor = np.median(diff)
        cand = np.empty(n, dtype=np.int64)
        m = 0
        for i in range(n):
            if not own[i]:
                continue
            nb = -math.inf
            for dy in (-1, 0, 1):
                y = min(max(ys[i] + dy, 0), h - 1)
                for dx in (-1, 0, 1):
                    if dy != 0 or dx != 0:
                        x = min(max(xs[i] + dx, 0), w - 1)
                        nb = max(nb, float(top[y, x]) - floor)
            if val[i] > nb:
                cand[m] = i
                m += 1
        if not 2 <= m <= max_blend:
            return cand[:0]
        for a in range(m):
            ya, xa = float(ys[cand[a]]), float(xs[cand[a]])
            for b in range(a + 1, m):
                yb, xb = float(ys[cand[b]]), float(xs[cand[b]])
                num = 2 + 2 * int(math.hypot(ya - yb, xa - xb))
                step = 1.0 / (num - 1)
                saddle = math.inf
                for i in range(num):
                    t = 1.0 if i == num - 1 else i * step + 0.0
                    ly = int(np.rint(ya + t * (yb - ya)))
                    lx = int(np.rint(xa + t * (xb - xa)))
                    saddle = min(saddle, float(top[ly, lx]))
                if not saddle - floor < blend_saddle * min(val[cand[a]], val[cand[b]]):
                    return cand[:0]
        return cand[:m].copy()


    @_jit
    def _deblend_kernel(starts, ys, xs, own, val, top, max_blend, blend_saddle):
        """:func:`estimator.glints.spots._deblend`'s loop over the spots: each spot's separated
        maxima (:func:`_blend_maxima_kernel`) and every pixel of a split spot given to its
        nearest maximum (squared distance, the first on a tie: numpy's argmin). Returns the
        number of maxima of each spot (n,) (0: not split) and each pixel's part (q,): the
        index of its (spot, maximum) pair over the split spots in order, -1 where its spot
        does not split."""
        q, n = ys.size, starts.size
        parts = np.zeros(n, dtype=np.int64)
        part = np.full(q, -1, dtype=np.int64)
        first = 0
        for s in range(n):
            a = starts[s]
            b = starts[s + 1] if s + 1 < n else q
            cand = _blend_maxima_kernel(ys[a:b], xs[a:b], own[a:b], val[a:b], top, max_blend,
                                        blend_saddle)
            m = cand.size
            if m == 0:
                continue
            parts[s] = m
            for i in range(a, b):
                best, kbest = math.inf, 0
                for k in range(m):
                    dy = float(ys[i]) - float(ys[a + cand[k]])
                    dx = float(xs[i]) - float(xs[a + cand[k]])
                    d = dy * dy + dx * dx
                    if d < best:
                        best, kbest = d, k
                part[i] = first + kbest
            first += m
        return parts, part


def deblend(px, value, top, params):
    """:func:`estimator.glints.spots._deblend` over every spot of ``px`` in one compiled call
    (the Python loop cost ~20 us a spot, and the clutter of a prototype render makes ~120
    elongated spots a frame): the same pixels in the same order, the same spots split.
    Returns the new spots' pixels (:class:`estimator.glints.spots._Pixels`) and the indices
    (s,) of the spots split, or (None, []) when none splits."""
    from .spots import _Pixels

    parts, part = _deblend_kernel(px.starts, px.ys, px.xs, px.own,
                                  np.asarray(value, dtype=np.float64), top,
                                  int(params.max_blend), float(params.blend_saddle))
    split = np.flatnonzero(parts)
    if split.size == 0:
        return None, []
    n = int(parts.sum())
    mine = np.flatnonzero(part >= 0)
    order = mine[np.argsort(part[mine], kind="stable")]  # part after part, pixel order kept
    pid = part[order]
    counts = np.bincount(pid, minlength=n)
    starts = np.zeros(n, dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    ys, own = px.ys[order], px.own[order]
    # Every part holds its own maximum, an own pixel: each part's own rows are non-empty.
    own_pid, own_ys = pid[own], ys[own]
    at = np.searchsorted(own_pid, np.arange(n))
    return _Pixels(n, np.repeat(np.arange(n), counts), starts, ys, px.xs[order], own,
                   px.usable[order], np.minimum.reduceat(own_ys, at),
                   np.maximum.reduceat(own_ys, at), np.repeat(px.edge[split], parts[split])), split


def blend_maxima(ys, xs, own, val, top, params) -> np.ndarray:
    """:func:`estimator.glints.spots._blend_maxima`, compiled (an elongated spot's separated
    maxima; ~100 us a spot in numpy, and Monte Carlo clutter in a 4-spp render makes ~20
    elongated spots a frame)."""
    return _blend_maxima_kernel(ys, xs, own, np.asarray(val, dtype=np.float64), top,
                                int(params.max_blend), float(params.blend_saddle))


def _model(img: np.ndarray, noise, params, top_level: int):
    """The noise model's arguments of the kernels: integer frames get the tables up to at
    least ``top_level``, float ones the model's nodes."""
    if img.dtype.kind == "u":  # the nodes are not read
        tables, nodes = noise.tables(top_level, params.centroid_floor_sigma), noise.floors
    else:
        tables, nodes = np.zeros((3, 0)), noise.floors + noise.k * noise.sigmas
    return (tables, noise.levels, noise.floors, noise.sigmas, nodes, float(noise.slope),
            float(params.centroid_floor_sigma), float(noise.k))


_scratch = threading.local()


def _label_image(height: int, width: int) -> np.ndarray:
    """A zeroed (height, width) int32 label image, a view of one kept per thread: zeroing a
    fresh one costs more than the labelling (1.2 MB at VGA, measured ~60 us), so only the
    pixels the thread's last call labelled are cleared. Valid until the thread's next call."""
    base = getattr(_scratch, "labels", None)
    if base is None or base.shape[0] < height or base.shape[1] < width:
        old = (0, 0) if base is None else base.shape
        base = np.zeros((max(height, old[0]), max(width, old[1])), np.int32)
        _scratch.labels, _scratch.written = base, None
    if _scratch.written is not None:
        view, rows, cols = _scratch.written
        view[rows, cols] = 0
        _scratch.written = None
    return base[:height, :width]


def _with_tables(kernel, img: np.ndarray, noise, params):
    """``kernel(model)`` (its first result: the largest level the tables miss, -1 when none)
    with the model's arguments (:func:`_model`), the integer tables grown until they reach
    every level the kernel meets. Returns the kernel's other results."""
    top_level = 255
    while True:
        short, *out = kernel(_model(img, noise, params, top_level))
        if short < 0:
            return out
        top_level = int(short)


def components(idx: np.ndarray, top: np.ndarray, img: np.ndarray, noise, params):
    """Steps 2 (the exact threshold) and 3 on the flat indices ``idx`` of the pixels whose
    top-hat exceeds the noise model's lowest threshold (sorted). Returns the (height, width)
    int32 label image (0: background; a view valid until this thread's next call) and, per
    component (labelled 1, 2, ... in the order of their first pixels, row by row), its area
    and inclusive box y0, y1, x0, x1."""
    image = _label_image(*top.shape)  # a kernel that misses a level labels nothing
    rows, cols, *found = _with_tables(
        lambda model: _components_kernel(image, idx, top, img, *model), img, noise, params)
    _scratch.written = (image, rows, cols)
    return image, *found


def measure(box, img, top, labels: np.ndarray, noise, table, params):
    """What :func:`estimator.glints.spots._measure_pixels` measures on the components of
    ``box`` (a ``glint_spots._Boxes``), as a ``glint_spots._Spots``."""
    from .spots import _Spots

    spots, = _with_tables(
        lambda model: _measure_kernel(img, top, labels, box.ids, box.gy0, box.gy1, box.gx0,
                                      box.gx1, *model, table.gain, table.dominant,
                                      table.weights), img, noise, params)
    return _Spots(*spots)


def finish(spots, area, row0, row1, edge, blended, replaced, table, m_off: int, strobe,
           full_scale: float, params):
    """:func:`estimator.glints.detector._finish`, compiled: the same arrays."""
    from .params import BLENDED, CUT_BY_BAND_EDGE, IMAGE_EDGE, NO_BAND, SATURATED, TWO_PULSES

    return _finish_kernel(
        *(getattr(spots, name) for name in spots.__slots__), area, row0, row1, edge, blended,
        replaced, table.local_index, table.below_plateau, int(m_off), float(strobe.phase_s),
        float(strobe.period_s), float(strobe.pulse_s), float(full_scale),
        float(params.max_elongation), float(params.min_neighbour_ratio),
        float(params.two_pulse_share), int(NO_PULSE),
        (SATURATED, CUT_BY_BAND_EDGE, TWO_PULSES, IMAGE_EDGE, NO_BAND, BLENDED))
