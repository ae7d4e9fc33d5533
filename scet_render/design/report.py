"""What ``scet design-lights`` writes: the designed scene (TOML, commented with its scores) and
a report (markdown and a figure of the frame's bands with their glints, before and after)."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write
from estimator.geometry.wire_model import WireMirror
from estimator.scene import parse_scene
from estimator.setup import Setup

from .objective import MIN_SEPARATION_PX, ROW_WEIGHT_MIN, VISIBLE_SHARE_MIN, layout_glints
from .search import DesignResult
from .wire import wire_mirror_table

_HEADER = re.compile(r"^\s*\[\[?[A-Za-z_\"]")  # a table header, not a row of an array


def scene_without_lights(text: str) -> str:
    """The scene text without its ``[[lights]]`` tables (and their sub-tables), and without
    the comment block right above each (it describes the old layout)."""
    out: list[str] = []
    skipping = False
    for line in text.splitlines():
        if _HEADER.match(line):
            name = line.strip()
            skipping = name == "[[lights]]" or name.startswith("[lights.")
            if name == "[[lights]]":
                while out and (out[-1].lstrip().startswith("#") or not out[-1].strip()):
                    out.pop()
        if not skipping:
            out.append(line)
    return "\n".join(out).rstrip() + "\n"


def _set_top(text: str, key: str, value: str) -> str:
    pattern = re.compile(rf'^{key}\s*=\s*".*"\s*$', re.M)
    if not pattern.search(text):
        raise ValueError(f"scene text has no top-level {key!r} to replace")
    return pattern.sub(f'{key} = "{value}"', text, count=1)


def score_lines(result: DesignResult) -> list[str]:
    """One line per measured figure (used in the scene's comments and in the report)."""
    s = result.settings
    lines = [f"counted (>= {s.need} usable glints) design bands: before "
             f"{100 * result.counted_before:.1f} %, arcs {100 * result.counted_arcs:.1f} %, "
             f"after {100 * result.counted_after:.1f} % (region bound "
             f"{100 * result.bound:.1f} %)"]
    for name, sc in (("before", result.before), ("after", result.after)):
        if sc is not None:
            mean, med, p95 = sc.accuracy()
            lines.append(f"matcher, {name}: valid design bands {100 * sc.share_design:.1f} %, "
                         f"all visible bands {100 * sc.share_all:.1f} %, {sc.lights} lights, "
                         f"error mean {mean:.3f} / median {med:.3f} / p95 {p95:.3f} deg")
    return lines


def designed_scene_text(source_setup: Setup, result: DesignResult, name: str) -> str:
    """The scene file of the designed layout: the source scene's text with its lights
    replaced (checked by loading it)."""
    src = Path(source_setup.source)
    text = scene_without_lights(src.read_text(encoding="utf-8"))
    text = _set_top(text, "name", name)
    text = _set_top(text, "description", f"{source_setup.name} with a layout from scet "
                                          f"design-lights: {result.lights} lights")
    b, r, s = result.budget, result.region, result.settings
    c_e = source_setup.eye.rotation_center_m
    head = ["", "# Lights designed by `scet design-lights` (scet_render.design): "
            f"{len(result.arcs)} arcs" + (f" and {result.free_m.shape[0]} free lights"
                                          if result.free_m.shape[0] else "")
            + f", {result.lights} lights of a budget of {b.lights} ({b.style} style).",
            f"# Region: {r.describe()}.",
            f"# Search: differential evolution, seed {s.seed}, {result.de_evaluations} "
            f"evaluations ({result.de_message.rstrip('.')}); design poses {s.grid[0]} x "
            f"{s.grid[1]} grid + {s.motion} motion poses.",
            *[f"# {line}." for line in score_lines(result)]]
    tables = []
    wires = [g for g in result.setup.lights.groups if isinstance(g.emitter, WireMirror)]
    for i, a in enumerate(result.arcs):
        if wires:  # the wire style: each arc is a wire-wound mirror with its LED
            m = wires[i].emitter.posed(wires[i].pose)
            tables.append(f"# arc {i}: {a.describe()}; a wire_mirror of {m.turns} turns, its LED "
                          f"at the cornea's mirror image through the arc's plane\n"
                          + wire_mirror_table(m, wires[i].name))
        else:
            tables.append(f"# arc {i}: {a.describe()}\n"
                          + a.scene_table(c_e, f"arc{i}", b.source_diameter_mm))
    if result.free_m.shape[0]:
        pos = ",\n".join("  [" + ", ".join(f"{x:.9f}" for x in p) + "]" for p in result.free_m)
        tables.append("# free lights: placed one at a time where each adds most bands\n"
                      f"[[lights]]\nname = \"free\"\nkind = \"list\"\npositions_m = [\n{pos},\n]\n"
                      "source_diameter_mm = 0.4\n")
    text = text + "\n".join(head) + "\n\n" + "\n".join(tables)
    loaded = parse_scene(text, "<designed scene>")
    if not np.allclose(loaded.lights_world_m, result.setup.lights_world_m, atol=1e-8):
        raise RuntimeError("the written scene does not reproduce the designed lights")
    for a, b in zip(loaded.lights.groups, result.setup.lights.groups):
        if isinstance(b.emitter, WireMirror) and not (
                isinstance(a.emitter, WireMirror)
                and np.allclose(a.emitter.posed(a.pose).led_position_m,
                                b.emitter.posed(b.pose).led_position_m, atol=1e-12)):
            raise RuntimeError("the written scene does not reproduce the designed LEDs")
    return text


def _figure(result: DesignResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .objective import DesignPoses

    setup = result.setup
    model = result.model
    cam = setup.camera
    primary = DesignPoses(np.zeros(1), np.zeros(1), ("primary",))
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), gridspec_kw={"width_ratios": [1, 1, 0.9]})
    layouts = (("before", result.source_lights_m), ("after", setup.lights_world_m))
    for ax, (name, lights) in zip(axes[:2], layouts):
        g, u = layout_glints(setup, lights, primary)
        for b in range(model.count):
            ax.axhspan(model.first_row[b] - 0.5, model.last_row[b] + 0.5,
                       color="C0" if b % 2 else "C1", alpha=0.12 if model.design[b] else 0.04)
        ax.scatter(g[0, u[0], 0], g[0, u[0], 1], s=8, c="k")
        ax.set_xlim(-0.5, cam.width_px - 0.5)
        ax.set_ylim(cam.height_px - 0.5, -0.5)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: {lights.shape[0]} lights, primary gaze")
        ax.set_xlabel("u (px)")
    axes[0].set_ylabel("v (px); shaded: bands")
    ax = axes[2]
    y = np.arange(model.count)
    need = result.settings.need
    for k, (name, counts, sc) in enumerate((("before", result.counts_before, result.before),
                                           ("after", result.counts_after, result.after))):
        share = sc.per_band() if sc is not None else (counts >= need).mean(axis=0)
        ax.barh(y + 0.2 - 0.4 * k, 100 * share, height=0.38, label=name)
        med = np.median(counts, axis=0)
        for yy, s, m in zip(y, share, med):
            ax.text(100 * s + 1, yy + 0.2 - 0.4 * k, f"{m:.0f}", va="center", fontsize=7)
    ax.set_yticks(y, [f"{model.first_row[b]}-{model.last_row[b]}" for b in y])
    ax.invert_yaxis()
    ax.set_xlim(0, 115)
    ax.set_xlabel("% of poses valid (matcher); label: median glints")
    ax.set_ylabel("band rows")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write(path, buf.getvalue())


