"""``reports/aspheric.md``: the aspheric study's tables and figure (:mod:`.aspheric`)."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write
from estimator.tracker import MAX_RESIDUAL_PX

from ..validate import POSITIONS, SIM_REPEATS, error_statistics

METHODS = ("polynomial", "geometric")
SOURCES = ("rendered", "simulated")


def _f(x, spec=".3f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def _pct(x) -> str:
    return "-" if not math.isfinite(x) else f"{100 * x:.1f} %"


def _lids(c) -> str:
    return c.lids


def _med(a) -> float:
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else math.nan


def _p95(a) -> float:
    a = np.asarray(a, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(np.percentile(a, 95)) if a.size else math.nan


def calibration_table(conditions, true_radius_m: float) -> str:
    out = ["| Q | lids | r_c mm (true " + f"{1e3 * true_radius_m:.2f})"
           + " | calibration RMS px | c_e error mm | e_f px | "
           "fit RMS px, rendered geometric: median (p95) | noise-free conic glints, same poses: "
           "median (p95) | refused (residual > limit) poly / geo |",
           "|---|---|---|---|---|---|---|---|---|"]
    for c in conditions:
        out.append(f"| {c.q:g} | {_lids(c)} | {1e3 * c.cornea_radius_m:.3f} | "
                   f"{c.calibration_rms_px:.3f} | {1e3 * c.eye_center_error_m:.3f} | "
                   f"{c.feature_noise_px:.3f} | {_f(_med(c.fit_rms_px['geometric']))} "
                   f"({_f(_p95(c.fit_rms_px['geometric']))}) | "
                   f"{_f(_med(c.model_rms_px['geometric']))} "
                   f"({_f(_p95(c.model_rms_px['geometric']))}) | "
                   f"{c.rejected['polynomial']} / {c.rejected['geometric']} |")
    return "\n".join(out) + "\n"


def accuracy_table(conditions) -> str:
    out = ["| Q | lids | method | source | samples | valid | mean (SD) deg | median deg | "
           "p95 deg | robustness (<5 deg) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for c in conditions:
        for m in METHODS:
            for s in SOURCES:
                n, valid, mean, sd, med, p95, rob = c.stats[(s, m, "all")]
                out.append(f"| {c.q:g} | {_lids(c)} | {m} | {s} | {n} | {_pct(valid)} | "
                           f"{_f(mean)} ({_f(sd)}) | {_f(med)} | {_f(p95)} | {_pct(rob)} |")
    return "\n".join(out) + "\n"


def position_table(conditions) -> str:
    head = " | ".join(f"{p}: valid, median (p95) deg" for p in POSITIONS)
    out = [f"| Q | lids | method | source | {head} |", "|---|---|---|---|---|---|---|"]
    for c in conditions:
        for m in METHODS:
            for s in SOURCES:
                cells = []
                for p in POSITIONS:
                    n, valid, _, _, med, p95, _ = c.stats[(s, m, p)]
                    cells.append(f"{_pct(valid)}, {_f(med)} ({_f(p95)})" if n else "no samples")
                out.append(f"| {c.q:g} | {_lids(c)} | {m} | {s} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def subset_table(conditions, features) -> str:
    """Mean error of band samples (simulated: their lights only) against fits of every
    visible glint with the same calibration, and the feature-level run's own calibration."""
    out = ["| Q | lids | method | band glints, simulated: mean deg | every visible glint, same "
           "calibration: mean (median) deg | every glint, feature-level calibration: mean deg |",
           "|---|---|---|---|---|---|"]
    for c in conditions:
        for m in METHODS:
            e = c.all_glints_deg[m]
            f = features.get(c.q)
            out.append(f"| {c.q:g} | {_lids(c)} | {m} | {_f(c.stats[('simulated', m, 'all')][2])} "
                       f"| {_f(error_statistics(e)[2])} ({_f(_med(e))}) | "
                       f"{_f(error_statistics(f[m]['errors_deg'])[2]) if f else '-'} |")
    return "\n".join(out) + "\n"


def reason_lines(conditions) -> str:
    return "".join(f"- Q = {c.q:g}, lids {_lids(c)}, {m}: "
                   + ", ".join(f"{k} {v}" for k, v in c.reasons[m].items()) + "\n"
                   for c in conditions for m in METHODS)


