"""``scet design-lights``, ``scet study events`` and ``scet study aspheric``: the subcommands
of the lighting designer and of the studies (wired into :mod:`scet_render.cli` by :func:`add_parsers`). Heavy
imports happen inside the commands; progress bars live here, not in the library."""

from __future__ import annotations

from pathlib import Path

from .cli_progress import StageBars, progress_bar
from .runner import MAX_SEED, finite, integer


def rendered_band_shares(setup, samples_csv) -> dict:
    """Valid share of a ``samples.csv``'s samples over design bands (at least half their light
    on visible rows) and over all bands, with the counts."""
    from estimator.banding import band_layout
    from estimator.folders import read_samples_csv
    from scet_render.design.objective import VISIBLE_SHARE_MIN

    rows = read_samples_csv(samples_csv)
    layouts = {}
    design = [0, 0]
    every = [0, 0]
    for r in rows:
        f, j = int(r["frame"]), int(r["strobe"])
        if f not in layouts:
            layouts[f] = {b.pulse_index: b.fraction_visible
                          for b in band_layout(setup.sensor, setup.strobe, f)}
        ok = r["reason"] == "ok"
        every[0] += ok
        every[1] += 1
        if layouts[f].get(j, 0.0) >= VISIBLE_SHARE_MIN:
            design[0] += ok
            design[1] += 1
    return {"design": design[0] / max(design[1], 1), "design_n": design[1],
            "all": every[0] / max(every[1], 1), "all_n": every[1]}


def cmd_design_lights(args) -> int:
    from estimator.scene import load_scene
    from scet_render.design import Budget, Region, SearchSettings, design_lights, write_design

    setup = load_scene(args.scene)
    if args.wire_led:
        return _wire_led(setup, args)
    budget = Budget(lights=args.lights, arcs=args.arcs, free=0 if args.style == "wire" else args.free,
                    style=args.style, strip_width_m=args.strip_width_mm * 1e-3)
    region = Region(min_eye_distance_m=args.min_eye_distance_mm * 1e-3,
                    max_eye_distance_m=args.max_eye_distance_mm * 1e-3,
                    max_z_m=args.max_z_mm * 1e-3, screen_margin_deg=args.screen_margin_deg,
                    frame_z_m=None if args.frame_z_mm is None else args.frame_z_mm * 1e-3)
    settings = SearchSettings(seed=args.seed, maxiter=args.maxiter, popsize=args.popsize,
                              need=args.need, motion=args.motion, search_step=args.search_step,
                              candidates=args.candidates)
    out = args.out or Path("scenes") / f"{setup.name}_designed.toml"
    bars = StageBars()
    try:
        result = design_lights(setup, budget, region, settings, progress=bars.update)
    finally:
        bars.close()
    extra = ""
    scene_path, report = write_design(setup, result, out, args.report_dir)
    if args.validate:
        extra = _validate_design(scene_path, args, bars)
        scene_path, report = write_design(setup, result, out, args.report_dir, extra_md=extra)
    from scet_render.design.report import score_lines

    for line in score_lines(result):
        print(line)
    if extra:
        print(extra.strip().splitlines()[-1])
    print(f"{result.lights} lights; scene written to {scene_path}, report to {report}")
    return 0


def _wire_led(setup, args) -> int:
    """``--wire-led``: the wire mirror's LED study; its section in ``--wire-report``."""
    from scet_render.design.wire_report import led_design_study, write_design_section

    bar, update = progress_bar(0, "pos", "LED positions")
    try:
        d = led_design_study(setup, progress=update)
    finally:
        bar.close()
    path = write_design_section(args.wire_report, d)
    s = d["scores"][d["rule"]]
    print(f"LED by the design rule: {100 * s.lost(d['mirror'].width_m):.1f} % of glints lost on the "
          f"{1e3 * d['mirror'].width_m:g} mm strip, {1e3 * s.required_width_m:.2f} mm keeps all, "
          f"brightness ratio {s.flux_ratio:.1f}; section 'Design' written to {path}")
    return 0