def write_design(source_setup: Setup, result: DesignResult, scene_path, report_dir,
                 name: str | None = None, extra_md: str = "") -> tuple[Path, Path]:
    """Write the designed scene and ``report_dir/<name>.md`` with its figure."""
    scene_path = Path(scene_path)
    name = name or scene_path.stem
    text = designed_scene_text(source_setup, result, name)
    atomic_write(scene_path, text)
    report_dir = Path(report_dir)
    fig_rel = f"figures/{name}_bands.png"
    _figure(_WithSource(result, source_setup.lights_world_m), report_dir / fig_rel)
    md = report_markdown(source_setup, result, name, scene_path, fig_rel) + extra_md
    report = report_dir / f"{name}.md"
    atomic_write(report, md)
    return scene_path, report


class _WithSource:
    """A result with the source layout's positions at hand for the figure."""

    def __init__(self, result: DesignResult, source_lights_m):
        self._r = result
        self.source_lights_m = np.asarray(source_lights_m)

    def __getattr__(self, key):
        return getattr(self._r, key)


def _band_table(result: DesignResult) -> str:
    m = result.model
    rows = ["| band rows | visible light | design band | before: valid (matcher) | "
            "before: median glints | after: valid (matcher) | after: median glints |",
            "|---|---|---|---|---|---|---|"]
    vb = result.before.per_band() if result.before is not None else None
    va = result.after.per_band() if result.after is not None else None
    for b in range(m.count):
        fmt = (lambda v: "-" if v is None else f"{100 * v[b]:.1f} %")  # noqa: E731
        rows.append(f"| {m.first_row[b]}-{m.last_row[b]} | {100 * m.fraction_visible[b]:.1f} % "
                    f"| {'yes' if m.design[b] else 'no'} | {fmt(vb)} | "
                    f"{np.median(result.counts_before[:, b]):.0f} | {fmt(va)} | "
                    f"{np.median(result.counts_after[:, b]):.0f} |")
    return "\n".join(rows) + "\n"


