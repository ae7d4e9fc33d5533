"""A sensor's black level, gain and read noise from one frame of its own output.

Photon transfer (Janesick, *Photon Transfer*, SPIE 2007; :mod:`scet_render.render.sensor`):
a pixel that collects mu electrons reads DN = black + (mu + read noise) / K with
K = conversion_gain_e_per_dn / analog_gain (e-/DN), so over a flat patch well below saturation

    var = (read_e / K)^2 + 1/12 + (mean - black) / K + (P (mean - black))^2,     (1)

the last term being Janesick's fixed-pattern term: here every pixel-to-pixel variation that
grows with the signal (a render's Monte Carlo noise: ~28 % of the signal at 4 spp, which
dominates the shot noise above ~10 DN; a real sensor's PRNU, ~1 %).

One frame has no repeated exposures, so the variance of each patch is taken from the
differences of horizontally adjacent pixels (var(x[i+1] - x[i]) / 2): a row of a banded frame
collects the same share of every pulse along its length (Eqs. (2)-(3)), so the bands add no
horizontal variance, and smooth scene texture (skin, sclera) adds little. Patches that hold a
glint or clip are left out. The black level comes from the darkest patches (rows between bands,
the pupil), where (1) has mean - black near zero. K and the read noise follow from a straight
line through the patches' (mean - black, var) pairs, binned by mean and fitted by weighted
least squares (a parabola: read noise, 1/K, P^2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PATCH_PX", "SensorFit", "fit_sensor"]

#: Side of the square patches (px): 64 differences a patch (an SD known to ~9 %), and small
#: enough for a 320x240 frame to give ~1,200 of them.
PATCH_PX = 8
#: Darkest share of patches that gives the black level (rows between bands, the pupil).
DARK_SHARE = 0.02
#: A patch whose brightest pixel passes this multiple of its mean above black holds a glint.
GLINT_FACTOR = 3.0
#: Patches closer than this to full scale (DN) can clip.
CLIP_MARGIN_DN = 40.0
#: Fewest usable patches (and bins) for a photon-transfer line.
MIN_PATCHES, MIN_BINS = 30, 4


@dataclass(frozen=True, slots=True)
class SensorFit:
    """What one frame says about its sensor (NaN where it cannot tell, with ``reason``).

    Attributes
    ----------
    black_level_dn : float
    gain_e_per_dn : float
        K of Eq. (1), e- per DN (the conversion gain over the analogue gain).
    read_noise_e : float
    noise_dn : float
        Median patch noise SD (DN) of the lit patches.
    pattern_share : float
        P of Eq. (1): the signal-proportional noise (Monte Carlo noise of a render).
    patches : int
        Patches on the photon-transfer line.
    mean_dn, var_dn2 : (m,) float
        The binned means above black and variances the line was fitted to.
    reason : str
        "ok", or why K is NaN.
    """

    black_level_dn: float
    gain_e_per_dn: float
    read_noise_e: float
    noise_dn: float
    pattern_share: float
    patches: int
    mean_dn: np.ndarray
    var_dn2: np.ndarray
    reason: str = "ok"


def _patches(img: np.ndarray, side: int):
    H, W = (img.shape[0] // side) * side, (img.shape[1] // side) * side
    blocks = img[:H, :W].reshape(H // side, side, W // side, side).swapaxes(1, 2)
    blocks = blocks.reshape(-1, side, side)
    diff = np.diff(blocks, axis=2)
    return blocks.mean(axis=(1, 2)), blocks.max(axis=(1, 2)), diff.var(axis=(1, 2)) / 2.0


def fit_sensor(image_dn, *, full_scale_dn: float = 1023.0, side: int = PATCH_PX) -> SensorFit:
    """Fit Eq. (1) to one frame (module docstring).

    Parameters
    ----------
    image_dn : (H, W) int or float
        One raw frame in DN, black level included.
    full_scale_dn : float
    side : int
        Patch side, px.
    """
    img = np.asarray(image_dn, dtype=np.float64)
    if img.ndim != 2 or min(img.shape) < 2 * side:
        raise ValueError(f"image_dn must be (H, W) with H, W >= {2 * side}, got {img.shape}")
    mean, peak, var = _patches(img, side)
    order = np.argsort(mean)
    dark = order[:max(3, int(DARK_SHARE * mean.size))]
    black = float(np.median(mean[dark]))
    above = mean - black
    usable = (peak < full_scale_dn - CLIP_MARGIN_DN) & (above > 2.0) \
        & (peak - black < GLINT_FACTOR * np.maximum(above, 1.0) + 6.0 * np.sqrt(var))
    noise = float(np.median(np.sqrt(var[usable]))) if usable.any() else math.nan
    empty = np.zeros(0)
    if usable.sum() < MIN_PATCHES:
        return SensorFit(black, math.nan, math.nan, noise, math.nan, int(usable.sum()), empty, empty,
                         f"{int(usable.sum())} lit flat patches, need {MIN_PATCHES}")
    m, v = above[usable], var[usable]
    edges = np.unique(np.quantile(m, np.linspace(0, 1, 9)))
    bm, bv, bw = [], [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (m >= lo) & (m <= hi)
        if sel.sum() < 5:
            continue
        vs = v[sel]
        keep = vs <= np.median(vs) * 3.0  # texture outliers (edges of the iris, lids)
        bm.append(m[sel][keep].mean())
        bv.append(vs[keep].mean())
        bw.append(keep.sum() / max(vs[keep].mean(), 1e-6) ** 2)
    if len(bm) < MIN_BINS or np.ptp(bm) < 2.0:
        return SensorFit(black, math.nan, math.nan, noise, math.nan, int(usable.sum()), np.array(bm),
                         np.array(bv), "the lit patches span too few levels for a slope")
    bm, bv, bw = np.array(bm), np.array(bv), np.array(bw)
    quad, slope, intercept = np.polyfit(bm, bv, 2, w=np.sqrt(bw))
    if not slope > 0:
        return SensorFit(black, math.nan, math.nan, noise, math.nan, int(usable.sum()), bm, bv,
                         f"photon-transfer slope {slope:.3g} DN is not positive")
    K = 1.0 / slope
    read = K * math.sqrt(max(intercept - 1.0 / 12.0, 0.0))
    return SensorFit(black, float(K), float(read), noise, math.sqrt(max(quad, 0.0)),
                     int(usable.sum()), bm, bv)
