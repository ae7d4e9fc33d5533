"""Eye velocity from local straight-line fits over irregular time stamps.

A SCET stream is not evenly sampled: each band is a strobe instant, the invisible lines of
every frame leave a gap (6.5 ms at S = 786 and 16 pulses per frame, 1.3 ms at S = 524) and
bands whose glints could not be identified are NaN. Resampling onto a uniform grid and
bridging the gaps (what a Savitzky-Golay filter needs) moves samples off their strobe
instants and fills the gaps with straight lines. Here each valid sample's velocity is the
slope of a least-squares line through the valid samples within ``half_window_s`` of it, at
their own instants: on an even clock this is the Savitzky-Golay first-derivative filter of
degree 1 (Savitzky and Golay 1964), and on an irregular one it is its natural extension
(local polynomial regression, Cleveland 1979). Where the window holds fewer than three
valid samples, it takes the nearest samples outside it one at a time, on the closer side,
up to ``max_gap_s``: at 60 Hz the velocity is then the central difference of Bahill et al.
(1982), and beside a blanking gap the fit takes one more sample on its own side rather than
smear the motion after the gap onto the samples before it (the onset is then bracketed by
the gap, and its uncertainty says so).
"""

from __future__ import annotations

import numpy as np

import estimator.events.kernels as kernels

#: Most neighbours on each side a fit looks at (window / shortest spacing rarely exceeds it:
#: 16 at 1 kHz and +-8 ms); the window is cut there.
MAX_NEIGHBOURS = 64
#: Samples per block of the vectorised fit.
CHUNK = 8192


def _windows(time_s, position_deg, half_window_s: float):
    """The stream as arrays (times (n,), positions (n, 2)), the indices (m,) of its valid
    samples, their times and positions, and for each the first and one-past-last index among
    them within ``half_window_s`` of it (a relative tolerance of 1e-9 on the window)."""
    t = np.asarray(time_s, dtype=np.float64)
    x = np.asarray(position_deg, dtype=np.float64)
    ok = np.flatnonzero(np.isfinite(x).all(axis=1))
    tv, xv = t[ok], x[ok]
    lo = np.searchsorted(tv, tv - half_window_s * (1 + 1e-9), side="left")
    hi = np.searchsorted(tv, tv + half_window_s * (1 + 1e-9), side="right")
    return t, x, ok, tv, xv, lo, hi


def local_velocity(time_s, position_deg, half_window_s: float, *, max_gap_s: float,
                   full: bool = False):
    """Velocity of every sample from a local line fit over its valid neighbours.

    Parameters
    ----------
    time_s : (n,) float
        Sample instants, strictly increasing (s).
    position_deg : (n, 2) float
        Gaze angles (deg); NaN rows are missing samples.
    half_window_s : float
        Neighbours within this time of a sample enter its fit (s).
    max_gap_s : float
        The window widens to reach the nearest valid sample on each side, but never beyond
        this (s); a sample with no valid neighbour within it on either side gets NaN.

    full : bool
        Also return where each fit's slope belongs and how noisy it is.

    Returns
    -------
    velocity : (n, 2) float
        deg/s; NaN for missing samples and for samples without a usable fit.
    centroid_s : (n,) float
        Only with ``full``: the mean instant of the fit's samples (s). A straight line's slope
        through samples of a curve is the curve's slope near their mean instant, not at the
        sample's own: beside a gap the window is one-sided, and its slope belongs up to half
        a window away (what a crossing is interpolated between).
    noise_gain_per_s : (n,) float
        Only with ``full``: the slope's standard error per unit of independent position noise,
        sqrt(n / (n S_tt - S_t^2)) (1/s; least squares, e.g. Press et al., Numerical Recipes,
        Sec. 15.2). A window with fewer samples (NaN bands, the blanking gap) has a larger one.
    """
    t, x, ok, tv, xv, lo, hi = _windows(time_s, position_deg, half_window_s)
    out = np.full(x.shape, np.nan)
    cen = np.full(t.shape, np.nan)
    gain = np.full(t.shape, np.nan)
    m = ok.size
    if m < 2:
        return (out, cen, gain) if full else out
    # Fewer than three samples in the window (60 Hz, a sample beside a gap): add the nearest
    # sample outside it, one at a time, on whichever side it is closer, within max_gap_s.
    idx = np.arange(m)
    for _ in range(2):
        few = (hi - lo) < 3
        d_back = np.where(lo > 0, tv - tv[np.maximum(lo - 1, 0)], np.inf)
        d_ahead = np.where(hi < m, tv[np.minimum(hi, m - 1)] - tv, np.inf)
        back = few & (d_back <= d_ahead) & (d_back <= max_gap_s)
        ahead = few & ~back & (d_ahead <= max_gap_s)
        lo = np.where(back, lo - 1, lo)
        hi = np.where(ahead, hi + 1, hi)
    lo = np.maximum(lo, idx - MAX_NEIGHBOURS)
    hi = np.minimum(hi, idx + MAX_NEIGHBOURS + 1)
    v = np.empty((m, 2))
    c = np.empty(m)
    g = np.empty(m)
    (kernels.line_fits if kernels.ENABLED else _line_fits)(tv, xv, lo, hi, v, c, g)
    out[ok] = v
    if not full:
        return out
    cen[ok] = c
    gain[ok] = g
    return out, cen, gain


