"""``reports/compare.md`` and ``compare/*.png``: a capture beside its render, per frame and per
quantity, with the verdict table (matplotlib, written as :mod:`scet_render.validate.report`
writes its plots)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write

__all__ = ["write_report"]


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, str):
        return v
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v) or "-"
    return f"{v:.4g}"


def _plots(result, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    f = result.frames[0]
    cap = result.capture_images[f].astype(np.float64)
    ren = result.render_images[f].astype(np.float64)
    vmax = float(np.percentile(cap, 99.5))
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.4))
    for a, img, title in ((ax[0], cap, "capture"), (ax[1], ren, "render")):
        a.imshow(img, cmap="gray", vmin=0, vmax=vmax)
        a.set_title(f"{title}, frame {f}")
        m = (result.capture_measures if title == "capture" else result.render_measures)[f]
        a.plot(m.u_px, m.v_px, "o", mfc="none", mec="tab:red", ms=5, lw=0.5)
    d = cap - ren
    lim = max(float(np.percentile(np.abs(d), 99)), 1.0)
    im = ax[2].imshow(d, cmap="RdBu_r", vmin=-lim, vmax=lim)
    ax[2].set_title("capture - render (DN)")
    fig.colorbar(im, ax=ax[2], fraction=0.046)
    for a in ax:
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    fig.savefig(out / "pair.png", dpi=90)
    plt.close(fig)
    names.append("pair.png")

    fig, ax = plt.subplots(1, 3, figsize=(13, 3.4))
    ax[0].plot(result.capture_measures[f].profile_dn, label="capture")
    ax[0].plot(result.render_measures[f].profile_dn, label="render", alpha=0.8)
    ax[0].set_xlabel("row")
    ax[0].set_ylabel("row mean above black (DN)")
    ax[0].legend()
    ax[0].set_title("per-row mean profile")
    bins = np.arange(-40.5, 41.0, 1.0)  # integer differences of integer DN
    for img, label in ((cap, "capture"), (ren, "render")):
        ax[1].hist(np.diff(img, axis=1).ravel(), bins=bins, histtype="step", label=label,
                   density=True)
    ax[1].set_yscale("log")
    ax[1].set_xlabel("difference of horizontal neighbours (DN)")
    ax[1].set_title("noise histogram")
    ax[1].legend()
    keys = sorted(result.gaze_deg)
    if keys:
        ax[2].boxplot([result.gaze_deg[k] for k in keys], positions=list(range(len(keys))))
        ax[2].set_xticks(range(len(keys)), [str(k) for k in keys])
    ax[2].set_xlabel("band in frame")
    ax[2].set_ylabel("gaze, capture vs render (deg)")
    ax[2].set_title("tracker on both")
    fig.tight_layout()
    fig.savefig(out / "profiles.png", dpi=90)
    plt.close(fig)
    names.append("profiles.png")
    return names


def write_report(result, report_dir) -> Path:
    """Write ``compare.md`` and its PNGs under ``report_dir``; returns the markdown path."""
    report_dir = Path(report_dir)
    pngs = report_dir / "compare"
    pngs.mkdir(parents=True, exist_ok=True)
    names = _plots(result, pngs)
    t = result.timing
    lines = [f"# Capture vs render: `{result.capture_dir}`", "",
             f"Scene `{result.setup.name}`; frames {result.frames}. Each frame was tracked, its "
             "timing measured from the capture (`scet bands --measure`), and rendered at that "
             "timing, the tracked poses and the sensor model the frames give (black level, "
             "response). Differences: capture - render, or capture - scene for the timing and "
             "sensor rows.", ""]
    lines += [f"- {n}" for n in result.notes]
    lines += ["", f"Measured timing: S = {t.total_lines:.3f} +- {t.total_lines_sd:.3f} lines, "
              f"exposure {1e6 * t.exposure_s:.2f} +- {1e6 * t.exposure_s_sd:.2f} us, pulse "
              f"{1e6 * t.pulse_s:.2f} us, strobe phase {1e6 * result.measured.strobe.phase_s:.2f}"
              f" us, clock {_fmt(t.clock_ppm)} ppm.", ""]
    lines += ["## Verdict", "",
              "| group | quantity | capture | render / scene | difference | tolerance | unit "
              "| verdict | likely cause | reason of the tolerance | note |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in result.rows:
        lines.append(f"| {r.group} | {r.quantity} | {_fmt(r.capture)} | {_fmt(r.render)} | "
                     f"{_fmt(r.difference)} | {_fmt(r.tolerance)} | {r.unit} | "
                     f"{'pass' if r.passed else '**flag**'} | {r.cause} | {r.reason} | {r.note} |")
    flagged = result.flagged
    lines += ["", f"{len(flagged)} of {len(result.rows)} rows flagged"
              + (": " + ", ".join(f"{r.quantity} ({r.cause})" for r in flagged) if flagged else "")
              + ".", "", "## Findings", ""]
    lines += [f"- `{k}`: {_fmt(v)}" for k, v in result.findings.items()]
    lines += ["", "## Gaze difference per band (deg, median)", "",
              "| band | samples | median |", "|---|---|---|"]
    for k in sorted(result.gaze_deg):
        v = result.gaze_deg[k]
        lines.append(f"| {k} | {len(v)} | {np.median(v):.3f} |")
    lines += ["", "## Images", ""]
    lines += [f"![{n}](compare/{n})" for n in names]
    path = report_dir / "compare.md"
    atomic_write(path, "\n".join(lines) + "\n")
    return path
