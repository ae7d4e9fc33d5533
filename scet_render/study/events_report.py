"""``reports/events.md``: the event study's tables and plots (:mod:`.events_run`)."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write

from .events import (EventScores, IDT_DISPERSION_DEG, IVT_THRESHOLD_DEG_S, MAX_GAP_S, MIN_FIXATION_S,
                     VELOCITY_WINDOW_S, detect_saccades, velocity)


#: The label of the 60 Hz condition (one sample per frame).
RATE_60 = 0


@dataclass(frozen=True, slots=True)
class Condition:
    """One row of the table: lighting, pulses per frame (0: the 60 Hz tracker), detector."""

    lighting: str
    pulses_per_frame: int
    detector: str
    samples_per_s: float
    valid_share: float
    scores: EventScores


def summary_row(c: Condition) -> dict:
    """Numbers of one condition (means of absolute errors, and signed means)."""
    s = c.scores

    def mae(a):
        return float(np.mean(np.abs(a))) if a.size else math.nan

    def bias(a):
        return float(np.mean(a)) if a.size else math.nan

    return {"lighting": c.lighting, "rate": "60 Hz" if c.pulses_per_frame == RATE_60 else
            f"{c.pulses_per_frame} pulses/frame", "detector": c.detector.upper().replace("I", "I-", 1),
            "samples_per_s": c.samples_per_s, "valid": c.valid_share, "n_true": s.n_true,
            "detection_rate": s.detection_rate, "false": s.false_detections,
            "onset_ms": mae(s.onset_ms), "onset_bias_ms": bias(s.onset_ms),
            "offset_ms": mae(s.offset_ms), "offset_bias_ms": bias(s.offset_ms),
            "duration_ms": mae(s.duration_ms), "duration_bias_ms": bias(s.duration_ms),
            "peak_velocity_deg_s": mae(s.peak_velocity_deg_s),
            "peak_velocity_bias_deg_s": bias(s.peak_velocity_deg_s),
            "amplitude_deg": mae(s.amplitude_deg), "amplitude_bias_deg": bias(s.amplitude_deg)}


def _fmt(v, spec=".1f", pct=False):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{100 * v:.0f} %" if pct else format(v, spec)


def conditions_table(conditions) -> str:
    head = ("| lighting | rate | detector | valid samples/s | saccades | detected | false | "
            "onset err ms (bias) | offset err ms (bias) | duration err ms (bias) | "
            "peak velocity err deg/s (bias) | amplitude err deg (bias) |\n"
            "|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    body = ""
    for c in conditions:
        r = summary_row(c)
        body += (f"| {r['lighting']} | {r['rate']} | {r['detector']} | {r['samples_per_s']:.0f} | "
                 f"{r['n_true']} | {_fmt(r['detection_rate'], pct=True)} | {r['false']} | "
                 f"{_fmt(r['onset_ms'])} ({_fmt(r['onset_bias_ms'], '+.1f')}) | "
                 f"{_fmt(r['offset_ms'])} ({_fmt(r['offset_bias_ms'], '+.1f')}) | "
                 f"{_fmt(r['duration_ms'])} ({_fmt(r['duration_bias_ms'], '+.1f')}) | "
                 f"{_fmt(r['peak_velocity_deg_s'], '.0f')} "
                 f"({_fmt(r['peak_velocity_bias_deg_s'], '+.0f')}) | "
                 f"{_fmt(r['amplitude_deg'], '.2f')} ({_fmt(r['amplitude_bias_deg'], '+.2f')}) |\n")
    return head + body


def buys_table(conditions) -> str:
    """The 16-pulse (most bands) condition against 60 Hz, per lighting and detector."""
    rows = {(c.lighting, c.pulses_per_frame, c.detector): summary_row(c) for c in conditions}
    top = max(c.pulses_per_frame for c in conditions)
    keys = (("samples_per_s", "valid samples/s", ".0f"), ("detection_rate", "saccades detected", "%"),
            ("false", "false saccades", "d"), ("onset_ms", "onset error (ms)", ".1f"),
            ("offset_ms", "offset error (ms)", ".1f"), ("duration_ms", "duration error (ms)", ".1f"),
            ("peak_velocity_deg_s", "peak velocity error (deg/s)", ".0f"),
            ("amplitude_deg", "amplitude error (deg)", ".2f"))
    out = ""
    for lighting in dict.fromkeys(c.lighting for c in conditions):
        for det in dict.fromkeys(c.detector for c in conditions):
            a, b = rows.get((lighting, top, det)), rows.get((lighting, RATE_60, det))
            if a is None or b is None:
                continue
            out += (f"\n**{lighting} lighting, {a['detector']}** ({top} pulses/frame against one "
                    "sample per frame)\n\n| measure | 60 Hz | SCET | SCET minus 60 Hz |\n"
                    "|---|---|---|---|\n")
            for key, name, spec in keys:
                x, y = b[key], a[key]
                if spec == "%":
                    out += f"| {name} | {_fmt(x, pct=True)} | {_fmt(y, pct=True)} | "
                    out += ("-" if math.isnan(x) or math.isnan(y) else f"{100 * (y - x):+.0f} points") + " |\n"
                else:
                    d = y - x if not (isinstance(x, float) and math.isnan(x)) else math.nan
                    out += f"| {name} | {_fmt(x, spec)} | {_fmt(y, spec)} | {_fmt(d, '+' + spec)} |\n"
    return out


def _plots(traces, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lighting = next(iter(dict.fromkeys(k[0] for k in traces)))
    top = max(k[1] for k in traces if k[0] == lighting)
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    for (lab, p), (series, traj) in traces.items():
        if lab != lighting or p not in (top, RATE_60):
            continue
        name = "60 Hz" if p == RATE_60 else f"SCET {p} pulses/frame"
        t = series.time_s
        axes[0].plot(t, series.position_deg[:, 0], ".-" if p == RATE_60 else "-", ms=3, lw=0.8,
                     label=f"{name}: yaw")
        v = velocity(series)
        axes[1].plot(t, np.hypot(v[:, 0], v[:, 1]), ".-" if p == RATE_60 else "-", ms=3, lw=0.8,
                     label=name)
        for s0, s1 in zip(*_onsets(series)):
            axes[1].axvspan(s0, s1, color="C1" if p == RATE_60 else "C0", alpha=0.15)
    tt = np.linspace(t.min(), t.max(), 4000)
    yaw, _ = traj.angles_at(tt)
    axes[0].plot(tt, np.degrees(yaw), "k:", lw=0.8, label="truth: yaw")
    axes[1].plot(tt, np.degrees(traj.velocity_at(tt)), "k:", lw=0.8, label="truth")
    axes[0].set_ylabel("yaw (deg)")
    axes[1].set_ylabel("speed (deg/s)")
    axes[1].set_xlabel("time (s)")
    axes[0].legend(fontsize=8)
    axes[1].legend(fontsize=8)
    axes[0].set_title(f"{lighting} lighting: gaze and speed; shaded: I-VT saccades")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write(path, buf.getvalue())


def _onsets(series):
    s = detect_saccades(series, "ivt")
    return s.onset_s, s.offset_s


def _error_plot(conditions, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [summary_row(c) for c in conditions]
    keys = (("onset_ms", "onset error (ms)"), ("duration_ms", "duration error (ms)"),
            ("peak_velocity_deg_s", "peak velocity error (deg/s)"),
            ("detection_rate", "saccades detected"))
    fig, axes = plt.subplots(1, len(keys), figsize=(14, 3.4))
    labels = list(dict.fromkeys((r["lighting"], r["detector"]) for r in rows))
    rates = list(dict.fromkeys(r["rate"] for r in rows))
    for ax, (key, name) in zip(axes, keys):
        for i, (lab, det) in enumerate(labels):
            vals = [next((r[key] for r in rows if r["lighting"] == lab and r["detector"] == det
                          and r["rate"] == rate), math.nan) for rate in rates]
            ax.bar(np.arange(len(rates)) + 0.8 * i / len(labels), vals, width=0.8 / len(labels),
                   label=f"{lab} {det}")
        ax.set_xticks(np.arange(len(rates)) + 0.4 - 0.4 / len(labels), rates, fontsize=7)
        ax.set_title(name, fontsize=9)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write(path, buf.getvalue())


def write_events_report(report_dir: Path, conditions, traces, cfg, lightings, timings) -> Path:
    figs = report_dir / "figures"
    _plots(traces, figs / "events_trace.png")
    _error_plot(conditions, figs / "events_errors.png")
    mode = "quick" if cfg.scale > 1 else "full"
    scenes = ", ".join(f"{k}: `{v}`" for k, v in lightings.items())
    text = f"""# Saccades at the band rate and at 60 Hz

