"""Glint centroids measured in rendered images: the one measurement the renderer's tests and
``benchmarks/bench_cornea.py`` hold against the closed-form glints."""

from __future__ import annotations

import numpy as np

#: Half-width (px) of the window a glint centroid is measured in: glints are ~3 x 5 px.
HALF_WINDOW_PX = 4


def glint_centroids(img: np.ndarray, pred_px: np.ndarray, all_px: np.ndarray,
                    half_px: int = HALF_WINDOW_PX) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) intensity-weighted centroids and (n,) energies of the glints predicted at
    ``pred_px``; NaN for a glint whose window leaves the image or holds no light.

    Each glint owns the pixels of its window nearer to it than to any glint of ``all_px``
    (every visible glint). Background: the median of the window's border. The energy is the
    owned pixels' sum above it; for the centroid, pixels below 5 % of the glint's peak are
    dropped, so that stray diffuse light does not pull it.
    """
    h = half_px
    out, energy = np.full(pred_px.shape, np.nan), np.full(len(pred_px), np.nan)
    for i, (u, v) in enumerate(pred_px):
        x0, y0 = int(round(u)), int(round(v))
        if not (h <= x0 < img.shape[1] - h and h <= y0 < img.shape[0] - h):
            continue
        yy, xx = np.mgrid[y0 - h:y0 + h + 1, x0 - h:x0 + h + 1]
        win = img[y0 - h:y0 + h + 1, x0 - h:x0 + h + 1].astype(np.float64)
        border = np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])
        d = np.hypot(xx[..., None] - all_px[:, 0], yy[..., None] - all_px[:, 1])
        own = d.min(axis=-1) >= np.hypot(xx - u, yy - v) - 1e-9
        w = np.where(own, np.clip(win - np.median(border), 0.0, None), 0.0)
        energy[i] = w.sum()
        w[w < 0.05 * w.max()] = 0.0
        if w.sum() > 0:
            out[i] = [(w * xx).sum() / w.sum(), (w * yy).sum() / w.sum()]
    return out, energy
