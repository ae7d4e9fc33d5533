"""The paper-reproduction report: markdown tables beside the paper's numbers, and figures.

:func:`write_report` takes the results of :func:`scet_render.reproduce.run_experiments` and
writes ``paper-reproduction.md`` and ``figures/*.png`` (matplotlib, Agg backend). The text
holds no clock times or dates, so a seed gives the same files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPORT_NAME = "paper-reproduction.md"
FIGURES = {"fig5": "fig5_calibration.png", "fig6": "fig6_error_maps.png",
           "fig7": "fig7_translation.png", "fig8": "fig8_compensation.png", "fig9": "fig9_bands.png"}

#: Sec. 3.1 of the paper: corneal radius at e_f = 0.5 px (mm). Fig. 5a, b, d are plots only.
PAPER_RC_MM, PAPER_RC_SD_MM = 7.78, 0.053
#: Sec. 3.2 of the paper: accuracy (SD) in degrees at e_f = 0.5 px.
PAPER_GEO = {"truth": (0.022, 0.012), "los": (4.62, 0.72), "sphere": (17.76, 6.71)}
PAPER_POLY = {"truth": {"eq1_9": (0.70, 0.54), "eq1_25": (0.31, 0.24), "quadratic_25": (0.30, 0.17)},
              "estimated": {"eq1_9": (1.27, 0.74), "eq1_25": (0.32, 0.12), "quadratic_25": (0.32, 0.11)}}
#: Fig. 9 of the paper: accuracy (deg), SD and robustness (%) per number of bands.
PAPER_BANDS = {1: {"single": (0.32, 0.11, 100), "doubled": (0.22, 0.18, 100)},
               2: {"single": (0.56, 0.58, 87), "doubled": (0.29, 0.26, 100)},
               4: {"single": (1.18, 1.36, 62), "doubled": (0.45, 0.41, 100)},
               8: {"single": (1.31, 1.89, 30), "doubled": (0.84, 0.72, 100)},
               12: {"single": (1.26, 2.09, 22), "doubled": (1.17, 0.93, 97)},
               16: {"single": (1.26, 2.42, 18), "doubled": (1.50, 1.14, 93)},
               20: {"single": (1.34, 2.51, 15), "doubled": (1.73, 1.20, 83)}}
#: The issue's targets for ours: geometric gaze with estimated geometry, and 20 bands.
TARGET_GEO_DEG = 1.0
TARGET_BAND_ROBUSTNESS = {"single": 0.60, "doubled": 0.97}

GEO_LABELS = {
    "truth": "ground-truth c_e, r_co, r_c, lighting",
    "paper_literal_los": "paper, literal: 10-unknown per-frame centres + law of sines",
    "paper_literal_sphere": "paper, literal: 10-unknown per-frame centres + sphere fit",
    "paper_cr_los": "paper: centre + radius refitted per frame + law of sines",
    "paper_cr_sphere": "paper: centre + radius refitted per frame + sphere fit",
    "paper_c_los": "paper, charitable: centres refitted with the calibrated lighting + law of sines",
    "paper_c_sphere": "paper, charitable: centres refitted with the calibrated lighting + sphere fit",
    "joint_lighting_los": "ours: joint lighting, its centres + law of sines",
    "joint_lighting_sphere": "ours: joint lighting, its centres + sphere fit",
    "ours_joint": "ours: joint fit of lighting, r_c, c_e, r_co",
}
MAPPING_LABELS = {"eq1_9": "Eq. (1), 9 points, as fitted (min-norm)",
                  "eq1_9_truncated": "Eq. (1), 9 points, truncated (rank 7)",
                  "eq1_25": "Eq. (1), 25 points", "quadratic_25": "second order, 25 points"}
BAND_LABELS = {"paper_c": "paper (c_c)", "paper_cr": "paper (c_c + r_c)", "ours_orbit": "ours, own glints",
               "ours_prior": "ours + prior"}


def _f(x, nd=2, pct=False) -> str:
    if x is None or not np.isfinite(x):
        return "n/a"
    if pct:
        return f"{100 * x:.{nd}f}"
    if x != 0 and (abs(x) >= 1e4 or abs(x) < 10 ** (-nd)):
        return f"{x:.1e}"
    return f"{x:.{nd}f}"


def _table(header, rows) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _closer(paper_values, candidates: dict) -> str:
    """Name of the candidate whose values are closest to the paper's (mean |log ratio|)."""
    best, best_d = None, np.inf
    for name, values in candidates.items():
        a, b = np.asarray(paper_values, float), np.asarray(values, float)
        ok = np.isfinite(b) & (b > 0) & (a > 0)
        if not ok.any():
            continue
        d = float(np.mean(np.abs(np.log(b[ok] / a[ok]))))
        if d < best_d:
            best, best_d = name, d
    return best


# --------------------------------------------------------------------------- figures