def feature_table(features: dict, true_radius_m: float) -> str:
    out = ["| Q | r_c mm (true " + f"{1e3 * true_radius_m:.2f})" + " | calibration RMS px | "
           "c_e error mm | method | mean deg | median deg | p95 deg | fit RMS px: median (p95) "
           f"| fits over the tracker's {MAX_RESIDUAL_PX:g} px limit |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for q, f in features.items():
        for m in METHODS:
            err, rms = f[m]["errors_deg"], f[m]["rms_px"]
            _, _, mean, _, med, p95, _ = error_statistics(err)
            fin = rms[np.isfinite(rms)]
            over = float((fin > MAX_RESIDUAL_PX).mean()) if fin.size else math.nan
            out.append(f"| {q:g} | {1e3 * f['cornea_radius_m']:.3f} | "
                       f"{f['calibration_rms_px']:.3f} | {1e3 * f['eye_center_error_m']:.3f} | "
                       f"{m} | {_f(mean)} | {_f(med)} | {_f(p95)} | {_f(_med(rms))} "
                       f"({_f(_p95(rms))}) | {_pct(over)} |")
    return "\n".join(out) + "\n"


def _figure(conditions, features, path: Path) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 3.8), dpi=110)
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(1, 3, k + 1) for k in range(3)]
    qs = sorted({c.q for c in conditions}, reverse=True)
    for k, m in enumerate(METHODS):
        for s, ls in (("rendered", "-"), ("simulated", "--")):
            for lids, marker in (("on", "o"), ("off", "s"), ("moving", "v")):
                y = [next((c.stats[(s, m, "all")][2] for c in conditions
                           if c.q == q and c.lids == lids), math.nan) for q in qs]
                if any(math.isfinite(v) for v in y):
                    axes[0].plot(qs, y, ls=ls, marker=marker, color=f"C{k}",
                                 label=f"{m} {s} lids {lids}")
        fq = sorted(features, reverse=True)
        axes[0].plot(fq, [error_statistics(features[q][m]["errors_deg"])[2] for q in fq], ":",
                     marker="^", color=f"C{k}", label=f"{m} feature level, noise-free")
    axes[0].set_xlabel("conic constant Q (0 = sphere)")
    axes[0].set_ylabel("mean gaze error (deg)")
    for ax in axes:  # polynomial's tens of degrees beside tenths: linear below 0.1 deg
        ax.set_yscale("symlog", linthresh=0.1)
    axes[0].set_title("error vs Q, per method and source", fontsize=9)
    axes[0].invert_xaxis()
    axes[0].legend(fontsize=6)
    for ax, m in zip(axes[1:], METHODS):
        for j, p in enumerate(POSITIONS):
            for s, ls in (("rendered", "-"), ("simulated", "--")):
                y = [next((c.stats[(s, m, p)][4] for c in conditions
                           if c.q == q and c.lids == "on"), math.nan) for q in qs]
                ax.plot(qs, y, ls=ls, marker="o", color=f"C{j + 2}", label=f"{p} {s}")
        ax.set_xlabel("conic constant Q")
        ax.set_ylabel("median gaze error (deg)")
        ax.set_title(f"{m}, lids on: per band position", fontsize=9)
        ax.invert_xaxis()
        ax.legend(fontsize=6)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write(path, buf.getvalue())