def leave_one_out_residual(time_s, position_deg, half_window_s: float, *,
                           degree: int = 2) -> np.ndarray:
    """How far each valid sample lies from a local polynomial through its valid neighbours.

    Each sample's neighbours within ``half_window_s`` (the sample itself left out) are fitted
    by least squares with a polynomial of ``degree`` in time, at their own instants, and the
    sample's position minus the fit's value at its instant is returned. Degree 2 follows a
    saccade's acceleration: its predicted position is off by about the jerk times the window
    cubed over six (a 20-deg saccade, ~1.4e6 deg/s^3, over 4 ms: ~0.015 deg, about one noise
    SD at 16 pulses per frame), where a one-band glitch of a poor fit is 5-10.

    Parameters
    ----------
    time_s : (n,) float
        Sample instants, strictly increasing (s).
    position_deg : (n, 2) float
        Gaze angles (deg); NaN rows are missing samples.
    half_window_s : float
        Neighbours within this time of a sample enter its fit (s).
    degree : int
        Degree of the local polynomial.

    Returns
    -------
    (n, 2) float
        deg; NaN for missing samples and for samples without a neighbour on each side or
        with fewer than ``degree + 2`` neighbours (no redundant fit).
    """
    _, x, ok, tv, xv, lo, hi = _windows(time_s, position_deg, half_window_s)
    out = np.full(x.shape, np.nan)
    m = ok.size
    if m < degree + 3:
        return out
    idx = np.arange(m)
    lo = np.maximum(lo, idx - MAX_NEIGHBOURS)
    hi = np.minimum(hi, idx + MAX_NEIGHBOURS + 1)
    res = np.empty((m, 2))
    if kernels.ENABLED and degree == 2:
        kernels.loo_quadratic(tv, xv, lo, hi, float(half_window_s), res)
    else:
        _loo_fits(tv, xv, lo, hi, half_window_s, degree, res)
    out[ok] = res
    return out


def _line_fits(tv, xv, lo, hi, velocity, centroid, gain) -> None:
    """numpy path of :func:`estimator.events.kernels.line_fits` (the same arguments): one
    (rows, 2 k + 1) block of every sample's window at a time, bounded memory."""
    m = tv.size
    idx = np.arange(m)
    k_max = int(max(np.max(idx - lo), np.max(hi - 1 - idx)))
    offsets = np.arange(-k_max, k_max + 1)
    for a in range(0, m, CHUNK):
        i = idx[a:a + CHUNK]
        j = i[:, None] + offsets[None, :]
        use = (j >= lo[i, None]) & (j < hi[i, None])
        jc = np.clip(j, 0, m - 1)
        dt = np.where(use, tv[jc] - tv[i, None], 0.0)  # relative to the sample: no cancellation
        dx = np.where(use[..., None], xv[jc] - xv[i, None, :], 0.0)
        s_n = use.sum(axis=1)
        s_t = dt.sum(axis=1)
        s_tt = (dt * dt).sum(axis=1)
        s_x = dx.sum(axis=1)
        s_tx = np.einsum("ij,ijk->ik", dt, dx)
        den = s_n * s_tt - s_t * s_t
        good = (s_n >= 2) & (den > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            vb = (s_n[:, None] * s_tx - s_t[:, None] * s_x) / den[:, None]
            vb[~good] = np.nan
            velocity[a:a + CHUNK] = vb
            centroid[a:a + CHUNK] = np.where(good, tv[i] + s_t / s_n, np.nan)
            gain[a:a + CHUNK] = np.where(good, np.sqrt(s_n / den), np.nan)


def _loo_fits(tv, xv, lo, hi, scale, degree, out) -> None:
    """numpy path of :func:`estimator.events.kernels.loo_quadratic`, any ``degree``."""
    m = tv.size
    idx = np.arange(m)
    k_max = int(max(np.max(idx - lo), np.max(hi - 1 - idx)))
    offsets = np.array([k for k in range(-k_max, k_max + 1) if k != 0])
    for a in range(0, m, CHUNK):
        i = idx[a:a + CHUNK]
        j = i[:, None] + offsets[None, :]
        use = (j >= lo[i, None]) & (j < hi[i, None])
        jc = np.clip(j, 0, m - 1)
        # relative, scaled instants: no cancellation, a well-conditioned normal matrix
        u = np.where(use, (tv[jc] - tv[i, None]) / scale, 0.0)
        basis = np.stack([u ** p for p in range(degree + 1)], axis=-1) * use[..., None]
        normal = np.einsum("mnk,mnl->mkl", basis, basis)
        rhs = np.einsum("mnk,mnd->mkd", basis, np.where(use[..., None], xv[jc], 0.0))
        good = ((use.sum(axis=1) >= degree + 2) & (use & (u < 0)).any(axis=1)
                & (use & (u > 0)).any(axis=1))
        normal[~good] = np.eye(degree + 1)
        coef = np.linalg.solve(normal, rhs)
        out[a:a + CHUNK] = np.where(good[:, None], xv[i] - coef[:, 0, :], np.nan)
