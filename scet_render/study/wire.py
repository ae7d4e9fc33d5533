"""``scet study wire``: the point-source model's error for the wire-wound mirror, at solver level.

The prototype's glints are the LED seen in each wire turn seen in the cornea
(:mod:`estimator.geometry.wire`); the tracker models each turn as a fixed point source on its
axis at mid-width (the scene group's lights). Over the paper's 24 x 15 grid of gaze targets
this study measures, per turn:

* the glint's offset from the point-source model's glint (both visible), split into a fixed
  part (the mean offset vector over the grid: a lighting calibration can absorb a rigid part
  of it) and the part that moves with the eye (RMS about that mean);
* the glints lost (labelled not visible by the two-bounce solver where the point model sees
  them): the highlight off the strip's width, or a ray blocked;
* the brightness across turns at primary gaze (relative flux, :func:`wire_glint_flux`);
* the tracker's accuracy on noise-free glints: the point-source glints (the model's ideal) and
  the wire's glints through (a) the nominal point lights, (b) their calibrated pose, (c) the
  estimator's virtual-source option (:mod:`scet_render.study.wire_track`), each calibrated on
  5 x 5 targets and run with both gaze methods on the grid;
* the same on rendered glints where ``benchmarks/bench_wire_track.py`` has rendered them
  (``wire_mirror_rendered.npz`` beside the report), with the point-source ideal rendered on the
  same poses (``--ideal``: ``wire_mirror_rendered_ideal.npz``) and (c) - ideal;
* the solvers' cost in glint samples per second (one pose = every turn).

Nothing here renders (``benchmarks/bench_wire_render.py`` and ``bench_wire_track.py`` do).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write
from estimator.geometry import wire_kernel
from estimator.geometry.wire import eye_wire_glints, setup_wire_mirrors, wire_glint_flux
from estimator.scene import load_scene
from estimator.setup import Setup

from .wire_track import (BAND_GLINTS, BOOTSTRAP_RESAMPLES, COST_BANDS, COST_REPEATS, IDEAL_SOURCE_M,
                         MODELS, accuracy_table, band_cost, load_rendered, method_accuracy,
                         rendered_accuracy, table_lines)

DEFAULT_SCENE = "prototype_ov5647_wire"


def _wire(setup: Setup):
    found = setup_wire_mirrors(setup)
    if len(found) != 1:
        raise ValueError(f"{setup.name}: expected one wire_mirror light group, found {len(found)}")
    return found[0]


def wire_glints_for(setup: Setup, targets_m):
    """(glints_px (m, n, 2), visible (m, n)) of every light of ``setup`` for the eye fixating
    ``targets_m``: the feature-level simulator's noise-free glints (the wire group's turns by the
    two-bounce solver, other groups as points)."""
    from ..simulate import ground_truth_glints

    yaw, pitch = setup.eye.angles_toward(targets_m)
    g, vis, _ = ground_truth_glints(setup, yaw, pitch)
    return g, vis


def tracker_accuracy(setup: Setup, source: str, grid=(24, 15)) -> dict:
    """Calibrate on the 5 x 5 pattern and track the grid with noise-free glints of ``source``
    (``"point"``: the scene's point lights; ``"wire"``: the two-bounce glints). Returns per
    method the errors (deg, NaN where no estimate)."""
    from estimator.folders import calibrate_from_glints

    from ..simulate import parse_targets

    def glints(targets):
        if source == "wire":
            g, v = wire_glints_for(setup, targets)
        else:
            yaw, pitch = setup.eye.angles_toward(targets)
            g, v, _ = setup.eye.glints(setup.camera, setup.lights_world_m, yaw, pitch)
        return np.where(v[..., None], g, np.nan)

    cal_targets = parse_targets("calib:5x5", setup)
    cal = calibrate_from_glints(setup, glints(cal_targets), cal_targets)
    targets = parse_targets(f"grid:{grid[0]}x{grid[1]}", setup)
    g = glints(targets)
    return {"calibration_rms_px": float(cal.quality["rms_px"]), "calibration": cal, "glints": g,
            **method_accuracy(setup, cal, g, targets, ("polynomial", "geometric"))}


def led_placement_search(setup: Setup, *, grid=(8, 5), radii_mm=(4, 9.2, 14.4, 19.6, 24.8, 30),
                         angles_deg=tuple(range(-30, 121, 30)), axial_mm=tuple(range(-30, 31, 10)),
                         pairs_from: int = 40) -> dict:
    """Where to put the LED (part 4): every candidate position in the group's frame (radius
    from the arc's axis, angle from the first turn, offset along the arc normal; aimed at the
    middle turn) scored by the share of (pose, turn) pairs whose glint is visible over the
    ``grid`` of gaze targets and by its worst turn; then the best second LED for each of the
    ``pairs_from`` best singles (a glint counts when either LED makes it).

    Returns
    -------
    dict
        ``positions_m`` (C, 3) local frame, ``coverage`` (C,), ``worst_turn`` (C,), ``best``
        (index), ``pair`` (i, j), ``pair_coverage``, ``pair_worst_turn``, ``turns_reachable``
        (turns visible at some pose for some candidate), ``candidates``.
    """
    gi, _, _ = _wire(setup)
    group = setup.lights.groups[gi]
    local = group.emitter
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(*grid))
    mid = local.wire_axes_m[local.turns // 2]
    positions, vis = [], []
    for rho in radii_mm:
        for ang in np.radians(angles_deg):
            for ax in axial_mm:
                p = (local.center_m + 1e-3 * rho * (np.cos(ang) * local.u + np.sin(ang) * local.v)
                     + 1e-3 * ax * local.normal)
                aim = (mid - p) / np.linalg.norm(mid - p)
                try:
                    m = replace(local, led_position_m=p, led_aim=aim)
                except ValueError:  # inside or behind the strip
                    continue
                w = eye_wire_glints(setup.eye, setup.camera, m.posed(group.pose), yaw, pitch)
                positions.append(p)
                vis.append(w.visible.reshape(-1, local.turns))
    vis = np.array(vis)
    coverage, worst = vis.mean((1, 2)), vis.mean(1).min(1)
    best = int(np.argmax(coverage))
    pair, pair_cov, pair_worst = (best, best), coverage[best], worst[best]
    for a in np.argsort(-coverage)[:pairs_from]:
        u = vis[a][None] | vis
        c = u.mean((1, 2))
        j = int(np.argmax(c))
        if c[j] > pair_cov:
            pair, pair_cov, pair_worst = (int(a), j), float(c[j]), float(u[j].mean(0).min())
    return {"positions_m": np.array(positions), "coverage": coverage, "worst_turn": worst,
            "best": best, "pair": pair, "pair_coverage": float(pair_cov),
            "pair_worst_turn": float(pair_worst), "turns_reachable": int(vis.any(1).any(0).sum()),
            "candidates": len(positions), "grid": grid}


def ideal_rendered_path(rendered) -> Path:
    """Where ``bench_wire_track.py --ideal`` writes the ideal's renders beside ``rendered``."""
    rendered = Path(rendered)
    return rendered.with_name(rendered.stem + "_ideal" + rendered.suffix)