def _findings(conditions, features) -> str:
    """Sentences computed from the numbers (no claim the tables do not carry)."""
    lines = []
    by = {(c.q, c.lids): c for c in conditions}
    qs = sorted({c.q for c in conditions}, key=abs)
    q0, q1 = qs[0], qs[-1]
    for m in METHODS:
        for s in SOURCES:
            a, b = by.get((q0, "on")), by.get((q1, "on"))
            if a is None or b is None:
                continue
            lines.append(f"- {m}, {s}, lids on: mean error {_f(a.stats[(s, m, 'all')][2])} deg "
                         f"at Q = {q0:g}, {_f(b.stats[(s, m, 'all')][2])} deg at Q = {q1:g}; "
                         f"valid {_pct(a.stats[(s, m, 'all')][1])} -> "
                         f"{_pct(b.stats[(s, m, 'all')][1])}.")
    d = [c.stats[("rendered", m, "all")][2] - c.stats[("simulated", m, "all")][2]
         for c in conditions for m in ("geometric",)]
    d = [x for x in d if math.isfinite(x)]
    if d:
        lines.append(f"- rendered minus simulated mean error, geometric: {min(d):+.3f} to "
                     f"{max(d):+.3f} deg over all conditions.")
    c = by.get((q1, "on"))
    if c is not None:
        lines.append(f"- geometric, rendered, lids on, Q = {q1:g}, by band position: " + "; ".join(
            f"{p} valid {_pct(c.stats[('rendered', 'geometric', p)][1])}, median "
            f"{_f(c.stats[('rendered', 'geometric', p)][4])} deg" for p in POSITIONS) + ".")
    fq = sorted(features, key=abs)
    if fq:
        f0, f1 = features[fq[0]], features[fq[-1]]
        for m in METHODS:
            lines.append(f"- feature level, noise-free, {m}: mean error "
                         f"{_f(error_statistics(f0[m]['errors_deg'])[2])} deg at Q = {fq[0]:g}, "
                         f"{_f(error_statistics(f1[m]['errors_deg'])[2])} deg at Q = {fq[-1]:g}; "
                         f"sphere-fit residual median {_f(_med(f0[m]['rms_px']))} -> "
                         f"{_f(_med(f1[m]['rms_px']))} px.")
    for other in ("off", "moving"):
        pairs = [(by[(q, "on")], by[(q, other)]) for q in qs
                 if (q, "on") in by and (q, other) in by]
        d = [abs(a.stats[(s, m, "all")][2] - b.stats[(s, m, "all")][2])
             for a, b in pairs for s in SOURCES for m in METHODS
             if math.isfinite(a.stats[(s, m, "all")][2] - b.stats[(s, m, "all")][2])]
        if d:
            lines.append(f"- lids on against {other}: mean errors differ by at most "
                         f"{max(d):.3f} deg (median " + f"{float(np.median(d)):.3f}" + " deg) "
                         "over all Q, methods and sources.")
        if other == "moving" and pairs:
            lines.append("- moving lids, lashes and blinks against the static lids, rendered, "
                         "geometric, valid share by band position (" + ", ".join(POSITIONS)
                         + "): " + "; ".join(
                             f"Q = {a.q:g} " + ", ".join(
                                 f"{100 * (b.stats[('rendered', 'geometric', p)][1] - a.stats[('rendered', 'geometric', p)][1]):+.1f}"
                                 for p in POSITIONS) for a, b in pairs) + " points.")
    for c in (by.get((q, "on")) for q in qs[1:]):
        if c is not None:
            band = c.stats[("simulated", "geometric", "all")][2]
            every = error_statistics(c.all_glints_deg["geometric"])[2]
            lines.append(f"- Q = {c.q:g}, geometric: band samples {_f(band)} deg (simulated), "
                         f"every visible glint with the same calibration {_f(every)} deg.")
    for lids in ("on", "off", "moving"):
        cs = [by[(q, lids)] for q in qs if (q, lids) in by]
        if cs:
            lines.append(f"- calibrated r_c, lids {lids}: "
                         + ", ".join(f"{1e3 * c.cornea_radius_m:.3f} mm (Q = {c.q:g})" for c in cs)
                         + "; calibration RMS " + ", ".join(f"{c.calibration_rms_px:.3f}"
                                                            for c in cs) + " px.")
    return "\n".join(lines) + "\n"


def conic_table(conditions) -> str:
    """The conic-aware tracker beside the spherical one on the same renders, per condition,
    method and source: calibrated Q, r_c, RMS; mean (median) error and valid share of each, and
    the conic's mean minus the sphere's at Q = 0 (same lids, method, source)."""
    sphere = {(c.q, c.lids): c for c in conditions if c.cornea_model == "sphere"}
    out = io.StringIO()
    out.write("| Q | lids | calibrated Q | r_c mm | RMS px | method | source | sphere: mean (median) deg, "
              "valid | conic: mean (median) deg, valid | conic minus sphere at Q = 0, deg |\n")
    out.write("|---|---|---|---|---|---|---|---|---|---|\n")
    for c in (c for c in conditions if c.cornea_model == "conic"):
        s, s0 = sphere.get((c.q, c.lids)), sphere.get((0.0, c.lids))
        for m in METHODS:
            for src in SOURCES:
                st = c.stats[(src, m, "all")]
                a = s.stats[(src, m, "all")] if s is not None else None
                d = st[2] - s0.stats[(src, m, "all")][2] if s0 is not None else math.nan
                out.write(f"| {c.q:g} | {_lids(c)} | {c.cornea_asphericity:.4f} | "
                          f"{1e3 * c.cornea_radius_m:.3f} | {c.calibration_rms_px:.3f} | {m} | {src} | "
                          + (f"{_f(a[2])} ({_f(a[4])}), {_pct(a[1])}" if a is not None else "-")
                          + f" | {_f(st[2])} ({_f(st[4])}), {_pct(st[1])} | {_f(d, '+.3f')} |\n")
    return out.getvalue()


