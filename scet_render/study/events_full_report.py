"""``reports/events.md`` of the full event study (:mod:`.events_full`): tables with 95 %
intervals and figures with interval bars."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from estimator.events import EventParams
from estimator.formats import atomic_write

from .events_changes import _fmt, _spec, changes_section
from .events_errors import rendered_errors_table
from .events_score import BOOTSTRAP, GOALS, MEASURES, TWIN_RESIDUALS

DET_NAMES = {"scet": "band detector", "ivt": "I-VT", "idt": "I-DT"}
TABLE_KEYS = ("detected_1deg", "false_per_min", "onset_mae_ms", "offset_mae_ms",
              "onset_bias_ms", "offset_bias_ms", "peak_rel_err_pct", "micro_detected")


def _met(key, v) -> str:
    if key not in GOALS or not math.isfinite(v[0]):
        return ""
    op, goal = GOALS[key]
    ok = v[0] >= goal if op == ">=" else v[0] <= goal
    if not ok:
        return "**no**"
    # the whole interval on the goal's side: shown; else the value meets it, the interval not
    sure = all(math.isfinite(x) and (x >= goal if op == ">=" else x <= goal) for x in v[1:])
    return "yes" if sure else "yes, interval reaches past it"


def _find(rows, lighting, setting, det):
    return next((r for r in rows if r["lighting"] == lighting and r["setting"] == setting
                 and r["detector"] == det), None)


def goal_table(rows) -> str:
    cols = [("designed", "16 pulses, S = 524", "SCET 16 pulses, S = 524"),
            ("designed", "16 pulses, S = 786", "SCET 16 pulses, S = 786"),
            ("designed", "60 Hz", "60 Hz, same camera"),
            ("designed", "1 kHz reference", "1 kHz uniform reference")]
    out = ""
    for det in ("scet", "ivt"):
        out += (f"\n**{DET_NAMES[det]}**, designed lighting\n\n| measure | goal | "
                + " | ".join(c[2] for c in cols) + " | goal met (S = 524) |\n|---|---|"
                + "---|" * len(cols) + "---|\n")
        for key in TABLE_KEYS:
            vals = [(_find(rows, lab, s, det) or {}).get("summary", {}).get(key, (math.nan,) * 3)
                    for lab, s, _ in cols]
            goal = f"{GOALS[key][0]} {GOALS[key][1]:g}" if key in GOALS else ""
            out += (f"| {MEASURES[key]} | {goal} | " + " | ".join(_fmt(v, _spec(key)) for v in vals)
                    + f" | {_met(key, vals[0])} |\n")
    return out


def budget_table(rows) -> str:
    names = ["16 pulses, S = 524", "16 pulses, S = 524, no blanking", "16 pulses, S = 524, no noise",
             "16 pulses, S = 524, no invalid bands", "16 pulses, S = 524, none of the three",
             "1 kHz reference"]
    keys = ("detected_1deg", "onset_mae_ms", "offset_mae_ms", "peak_rel_err_pct", "micro_detected",
            "false_per_min")
    out = ("| simulation (designed lighting, band detector) | valid samples/s | "
           + " | ".join(MEASURES[k] for k in keys) + " |\n|---|---|" + "---|" * len(keys) + "\n")
    for n in names:
        r = _find(rows, "designed", n, "scet")
        if r is None:
            continue
        out += (f"| {n} | {r['samples_per_s']:.0f} | "
                + " | ".join(_fmt(r["summary"][k], _spec(k)) for k in keys) + " |\n")
    return out


def budget_summary(rows) -> str:
    """One line per measure: the goal setting's value and what each switch leaves."""
    base = _find(rows, "designed", "16 pulses, S = 524", "scet")
    if base is None:
        return ""
    lines = []
    for key in ("onset_mae_ms", "offset_mae_ms", "false_per_min", "micro_detected"):
        parts = []
        for name in ("no blanking", "no noise", "no invalid bands", "none of the three"):
            r = _find(rows, "designed", f"16 pulses, S = 524, {name}", "scet")
            if r is not None:
                parts.append(f"{name} {r['summary'][key][0]:{_spec(key)}}")
        lines.append(f"- {MEASURES[key]}: {base['summary'][key][0]:{_spec(key)}} with all three; "
                     + ", ".join(parts) + ".")
    return "\n".join(lines) + "\n"


