"""The optics row of a comparison: the capture's blur beyond its render's, and which flagged
rows that blur explains.

A defocused or soft lens spreads every glint: the glint spots grow, their peaks drop, the
band edges soften (the band fit's rise lengthens: a longer pulse; its phase moves), and more
of a glint's light falls below the detection threshold. Without a row for the optics, each of
these is blamed on what its row measures (timing, sensor, material). So:

1. the spot size: :func:`~.measure.spot_sigma_px` of the glints that capture and render both
   identified (same light, same band); a Gaussian blur of σ adds σ² to its square;
2. the blur is fitted: the σ for which the render, blurred by it, has the capture's spot
   sizes, pair by pair (the median of σ_capture² - σ_render² is 0; bisection; the window's
   truncation biases both alike). Two ways to blur: before the
   sensor (:data:`OPTICS`: the radiance, then the sensor model with the render's own noise
   draws; what a lens does) and after it (:data:`AFTER_SENSOR`: the render's frames; an image
   processing step, or frames blurred after the fact, which smooths the noise too);
3. every row is measured again against each blurred render, tracked again; the way that
   explains more flagged rows is kept, and when the blur row itself is flagged, each flagged
   row that passes against that blurred render, or keeps at most :data:`EXPLAINED_SHARE` of
   its difference, is blamed on the optics, its note saying what is left;
4. the timing rows are measured on the capture alone (against the scene's timing), so the
   blur's bias on them is that of the band fit (:func:`~estimator.capture.timing.
   measure_frame`) on the scene's band profile blurred by σ along the columns
   (:func:`blur_timing_bias_lines`): the ramps lengthen (the pulse, the shorter of pulse and
   exposure, grows: +1.37 rows for 2.42-row ramps blurred by 1.2 px) and the onset moves
   earlier. A symmetric blur leaves each band's centre φ + (a + b)/2 in place, so the phase
   row is the blur's when the measured band centre, Δφ + (Δa + Δb)/2 of the phase, pulse and
   exposure rows, is within the phase's tolerance. (The bias was once taken as the change
   from the render to the blurred render; but the render is made at the capture's measured,
   already blurred timing, whose longer ramps a blur lengthens less: +0.64 rows measured on
   a 320x240 capture blurred by 1.2 px, where the capture's pulse read +1.18 rows.)
"""

from __future__ import annotations

import math

import numpy as np

from .measure import measure_image, spot_sigma_px
from .verdict import TOL

__all__ = ["OPTICS", "AFTER_SENSOR", "BLUR_MAX_PX", "blur_kernel", "blur_timing_bias_lines",
           "optics_verdict"]

OPTICS, AFTER_SENSOR = "before the sensor (optics)", "after the sensor"
#: Largest blur σ fitted (px), and bisection steps (6 px / 2^10 = 0.006 px).
BLUR_MAX_PX, BLUR_STEPS = 6.0, 10
#: A flagged row is the blur's when, against the blurred render, it passes or keeps at most
#: this share of its difference: the blur is then the larger part of it. Measured on paper_sim
#: 640x480 frames blurred by 1.2 px after the sensor: clutter +13.3 a frame against the sharp
#: render, +4.7 against the blurred one (the tolerance is 4; clutter differs by up to 2.7
#: between a capture and its render from the noise draws alone). Clutter is the fragile one:
#: on today's 3-frame 640x480 capture (+21 a frame sharp) it reads +13.7, +8.3 and +14.7
#: against renders blurred by 1.22, 1.24 and 1.29 px, on either side of this share.
EXPLAINED_SHARE = 0.5
#: The timing rows a blur biases (:func:`blur_timing_bias_lines`).
EXPOSURE, PULSE, PHASE = "exposure (us)", "pulse (us)", "strobe phase (us)"
#: Pitches of the synthetic band profile the blur's timing bias is fitted on (the ends,
#: where the blur meets the profile's edge, are left out of the fit).
BIAS_PITCHES = 12


def blur_kernel(sigma_px: float) -> np.ndarray:
    """(2 R + 1,) a sampled Gaussian whose variance is exactly σ²: its width parameter s is
    σ where sampling keeps the variance (σ above ~0.6 px: there it is ``cv2.GaussianBlur``'s
    kernel, to 1e-6), and widened below, where a sampled Gaussian's variance falls short of s²
    (at s = 0.2 px its 3 taps are ~[0, 1, 0], variance 1e-5).

    With ``cv2.GaussianBlur`` itself, the fitted blur of an unperturbed 320x240 capture, whose
    spots have a few hundredths of a px² more variance than its render's, overshot to 0.30 px
    (the pairs' quadrature reads 0.07); the discrete Gaussian of Lindeberg (1990), also of
    variance exactly σ², has heavier tails than the frames' 7 px window holds and read a
    capture blurred by cv2's 1.2 px kernel as 1.29 px at 640x480 (1.24 with this one)."""
    t = float(sigma_px) ** 2
    r = int(math.ceil(4 * sigma_px)) + 2
    n = np.arange(-r, r + 1, dtype=np.float64)

    def var(s):
        k = np.exp(-0.5 * (n / s) ** 2)
        return float((k * n * n).sum() / k.sum())

    lo, hi = 1e-3, float(sigma_px) + 1.0  # var() grows with s from ~0 past σ²
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if var(mid) < t else (lo, mid)
    k = np.exp(-0.5 * (n / (0.5 * (lo + hi))) ** 2)
    return k / k.sum()