def _figures(results, fig_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig_dir.mkdir(parents=True, exist_ok=True)
    meta = {"Software": None}
    _fig5(plt, results["fig5"], fig_dir / FIGURES["fig5"], meta)
    _fig6(plt, results, fig_dir / FIGURES["fig6"], meta)
    _fig78(plt, results["translation"], fig_dir, meta)
    _fig9(plt, results["bands"], fig_dir / FIGURES["fig9"], meta)


def _fig5(plt, fig5, path, meta):
    ef = np.asarray(fig5["noise_px"])
    s = fig5["series"]
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    floor = 1e-6

    def line(a, key, label, stat="median", **kw):
        y = np.array([v[stat] for v in s[key]], dtype=float)
        a.plot(ef, np.maximum(np.abs(y), floor), marker="o", ms=3, label=label, **kw)

    for a, q, title in ((ax[0, 0], "ce", "a) eye centre c_e: |error| (mm), median over trials"),
                        (ax[0, 1], "rco", "b) orbit radius r_co: |error| (mm), median over trials")):
        for key, label, style in (("paper_literal_los", "paper literal, law of sines", "-"),
                                  ("paper_literal_sphere", "paper literal, sphere fit", "--"),
                                  ("paper_cr_los", "paper c_c+r_c, law of sines", "-"),
                                  ("paper_cr_sphere", "paper c_c+r_c, sphere fit", "--"),
                                  ("paper_c_los", "paper charitable, law of sines", "-"),
                                  ("paper_c_sphere", "paper charitable, sphere fit", "--"),
                                  ("ours_joint", "ours, joint fit", "-")):
            line(a, f"{'rco_abs' if q == 'rco' else 'ce'}_{key}", label, ls=style)
        a.set_yscale("log")
        a.set_title(title, fontsize=10)
        a.set_xlabel("e_f (px)")
        a.grid(alpha=0.3)
    ax[0, 0].legend(fontsize=7)
    a = ax[1, 0]
    # Shifted sideways a little: the two paper readings share the averaged lighting and overlap.
    dx = 0.004
    for shift, (key, label) in zip((-dx, 0.0, dx), (("rc_paper", "paper, per frame (10 unknowns)"),
                                                   ("rc_paper_cr", "paper, c_c + r_c per frame"),
                                                   ("rc_ours_joint", "ours, joint fit"))):
        m = np.array([v["mean"] for v in s[key]], dtype=float)
        sd = np.array([v["sd"] for v in s[key]], dtype=float)
        a.errorbar(ef + shift, m, yerr=sd, marker="o", ms=3, capsize=3, label=label)
    a.axhline(7.8, color="k", lw=0.8, ls=":", label="true 7.8 mm")
    a.set_title("c) corneal radius r_c (mm): mean and SD over trials", fontsize=10)
    a.set_xlabel("e_f (px)")
    a.legend(fontsize=7)
    a.grid(alpha=0.3)
    a = ax[1, 1]
    for key, label in (("light_paper", "paper, per frame"), ("light_joint_lighting", "ours, joint lighting"),
                       ("light_ours_joint", "ours, joint fit")):
        m = np.array([v["mean"] for v in s[key]], dtype=float)
        sd = np.array([v["sd"] for v in s[key]], dtype=float)
        a.errorbar(ef, m, yerr=sd, marker="o", ms=3, capsize=3, label=label)
    a.set_title("d) lighting: mean light position error (mm), 6x6 grid", fontsize=10)
    a.set_xlabel("e_f (px)")
    a.legend(fontsize=7)
    a.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata=meta)
    plt.close(fig)


FIG6_PANELS = (("poly_eq1_9_paper_c", "a) Eq. (1), 9 points", 9),
               ("poly_eq1_25_paper_c", "b) Eq. (1), 25 points", 25),
               ("poly_quadratic_25_paper_c", "c) second order, 25 points", 25),
               ("geo_paper_c_los", "d) geometric, paper's c_e (charitable)", 25),
               ("geo_ours_joint", "e) geometric, ours (joint fit)", 25),
               ("poly_quadratic_25_paper_cr", "f) second order, c_c + r_c per sample", 25))


def _fig6(plt, results, path, meta):
    methods = results["sec32"]["methods"]
    (x0, x1), (y0, y1) = results["screen"]["x_range_m"], results["screen"]["y_range_m"]
    calib = {9: results["targets"]["calib9"], 25: results["targets"]["calib25"]}
    fig, axes = plt.subplots(2, 3, figsize=(14, 6.5))
    for a, (key, title, n) in zip(axes.ravel(), FIG6_PANELS):
        if key in methods:
            img = np.asarray(methods[key]["per_target"], dtype=float).reshape(15, 24)
            im = a.imshow(img, extent=(x0 * 100, x1 * 100, y0 * 100, y1 * 100), origin="upper", cmap="viridis",
                          aspect="equal")
            fig.colorbar(im, ax=a, shrink=0.8, label="error (deg)")
        T = calib[n]
        a.plot(T[:, 0] * 100, T[:, 1] * 100, "x", color="white", ms=7, mew=2, clip_on=False)
        a.set_title(title, fontsize=10)
        a.set_xlabel("screen x (cm)")
        a.set_ylabel("screen y (cm)")
    fig.suptitle("Gaze error over the 24 x 15 grid (mean over trials, e_f = 0.5 px, the paper's lighting "
                 "calibration for a-d, f); crosses: calibration targets", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata=meta)
    plt.close(fig)


TRANSLATION_LABELS = {"eq1_9_truncated": "Eq. (1), 9 points (truncated)", "eq1_25": "Eq. (1), 25 points",
                      "quadratic_25": "second order, 25 points", "geometric": "geometric (true c_e, r_co)",
                      "quadratic_da_27": "15-term with d_a, 27 points"}


PLANE_LABELS = {"xz": "x-z: s (w/2, 0, d/2)", "yz": "y-z: s (0, h/2, d/2)", "z": "z only: s (0, 0, d/2)"}


