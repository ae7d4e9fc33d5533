"""Band diagrams and band tables: the rolling-shutter timing of Fig. 2 of the SCET paper.

:func:`draw_band_diagram` draws rows against time with each row's exposure window
[E(y), R(y)] (Eqs. (2)-(3)), the strobes, and the rows each strobe lights (Eqs. (4)-(7)), next to
the banded frame they produce. :func:`band_table` lists the same bands for a CLI table.
Matplotlib is imported inside the drawing function, with the Agg canvas, so importing this
module costs nothing and never touches a display.
"""

from __future__ import annotations

import numbers
from pathlib import Path

import numpy as np

from estimator.banding import (
    band_gap_rows,
    band_layout,
    exposure_start,
    readout_time,
    row_pulse_weights,
)
from estimator.setup import Sensor, Strobe


def band_table(sensor: Sensor, strobe: Strobe, frame_index: int = 0) -> list[dict]:
    """One row per pulse lighting any of the frame's S lines, for a CLI or report table.

    Parameters
    ----------
    sensor : Sensor
    strobe : Strobe
    frame_index : int

    Returns
    -------
    list of dict
        Keys: ``strobe`` (global pulse index j), ``time_us`` (pulse start s_j from the start of
        the sequence), ``frame_time_us`` (s_j - t0 of the frame), ``k_first`` (Eq. (4), rows,
        may be negative for a band that began in the previous frame), ``first_row``,
        ``last_row`` (rows of the frame with light), ``onset_rows`` and ``end_rows``
        (partially lit rows as half-open ``(start, stop)``), ``partial_rows`` (their count),
        ``visible`` (any visible row lit) and ``fraction_visible``.
    """
    t0_s = float(readout_time(0, sensor, frame_index))
    table = []
    for band in band_layout(sensor, strobe, frame_index):
        table.append(
            {
                "strobe": band.pulse_index,
                "time_us": band.strobe_time_s * 1e6,
                "frame_time_us": (band.strobe_time_s - t0_s) * 1e6,
                "k_first": band.k_first,
                "first_row": band.first_row,
                "last_row": band.last_row,
                "onset_rows": band.onset_rows,
                "end_rows": band.end_rows,
                "partial_rows": (band.onset_rows[1] - band.onset_rows[0])
                + (band.end_rows[1] - band.end_rows[0]),
                "visible": band.visible,
                "fraction_visible": band.fraction_visible,
            }
        )
    return table


def _clip_polygon_t(poly: np.ndarray, t_lo: float, t_hi: float) -> np.ndarray:
    """(m, 2) convex polygon (t, y) clipped to t_lo <= t <= t_hi (Sutherland-Hodgman)."""

    def clip(points, inside, cross):
        out = []
        for a, b in zip(points, np.roll(points, -1, axis=0)):
            if inside(b):
                if not inside(a):
                    out.append(cross(a, b))
                out.append(b)
            elif inside(a):
                out.append(cross(a, b))
        return np.array(out).reshape(-1, 2)

    def at_t(t):
        return lambda a, b: a + (b - a) * ((t - a[0]) / (b[0] - a[0]))

    poly = clip(poly, lambda p: p[0] >= t_lo, at_t(t_lo))
    if len(poly):
        poly = clip(poly, lambda p: p[0] <= t_hi, at_t(t_hi))
    return poly