def run_wire_study(scene=DEFAULT_SCENE, *, grid=(24, 15), design: bool = False,
                   rendered=None) -> dict:
    """The solver-level measurements of the module docstring, as a dict of arrays and numbers;
    with ``rendered`` (a ``benchmarks/bench_wire_track.py`` file, used where it exists) the
    tracker's accuracy on its rendered glints too."""
    from ..simulate import parse_targets

    setup = load_scene(scene)
    _, first, mirror = _wire(setup)
    targets = setup.screen.grid(*grid)
    yaw, pitch = setup.eye.angles_toward(targets)
    eye, cam = setup.eye, setup.camera
    t0 = time.perf_counter()
    w = eye_wire_glints(eye, cam, mirror, yaw, pitch)
    t_wire = time.perf_counter() - t0
    t0 = time.perf_counter()
    p, pv, _ = eye.glints(cam, mirror.wire_axes_m, yaw, pitch)
    t_point = time.perf_counter() - t0
    both = w.visible & pv
    off = np.where(both[..., None], w.glints_px - p, np.nan)  # (m, T, 2)
    n_both = both.sum(0)
    fixed = np.where(n_both[:, None] > 0, np.nansum(off, axis=0) / np.maximum(n_both, 1)[:, None], np.nan)
    dev = np.where(both, np.sum((off - fixed) ** 2, -1), 0.0)
    moving = np.where(n_both > 0, np.sqrt(dev.sum(0) / np.maximum(n_both, 1)), np.nan)
    lost = (pv & ~w.visible).sum(0) / np.maximum(pv.sum(0), 1)
    c0 = eye.cornea_center(0.0, 0.0)
    g0, flux = wire_glint_flux(cam, mirror, c0, eye.cornea_radius_m)
    lit = flux[flux > 0]
    ideal = tracker_accuracy(setup, "point")
    ideal["rms_px"] = ideal["calibration_rms_px"]
    cal_t = parse_targets("calib:5x5", setup)
    wire_g = lambda t: np.where((v := wire_glints_for(setup, t))[1][..., None], v[0], np.nan)  # noqa: E731
    test_g = wire_g(targets)
    acc = accuracy_table(setup, wire_g(cal_t), cal_t, test_g, targets)
    cost = band_cost(setup, {"ideal": (setup, ideal["calibration"], ideal["glints"]),
                             **{k: (setup, acc[k]["calibration"], test_g) for k, _ in MODELS}}, targets)
    found = load_rendered(rendered) if rendered is not None else None
    ideal_found = None if found is None else load_rendered(ideal_rendered_path(rendered))
    return {
        "scene": setup.name, "grid": grid, "turns": mirror.turns, "poses": len(targets),
        "visible_wire": w.visible.mean(0), "visible_point": pv.mean(0),
        "visible_fraction": float(w.visible.mean()), "lost": lost,
        "fixed_px": np.linalg.norm(fixed, axis=-1), "moving_px": moving,
        "axial_mm": (np.nanmin(w.axial_m, 0) * 1e3, np.nanmax(w.axial_m, 0) * 1e3),
        "flux": flux, "flux_ratio": float(lit.max() / lit.min()) if lit.size else float("nan"),
        "led_relative": g0.led_relative, "wire_reflectance": g0.wire_reflectance,
        "wire_samples_per_s": w.visible.size / t_wire, "point_samples_per_s": pv.size / t_point,
        "accuracy": acc, "ideal": ideal, "cost": cost, "kernel": wire_kernel.ENABLED,
        "rendered": None if found is None else rendered_accuracy(setup, found, ideal_found),
        "design": led_placement_search(setup) if design else None,
    }