def _fig78(plt, tr, fig_dir, meta):
    x = np.asarray(tr["steps"]) * tr["half_mm"]
    for fig_key, methods, planes in (("fig7", ("eq1_9_truncated", "eq1_25", "quadratic_25", "geometric"), ("xz", "yz")),
                                     ("fig8", ("quadratic_25", "quadratic_da_27"), ("xz", "yz", "z"))):
        fig, ax = plt.subplots(1, len(planes), figsize=(5.5 * len(planes), 4))
        for a, plane in zip(ax, planes):
            for m in methods:
                a.plot(x, tr[plane][m], marker="o", ms=3, label=TRANSLATION_LABELS[m])
            a.set_yscale("log")
            a.set_xlabel(f"translation along {PLANE_LABELS[plane]} (mm per axis)", fontsize=9)
            a.set_ylabel("accuracy (deg)")
            a.grid(alpha=0.3)
        ax[0].legend(fontsize=7)
        title = ("Fig. 7: accuracy after camera and lights translate (calibrated at 0)" if fig_key == "fig7" else
                 "Fig. 8: translation compensation with the distance sensor d_a (27 points at z = 0, -0.5, -1 mm)")
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
        fig.savefig(fig_dir / FIGURES[fig_key], dpi=110, metadata=meta)
        plt.close(fig)


def _fig9(plt, bands, path, meta):
    counts = sorted(bands["single"])
    fig, ax = plt.subplots(2, 2, figsize=(11, 7))
    for col, lighting in enumerate(("single", "doubled")):
        rows = bands[lighting]
        pa = [PAPER_BANDS[b][lighting][0] if b in PAPER_BANDS else np.nan for b in counts]
        pr = [PAPER_BANDS[b][lighting][2] if b in PAPER_BANDS else np.nan for b in counts]
        ax[0, col].plot(counts, pa, "k--", marker="s", label="paper (Fig. 9)")
        ax[1, col].plot(counts, pr, "k--", marker="s", label="paper (Fig. 9)")
        for m, label in BAND_LABELS.items():
            ax[0, col].plot(counts, [rows[b][m]["accuracy_deg"] for b in counts], marker="o", ms=3, label=label)
            ax[1, col].plot(counts, [100 * rows[b][m]["robustness"] for b in counts], marker="o", ms=3, label=label)
        ax[1, col].plot(counts, [100 * (1 - rows[b]["no_glint_share"]) for b in counts], ":", color="grey",
                        label="bound: share of bands with a glint")
        ax[0, col].set_yscale("log")
        for a in ax[:, col]:
            a.set_xticks(counts)
        ax[0, col].set_title(f"{lighting} lighting: accuracy (deg, samples < 5 deg)", fontsize=10)
        ax[1, col].set_title(f"{lighting} lighting: robustness (%)", fontsize=10)
        for a in ax[:, col]:
            a.set_xlabel("bands per frame (60 Hz camera)")
            a.grid(alpha=0.3)
    ax[1, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata=meta)
    plt.close(fig)


# --------------------------------------------------------------------------- markdown


def _sec32_value(results, key):
    m = results["sec32"]["methods"].get(key)
    return (np.nan, np.nan) if m is None else (m["mean"], m["sd"])


def _ms(v) -> str:
    return f"{_f(v[0])} ({_f(v[1])})"


def write_report(out_dir: Path, results: dict) -> Path:
    """Write the markdown report and its figures under ``out_dir``; returns the report path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    _figures(results, out_dir / "figures")
    path = out_dir / REPORT_NAME
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(markdown(results), encoding="utf-8")
    tmp.replace(path)
    return path


def markdown(results: dict) -> str:
    """The report's markdown text."""
    parts = [_intro(results), _summary(results), _setup(results), _fig5_md(results), _sec32_md(results),
             _fig6_md(), _translation_md(results), _bands_md(results), _beat_md(results), _solver_md(results),
             _differences_md(results)]
    return "\n\n".join(parts) + "\n"


def _intro(r) -> str:
    c = r["config"]
    mode = "quick" if c["quick"] else "full"
    levels = ", ".join(_f(x) for x in c["noise_levels_px"])
    return (
        "# SCET paper reproduction\n\n"
        "Every simulated experiment of Sec. 3 of the SCET paper, with the paper's value beside ours, "
        "measured on the same simulated data in the same run. Generated by "
        f"`scet_render.reproduce.run_reproduction(quick={c['quick']}, seed={c['seed']})` ({mode} mode); "
        "the same seed gives the same numbers and figures.\n\n"
        f"- Fig. 5: e_f = {levels} px, {c['calibration_trials']} trials per level.\n"
        f"- Sec. 3.2 and Fig. 6: the first {c['gaze_trials']} trials at e_f = 0.5 px.\n"
        f"- Fig. 7 and 8: {c['translation_trials']} trials, {len(c['translation_steps'])} steps per plane.\n"
        f"- Fig. 9: {c['band_trials']} trials of the 360 targets (the paper: 10).\n"
        f"- Solver check: the paper's TRF on {c['trf_frames']} calibration frames and {c['trf_samples']} gaze "
        "samples.")