def draw_band_diagram(
    sensor: Sensor,
    strobe: Strobe,
    path,
    frame_index: int = 0,
    frames: int = 1,
    dpi: int = 110,
) -> Path:
    """Draw a Fig. 2-style timing diagram of the bands to a PNG.

    Left: rows 0..S (down; the invisible lines N..S shaded) against time in ms from t0 of
    ``frame_index``. Each frame's exposure windows [E(y), R(y)] form a parallelogram (outlined,
    with a few rows' windows as thin lines); each strobe is a vertical bar; the part of the
    bar inside a frame's parallelogram, the rows (k_j, k'''_j) it lights, is filled and labelled
    k_j. Right: the banded image of frame ``frame_index``, each row's total weight sum_j w_j(y).

    Parameters
    ----------
    sensor : Sensor
    strobe : Strobe
    path : str or path-like
        PNG file to write; its folder must exist.
    frame_index : int
        First frame drawn.
    frames : int
        Consecutive frames drawn, >= 1.
    dpi : int
        Resolution of the 10 x 6 inch figure.

    Returns
    -------
    Path
        ``path``.
    """
    if isinstance(frames, bool) or not isinstance(frames, numbers.Integral) or frames < 1:
        raise ValueError(f"frames must be an integer >= 1, got {frames!r}")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    S, N = sensor.total_lines, sensor.visible_lines
    t0_s = float(readout_time(0, sensor, frame_index))

    def ms(t):
        return (np.asarray(t) - t0_s) * 1e3

    fig = Figure(figsize=(10, 6), dpi=dpi)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(1, 2, width_ratios=(5, 1), wspace=0.08)
    ax = fig.add_subplot(grid[0])
    ax_img = fig.add_subplot(grid[1], sharey=ax)

    for a in (ax, ax_img):
        a.axhspan(N, S, color="0.85", zorder=0)
    ax.axhline(N, color="0.4", lw=0.8, ls=":")
    ax.text(1.0, N, " N", transform=ax.get_yaxis_transform(), va="center", fontsize=8)

    pulses = {}
    for f in range(frame_index, frame_index + frames):
        r_top, r_bottom = readout_time([0, S], sensor, f)
        e_top, e_bottom = exposure_start([0, S], sensor, f)
        frame_poly = np.array([[e_top, 0], [r_top, 0], [r_bottom, S], [e_bottom, S]], float)
        ax.fill(ms(frame_poly[:, 0]), frame_poly[:, 1], fill=False, ec="tab:blue", lw=1.2,
                zorder=3)
        sample_rows = np.linspace(0, S, 25)
        ax.hlines(sample_rows, ms(exposure_start(sample_rows, sensor, f)),
                  ms(readout_time(sample_rows, sensor, f)), color="tab:blue", lw=0.4, alpha=0.5,
                  zorder=2)
        for band in band_layout(sensor, strobe, f):
            pulses[band.pulse_index] = band.strobe_time_s
            lit = _clip_polygon_t(frame_poly, band.strobe_time_s,
                                  band.strobe_time_s + strobe.pulse_s)
            if len(lit):
                ax.fill(ms(lit[:, 0]), lit[:, 1], color="tab:orange", alpha=0.8, lw=0, zorder=4)
            k = min(max(band.k_first, 0.0), S)
            ax.text(ms(band.strobe_time_s), k, rf"$k_{{{band.pulse_index}}}$", fontsize=7,
                    ha="right", va="bottom", zorder=5)
    for s_j in pulses.values():
        ax.axvspan(ms(s_j), ms(s_j + strobe.pulse_s), color="gold", alpha=0.35, lw=0, zorder=1)

    ax.set_ylim(S, 0)
    ax.set_xlabel(f"time from t0 of frame {frame_index} (ms)")
    ax.set_ylabel("row y (0 = first read out)")
    gap = band_gap_rows(sensor, strobe)
    ax.set_title(
        f"S={S}, N={N}, Δt={sensor.frame_period_s * 1e3:.3f} ms,"
        f" Δe={sensor.exposure_s * 1e6:.0f} µs, Δs={strobe.pulse_s * 1e6:.0f} µs, Δclk={strobe.period_s * 1e6:.2f} µs,"
        f" gap {gap:+.2f} rows",
        fontsize=9,
    )

    _, _, w = row_pulse_weights(sensor, strobe, frame_index, rows=np.arange(S))
    ax_img.imshow(np.repeat(w.sum(axis=1)[:, None], 8, axis=1), cmap="gray", vmin=0,
                  vmax=max(1.0, float(w.sum(axis=1).max())), aspect="auto",
                  extent=(0, 1, S, 0), interpolation="nearest", zorder=1)
    ax_img.axhspan(N, S, color="tab:red", alpha=0.15, zorder=2)
    ax_img.set_xticks([])
    ax_img.tick_params(labelleft=False)
    ax_img.set_title(f"frame {frame_index}", fontsize=9)

    fig.savefig(path, format="png")
    return path


def band_glint_counts(setup, obs) -> list[dict]:
    """For each visible band of frame 0 (`scet demo`): the rows it dominates and how many glints of each
    target land there (which limits the samples one band can give)."""
    from estimator.banding import NO_PULSE, row_strobe

    pulse, _, _ = row_strobe(setup.sensor, setup.strobe, 0)
    v = np.round(obs.glints_true_px[..., 1])
    rows = []
    for j in np.unique(pulse[pulse != NO_PULSE]):
        lit = np.flatnonzero(pulse == j)
        inside = obs.visible & (v >= lit[0]) & (v <= lit[-1])
        counts = inside.sum(axis=1)
        rows.append({"strobe": int(j), "rows": (int(lit[0]), int(lit[-1])),
                     "glints_mean": float(counts.mean()), "glints_min": int(counts.min()),
                     "share_none": float((counts == 0).mean()),
                     "share_ge3": float((counts >= 3).mean())})
    return rows