def conic_feature_table(features: dict) -> str:
    """Feature level, noise-free, full size: the conic-aware tracker's calibration and errors."""
    out = io.StringIO()
    out.write("| Q | calibrated Q | r_c mm | calibration RMS px | c_e error mm | polynomial mean (max) deg "
              "| geometric mean (max) deg |\n|---|---|---|---|---|---|---|\n")
    for key in sorted((k for k in features if isinstance(k, tuple)), key=lambda k: -k[0]):
        f = features[key]
        cells = []
        for m in METHODS:
            e = np.asarray(f[m]["errors_deg"], dtype=np.float64)
            e = e[np.isfinite(e)]
            cells.append(f"{_f(float(e.mean()) if e.size else math.nan)} "
                         f"({_f(float(e.max()) if e.size else math.nan)})")
        out.write(f"| {key[0]:g} | {f['cornea_asphericity']:.5f} | {1e3 * f['cornea_radius_m']:.4f} | "
                  f"{f['calibration_rms_px']:.4f} | {1e3 * f['eye_center_error_m']:.4f} | "
                  + " | ".join(cells) + " |\n")
    return out.getvalue()


def _conic_findings(conditions) -> str:
    """Per method and Q (lids on, rendered): the conic tracker's mean error against the
    sphere's at Q = 0, and the calibrated Q."""
    sphere = {(c.q, c.lids): c for c in conditions if c.cornea_model == "sphere"}
    lines = []
    for m in METHODS:
        for c in (c for c in conditions if c.cornea_model == "conic" and c.lids == "on"
                  and c.q != 0):
            s0, s = sphere.get((0.0, "on")), sphere.get((c.q, "on"))
            if s0 is None or s is None:
                continue
            a, b0, b = (x.stats[("rendered", m, "all")][2] for x in (c, s0, s))
            lines.append(f"- {m}, rendered, lids on, Q = {c.q:g} (calibrated {c.cornea_asphericity:.4f}): "
                         f"conic tracker {_f(a)} deg, {_f(a - b0, '+.3f')} deg from the sphere's "
                         f"{_f(b0)} at Q = 0 (spherical tracker here: {_f(b)} deg).")
    return "\n".join(lines) + ("\n" if lines else "")


def _conic_section(conditions, features) -> str:
    if not any(c.cornea_model == "conic" for c in conditions):
        return ""
    return f"""
## The conic-aware tracker (`cornea_model = "conic"`)

The same renders tracked again with the estimator's conic option
(`scet calibrate --cornea-model conic`, `estimator.cornea.fit_cornea_conic`,
`estimator.calibration.calibrate_joint_conic`): the calibration fits Q with r_c, the lighting
pose, c_e and r_co to the exact conic reflections (12 unknowns, started from the spherical
joint fit), then identifies every calibration frame's detections again on the calibrated
conic and recalibrates (the spherical matcher's identities of oblique glints are wrong on a
conic); each band's fit starts from the sphere's answer and iterates on the conic's glints
(the optical axis from c_e through the fitted centre). Identification stays the spherical
matcher's. Glints cut by a lash are flagged by their flux as the spherical tracker's are, on
the conic's model (`estimator.calibration.flux.conic_flux`) with each light's power from the
conic calibration's frames.

{_conic_findings(conditions)}
{conic_table(conditions)}
Feature level (full size, noise-free, every visible glint, calibrated from the simulated 5x5
pattern):

{conic_feature_table(features)}"""