def every_table(rows) -> str:
    keys = ("detected_1deg", "false_per_min", "onset_mae_ms", "offset_mae_ms", "peak_rel_err_pct",
            "micro_detected")
    out = ("| lighting | setting | detector | valid samples/s (share) | noise SD deg | "
           + " | ".join(MEASURES[k] for k in keys) + " |\n|---|---|---|---|---|"
           + "---|" * len(keys) + "\n")
    for r in rows:
        if ", no " in r["setting"] or "none of" in r["setting"]:
            continue
        out += (f"| {r['lighting']} | {r['setting']} | {DET_NAMES[r['detector']]} | "
                f"{r['samples_per_s']:.0f} ({100 * r['valid']:.0f} %) | {r['noise_sd_deg']:.4f} | "
                + " | ".join(_fmt(r["summary"][k], _spec(k)) for k in keys) + " |\n")
    return out


def rendered_table(rendered) -> str:
    if rendered is None:
        return ("No rendered frames were found in the work folder (`--out`) and this run did not "
                "render them (`--no-render`), so it has no comparison of renders and "
                "simulation.\n")
    keys = ("detected_1deg", "false_per_min", "onset_mae_ms", "offset_mae_ms", "onset_bias_ms",
            "offset_bias_ms", "peak_rel_err_pct")
    out = ("| detector | source | " + " | ".join(MEASURES[k] for k in keys) + " |\n|---|---|"
           + "---|" * len(keys) + "\n")
    for det in DET_NAMES:
        for src in ("rendered", "simulated", "simulated, the renders' valid bands",
                    TWIN_RESIDUALS):
            if src not in rendered[det]:
                continue
            s = rendered[det][src]
            out += (f"| {DET_NAMES[det]} | {src} | "
                    + " | ".join(_fmt(s[k], _spec(k)) for k in keys) + " |\n")
    return out


def agreement_text(rendered) -> str:
    """Band by band, which bands the renders and the simulator's rule call valid
    (:func:`scet_render.study.events_full.band_agreement`)."""
    a = None if rendered is None else rendered.get("agreement")
    if not a or not a["bands"]:
        return ""
    n = a["bands"]
    why = ", ".join(f"{k} {v}" for k, v in a["simulated only, reasons"][:6])
    return ("Band by band (the same instants):\n\n| | simulated valid | simulated invalid |\n"
            "|---|---|---|\n"
            f"| rendered valid | {a['both']} ({100 * a['both'] / n:.1f} %) | "
            f"{a['rendered only']} ({100 * a['rendered only'] / n:.1f} %) |\n"
            f"| rendered invalid | {a['simulated only']} ({100 * a['simulated only'] / n:.1f} %) | "
            f"{a['neither']} ({100 * a['neither'] / n:.1f} %) |\n\n"
            f"The tracker's reasons for the bands valid only in the simulation: {why}.\n")


def _overlap(a, b) -> bool:
    return not (a[2] < b[1] or b[2] < a[1])


def rendered_verdict(rendered) -> str:
    if rendered is None:
        return ""
    lines = []
    for det in DET_NAMES:
        r = rendered[det]["rendered"]
        for twin in ("simulated", "simulated, the renders' valid bands", TWIN_RESIDUALS):
            if twin not in rendered[det]:
                continue
            s = rendered[det][twin]
            for k in ("onset_mae_ms", "offset_mae_ms", "detected_1deg", "peak_rel_err_pct"):
                if all(math.isfinite(x) for x in (*r[k], *s[k])):
                    same = _overlap(r[k], s[k])
                    lines.append(f"- {DET_NAMES[det]}, {MEASURES[k]}: rendered "
                                 f"{_fmt(r[k], _spec(k))}, {twin} {_fmt(s[k], _spec(k))}: "
                                 "intervals " + ("overlap" if same else "**do not overlap**"))
    return "\n".join(lines) + "\n"