def _f(x, fmt="{:.2f}"):
    return "-" if not np.isfinite(x) else fmt.format(x)


def cost_lines(r: dict) -> list[str]:
    """The band step's cost, (a)-(c) and the ideal from one run, as ranges and ratios."""
    cost = r.get("cost")
    if not cost:
        return []
    labels = {"ideal": "point-source glints (the model's ideal), (b)", **dict(MODELS)}
    ref = cost["calibrated"]
    out = [f"**Cost of the band step** (geometric, {BAND_GLINTS} glints a sample, the grid's samples; "
           f"{COST_REPEATS} repeats in this run, lowest..highest samples/s; the ratio is of the "
           "ranges' midpoints against (b); the machine's speed swings ~2x). Batched: every sample in "
           f"one call; one band a call: {COST_BANDS} samples, one call each (a band at a time, "
           "where per-call overhead dominates). The option's highlight alternation ran "
           + ("compiled (Numba, `estimator.geometry.wire_kernel`)." if r.get("kernel") else
              "in numpy (no Numba).")
           + " `benchmarks/bench_wire_option.py` prints this table with the kernel and again in numpy "
             "(`NUMBA_DISABLE_JIT=1`).",
           "",
           "| glints / model | batched samples/s | ratio | one band a call, samples/s | ratio |",
           "|---|---:|---:|---:|---:|"]
    mid = lambda x: 0.5 * (x[0] + x[1])  # noqa: E731
    for k, label in labels.items():
        c = cost[k]
        out.append(f"| {label} | {c['batched'][0]:.0f}..{c['batched'][1]:.0f} | "
                   f"{mid(c['batched']) / mid(ref['batched']):.2f} | {c['per_band'][0]:.1f}..{c['per_band'][1]:.1f} | "
                   f"{mid(c['per_band']) / mid(ref['per_band']):.2f} |")
    return out


