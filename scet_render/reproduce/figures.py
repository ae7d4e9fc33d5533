"""The reproduction's figures (Fig. 5-9 of the paper, ours beside them).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .paper_numbers import BAND_LABELS, FIGURES, PAPER_BANDS, PLANE_LABELS, TRANSLATION_LABELS

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