def _summary(r) -> str:
    s = r["fig5"]["series"]
    last = -1
    rc = s["rc_paper"][last]
    rcr = s["rc_paper_cr"][last]
    rcj = s["rc_ours_joint"][last]
    rows = [
        ["r_c (mm), e_f = 0.5", f"{PAPER_RC_MM} (SD {PAPER_RC_SD_MM})",
         f"per frame {_f(rc['mean'], 3)} (SD over trials {_f(rc['sd'], 3)}, within a trial "
         f"{_f(s['rc_paper_within_sd'][last]['mean'], 3)}); c_c + r_c {_f(rcr['mean'], 3)} (within "
         f"{_f(s['rc_paper_cr_within_sd'][last]['mean'], 3)})",
         f"{_f(rcj['mean'], 3)} (SD {_f(rcj['sd'], 3)})"],
        ["geometric gaze, ground truth (deg)", _ms(PAPER_GEO["truth"]), _ms(_sec32_value(r, "geo_truth")), "same"],
        ["geometric gaze, estimated c_e, r_co (deg)", _ms(PAPER_GEO["los"]),
         f"literal {_ms(_sec32_value(r, 'geo_paper_literal_los'))}; c_c + r_c "
         f"{_ms(_sec32_value(r, 'geo_paper_cr_los'))}; charitable {_ms(_sec32_value(r, 'geo_paper_c_los'))}",
         _ms(_sec32_value(r, "geo_ours_joint"))],
        ["geometric gaze, sphere fit (deg)", _ms(PAPER_GEO["sphere"]),
         f"literal {_ms(_sec32_value(r, 'geo_paper_literal_sphere'))}; c_c + r_c "
         f"{_ms(_sec32_value(r, 'geo_paper_cr_sphere'))}; charitable "
         f"{_ms(_sec32_value(r, 'geo_paper_c_sphere'))}", ""],
    ]
    for light, plabel, key in (("truth", "true lighting", "truth"), ("estimated", "estimated lighting", "paper")):
        for m in ("eq1_9", "eq1_25", "quadratic_25"):
            rows.append([f"{MAPPING_LABELS[m]}, {plabel} (deg)", _ms(PAPER_POLY[light][m]),
                         f"c_c {_ms(_sec32_value(r, f'poly_{m}_{key}_c'))}; c_c + r_c "
                         f"{_ms(_sec32_value(r, f'poly_{m}_{key}_cr'))}",
                         _ms(_sec32_value(r, f"poly_{m}_ours_c")) if light == "estimated" else ""])
    b = r["bands"]
    top = max(b["single"])
    for lighting in ("single", "doubled"):
        row = b[lighting][top]
        p = PAPER_BANDS.get(top, {}).get(lighting, (np.nan, np.nan, np.nan))
        rows.append([f"Fig. 9, {top} bands, {lighting} lighting: accuracy (SD), robustness",
                     f"{_f(p[0])} ({_f(p[1])}), {_f(p[2], 0)} %",
                     "; ".join(f"{BAND_LABELS[m]} {_f(row[m]['accuracy_deg'])} ({_f(row[m]['sd_deg'])}), "
                               f"{_f(row[m]['robustness'], 1, pct=True)} %" for m in ("paper_c", "paper_cr")),
                     f"{_f(row['ours_prior']['accuracy_deg'])} ({_f(row['ours_prior']['sd_deg'])}), "
                     f"{_f(row['ours_prior']['robustness'], 1, pct=True)} %"])
    return ("## Summary: the paper, the paper's method as reproduced here, ours\n\n"
            + _table(["quantity", "paper", "paper's method, our reproduction", "ours"], rows))


def _setup(r) -> str:
    rig = r["rig"]
    return (
        "## Setup and protocol\n\n"
        "- Scenes: `paper_sim` (Fig. 3: camera at (12, -8, -30) mm, f = 1300 px, 640 x 480; 40 lights on a "
        "90 degree arc of radius 33 mm from G, tilted 45 degrees), `paper_sim_doubled` (the arc and a copy "
        "tilted 64 degrees, Sec. 3.4) and `lighting_grid` (the 6 x 6 grid of 36 lights, 33 mm side, "
        "Sec. 3.1). Screen 48 x 30 cm at 70 cm; accuracy over the 24 x 15 grid of 360 targets (cell "
        "centres); calibration on `calib:3x3` (9) and `calib:5x5` (25) targets, edge to edge.\n"
        "- Feature error e_f: uniform in [-e_f, e_f] px on both axes, e_f = 0.5 px unless stated.\n"
        f"- The true rig is off its nominal model by {rig['rotation_deg']} degree about "
        f"{tuple(round(v, 3) for v in rig['rotation_axis'])} (normalised) through the grid's centre "
        f"{rig['pivot_mm']} mm, then {rig['translation_mm']} mm; every light group (grid, arc, its copy) "
        "rides on the same frame and moves with it. The estimators know only the nominal model; the lighting "
        "calibration (6 x 6 grid) estimates the correction, which then applies to the arc.\n"
        "- Angular error at the true eye centre; robustness = share of estimates below 5 degrees; failed "
        "estimates count against robustness and are left out of means.\n"
        "- The paper's per-frame fits (10 unknowns) and every cornea and gaze fit run on batched "
        "Levenberg-Marquardt with the paper's bounds; the solver check below runs the paper's scipy TRF on "
        "the same frames and samples and finds the same minima.\n"
        "- Three readings of the paper's cornea centres, since the paper does not say how the per-frame "
        "calibration results are combined: **literal** (the centres of the 10-unknown per-frame fits of "
        "c_c, r_c and lighting pose), **c_c + r_c** (Sec. 3.1: \"estimating the corneal center (c_c) and "
        "radius (r_c)\" of every frame, with the lighting pose averaged over the frames) and **charitable** "
        "(the centre alone, with the averaged lighting and r_c). For polynomial gaze the same two last "
        "readings apply to every sample: centre alone (3 unknowns, **c_c**) or centre and radius "
        "(4 unknowns, **c_c + r_c**).")


FIG5_KEYS = ("paper_literal_los", "paper_literal_sphere", "paper_cr_los", "paper_cr_sphere", "paper_c_los",
             "paper_c_sphere", "joint_lighting_los", "joint_lighting_sphere", "ours_joint")


