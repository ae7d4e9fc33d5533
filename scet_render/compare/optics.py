"""The optics row of a comparison: the capture's blur beyond its render's, and which flagged
rows that blur explains.

A defocused or soft lens spreads every glint: the glint spots grow, their peaks drop, the
band edges soften (the band fit's rise lengthens: a longer pulse; its phase moves), and more
of a glint's light falls below the detection threshold. Without a row for the optics, each of
these is blamed on what its row measures (timing, sensor, material). So:

1. the spot size: :func:`~.measure.spot_sigma_px` of the glints that capture and render both
   identified (same light, same band); a Gaussian blur of σ adds σ² to its square;
2. the blur is fitted: the σ for which the render, blurred by it, has the capture's median spot
   size (bisection; the window's truncation biases both alike). Two ways to blur: before the
   sensor (:data:`OPTICS`: the radiance, then the sensor model with the render's own noise
   draws; what a lens does) and after it (:data:`AFTER_SENSOR`: the render's frames; an image
   processing step, or frames blurred after the fact, which smooths the noise too);
3. every row is measured again against each blurred render, tracked again (timing rows: the
   band fits' change from render to blurred render is the blur's bias on the timing
   measurement); the
   way that explains more flagged rows is kept, and when the blur row itself is flagged, each
   flagged row that passes against that blurred render, or keeps at most
   :data:`EXPLAINED_SHARE` of its difference, is blamed on the optics, its note saying what
   is left.
"""

from __future__ import annotations

import math

import numpy as np

from .measure import measure_image, spot_sigma_px
from .verdict import TOL

__all__ = ["OPTICS", "AFTER_SENSOR", "BLUR_MAX_PX", "optics_verdict"]

OPTICS, AFTER_SENSOR = "before the sensor (optics)", "after the sensor"
#: Largest blur σ fitted (px), and bisection steps (6 px / 2^10 = 0.006 px).
BLUR_MAX_PX, BLUR_STEPS = 6.0, 10
#: A flagged row is the blur's when, against the blurred render, it passes or keeps at most
#: this share of its difference: the blur is then the larger part of it. Measured on paper_sim
#: 640x480 frames blurred by 1.2 px after the sensor: clutter +13.3 a frame against the sharp
#: render, +4.7 against the blurred one (the tolerance is 4; clutter differs by up to 2.7
#: between a capture and its render from the noise draws alone).
EXPLAINED_SHARE = 0.5
#: Timing rows and the band-fit quantity (FrameBands attribute) whose change a blur causes.
TIMING_BIAS = {"exposure (us)": "width_rows", "pulse (us)": "rise_rows",
               "strobe phase (us)": "phase_rows"}


def _blur(img, sigma):
    import cv2

    return cv2.GaussianBlur(np.asarray(img, dtype=np.float64), (0, 0), sigma) if sigma > 0 \
        else np.asarray(img, dtype=np.float64)


def _blurred(way, sigma, radiance, renders, est, seed, full_dn):
    if way == OPTICS:
        return {f: est.apply(_blur(radiance[f], sigma), np.random.SeedSequence([seed, 0x5CE7, f]))
                for f in radiance}
    return {f: np.clip(np.rint(_blur(renders[f], sigma)), 0, full_dn).astype(renders[f].dtype)
            for f in renders}


def _spot_median(images, positions) -> float:
    s = np.concatenate([spot_sigma_px(images[f], positions[f]) for f in positions]) \
        if positions else np.zeros(0)
    s = s[np.isfinite(s)]
    return float(np.median(s)) if s.size else math.nan