def _validate_design(scene_path: Path, args, bars: StageBars) -> str:
    """``scet validate --quick`` on the designed scene; the report's section on it."""
    from estimator.scene import load_scene
    from estimator.banding import scaled_setup, strobe_setup
    from scet_render.validate import run_validation

    name = scene_path.stem
    report_dir = Path(args.report_dir) / f"{name}_validation"
    bars2 = StageBars()
    try:
        result = run_validation(str(scene_path), quick=True, out_dir=Path(args.validate_out) / name,
                                seed=args.seed, progress=bars2.update, report_dir=report_dir)
    finally:
        bars2.close()
    setup = scaled_setup(load_scene(str(scene_path)), result.config.scale)
    lines = []
    for ppf in result.config.pulses_per_frame:
        for method in ("polynomial", "geometric"):
            csv = Path(args.validate_out) / name / f"samples_{method}_p{ppf}.csv"
            s = rendered_band_shares(strobe_setup(setup, ppf), csv)
            row = result.row("rendered", method, ppf)
            lines.append(f"| {ppf} | {method} | {s['design_n']} | {100 * s['design']:.1f} % | "
                         f"{s['all_n']} | {100 * s['all']:.1f} % | {row.mean_deg:.3f} | "
                         f"{row.median_deg:.3f} |")
    return ("\n## Rendered: `scet validate --quick` on the designed scene\n\n"
            f"320x240, 4 spp, conductor cornea, {result.config.frames} test frames per strobe "
            f"setting (report: `{report_dir}/validation.md`). Valid samples (own glints or "
            "prior-assisted, as the tracker gives them):\n\n"
            "| pulses/frame | method | design-band samples | valid | all samples | valid | "
            "mean deg | median deg |\n|---|---|---|---|---|---|---|---|\n"
            + "\n".join(lines) + f"\n\nIdentities right: {100 * result.identity_rate:.2f} % of "
            f"{result.n_identified}.\n")


def cmd_study_events(args) -> int:
    from scet_render.study import run_event_study
    from scet_render.study.events_report import buys_table

    lightings = {}
    for item in args.lighting or ["current=paper_sim"]:
        label, sep, scene = item.partition("=")
        if not sep or not label or not scene:
            raise ValueError(f"--lighting {item!r}: expected LABEL=SCENE, e.g. designed=scenes/"
                             "paper_sim_designed.toml")
        lightings[label] = scene
    bars = StageBars()
    try:
        conditions, path = run_event_study(lightings, quick=args.quick, out_dir=args.out,
                                           report_dir=args.report_dir, seed=args.seed,
                                           progress=bars.update, render=not args.no_render)
    finally:
        bars.close()
    print(buys_table(conditions))
    print(f"report written to {path}")
    return 0


def cornea_models(text: str) -> tuple:
    """``--cornea-models`` text: comma-separated names of estimator.cornea.CORNEA_MODELS,
    starting with ``sphere`` (the study's tables compare the conic tracker with it)."""
    import argparse

    from estimator.cornea import CORNEA_MODELS

    names = tuple(t.strip() for t in str(text).split(","))
    bad = [n for n in names if n not in CORNEA_MODELS]
    if bad or not names or names[0] != "sphere" or len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected sphere or sphere,conic (models {', '.join(CORNEA_MODELS)})")
    return names


def cmd_study_aspheric(args) -> int:
    from scet_render.study.aspheric import parse_asphericities, run_aspheric_study
    from scet_render.study.aspheric_report import accuracy_table, conic_table

    qs = parse_asphericities(args.q)
    bars = StageBars()
    try:
        conditions, _, path = run_aspheric_study(args.scene, quick=args.quick, out_dir=args.out,
                                                 report_dir=args.report_dir, asphericities=qs,
                                                 seed=args.seed, progress=bars.update,
                                                 cornea_models=tuple(args.cornea_models))
    finally:
        bars.close()
    print(accuracy_table([c for c in conditions if c.cornea_model == "sphere"]))
    if any(c.cornea_model == "conic" for c in conditions):
        print(conic_table(conditions))
    print(f"report written to {path}")
    return 0


def cmd_study_lens(args) -> int:
    from estimator.formats import atomic_write
    from estimator.scene import load_scene

    from .study.lens import run_study

    setup = load_scene(args.scene)
    gaze, steps, command = None, 0, f"scet study lens {setup.name} --spp {args.spp} --seed " \
        f"{args.seed} --poses {args.poses}"
    if args.gaze:
        from dataclasses import replace

        from .study.lens_gaze import CONFIG, gaze_conditions, gaze_runner

        config = replace(CONFIG, spp=args.gaze_spp, frames=args.gaze_frames,
                         calib_grid=(args.gaze_grid, args.gaze_grid))
        gaze, steps = gaze_runner(setup, args.out, config=config, seed=args.seed), \
            len(gaze_conditions(setup))
        command += (f" --gaze --gaze-spp {args.gaze_spp} --gaze-frames {args.gaze_frames} "
                    f"--gaze-grid {args.gaze_grid}")
    bar, update = progress_bar(10 + steps, "condition", f"study lens {setup.name}")
    try:
        text, _, _ = run_study(setup, spp=args.spp, seed=args.seed, poses=args.poses,
                               progress=update, gaze=gaze, gaze_steps=steps, command=command)
    finally:
        bar.close()
    path = atomic_write(Path(args.report_dir) / "lens.md", text)
    print(text)
    print(f"report written to {path}")
    return 0