def _fig5_md(r) -> str:
    f5 = r["fig5"]
    s, ef = f5["series"], f5["noise_px"]
    rows = []
    for k in FIG5_KEYS:
        ce, rco = s[f"ce_{k}"][-1], s[f"rco_{k}"][-1]
        rows.append([GEO_LABELS[k], f"{_f(ce['mean'], 3)} ± {_f(ce['sd'], 3)}", _f(ce["median"], 3),
                     f"{_f(rco['mean'], 3)} ± {_f(rco['sd'], 3)}", f"{ce['n']}/{ce['n_total']}"])
    t1 = _table(["method (e_f = 0.5 px)", "c_e error (mm)", "median", "r_co error (mm)", "fits"], rows)
    rows = []
    for i, e in enumerate(ef):
        rows.append([_f(e), *(_f(s[f"ce_{k}"][i]["median"], 3) for k in ("paper_literal_los", "paper_cr_los",
                                                                        "paper_c_los", "paper_c_sphere",
                                                                        "ours_joint")),
                     f"{_f(s['rc_paper'][i]['mean'], 3)} ± {_f(s['rc_paper'][i]['sd'], 3)}",
                     f"{_f(s['rc_ours_joint'][i]['mean'], 3)} ± {_f(s['rc_ours_joint'][i]['sd'], 3)}",
                     _f(s["light_paper"][i]["mean"], 3), _f(s["light_ours_joint"][i]["mean"], 3)])
    t2 = _table(["e_f (px)", "c_e literal", "c_e c_c+r_c", "c_e charitable", "c_e charit. sphere", "c_e ours",
                 "r_c paper (mm)", "r_c ours (mm)", "lights paper (mm)", "lights ours (mm)"], rows)
    rc_lit = s["rc_paper"][-1]
    return (
        "## Fig. 5: system geometric calibration (Sec. 3.1)\n\n"
        f"![Fig. 5](figures/{FIGURES['fig5']})\n\n"
        "The paper gives Fig. 5a, b and d as plots only; its text gives r_c = 7.78 mm (SD 0.053) at "
        f"e_f = 0.5 px. Ours: {_f(rc_lit['mean'], 3)} mm per frame (SD over trials {_f(rc_lit['sd'], 3)}; "
        f"within a trial the 25 frames scatter by {_f(s['rc_paper_within_sd'][-1]['mean'], 3)} mm), "
        f"{_f(s['rc_paper_cr'][-1]['mean'], 3)} mm with c_c + r_c refitted per frame (within-trial SD "
        f"{_f(s['rc_paper_cr_within_sd'][-1]['mean'], 3)} mm, the paper's order of magnitude), "
        f"{_f(s['rc_ours_joint'][-1]['mean'], 3)} ± {_f(s['rc_ours_joint'][-1]['sd'], 3)} mm with our joint fit. "
        "The 10-unknown per-frame problem cannot tell a shifted cornea from a shifted lighting, hence the "
        "scatter of its radius and centres; the joint fits share one pose and r_c across the 25 frames.\n\n"
        "Eye centre and orbit radius at e_f = 0.5 px (mean ± SD over trials):\n\n" + t1 + "\n\n"
        "Against e_f (c_e errors are medians in mm; r_c mean ± SD over trials; mean light position "
        "error in mm):\n\n" + t2)


def _sec32_md(r) -> str:
    sec = r["sec32"]
    rows = [[GEO_LABELS["truth"], _ms(PAPER_GEO["truth"]), _ms(_sec32_value(r, "geo_truth")),
             _f(sec["methods"]["geo_truth"]["failed_share"], 1, pct=True)]]
    for k in FIG5_KEYS:
        paper = PAPER_GEO["los"] if k.startswith("paper") and k.endswith("los") else (
            PAPER_GEO["sphere"] if k.startswith("paper") else None)
        m = sec["methods"][f"geo_{k}"]
        rows.append([GEO_LABELS[k], _ms(paper) if paper else "", _ms((m["mean"], m["sd"])),
                     _f(m["failed_share"], 1, pct=True)])
    t_geo = _table(["geometric gaze", "paper (deg)", "ours: mean (SD) (deg)", "failed %"], rows)
    rows = []
    for m in MAPPING_LABELS:
        pm = m if m != "eq1_9_truncated" else "eq1_9"
        rows.append([MAPPING_LABELS[m], _ms(PAPER_POLY["truth"][pm]), _ms(_sec32_value(r, f"poly_{m}_truth_c")),
                     _ms(_sec32_value(r, f"poly_{m}_truth_cr")), _ms(PAPER_POLY["estimated"][pm]),
                     _ms(_sec32_value(r, f"poly_{m}_paper_c")), _ms(_sec32_value(r, f"poly_{m}_paper_cr")),
                     _ms(_sec32_value(r, f"poly_{m}_ours_c"))])
    t_poly = _table(["mapping", "paper, true lighting", "c_c, true", "c_c + r_c, true", "paper, est. lighting",
                     "c_c, paper's est.", "c_c + r_c, paper's est.", "c_c, our joint est."], rows)
    ranks = sec["ranks"]
    rank_txt = ", ".join(f"{MAPPING_LABELS[m]} {_f(ranks[f'poly_{m}_truth_c']['mean'], 1)}"
                         for m in MAPPING_LABELS if f"poly_{m}_truth_c" in ranks)
    paper_vals = [PAPER_POLY[l][m][0] for l in ("truth", "estimated") for m in ("eq1_9", "eq1_25", "quadratic_25")]
    cand = {"c_c (3 unknowns)": [_sec32_value(r, f"poly_{m}_{k}_c")[0] for k in ("truth", "paper")
                                 for m in ("eq1_9", "eq1_25", "quadratic_25")],
            "c_c + r_c (4 unknowns)": [_sec32_value(r, f"poly_{m}_{k}_cr")[0] for k in ("truth", "paper")
                                       for m in ("eq1_9", "eq1_25", "quadratic_25")]}
    poly_match = _closer(paper_vals, cand)
    geo_match = _closer([PAPER_GEO["los"][0], PAPER_GEO["sphere"][0]],
                        {lab: [_sec32_value(r, f"geo_paper_{k}_los")[0], _sec32_value(r, f"geo_paper_{k}_sphere")[0]]
                         for k, lab in (("literal", "literal"), ("cr", "c_c + r_c"), ("c", "charitable"))})
    return (
        "## Sec. 3.2: geometric and polynomial gaze\n\n"
        f"Mean and SD of the error over the 360 targets of a trial, averaged over {sec['trials']} trials, "
        "e_f = 0.5 px. Geometric gaze uses each method's lighting, r_c, c_e and r_co; polynomial gaze the "
        "lighting and r_c only.\n\n" + t_geo + "\n\n" + t_poly + "\n\n"
        f"Mean rank of the mappings (true lighting, c_c): {rank_txt}. Eq. (1) has 8 terms but the 3 x 3 "
        "pattern is mirror-symmetric about the eye's vertical plane, and x enters Eq. (1) only linearly: "
        "mirror pairs determine only 3 of the 4 coefficients of x, xy, xz, xyz, so 9 points give rank 7 "
        "without noise; with noise the 8th direction is fitted to noise (\"as fitted\", minimum-norm "
        "least squares, singular values below 1e-6 of the largest dropped) or dropped (\"truncated\", "
        "below 5e-2 of the largest: over 30 noise draws the noise-fitted direction sits at 6e-4 to 1.8e-2, "
        "the next at 0.17 to 0.21). The 10-term quadratic is rank 9 on noise-free data, because the cornea centres lie "
        "exactly on the orbit sphere (x² + y² + z² is a linear function of x, y, z there); with noise the "
        "10th direction is kept and fitted to noise, harmlessly, since test points lie on the same sphere.\n\n"
        f"Which reading matches the paper: for polynomial gaze, **{poly_match}** (closest in mean log ratio "
        f"over the six polynomial rows); for geometric gaze with the paper's c_e, **{geo_match}**.")