def _fit_sigma(way, target, positions, radiance, renders, est, seed, full_dn) -> float:
    """The blur σ (px) that gives the render the spot size ``target`` (0 if it has it)."""
    def size(sigma):
        return _spot_median(_blurred(way, sigma, radiance, renders, est, seed, full_dn),
                            positions)

    if not math.isfinite(target) or not size(0.0) < target:
        return 0.0
    lo, hi = 0.0, BLUR_MAX_PX
    for _ in range(BLUR_STEPS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if size(mid) < target else (lo, mid)
    return 0.5 * (lo + hi)


def _pairs(cm, rm, camera):
    """Per frame, the raw (sensor) positions of the render's glints that the capture
    identified too, and the capture's median spot size over them."""
    positions, cap = {}, []
    for f in rm:
        keys = sorted(set(cm[f].identified) & set(rm[f].identified))
        if not keys:
            continue
        uv = np.array([rm[f].identified[k][:2] for k in keys])
        positions[f] = camera.distort_px(uv)
        cap.extend(cm[f].identified[k][5] for k in keys)
    c = np.asarray(cap, dtype=np.float64)
    c = c[np.isfinite(c)]
    return positions, (float(np.median(c)) if c.size else math.nan)


def _bias_lines(rm, rm_b, attr, pitch=None) -> float:
    d = []
    for f in rm:
        a, b = rm[f].bands, rm_b[f].bands
        if a.status == "bands" and b.status == "bands":
            x = getattr(b, attr) - getattr(a, attr)
            if pitch is not None:
                x = (x + a.pitch_rows / 2) % a.pitch_rows - a.pitch_rows / 2
            d.append(x)
    return float(np.median(d)) if d else math.nan


def _explained(rows, rows_b, rm, rm_b) -> dict:
    """{quantity: difference against the blurred render} of the flagged rows it explains."""
    out = {}
    again = {r.quantity: r for r in rows_b}
    for r in rows:
        if r.passed or r.cause == "optics":
            continue
        if r.quantity in TIMING_BIAS:
            attr = TIMING_BIAS[r.quantity]
            bias = _bias_lines(rm, rm_b, attr, pitch=attr == "phase_rows")
            d = r.difference - bias
            if math.isfinite(d) and abs(d) <= r.tolerance:
                out[r.quantity] = d
        elif r.quantity in again:
            d = again[r.quantity].difference
            if again[r.quantity].passed or (math.isfinite(d) and math.isfinite(r.difference)
                                            and abs(d) <= EXPLAINED_SHARE * abs(r.difference)):
                out[r.quantity] = d
    return out


def optics_verdict(rows, findings, rows_again, msetup, cm, rm, track, radiance, renders, est,
                   seed, black_dn):
    """The verdict with its blur row filled in and the rows the blur explains blamed on the
    optics (module docstring).

    Parameters
    ----------
    rows, findings
        From :func:`~.rows.verdict_rows`.
    rows_again : callable
        ``rows_again(rm_blurred)``: the rows measured against other render measures.
    msetup : Setup
        The measured setup the render was made with.
    cm, rm : dict
        Frame measures of the capture and the render.
    track : callable
        ``track(images)``: the tracker's samples on frames {index: image} (the blurred
        render is tracked again, as the capture was: a blur loses glints, whose detections
        then count as clutter).
    radiance, renders : dict
        The render's radiance and its frames (DN).
    est : SensorModel
        The sensor model the render's frames were made with.
    """
    full = float(2 ** msetup.sensor.bit_depth - 1)
    positions, target = _pairs(cm, rm, msetup.camera)
    blur = next(r for r in rows if r.quantity.startswith("glint spot size"))
    quad = blur.difference
    tol = TOL["blur"].value
    sigmas = {OPTICS: _fit_sigma(OPTICS, target, positions, radiance, renders, est, seed, full)}
    # Within tolerance (an unperturbed capture) nothing is blamed on the blur: the blurred
    # renders are not tracked and measured again.
    ways = (OPTICS, AFTER_SENSOR) if sigmas[OPTICS] > tol else ()
    best = (OPTICS, sigmas[OPTICS], {})
    for way in ways:
        sigma = sigmas.get(way)
        if sigma is None:
            sigma = _fit_sigma(way, target, positions, radiance, renders, est, seed, full)
        imgs = _blurred(way, sigma, radiance, renders, est, seed, full)
        samples = track(imgs)
        rm_b = {f: measure_image(msetup, imgs[f], f,
                                 [s for s in samples if s.frame_index == f], black_dn)
                for f in imgs}
        explained = _explained(rows, rows_again(rm_b), rm, rm_b)
        if len(explained) > len(best[2]) or (way == OPTICS and not best[2]):
            best = (way, sigma, explained)
    way, sigma, explained = best
    # The row's difference is the fitted blur (the quadrature of the medians where the capture's
    # spots are the smaller: a render blurrier than the capture).
    diff = sigma if sigma > 0 else (quad if math.isfinite(quad) and quad < 0 else 0.0)
    if not math.isfinite(target):
        diff = math.nan
    blur.difference = diff
    blur.passed = math.isfinite(diff) and abs(diff) <= tol
    blur.cause = "" if blur.passed else "optics"
    blur.note = (f"{blur.note}; blur fitted {way}: the render blurred by {sigma:.2f} px has the "
                 f"capture's spot size (quadrature of the medians {quad:+.2f} px)")
    findings.update({"extra_blur_px": diff, "blur_way": way,
                     "explained_by_blur": sorted(explained) if not blur.passed else []})
    if not blur.passed and sigma > 0:
        for r in rows:
            if r.quantity in explained:
                r.note = (f"{r.note}; " if r.note else "") + (
                    f"blamed on the optics: {explained[r.quantity]:+.3g} {r.unit} left against "
                    f"the render blurred by {sigma:.2f} px ({way}), was {r.cause}")
                r.cause = "optics"
    return rows, findings