Generated by `scet study events` (`scet_render.study.events_run`), **{mode} mode**:
{cfg.frames} frames per sequence at 1/{cfg.scale} resolution, {cfg.spp} spp, {cfg.cornea}
cornea. Lightings: {scenes}. Each lighting: one 5x5 single-pulse calibration, one rendered
"saccades" sequence (main-sequence saccades between random screen points, fixations of
0.1-0.3 s with drift and tremor; the same trajectory and seed everywhere) per strobe setting
({", ".join(str(p) for p in cfg.pulses_per_frame)} pulses/frame, period locked to the frame)
and one with a single pulse per frame that every row collects (the 60 Hz tracker of the same
camera). Tracked with the prototype's tracker, geometric gaze.

Events: pymovements (`pymovements.events.ivt`, `idt`; velocities from
`pymovements.transforms.numpy.pos2vel`, Savitzky-Golay over ~{1e3 * VELOCITY_WINDOW_S:g} ms,
at least 3 samples); I-VT at {IVT_THRESHOLD_DEG_S:g} deg/s, I-DT at {IDT_DISPERSION_DEG:g} deg,
fixations of at least {1e3 * MIN_FIXATION_S:g} ms. Samples on the strobe's clock, gaps up to
{1e3 * MAX_GAP_S:g} ms bridged linearly. A saccade is the stretch between two fixations, from
half a sample after the last fixation sample to half a sample before the next one; it is
matched to the true saccade it overlaps most (one to one). Errors are mean absolute values
over matched saccades, detected minus true, with the signed mean (bias) in brackets. Truth:
the trajectory's saccades wholly inside the tracked span with a fixation's room on each side;
peak velocity and amplitude as the motion model draws them.

## What the band rate buys over 60 Hz
{buys_table(conditions)}
## Every condition

{conditions_table(conditions)}
![gaze and speed](figures/events_trace.png)

![errors by rate](figures/events_errors.png)

Wall time (s, 2-core CPU): """ + ", ".join(f"{k} {v:.1f}" for k, v in timings.items()) + "\n"
    path = report_dir / "events.md"
    atomic_write(path, text)
    return path