def _fig6_md() -> str:
    return ("## Fig. 6: error over the screen\n\n"
            f"![Fig. 6](figures/{FIGURES['fig6']})\n\n"
            "Mean error per target over the Sec. 3.2 trials. As in the paper, Eq. (1) from 9 points is worst "
            "away from its calibration points, and the 25-point mappings are flat; the geometric method's "
            "error follows its c_e error.")


def _translation_md(r) -> str:
    tr = r["translation"]
    steps = np.asarray(tr["steps"])
    zero = int(np.argmin(np.abs(steps)))
    rows = []
    for m, label in TRANSLATION_LABELS.items():
        rows.append([label, _f(tr["xz"][m][zero], 3), *(_f(np.nanmax(tr[p][m]), 2) for p in ("xz", "yz", "z"))])
    half = tr["half_mm"]
    return (
        "## Fig. 7 and 8: camera and lights translated after calibration (Sec. 3.3)\n\n"
        f"![Fig. 7](figures/{FIGURES['fig7']})\n\n![Fig. 8](figures/{FIGURES['fig8']})\n\n"
        f"Calibrated at the nominal pose, then camera and every light moved together by s (±{_f(half, 1)}, 0, "
        f"±{_f(half, 1)}) mm (x-z), s (0, ±{_f(half, 1)}, ±{_f(half, 1)}) mm (y-z) and, ours, s (0, 0, "
        f"±{_f(half, 1)}) mm (z only), s from -1 to 1; true "
        "lighting, r_c, c_e and r_co (Sec. 3.3 uses the true c_e and r_co to isolate the translation). "
        "Accuracy in degrees; the paper gives Fig. 7 and 8 as plots only, and says in Sec. 3.5 that the "
        "accuracy drops a few degrees with less than half a millimetre of deviation, and that the "
        "distance-sensor compensation works effectively. The 15-term mapping in (x, y, z, d_a) is fitted "
        f"to 27 points (the 9-point pattern at z = 0, -0.5, -1 mm), mean rank {_f(tr['da_rank']['mean'], 1)} "
        "of 15 (minimum-norm where deficient); d_a = 1000 t_z + v, v uniform with SD 8e-3.\n\n"
        + _table(["method", "at 0 (deg)", "worst, x-z (deg)", "worst, y-z (deg)", "worst, z only (deg)"], rows)
        + "\n\nThe distance sensor measures depth only: it compensates translations along z (our third "
        "sweep, which also reaches +0.5 mm, a depth not seen in calibration) but cannot sense the lateral "
        "part of the x-z and y-z sweeps, which moves the cornea in the camera's frame like a gaze change "
        "(0.5 mm at r_co = 4.25 mm is about 7 degrees).")