def ideal_lines(rr: dict) -> list[str]:
    """The rendered ideal's paragraph: what it is and (c) - ideal with its intervals."""
    ide = rr.get("ideal")
    if ide is None:
        return ["The point-source ideal is not rendered (`benchmarks/bench_wire_track.py --ideal` "
                "writes `reports/wire_mirror_rendered_ideal.npz`, which `scet study wire` then reads)."]
    e = ide["centroid_error_px"]
    out = [f"The ideal row: the same {rr['frames'][0]} + {rr['frames'][1]} poses, camera, size, "
           f"{rr['spp']} spp and conductor cornea, the wire turns replaced by spheres of "
           f"{1e3 * IDEAL_SOURCE_M:g} mm at the point-source model's positions (the turns' axes at "
           "mid-width, `wire_track.ideal_setup`), labelled by the closed-form projection, "
           "calibrated and tracked the default way (light model `points`): the tracker's model is "
           f"exact there up to the spheres' size. Centroids {np.median(e):.3f} px median, "
           f"{np.percentile(e, 95):.3f} px 95th percentile from those labels ({e.size} glints; "
           f"{ide['seconds']:.0f} s of rendering).",
           "",
           "| (c) - ideal | median of the errors, deg | 95 % interval | mean, deg | 95 % interval "
           "| per pose, deg min..max |",
           "|---|---:|---:|---:|---:|---:|"]
    for m in ("geometric", "polynomial"):
        d = ide["option_minus_ideal"][m]
        pp = d["per_pose"]
        out.append(f"| {m} | {_f(d['median'], '{:+.3f}')} | {_f(d['median_ci'][0], '{:+.3f}')} .. "
                   f"{_f(d['median_ci'][1], '{:+.3f}')} | {_f(d['mean'], '{:+.3f}')} | "
                   f"{_f(d['mean_ci'][0], '{:+.3f}')} .. {_f(d['mean_ci'][1], '{:+.3f}')} | "
                   + (f"{pp.min():+.3f} .. {pp.max():+.3f} |" if pp.size else "- |"))
    g = ide["option_minus_ideal"]["geometric"]
    lab = ide["option_on_labels"]
    out += ["", "Where the gap comes from: (c) calibrated and tracked on the wire renders' labels "
            f"(the solver's glints averaged over the {rr['led_mm']:g} mm LED's disk, noise-free, "
            f"nothing rendered) errs {np.nanmedian(lab['geometric']['errors_deg']):.3f} deg median, "
            f"{np.nanmax(lab['geometric']['errors_deg']):.3f} max (geometric; calibration RMS "
            f"{lab['rms_px']:.3f} px): most of (c) - ideal is the LED's size, which the option "
            "models as a point, not the renders' noise. The same on noise-free disk glints of "
            "smaller LEDs (`wire_track.led_size_accuracy`, the same poses): "
            + "; ".join(f"{1e3 * d:g} mm {v['median_deg']:.3f} deg median, {v['max_deg']:.3f} max "
                        f"(RMS {v['rms_px']:.2f} px)" for d, v in ide["led_sizes"].items())
            + "."]
    out += ["", f"Intervals: paired bootstrap over the {g['poses']} test poses ({BOOTSTRAP_RESAMPLES} "
            "resamples, percentile, seeded). The issue's target, (c) within 0.1 deg of the ideal "
            "(geometric, median): " + (
                f"met, the interval's upper end {_f(g['median_ci'][1], '{:+.3f}')} deg."
                if g["median_ci"][1] < 0.1 else
                f"met by the estimate ({_f(g['median'], '{:+.3f}')} deg), but the interval's upper end "
                f"({_f(g['median_ci'][1], '{:+.3f}')} deg) passes 0.1: {g['poses']} poses do not show it at "
                f"{100 * g['level']:.0f} %." if g["median"] < 0.1 else
                f"not met ({_f(g['median'], '{:+.3f}')} deg).")]
    return out