def _blur(img, sigma):
    import cv2

    img = np.asarray(img, dtype=np.float64)
    if not sigma > 0:
        return img
    k = blur_kernel(sigma)
    return cv2.sepFilter2D(img, cv2.CV_64F, k, k, borderType=cv2.BORDER_REFLECT)


def _blurred(way, sigma, radiance, renders, est, seed, full_dn):
    if way == OPTICS:
        return {f: est.apply(_blur(radiance[f], sigma), np.random.SeedSequence([seed, 0x5CE7, f]))
                for f in radiance}
    return {f: np.clip(np.rint(_blur(renders[f], sigma)), 0, full_dn).astype(renders[f].dtype)
            for f in renders}


def _excess(images, positions, cap) -> float:
    """Median over the pairs of σ_capture² - σ_render² (px²) with the render ``images``."""
    if not positions:
        return math.nan
    s = np.concatenate([spot_sigma_px(images[f], positions[f]) for f in sorted(positions)])
    c = np.concatenate([cap[f] for f in sorted(positions)])
    ok = np.isfinite(s) & np.isfinite(c)
    return float(np.median(c[ok] ** 2 - s[ok] ** 2)) if ok.any() else math.nan


def _fit_sigma(way, positions, cap, radiance, renders, est, seed, full_dn) -> float:
    """The blur σ (px) for which the render's spots, pair by pair, are the capture's: the
    median of σ_capture² - σ_render² is 0 (0 if it is not positive unblurred).

    Pair by pair, as the blur row's quadrature (:func:`~.rows.extra_blur_px`): the median
    spot sizes of capture and render, taken over different subsets (a spot measured in one
    and not the other where a detection lies near it), read +0.35-0.40 px of blur on
    unperturbed captures whose pairs read +0.07."""
    def excess(sigma):
        return _excess(_blurred(way, sigma, radiance, renders, est, seed, full_dn), positions,
                       cap)

    if not excess(0.0) > 0:
        return 0.0
    lo, hi = 0.0, BLUR_MAX_PX
    for _ in range(BLUR_STEPS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) > 0 else (lo, mid)
    return 0.5 * (lo + hi)


def _pairs(cm, rm, camera):
    """Per frame, the raw (sensor) positions of the render's glints that the capture
    identified too, both spots measured (:func:`~.measure.spot_sigma_px`: isolated from
    every detection), and the capture's spot sizes there."""
    positions, cap = {}, {}
    for f in rm:
        keys = [k for k in sorted(set(cm[f].identified) & set(rm[f].identified))
                if math.isfinite(cm[f].identified[k][5]) and math.isfinite(rm[f].identified[k][5])]
        if not keys:
            continue
        uv = np.array([rm[f].identified[k][:2] for k in keys])
        positions[f] = camera.distort_px(uv)
        cap[f] = np.array([cm[f].identified[k][5] for k in keys])
    return positions, cap


def blur_timing_bias_lines(setup, sigma_px: float) -> dict:
    """What a Gaussian blur of ``sigma_px`` (along the columns) does to the band fit of
    ``setup``'s timing: ``{row quantity: bias (lines)}`` for the exposure, pulse and phase
    rows (module docstring, step 4).

    The scene's band profile Σ_j w(y - j p; a, b) (Eqs. (2)-(7),
    :func:`~estimator.capture.timing.band_profile_model`) is blurred and fitted again by least
    squares with the pitch held; the biases are the fitted ramp a, width b and onset φ less
    the scene's (a is the pulse when it is the shorter, b the exposure).
    """
    from scipy.ndimage import gaussian_filter1d
    from scipy.optimize import least_squares

    from estimator.capture.timing import band_profile_model

    sensor, strobe = setup.sensor, setup.strobe
    lines = sensor.total_lines / sensor.frame_period_s  # per second
    p = strobe.period_s * lines
    a, b = sorted((strobe.pulse_s * lines, sensor.exposure_s * lines))
    y = np.arange(0.0, BIAS_PITCHES * p)
    q = band_profile_model(y, p, 2 * p, a, b)
    if sigma_px > 0:
        q = gaussian_filter1d(q, float(sigma_px), mode="nearest")
    inner = (y >= p) & (y < (BIAS_PITCHES - 1) * p)

    def resid(x):
        return x[3] * band_profile_model(y[inner], p, x[0], x[1], x[2]) - q[inner]

    fit = least_squares(resid, [2 * p, a, b, 1.0], bounds=([p, 0.05, 0.05, 0.0],
                                                          [3 * p, 2 * p, 3 * p, np.inf]))
    d_phase, d_a, d_b = fit.x[0] - 2 * p, fit.x[1] - a, fit.x[2] - b
    pulse_first = strobe.pulse_s <= sensor.exposure_s
    return {EXPOSURE: float(d_b if pulse_first else d_a),
            PULSE: float(d_a if pulse_first else d_b), PHASE: float(d_phase)}