def _bands_md(r) -> str:
    b = r["bands"]
    out = ["## Fig. 9: banding, accuracy and robustness (Sec. 3.4)\n\n"
           f"![Fig. 9](figures/{FIGURES['fig9']})\n\n"
           "A 60 Hz camera; a sample uses only the glints in the central band of 480 / bands rows (the band "
           "its noise-free reflection falls in). Accuracy and SD over the samples with an error below "
           "5 degrees, robustness = their share, pooled over trials. **Paper (c_c)** and **paper (c_c + r_c)**: "
           "the paper's method (second-order polynomial, 25 calibration points, the paper's per-frame "
           "lighting calibration) in the two readings of Sec. 3.2. **Ours, own glints**: geometric gaze with "
           "our joint calibration; with c_e and r_co known the cornea has 2 unknowns (Fick angles), so one "
           "glint suffices. **Ours + prior**: the same plus a Gaussian prior on the Fick angles from the "
           "previous band: the band just above the central one (rows [240 - 3h/2, 240 - h/2), clipped to "
           "the image) in the same frame and fixation, fitted to its own glints alone; prior covariance = "
           "its Gauss-Newton covariance (glint noise SD e_f/sqrt 3) plus 0.5 degree SD of eye motion "
           "between bands. One band has no band above it, so no prior. **No glint**: share of samples whose "
           "band holds no visible glint, which bounds any method that does not borrow from another band."]
    for lighting, title in (("single", "single lighting (`paper_sim`)"), ("doubled", "doubled lighting "
                                                                           "(`paper_sim_doubled`)"),
                            ("sparse", "stress test of ours: every fourth light of the arc (10 lights)")):
        rows = []
        for n, row in sorted(b[lighting].items()):
            p = PAPER_BANDS.get(n, {}).get(lighting)
            cells = [str(n), str(row["rate_hz"]), _f(row["rows"], 0), _f(row["glints_mean"], 1),
                     _f(row["no_glint_share"], 1, pct=True)]
            if lighting != "sparse":
                cells.append("n/a" if p is None else f"{_f(p[0])} ({_f(p[1])}) {p[2]} %")
            for m in BAND_LABELS:
                cells.append(f"{_f(row[m]['accuracy_deg'])} ({_f(row[m]['sd_deg'])}) "
                             f"{_f(row[m]['robustness'], 1, pct=True)} %")
            rows.append(cells)
        header = ["bands", "Hz", "rows", "glints", "no glint %"] + (["paper (Fig. 9)"] if lighting != "sparse" else [])
        header += [BAND_LABELS[m] for m in BAND_LABELS]
        out.append(f"### {title[0].upper()}{title[1:]}\n\nAccuracy (SD) in degrees, robustness:\n\n"
                   + _table(header, rows))
    sparse_top = b["sparse"][max(b["sparse"])]
    out.append(f"In the sparse stress test at {max(b['sparse'])} bands, "
               f"{_f(sparse_top['no_glint_share'], 1, pct=True)} % of the bands hold no glint; the prior "
               f"holds the previous band's estimate for {_f(sparse_top['held_share'], 1, pct=True)} % of the "
               "samples (this is borrowing, and is counted in its robustness).")
    return "\n\n".join(out)


def _beat_md(r) -> str:
    geo = _sec32_value(r, "geo_ours_joint")
    paper_geo = _sec32_value(r, "geo_paper_c_los")
    b = r["bands"]
    top = max(b["single"])
    rows = [["geometric gaze with estimated geometry (deg)", f"{PAPER_GEO['los'][0]}",
             f"<= {TARGET_GEO_DEG}", _f(geo[0], 3), "PASS" if geo[0] <= TARGET_GEO_DEG else "FAIL"]]
    for lighting in ("single", "doubled"):
        p = PAPER_BANDS[20][lighting] if top == 20 else (np.nan, np.nan, np.nan)
        row = b[lighting][top]["ours_prior"]
        ok = row["robustness"] >= TARGET_BAND_ROBUSTNESS[lighting] and row["accuracy_deg"] <= p[0]
        rows.append([f"{top} bands, {lighting} lighting: robustness, accuracy",
                     f"{p[2]} %, {_f(p[0])} deg",
                     f">= {_f(TARGET_BAND_ROBUSTNESS[lighting], 0, pct=True)} %, <= {_f(p[0])} deg",
                     f"{_f(row['robustness'], 1, pct=True)} %, {_f(row['accuracy_deg'], 3)} deg",
                     "PASS" if ok else "FAIL"])
    return ("## Beating the paper (same data, same run)\n\n"
            + _table(["claim", "paper", "target", "ours", ""], rows) + "\n\n"
            f"The paper's own geometric method reproduced here (charitable reading) reaches {_ms(paper_geo)} "
            "deg on the same data; ours fits r_c, the lighting pose, c_e and r_co to the glints of all 25 "
            "calibration frames at once, with each frame's cornea on the orbit toward its known target, "
            "instead of chaining per-frame fits, the law of sines and a sphere.")


def _solver_md(r) -> str:
    c = r["solver_check"]
    series = r["fig5"]["series"]
    fallback = int(round(sum(v["mean"] * v["n"] for v in series["paper_trf_fallback"])))
    failed = int(round(sum(v["mean"] * v["n"] for v in series["paper_failed"])))
    total = sum(v["n_total"] for v in series["paper_failed"])
    return ("## Solver check: the paper's TRF against our LM\n\n"
            f"On {c['frames']} calibration frames (10 unknowns each, the paper's bounds) the largest "
            f"difference between scipy's trust-region-reflective (the paper's solver, one frame at a time) "
            f"and our batched Levenberg-Marquardt is {_f(c['frame_center_diff_um'], 4)} µm in a cornea centre "
            f"and {_f(c['frame_radius_diff_um'], 4)} µm in r_c; the averaged lighting is off by "
            f"{_f(c['light_error_trf_mm'], 4)} mm (TRF) and {_f(c['light_error_lm_mm'], 4)} mm (LM). "
            f"Geometric gaze with the true geometry on {c['samples']} samples: TRF chained from sample to "
            f"sample as in the paper {_f(c['gaze_trf_deg'], 4)} deg, LM batched {_f(c['gaze_lm_deg'], 4)} "
            f"deg, largest difference between the two estimates {_f(c['gaze_diff_max_deg'], 6)} deg. "
            "The paper's per-frame fits and every cornea and gaze fit in this report therefore run on batched "
            "LM, about 30 times faster (our joint calibrations are one problem per trial and use scipy's TRF "
            "with analytic Jacobians, `estimator.calibration`). "
            f"Exception: in {fallback} of {total} Fig. 5 calibrations our LM for the 10-unknown per-frame "
            "fits (`estimator.cornea`) took a non-finite step and stopped with an error, and the paper's TRF "
            "ran instead for that calibration"
            + (f"; in {failed} even TRF failed on every frame (the paper's rows are n/a there)." if failed else "."))