def _bar_figure(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ("onset_mae_ms", "offset_mae_ms", "detected_1deg", "micro_detected")
    settings = [s for s in dict.fromkeys(r["setting"] for r in rows)
                if ", no " not in s and "none of" not in s]
    fig, axes = plt.subplots(len(keys), 1, figsize=(13, 11), sharex=True)
    combos = [(lab, det) for lab in dict.fromkeys(r["lighting"] for r in rows) for det in DET_NAMES]
    w = 0.8 / len(combos)
    for ax, key in zip(axes, keys):
        for i, (lab, det) in enumerate(combos):
            v = np.array([(_find(rows, lab, s, det) or {}).get("summary", {}).get(key, (np.nan,) * 3)
                          for s in settings], dtype=float)
            x = np.arange(len(settings)) + i * w
            err = np.array([v[:, 0] - v[:, 1], v[:, 2] - v[:, 0]])
            ax.bar(x, v[:, 0], width=w, label=f"{lab}, {DET_NAMES[det]}")
            ax.errorbar(x, v[:, 0], yerr=_bars(err), fmt="none", ecolor="k", lw=0.7,
                        capsize=1.5)
        ax.set_ylabel(MEASURES[key], fontsize=7)
        if key in ("onset_mae_ms", "offset_mae_ms"):
            ax.set_yscale("log")
            ax.axhline(1.0, color="r", lw=0.7, ls="--")
    axes[-1].set_xticks(np.arange(len(settings)) + 0.4 - w / 2, settings, rotation=20, fontsize=7)
    axes[0].legend(fontsize=6, ncol=3)
    axes[0].set_title("every setting, 95 % intervals (dashed: the 1 ms goal)", fontsize=9)
    fig.tight_layout()
    _save(fig, path)


def _budget_figure(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = ["16 pulses, S = 524", "16 pulses, S = 524, no blanking", "16 pulses, S = 524, no noise",
             "16 pulses, S = 524, no invalid bands", "16 pulses, S = 524, none of the three",
             "1 kHz reference"]
    names = [n for n in names if _find(rows, "designed", n, "scet")]
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.6))
    for ax, key in zip(axes, ("onset_mae_ms", "offset_mae_ms")):
        v = np.array([_find(rows, "designed", n, "scet")["summary"][key] for n in names], float)
        ax.bar(np.arange(len(names)), v[:, 0], color="C0")
        ax.errorbar(np.arange(len(names)), v[:, 0],
                    yerr=_bars(np.array([v[:, 0] - v[:, 1], v[:, 2] - v[:, 0]])),
                    fmt="none", ecolor="k", capsize=3)
        ax.axhline(1.0, color="r", lw=0.7, ls="--")
        ax.set_xticks(np.arange(len(names)), [n.replace("16 pulses, S = 524", "goal") for n in names],
                      rotation=20, fontsize=7)
        ax.set_title(MEASURES[key] + ", 95 % intervals", fontsize=8)
    fig.tight_layout()
    _save(fig, path)