def cmd_study_wire(args) -> int:
    from scet_render.study.wire import write_wire_report

    path = write_wire_report(args.report_dir, args.scene or "prototype_ov5647_wire", design=args.design)
    print(f"report written to {path}")
    return 0


def add_parsers(sub) -> None:
    """Add ``design-lights`` and ``study`` to the ``scet`` subcommands."""
    scene_help = "scene file or built-in scene name (default: paper_sim)"
    p = sub.add_parser("design-lights", help="search a light layout that puts enough glints in "
                                             "every band; writes a scene and a report")
    p.add_argument("scene", nargs="?", help=scene_help)
    p.add_argument("--lights", type=integer(1, 10_000), default=80, help="light budget (default 80)")
    p.add_argument("--arcs", type=integer(1, 100), default=3, help="arcs of the family (default 3)")
    p.add_argument("--free", type=integer(0, 10_000), default=16,
                   help="lights of the budget kept for free positions (default 16; 0 in wire style)")
    p.add_argument("--style", choices=("free", "wire"), default="free",
                   help="wire: each arc a wire_mirror (0.8 mm turns, one LED), as the prototype's wound mirror")
    p.add_argument("--strip-width-mm", type=finite(0.8, 50.0), default=2.0,
                   help="wire style: the strips' width (default 2, the prototype's)")
    p.add_argument("--wire-led", action="store_true",
                   help="instead: where to put the LED of the scene's wire_mirror (the Design "
                        "section of --wire-report)")
    p.add_argument("--wire-report", type=Path, default=Path("reports/wire_mirror.md"))
    p.add_argument("--min-eye-distance-mm", type=finite(0.0, 1000.0), default=20.0)
    p.add_argument("--max-eye-distance-mm", type=finite(0.0, 1000.0), default=50.0)
    p.add_argument("--max-z-mm", type=finite(-1000.0, 1000.0), default=-2.0, help="lights in front of this plane")
    p.add_argument("--screen-margin-deg", type=finite(0.0, 45.0), default=2.0)
    p.add_argument("--frame-z-mm", type=finite(-1000.0, 1000.0), help="put lights on the glasses-frame plane z")
    p.add_argument("--seed", type=integer(0, MAX_SEED), default=0)
    p.add_argument("--maxiter", type=integer(1, 10_000), default=40, help="differential evolution generations")
    p.add_argument("--popsize", type=integer(1, 1000), default=8)
    p.add_argument("--need", type=integer(1, 1000), default=6, help="glints a band should hold (>= 5)")
    p.add_argument("--motion", type=integer(1, 100_000), default=96, help="design poses from the motion model")
    p.add_argument("--search-step", type=integer(1, 100_000), default=3, help="search on every n-th design pose")
    p.add_argument("--candidates", type=integer(1, 1_000_000), default=1500, help="free positions drawn")
    p.add_argument("--out", type=Path, help="scene file (default scenes/<scene>_designed.toml)")
    p.add_argument("--report-dir", type=Path, default=Path("reports/design"))
    p.add_argument("--validate", action="store_true",
                   help="also run scet validate --quick on the designed scene (renders)")
    p.add_argument("--validate-out", type=Path, default=Path("out/design-validate"))
    p.set_defaults(func=cmd_design_lights)

    p = sub.add_parser("study", help="studies on rendered sequences")
    studies = p.add_subparsers(dest="study", required=True)
    e = studies.add_parser(
        "events", help="saccade and microsaccade timing at the band rate: the band detector "
                       "(estimator.events) and pymovements' I-VT and I-DT on hundreds of "
                       "simulated saccades at 4 / 8 / 16 pulses, S = 524 and 786, against 60 Hz "
                       "and a 1 kHz reference, with a rendered full-size sub-sequence: "
                       "reports/events.md",
        description="Full mode (default): the feature-level simulation of 200 saccades and 100 "
                    "microsaccades per lighting (the designed lighting is always added), the "
                    "error budget, the band detector's changes against its first round, and "
                    "the rendered sub-sequence (570 frames, 640 x 480; rendered into --out "
                    "unless --no-render). --quick: the rendered study at reduced size.")
    e.add_argument("--lighting", action="append", metavar="LABEL=SCENE",
                   help="a lighting to study (repeatable; default current=paper_sim; full mode "
                        "adds designed=scenes/paper_sim_designed.toml)")
    e.add_argument("--quick", action="store_true",
                   help="the rendered study at reduced size instead: 320x240, 4 spp, conductor "
                        "cornea, 120 frames per setting")
    e.add_argument("--no-render", action="store_true",
                   help="full mode: score only the sub-sequence frames already rendered in "
                        "--out (none: the report says the comparison was not run)")
    e.add_argument("--seed", type=integer(0, MAX_SEED), default=0)
    e.add_argument("--out", type=Path, default=Path("out/events"), help="work folder for renders")
    e.add_argument("--report-dir", type=Path, default=Path("reports"))
    e.set_defaults(func=cmd_study_events)
    a = studies.add_parser("aspheric", help="the spherical tracker on conic corneas (Q), rendered "
                                            "and simulated, lids static, off and moving: reports/aspheric.md")
    a.add_argument("scene", nargs="?", help=scene_help)
    a.add_argument("--q", default="0,-0.1,-0.25,-0.45",
                   help="conic constants, comma separated, -1 < Q <= 1 (default 0,-0.1,-0.25,-0.45; "
                        "a list that starts with a minus sign needs --q=...)")
    a.add_argument("--quick", action="store_true",
                   help="reduced size: 320x240, 4 spp, conductor cornea, 60 frames")
    a.add_argument("--seed", type=integer(0, MAX_SEED), default=0)
    a.add_argument("--out", type=Path, default=Path("out/aspheric"), help="work folder for renders")
    a.add_argument("--report-dir", type=Path, default=Path("reports"))
    a.add_argument("--cornea-models", type=cornea_models, default=("sphere", "conic"),
                   help="the trackers to run on the same renders, comma separated: sphere (the "
                        "paper's), conic (Q calibrated; scet calibrate --cornea-model conic); "
                        "default sphere,conic")
    a.set_defaults(func=cmd_study_aspheric)
    lens = studies.add_parser("lens", help="glint detection and centroid error through the "
                                           "scene's lens: defocus, focal length, aperture, "
                                           "distance (reports/lens.md)")
    lens.add_argument("scene", nargs="?", default="prototype_ov5647",
                      help="scene file or built-in scene name (default: prototype_ov5647)")
    lens.add_argument("--spp", type=integer(1, 4096), default=16)
    lens.add_argument("--seed", type=integer(0, MAX_SEED), default=0)
    lens.add_argument("--poses", type=integer(1, 3), default=3, help="fixations per condition (1-3)")
    lens.add_argument("--gaze", action="store_true",
                      help="also calibrate and track per lens condition (valid share, gaze "
                           "error; tracked with the lens model, as a pinhole, from a board "
                           "calibration): minutes per condition")
    lens.add_argument("--gaze-spp", type=integer(1, 4096), default=4,
                      help="spp of the gaze renders (conductor cornea; default 4)")
    lens.add_argument("--gaze-frames", type=integer(1, 10_000), default=24,
                      help="banded test frames per gaze condition (15 per fixation; default 24)")
    lens.add_argument("--gaze-grid", type=integer(2, 24), default=4,
                      help="calibration grid N x N of the gaze conditions (default 4)")
    lens.add_argument("--out", type=Path, default=Path("out/lens_study"),
                      help="work folder of the gaze renders (reused by a rerun)")
    lens.add_argument("--report-dir", type=Path, default=Path("reports"))
    lens.set_defaults(func=cmd_study_lens)
    w = studies.add_parser("wire", help="the wire-wound mirror's glints against the point-source "
                                        "model, solver level: reports/wire_mirror.md")
    w.add_argument("scene", nargs="?", help="scene with one wire_mirror light group "
                                            "(default: prototype_ov5647_wire)")
    w.add_argument("--report-dir", type=Path, default=Path("reports"))
    w.add_argument("--design", action="store_true",
                   help="also search the LED's position (a few minutes)")
    w.set_defaults(func=cmd_study_wire)


__all__ = ["add_parsers", "rendered_band_shares", "cmd_design_lights", "cmd_study_events",
           "cmd_study_aspheric", "cmd_study_lens", "cmd_study_wire", "cornea_models"]