def _differences_md(r) -> str:
    b = r["bands"]
    top = max(b["single"])
    single, one = b["single"][top], b["single"][min(b["single"])]
    s = r["fig5"]["series"]

    def v(key):
        return _sec32_value(r, key)

    lit, cr, ch = v("geo_paper_literal_los"), v("geo_paper_cr_los"), v("geo_paper_c_los")
    sph_ratio = v("geo_paper_c_sphere")[0] / ch[0] if ch[0] > 0 else np.nan
    # Rounded first, so that a change of -0.001 prints as +0.00 rather than -0.00.
    d9_cr = round(v("poly_eq1_9_paper_cr")[0] - v("poly_eq1_9_truth_cr")[0], 2) + 0.0
    d9_c = round(v("poly_eq1_9_paper_c")[0] - v("poly_eq1_9_truth_c")[0], 2) + 0.0
    d25 = max(abs(v(f"poly_{m}_paper_{k}")[0] - v(f"poly_{m}_truth_{k}")[0])
              for m in ("eq1_25", "quadratic_25") for k in ("c", "cr"))
    return (
        "## Differences from the paper, and why\n\n"
        f"- **Geometric gaze with ground truth**: {_ms(v('geo_truth'))} deg against the paper's 0.022 (0.012).\n"
        f"- **The paper's estimated geometry** (4.62 deg; sphere fit 17.76): the literal pipeline (c_e from the "
        f"centres of the 10-unknown per-frame fits) gives {_ms(lit)} deg, c_e off by "
        f"{_f(s['ce_paper_literal_los'][-1]['median'], 1)} mm (median): per frame, a shifted cornea and a "
        "shifted lighting give almost the same glints, so those centres are far off. Refitting the centres "
        f"with the averaged lighting gives {_ms(ch)} deg (charitable), and refitting centre and radius per "
        f"frame {_ms(cr)} deg, the reading closest to the paper; the paper does not describe its pipeline "
        f"well enough to pin it down. Our sphere fit costs {_f(sph_ratio, 1)}x the law of sines on the "
        "charitable centres; the paper's cost 3.8x.\n"
        "- **Polynomial gaze**: with the centre alone (3 unknowns, known r_c) our 25-point mappings reach "
        f"{_f(v('poly_eq1_25_truth_c')[0], 3)} and {_f(v('poly_quadratic_25_truth_c')[0], 3)} deg, several "
        "times better than the paper's 0.31 and 0.30. Fitting centre and radius of every sample "
        f"(4 unknowns) gives {_f(v('poly_eq1_25_truth_cr')[0], 2)} and {_f(v('poly_quadratic_25_truth_cr')[0], 2)} "
        f"deg, and {_f(v('poly_eq1_9_truth_cr')[0], 2)} deg for Eq. (1) from 9 points (paper 0.70): the paper "
        "most likely fitted r_c with every sample, as Sec. 3.1 describes for the calibration frames. The "
        f"same reading gives a per-frame r_c scatter of {_f(s['rc_paper_cr_within_sd'][-1]['mean'], 3)} mm "
        "(paper: SD 0.053 mm), where the 10-unknown fits scatter by "
        f"{_f(s['rc_paper_within_sd'][-1]['mean'], 2)} mm.\n"
        "- **Estimated lighting** costs the paper's Eq. (1) 9-point mapping 0.57 deg (0.70 to 1.27) and its "
        "25-point mappings 0.01-0.02 deg. Here the paper's lighting estimate changes Eq. (1) 9-point by "
        f"{d9_cr:+.2f} deg (c_c + r_c) and {d9_c:+.2f} deg (c_c), the 25-point mappings by at most "
        f"{d25:.3f} deg: a lighting error of a few tenths of a millimetre moves all cornea centres nearly "
        "alike, and a mapping calibrated with the same lighting absorbs it.\n"
        "- **Eq. (1) from 9 points** is rank-deficient on the mirror-symmetric 3 x 3 pattern (Sec. 3.2 above), "
        "which the paper does not mention: we report the minimum-norm fit (the 8th direction fitted to "
        "noise) and the truncated one (rank 7; used in Fig. 7). The 10-term quadratic is rank 9 without noise "
        "(cornea centres on the orbit sphere); we keep the minimum-norm fit.\n"
        f"- **Banding**: our arc (scene `paper_sim`; the paper leaves the arc's plane open) keeps at least "
        f"{one['glints_min']} of the 40 glints on the cornea at every target and spreads them over about "
        f"220 rows, so even at {top} bands ({_f(single['rows'], 0)} rows) a band holds {_f(single['glints_mean'], 1)} "
        f"glints on average and {_f(single['no_glint_share'], 1, pct=True)} % of the bands hold none; the "
        "paper does not give its glint count. The paper's method in the c_c reading therefore keeps "
        f"{_f(single['paper_c']['robustness'], 1, pct=True)} % robustness at {top} bands, while in the "
        f"c_c + r_c reading (4 unknowns from a handful of glints) it falls to "
        f"{_f(single['paper_cr']['robustness'], 1, pct=True)} %, the paper's trend (15 %). Because our "
        "lighting never leaves a band empty, the sparse stress test shows what the prior buys when it does.\n"
        "- **Fig. 5a, b, d and Fig. 7, 8** are plots in the paper with no numbers in the text; we compare "
        "trends only. Fig. 8's x-z and y-z sweeps cannot be compensated by a depth sensor (see above).\n"
        "- **Solvers**: the paper's TRF is replaced by our batched LM after the solver check (same minima).\n"
        "- **Trials**: the paper runs 50 calibration trials per e_f and 10 banding trials, as does the full "
        "mode here; it does not state its trial counts for Sec. 3.2 and 3.3.")