def _trace_figure(traces, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.events import detect_events

    from .events_score import truth_events

    t, pos, traj = traces["goal"]
    truth = truth_events(traj, t[0], t[-1])
    big = np.flatnonzero(truth.amplitude_deg >= 5)[:1]
    small = np.flatnonzero((truth.amplitude_deg >= 0.3) & (truth.amplitude_deg < 1))[:1]
    picks = [i for i in (*big, *small)]
    fig, axes = plt.subplots(1, len(picks), figsize=(12, 3.8))
    for ax, i in zip(np.atleast_1d(axes), picks):
        lo, hi = truth.onset_s[i] - 0.03, truth.offset_s[i] + 0.03
        tt = np.linspace(lo, hi, 2000)
        ax.plot(1e3 * (tt - truth.onset_s[i]), np.degrees(traj.velocity_at(tt)), "k:", lw=1,
                label="truth")
        for key, name, c in (("goal", "16 pulses, S = 524", "C0"), ("786", "16 pulses, S = 786", "C2"),
                             ("60", "60 Hz", "C3")):
            if key not in traces:
                continue
            ts, ps, _ = traces[key]
            sel = (ts >= lo - 0.05) & (ts <= hi + 0.05)
            from estimator.events import EventParams as _P  # noqa: N814
            from estimator.events.detect import scale_velocities

            ok = np.isfinite(ps[sel]).all(axis=1)
            v = scale_velocities(ts[sel][ok], ps[sel][ok], _P())["timing"].velocity_deg_s
            m = (ts[sel][ok] >= lo) & (ts[sel][ok] <= hi)
            ax.plot(1e3 * (ts[sel][ok][m] - truth.onset_s[i]), np.hypot(v[m, 0], v[m, 1]), ".-",
                    ms=3, lw=0.7, color=c, label=name)
            ev = detect_events(ts[sel], ps[sel])
            for a, b in zip(ev.onset_s, ev.offset_s):
                if b > lo and a < hi:
                    ax.axvspan(1e3 * (a - truth.onset_s[i]), 1e3 * (b - truth.onset_s[i]),
                               color=c, alpha=0.1)
        ax.set_xlabel("time from the true onset (ms)")
        ax.set_ylabel("speed (deg/s)")
        ax.set_title(f"{truth.amplitude_deg[i]:.2f} deg (shaded: detected)", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, path)


def _rendered_figure(rendered, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ("onset_mae_ms", "offset_mae_ms", "detected_1deg")
    fig, axes = plt.subplots(1, len(keys), figsize=(12, 3.4))
    for ax, key in zip(axes, keys):
        for j, src in enumerate(("rendered", "simulated", "simulated, the renders' valid bands")):
            v = np.array([rendered[d][src][key] for d in DET_NAMES], float)
            x = np.arange(len(DET_NAMES)) + 0.27 * j
            ax.bar(x, v[:, 0], width=0.27, label=src)
            err = np.array([v[:, 0] - v[:, 1], v[:, 2] - v[:, 0]])
            ax.errorbar(x, v[:, 0], yerr=_bars(err), fmt="none", ecolor="k", capsize=3)
        ax.set_xticks(np.arange(len(DET_NAMES)) + 0.27, list(DET_NAMES.values()), fontsize=8)
        ax.set_title(MEASURES[key] + ", 95 %", fontsize=8)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)


def _bars(err) -> np.ndarray:
    """(2, k) interval bars: NaN (no interval) as none, and never negative (a bootstrap
    interval of identical values can miss its mean by a rounding)."""
    return np.clip(np.where(np.isfinite(err), err, 0.0), 0.0, None)


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write(path, buf.getvalue())


def blanking_markdown(blanking, rows) -> str:
    """The vertical blanking: samples a frame, the longest gap, and the band detector's
    timing at 524 and 786 lines (designed lighting)."""
    out = ("| pulses/frame | S | band samples a frame | longest gap (ms) | onset MAE ms | "
           "offset MAE ms |\n|---|---|---|---|---|---|\n")
    for p, S, per_frame, gap in blanking:
        r = _find(rows, "designed", f"{p} pulses, S = {S}", "scet")
        on = _fmt(r["summary"]["onset_mae_ms"]) if r else "-"
        off = _fmt(r["summary"]["offset_mae_ms"]) if r else "-"
        out += f"| {p} | {S} | {per_frame:.2f} | {1e3 * gap:.2f} | {on} | {off} |\n"
    return out


def stream_table(latency) -> str:
    """The streaming forms (:func:`scet_render.study.events_full.stream_latency`): latency
    and the streamed events' scores."""
    if not latency:
        return "Not measured in this run.\n"
    keys = ("detected_1deg", "false_per_min", "onset_mae_ms", "offset_mae_ms",
            "peak_rel_err_pct", "micro_detected")
    out = ("| stream | wait after the offset (ms) | saccades >= 1 deg | latency after the true "
           "onset, median (ms) | 95th percentile (ms) | after the true offset, median (ms) | "
           + " | ".join(MEASURES[k] for k in keys) + " |\n|---|---|---|---|---|---|"
           + "---|" * len(keys) + "\n")
    for r in latency:
        out += (f"| {'early' if r['early'] else 'settled'} | {r['settle_ms']:.0f} | {r['n']} | "
                f"{r['median_ms']:.1f} | {r['p95_ms']:.1f} | {r['after_offset_median_ms']:.1f} | "
                + " | ".join(_fmt(r["summary"][k], _spec(k)) for k in keys) + " |\n")
    return out


def write_full_report(report_dir: Path, rows, latency, rendered, traces, timings, labels,
                      counts, noise_table, blanking=(), changes=None) -> Path:
    """Write ``events.md`` and its figures; ``counts`` (saccades, microsaccades) per lighting,
    ``noise_table`` the rendered validation's mean errors the noise comes from."""
    from .events_render import RENDER_CORNEA, RENDER_SPP
    from .events_sim import FIXATION_RANGE_S, MIN_GLINTS, PRIOR_REACH_S

    figs = report_dir / "figures"
    _bar_figure(rows, figs / "events_settings.png")
    _budget_figure(rows, figs / "events_budget.png")
    if "goal" in traces:
        _trace_figure(traces, figs / "events_trace.png")
    if rendered is not None:
        _rendered_figure(rendered, figs / "events_rendered.png")
    p = EventParams()
    noise_text = "; ".join(f"`{k}` " + " / ".join(f"{v:.3f}" for v in row.values())
                           for k, row in noise_table.items())
    scenes = ", ".join(f"{k}: `{v}`" for k, v in labels.items())
    lat = stream_table(latency)
    rend_head = "" if rendered is None else (
        f"{rendered['frames']} of the planned {rendered['planned']} frames rendered and tracked "
        f"(designed lighting, 16 pulses per frame, S = 524, 640 x 480, {RENDER_SPP} spp, "
        f"{RENDER_CORNEA} cornea; the dataset's `saccades` trajectory, seed 0): "
        f"{rendered['scet']['n_all']} saccades scored ({rendered['scet']['n']} of >= 1 deg). Valid bands: rendered "
        f"{100 * rendered['valid_rendered']:.1f} %, simulated {100 * rendered['valid_simulated']:.1f} %. "
        f"Per-sample noise of the tracked renders (per axis about the truth, less the median "
        f"bias; 1.4826 times the median absolute deviation): {rendered['noise_sd_deg']:.4f} deg, "
        f"used by the simulation in this comparison (the RMS is {rendered['rms_deg']:.4f} deg: "
        f"{100 * rendered['outliers']:.1f} % of the valid rendered samples are further than 5 "
        "such SDs from the truth, misidentified bands, which the simulation does not make). "
        f"The event gate (`estimator.events.quality`) flags {100 * rendered.get('poor fits', 0):.1f} % "
        "of them as poor fits (prior-assisted bands of fewer than 3 glints, residuals beyond "
        f"the stream's Hampel bound) and leaves out the {100 * rendered.get('left out', 0):.1f} % "
        "whose gaze also disagrees with their neighbours', as `scet track --events` does: "
        f"{100 * rendered.get('outliers of the left out', 0):.1f} % of those are outliers, "
        f"{100 * rendered.get('outliers left', 0):.1f} % of the samples the detectors see. "
        "Three simulated twins of the same trajectory and setting: the simulator's own band "
        "validity (simulated); the renders' own instants and used bands with the simulated "
        "noise (no outliers), which separates what the valid bands change from what the "
        "outliers do; and those bands with the renders' own errors, each drawn from the used "
        "samples whose true eye speed lies in the same band (0-30, 30-100, 100-300, above 300 "
        "deg/s), which keeps their distribution and its growth at saccadic speeds but not their "
        "order. The tracker's reasons for the rendered bands it gave no gaze: "
        + ", ".join(f"{k} {v}" for k, v in rendered["reasons"]) + "."
        + ("" if rendered["scet"]["n"] >= 30 else
           f" With {rendered['scet']['n']} saccades >= 1 deg (issue 34 asks for at least 30) the "
           "intervals are wide: that they overlap shows no disagreement, and cannot show "
           "agreement either; `scet study events` without `--no-render` resumes the render."))
    text = f"""# Saccades at the band rate: event timing on hundreds of saccades

Generated by `scet study events` (full mode; `scet_render.study.events_full`). Lightings:
{scenes}. Confidence intervals: 95 %, in brackets after every value (Wilson score for rates,
percentile bootstrap of {BOOTSTRAP} resamples for means, exact Poisson for false events per
minute); the figures draw the same intervals.

## How

**Feature-level simulation** (`scet_render.study.events_sim`): per lighting one trajectory of
{counts[0]} saccades of 0.5-20 deg and {counts[1]} microsaccades of 0.1-1 deg (uniform
amplitudes, random directions, seeded order) between fixations of {FIXATION_RANGE_S[0]:g}-{FIXATION_RANGE_S[1]:g} s with the
motion model's drift and tremor; main-sequence saccades (Carpenter 1988 durations, Baloh et al.
1975 peak velocities). One sample per visible band at its strobe instant (the band layout of
Eqs. 2-8, so the blanking gap is where it is); a band is valid when the closed-form glints of
the pose at its instant put at least {MIN_GLINTS} visible glints inside its rows (the
tracker's own identification) or at least one with a valid band {1e3 * PRIOR_REACH_S:g} ms
before (prior assistance); a valid sample is the true Fick angles plus Gaussian noise per axis
of the geometric gaze's error in the full-size rendered validation of the same lighting and
pulse count (mean errors {noise_text} deg at 4 / 8 / 16 pulses, over sqrt(pi/2); at S = 786; the 60 Hz
tracker: one sample a frame, lit by one pulse that every row collects, with the 4-pulse noise;
the 1 kHz reference: a valid sample every millisecond with the goal setting's noise).

**Detectors on the same samples**: the band detector (`estimator.events`: line fits over
irregular instants, half windows {1e3 * p.timing_window_s:g} / {1e3 * p.peak_window_s:g} /
{1e3 * p.small_window_s:g} ms for timing / peak / microsaccades, threshold {p.detect_sd:g}
median-based SDs (Engbert and Kliegl 2003) of each speed's own fit, events bounded where the
speed crosses {p.bound_sd:g} SDs, merged when one starts within {1e3 * p.min_interval_s:g} ms
of the last one's end, each onset and offset then placed by a position model fitted across the
edge, main-sequence checks; the next section measures each change against the first full-size
study's detector); pymovements' I-VT (30 deg/s) and I-DT (1 deg) on the samples put on
the strobe clock with gaps up to 20 ms bridged (the quick study's baselines,
`scet_render.study.events`). A true event is matched to the detected event it overlaps most
(one to one); unmatched detections are false events. Truth: every saccade of the trajectory
with 50 ms of samples on each side.

## Goals (designed lighting)
{goal_table(rows)}
Goal met: "yes" when the value and its whole interval meet the goal; "yes, interval reaches
past it" when the value meets it but the interval does not rule out missing it. These are one
trajectory per lighting; the next two sections measure the goal setting on eight more
(four held out from the second round, four fresh).

{changes_section(changes)}
## Where the error comes from (designed lighting, 16 pulses, S = 524)

Each switch turns one cause off in the simulation: the blanking gap (a sample at every pulse,
each read as the band at its phase), the per-sample noise, the invalid bands. At S = 524 every
pulse already lights visible rows (next section), so the blanking switch changes only which
rows the edge pulses' bands have, and its row differs from the first by the noise draw alone;
the blanking's cost shows between S = 524 and S = 786.

{budget_table(rows)}
{budget_summary(rows)}
![error budget](figures/events_budget.png)

## The vertical blanking

Band instants from the band layout (Eqs. 2-8; a pulse counts when it lights any visible row,
however few): at S = 524 the 44 invisible lines last 1.40 ms, less than a pulse's band of rows
(the 1 ms exposure), so every pulse still lights visible rows and no sample is lost; only the
bands at the frame's edges are short (fewer glints, more often invalid). At S = 786 the 306
invisible lines (6.48 ms) swallow whole pulses. The band detector's timing (designed lighting)
beside it: the difference between the two S is what the blanking costs, with the invalid
bands of each.

{blanking_markdown(blanking, rows)}
## Streaming

`estimator.events.EventStream`, samples pushed a frame (16.6 ms) at a time, goal setting
(the study's trajectory): each event reported once its offset is the wait old, at the first
push after. Settled (the default): {1e3 * p.settle_s:g} ms, every velocity window and the
amplitude window full and the minimum intersaccadic interval waited out, so the streamed
events are the offline ones. Early (`EventStream(early=True)`): {1e3 * p.early_settle_s:g} ms,
the event's own fits, edge fit and amplitude final, and an event starting within the minimum
interval after a reported one taken as its continuation. Latency over the matched saccades
>= 1 deg, and the streamed events scored as the offline ones are:

{lat}
## Rendered sub-sequence against the simulation

{rend_head}

{agreement_text(rendered)}
{rendered_table(rendered)}
{rendered_verdict(rendered)}
{rendered_errors_table(rendered, DET_NAMES, _met)}
{"![rendered and simulated](figures/events_rendered.png)" if rendered is not None else ""}

## Every setting

{every_table(rows)}
![every setting](figures/events_settings.png)

![speed around two events](figures/events_trace.png)

Wall time (s, shared 2-core CPU): """ + ", ".join(f"{k} {v:.1f}" for k, v in timings.items()) + "\n"
    path = report_dir / "events.md"
    atomic_write(path, text)
    return path