def wire_report(r: dict) -> str:
    """The study as markdown."""
    lines = [
        "# The wire-wound mirror: the point-source model's error (solver level)",
        "",
        f"Scene `{r['scene']}`, {r['turns']} turns, {r['poses']} gaze targets ({r['grid'][0]} x "
        f"{r['grid'][1]} grid over the screen). Generated by `scet study wire` "
        "(`scet_render/study/wire.py`); glints by `estimator.geometry.wire` (two bounces, exact); "
        "the point-source model is the scene group's lights (each turn's axis at mid-width). "
        "Noise-free at the solver level; the rendered tables read the benchmarks' renders.",
        "",
        "## Per turn",
        "",
        f"Visible over the grid: {100 * r['visible_fraction']:.1f} % of turn x pose pairs with the "
        f"wire (point model: {100 * r['visible_point'].mean():.1f} %). The highlight's position "
        "along its wire (axial, mm from mid-width; the strip is "
        "+-1 mm) shows why glints are lost: it follows the cornea.",
        "",
        "| turn | visible wire | visible point | lost | fixed offset px | moving px (RMS) | axial mm min..max | rel. flux at primary |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    fl = r["flux"][0] if r["flux"].ndim > 1 else r["flux"]
    peak = fl.max() if fl.max() > 0 else 1.0
    for k in range(r["turns"]):
        lines.append(
            f"| {k} | {100 * r['visible_wire'][k]:.0f} % | {100 * r['visible_point'][k]:.0f} % | "
            f"{100 * r['lost'][k]:.0f} % | {_f(r['fixed_px'][k])} | {_f(r['moving_px'][k])} | "
            f"{_f(r['axial_mm'][0][k], '{:.2f}')}..{_f(r['axial_mm'][1][k], '{:.2f}')} | "
            f"{_f(fl[k] / peak, '{:.3f}')} |")
    lines += [
        "",
        f"Brightness at primary gaze: the visible turns' relative flux spans {_f(r['flux_ratio'], '{:.1f}')}x "
        "(LED beam x wire reflectance x cornea Fresnel x the two mirrors' demagnification).",
        "",
        "## Tracker accuracy (noise-free, feature level)",
        "",
        "Calibration on the 5 x 5 pattern from the same kind of glints, then the grid; "
        "(a)-(c) as in `scet_render/study/wire_track.py`: (a) the point lights where the 3D "
        "model puts them (r_c, c_e, r_co fitted), (b) their pose calibrated too (the default), "
        "(c) the estimator option `light_model = \"wire_mirror\"`, whose calibration fits the "
        "mirror's pose on the moving highlights. Samples/s: the gaze call over the grid.",
        "",
    ]
    lines += table_lines(r["accuracy"], r["ideal"])
    lines += [""] + cost_lines(r)
    lines += ["", "## Tracker accuracy on rendered glints", ""]
    rr = r.get("rendered")
    if rr is None:
        lines.append("Not rendered (`benchmarks/bench_wire_track.py` writes "
                     "`reports/wire_mirror_rendered.npz`, which `scet study wire` then reads).")
    else:
        e = rr["centroid_error_px"]
        lines += [
            f"{rr['frames'][0]} calibration frames (5 x 5 pattern) and {rr['frames'][1]} test "
            f"poses rendered by `benchmarks/bench_wire_track.py` ({rr['spp']} spp, LED "
            f"{rr['led_mm']:g} mm, conductor cornea, strobe only, glint rows only; "
            f"{rr['seconds']:.0f} s of rendering). Centroids measured in the render tests' window "
            "at the solver's labels (identities known; the detector is not part of this "
            f"table): {np.median(e):.3f} px median, {np.percentile(e, 95):.3f} px 95th "
            f"percentile from the labels averaged over the LED's disk, {e.size} glints.",
            "",
        ]
        ide = rr.get("ideal")
        lines += (table_lines(rr["table"]) if ide is None else
                  table_lines(rr["table"], ide["row"], "ideal: point-like sources at the model's positions, (b)"))
        lines += [""] + ideal_lines(rr)
        sh = rr["disk_shift_px"]
        lines += [
            "",
            f"The option models the LED as a point. The rendered LED's glints (its {rr['led_mm']:g} mm "
            f"disk's image, clipped where its highlight leaves the strip) lie {np.median(sh):.3f} px "
            f"median, {np.percentile(sh, 95):.3f} px 95th percentile, {sh.max():.3f} px max from the "
            "LED centre's glints: most of the option's calibration residual, against the centroids' "
            f"{np.median(e):.3f} px median error. Samples/s here are over {rr['frames'][1]} test "
            "samples (start-up costs included).",
        ]
    lines += ["", "## Where to put the LED", ""]
    d = r.get("design")
    if d is None:
        lines.append("Not run (`scet study wire --design`: a few minutes).")
    else:
        b, (i, j) = d["best"], d["pair"]
        mm = lambda p: "[" + ", ".join(f"{1e3 * x:.1f}" for x in p) + "] mm"  # noqa: E731
        lines += [
            f"{d['candidates']} LED positions (group frame, aimed at the middle turn) over a "
            f"{d['grid'][0]} x {d['grid'][1]} grid of gaze targets. Best single LED at "
            f"{mm(d['positions_m'][b])}: {100 * d['coverage'][b]:.1f} % of (pose, turn) glints "
            f"visible, worst turn {100 * d['worst_turn'][b]:.0f} %. Best pair, {mm(d['positions_m'][i])} "
            f"and {mm(d['positions_m'][j])}: {100 * d['pair_coverage']:.1f} %, worst turn "
            f"{100 * d['pair_worst_turn']:.0f} %. Turns that some candidate lights at some pose: "
            f"{d['turns_reachable']} of {r['turns']}.",
            "",
            "A turn's highlight stays on the 2 mm strip only while the LED sits near the mirror "
            "image of the cornea as that turn sees it; the cornea's travel over the screen moves "
            "it by ~1-2 mm along the wire, so the coverage is sharp in the LED's position. "
            + ("No candidate single LED or pair keeps every turn's glint over the whole grid."
               if d["pair_worst_turn"] < 1 else "The best pair keeps every turn's glint."),
        ]
    lines += ["", "## Rendered glints", "",
              "Not rendered here: `benchmarks/bench_wire_render.py` renders the scene (2 mm LED, "
              "conductor cornea) at several spp and prints the glint centroids' error against "
              "the labels; `tests/scet_render/test_wire_render.py` (slow) holds it to 0.1 px median."]
    lines += [
        "",
        "## Cost of the labels",
        "",
        f"Glint samples (turn x pose) per second on this machine: two-bounce solver "
        f"{r['wire_samples_per_s']:.0f}, point-source projection {r['point_samples_per_s']:.0f} "
        f"({r['point_samples_per_s'] / r['wire_samples_per_s']:.0f}x); the machine's speed swings ~2x.",
        "",
        "## Not done here",
        "",
        "The option models the LED as a point: a finite LED's glint is its disk's image, "
        "clipped where the highlight runs off the strip (the rendered table's LED is 2 mm).",
        "",
    ]
    return "\n".join(lines)


def write_wire_report(report_dir, scene=DEFAULT_SCENE, *, design: bool = False) -> Path:
    """Write ``wire_mirror.md`` in ``report_dir``, with the rendered table where
    ``wire_mirror_rendered.npz`` lies beside it (and the ideal's, ``..._ideal.npz``); the
    "## Design" sections that ``scet design-lights --wire-led`` and the designer's notes
    appended to an existing report are kept."""
    r = run_wire_study(scene, design=design, rendered=Path(report_dir) / "wire_mirror_rendered.npz")
    path = Path(report_dir) / "wire_mirror.md"
    text = wire_report(r)
    old = path.read_text(encoding="utf-8") if path.exists() else ""
    if "\n## Design" in old:  # the design sections other commands write (design/wire_report.py)
        text = text.rstrip() + "\n\n" + old[old.index("\n## Design") + 1:]
    return atomic_write(path, text)


__all__ = ["run_wire_study", "wire_report", "write_wire_report", "wire_glints_for",
           "tracker_accuracy", "led_placement_search", "DEFAULT_SCENE"]