def write_aspheric_report(report_dir: Path, conditions, features, cfg, base, wall_s: float,
                          seed: int) -> Path:
    every = conditions
    conditions = [c for c in every if c.cornea_model == "sphere"]
    conic_part = _conic_section(every, features)
    features = {k: v for k, v in features.items() if not isinstance(k, tuple)}
    figs = report_dir / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    _figure(conditions, features, figs / "aspheric_errors.png")
    mode = "quick" if cfg.scale > 1 else "full"
    (ppf,) = cfg.pulses_per_frame
    r_true = base.eye.cornea_radius_m
    qs = ", ".join(f"{q:g}" for q in dict.fromkeys(c.q for c in conditions))
    stage = {}
    for c in every:
        for k, v in c.timings_s.items():
            stage[k] = stage.get(k, 0.0) + v
    w, h = base.camera.width_px // cfg.scale, base.camera.height_px // cfg.scale
    text = f"""# The spherical tracker on aspheric corneas

Generated by `scet study aspheric` (`scet_render.study.aspheric`), **{mode} mode**, seed {seed}.
Scene `{base.name}` with its cornea's conic constant Q set to each of {qs} (Q = 0 the sphere;
apex radius R = {1e3 * r_true:.2f} mm kept; `[eye] cornea_asphericity`, recorded in every
dataset's manifest), rendered at {w}x{h} px, {cfg.spp} spp, {cfg.cornea} cornea (the conic
drawn exactly), {cfg.frames} test frames at {ppf} pulses/frame (fixations of
{max(c.gaze_targets for c in conditions)} grid cells of the 24 x 15 accuracy grid, the same
for every condition: one seeded sequence). Each (Q, lids) condition runs
exactly what `scet validate` runs (`scet_render.validate.validate_setup`): a
{cfg.calib_grid[0]}x{cfg.calib_grid[1]} single-pulse
calibration, the banded fixation sequence, both gaze methods of the tracker as it is (its
cornea a sphere), the ground truth of the labels, and the feature-level simulation of the same
poses, lights and calibration ({SIM_REPEATS} noise realisations at the e_f of the rendered
detections; its glints are the exact conic reflections). Lids: "on", the renderer's static
eyelids at their default openness (1.0: they clear the cornea for every gaze at the screen);
"off", none; "moving", the scene's `[eyelids]` table with its defaults (lids that follow the
pitch with gains 0.9 / 0.3, margins clear of the cornea by 5 deg at every gaze at the screen),
40 lashes on the upper lid and 15 blinks a minute (the trajectory's own seeded blinks). Band
position: the third of the visible rows holding the band's centre.

## What the numbers mean

{_findings(conditions, features)}
The tracker fits a sphere to glints of a conic: the calibration absorbs part of the asphericity
(its r_c and c_e move, and its RMS grows), the rest is model error that grows with |Q|. The
feature-level section below (full size, noise-free, every visible glint, the calibration also
from simulated glints) isolates it: there is nothing but the model in it. Glint residuals are
in pixels of the image they were measured on ({w}x{h} for the rendered rows, 1/{cfg.scale} of
the full-size pixels' count per axis); the tracker refuses fits over {MAX_RESIDUAL_PX:g} px at
any size, so at full size, where the same model error is {cfg.scale}x as many pixels, more fits
would be refused (a reduced size can understate the robustness lost). The simulated rows reuse
the rendered samples' identities and have no residual limit (as in `scet validate`): their
valid share follows the rendered one.

How to read them. (1) The rendered rows follow the simulated ones (the renderer's conic glints
and the simulator's are the same glints; "rendered minus simulated" above): the error is the
model's, not the image pipeline's. (2) A band holds a handful of glints from one height of the
cornea, and a sphere fitted to a patch of a conic takes the conic's local curvature there: the
table "Band glints against every glint" puts each condition's band samples beside fits of every
visible glint with the same calibration. The band samples are those that passed the tracker's
gates, a selection that narrows with |Q| (valid shares), so their mean is not the model error
of every pose. (3) Robustness falls with |Q| because the tracker's matcher predicts glints with
the sphere (bands it can no longer identify: `match_*` reasons) and because fits over its
residual limit are refused (the refused column; reasons below): the accepted fits' residuals
stay small because the large ones are refused. (4) Polynomial gaze maps the fitted cornea
centre through the calibrated Eq. (1) polynomial, which amplifies a band fit's biased centre
(the tens of degrees of its p95 at large |Q|, against a few degrees from every glint). (5) The
static lids at openness 1.0 clear the cornea for every gaze at the screen, so lids on and off
differ little. The moving lids' default margins clear it too; what they add is their lashes,
which hide or cut glints of the top bands, and the blinks that close the eye (the valid share
by band position against the static lids is in the findings). Lids that cover part of the
cornea at rest are not in this study.

## Calibration and glint fits per condition

{calibration_table(conditions, r_true)}
Fit RMS: the rendered own-glint samples' sphere-fit residuals (detection noise and model
error); noise-free: the same poses and lights fitted to the exact conic glints with the same
calibration (the model's part alone).

## Accuracy and robustness

{accuracy_table(conditions)}
## Per band position

{position_table(conditions)}
## Band glints against every glint

{subset_table(conditions, features)}
## Reasons (rendered)

{reason_lines(conditions)}
![error vs Q](figures/aspheric_errors.png)

## Feature level only (no rendering): full size, noise-free

The simulator's conic glints of every visible light on the 5x5 calibration pattern calibrate
the tracker (`estimator.folders.calibrate_from_glints`); both methods then run on the 24 x 15
grid.

{feature_table(features, r_true)}{conic_part}
Wall time (s, 2-core CPU shared with other work): total {wall_s:.1f}; by stage, summed over
conditions: """ + ", ".join(f"{k} {v:.1f}" for k, v in stage.items()) + "\n"
    path = report_dir / "aspheric.md"
    atomic_write(path, text)
    return path