def report_markdown(source_setup: Setup, result: DesignResult, name: str, scene_path: Path,
                    fig_rel: str) -> str:
    b, r, s = result.budget, result.region, result.settings
    arcs = "".join(f"- arc {i}: {a.describe()}\n" for i, a in enumerate(result.arcs))
    free = (f"- {result.free_m.shape[0]} free lights (kind `list`)\n"
            if result.free_m.shape[0] else "")
    reasons = ""
    for label, sc in (("before", result.before), ("after", result.after)):
        if sc is not None:
            reasons += f"- {label}: " + ", ".join(f"{k} {v}" for k, v in sc.reasons.items()) + "\n"
    return f"""# Light layout for `{source_setup.name}`: `{name}`

Generated by `scet design-lights` (`scet_render.design`). Scene written to `{scene_path}`.

Budget: {b.lights} lights, {b.arcs} arcs, {b.free} free, {b.style} style. Region:
{r.describe()}. Search: scipy differential evolution, seed {s.seed}, popsize {s.popsize},
maxiter {s.maxiter} ({result.de_evaluations} evaluations; {result.de_message}), objective on
every {s.search_step}th of the design poses ({s.grid[0]} x {s.grid[1]} accuracy grid + {s.motion}
poses of the "saccades" trajectory); free lights from {s.candidates} positions drawn over the
region.

A glint counts for a band when it lands on rows its pulse dominates with at least
{ROW_WEIGHT_MIN:g} of its light, on the corneal cap, past the rendered scene's eyelids and skin,
and {MIN_SEPARATION_PX:g} px or more from every other glint. Design bands: those with at least
{100 * VISIBLE_SHARE_MIN:.0f} % of their light on visible rows. "Valid (matcher)": the band's
glints with e_f = {s.noise_px:g} px uniform noise, identified cold by
`estimator.matching.GlintMatcher` (ok, >= 5 identities, RMS <= 1 px); the error is the
angle between fitted and true optical axis.

## Scores

""" + "".join(f"- {line}\n" for line in score_lines(result)) + f"""
The region bound is the share of (pose, design band) pairs that any {s.need} well-separated
glints from the candidate positions could reach: where the cornea is not in a band's rows at a
pose (the eye looks down and the top rows show lid and sclera), no layout helps.

## Layout

{arcs}{free}
## Per band (all design poses)

{_band_table(result)}
Failures:
{reasons}
![bands and glints]({fig_rel})

Left and middle: the glints at primary gaze over the frame's bands (shaded; faint: not design
bands). Right: the share of design poses at which each band is valid, before and after, with
the median glint count.
"""


__all__ = ["scene_without_lights", "designed_scene_text", "write_design", "report_markdown", "score_lines"]