def _timing_explained(rows, bias) -> dict:
    """{quantity: what is left} of the flagged timing rows the blur explains (step 4)."""
    out, by = {}, {r.quantity: r for r in rows}
    for q in (EXPOSURE, PULSE):
        r = by.get(q)
        if r is not None and not r.passed and r.cause != "optics":
            d = r.difference - bias[q]
            if math.isfinite(d) and abs(d) <= r.tolerance:
                out[q] = d
    r = by.get(PHASE)
    if r is not None and not r.passed and r.cause != "optics" and EXPOSURE in by \
            and PULSE in by:
        d = r.difference + 0.5 * (by[EXPOSURE].difference + by[PULSE].difference)
        if math.isfinite(d) and abs(d) <= r.tolerance:
            out[PHASE] = d
    return out


def _explained(rows, rows_b, bias) -> dict:
    """{quantity: difference against the blurred render} of the flagged rows it explains."""
    out = _timing_explained(rows, bias)
    again = {r.quantity: r for r in rows_b}
    for r in rows:
        if r.passed or r.cause == "optics" or r.quantity in (EXPOSURE, PULSE, PHASE):
            continue
        if r.quantity in again:
            d = again[r.quantity].difference
            if again[r.quantity].passed or (math.isfinite(d) and math.isfinite(r.difference)
                                            and abs(d) <= EXPLAINED_SHARE * abs(r.difference)):
                out[r.quantity] = d
    return out


def optics_verdict(rows, findings, rows_again, msetup, cm, rm, track, radiance, renders, est,
                   seed, black_dn, setup):
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
    setup : Setup
        The scene (its timing: the timing rows' reference).
    """
    full = float(2 ** msetup.sensor.bit_depth - 1)
    positions, cap = _pairs(cm, rm, msetup.camera)
    blur = next(r for r in rows if r.quantity.startswith("glint spot size"))
    quad = blur.difference
    tol = TOL["blur"].value
    sigmas = {OPTICS: _fit_sigma(OPTICS, positions, cap, radiance, renders, est, seed, full)}
    # Within tolerance (an unperturbed capture) nothing is blamed on the blur: the blurred
    # renders are not tracked and measured again.
    ways = (OPTICS, AFTER_SENSOR) if sigmas[OPTICS] > tol else ()
    best = (OPTICS, sigmas[OPTICS], {})
    for way in ways:
        sigma = sigmas.get(way)
        if sigma is None:
            sigma = _fit_sigma(way, positions, cap, radiance, renders, est, seed, full)
        imgs = _blurred(way, sigma, radiance, renders, est, seed, full)
        samples = track(imgs)
        rm_b = {f: measure_image(msetup, imgs[f], f,
                                 [s for s in samples if s.frame_index == f], black_dn)
                for f in imgs}
        explained = _explained(rows, rows_again(rm_b), blur_timing_bias_lines(setup, sigma))
        if len(explained) > len(best[2]) or (way == OPTICS and not best[2]):
            best = (way, sigma, explained)
    way, sigma, explained = best
    # The row's difference is the fitted blur (the pairs' quadrature where the capture's
    # spots are the smaller: a render blurrier than the capture).
    diff = sigma if sigma > 0 else (quad if math.isfinite(quad) and quad < 0 else 0.0)
    if not positions:
        diff = math.nan
    blur.difference = diff
    blur.passed = math.isfinite(diff) and abs(diff) <= tol
    blur.cause = "" if blur.passed else "optics"
    blur.note = (f"{blur.note}; blur fitted {way}: the render blurred by {sigma:.2f} px has the "
                 f"capture's spot sizes (unblurred, the pairs' quadrature {quad:+.2f} px)")
    findings.update({"extra_blur_px": diff, "blur_way": way,
                     "explained_by_blur": sorted(explained) if not blur.passed else []})
    if not blur.passed and sigma > 0:
        for r in rows:
            if r.quantity in explained:
                r.note = (f"{r.note}; " if r.note else "") + (
                    f"blamed on the optics: {explained[r.quantity]:+.3g} {r.unit} left once "
                    f"a blur of {sigma:.2f} px ({way}) is accounted for, was {r.cause}")
                r.cause = "optics"
    return rows, findings
