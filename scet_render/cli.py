"""The ``scet`` command line: one command, one subcommand per job.

Heavy imports happen inside the subcommand that needs them. Errors in the user's input (a bad
scene file, a bad target spec) print one line naming the problem and exit with status 2.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .cli_data import add_cluster_arguments, add_dataset_parsers, add_render_parser
from .cli_progress import StageBars, print_table, progress_bar
from .cli_camera import (add_parsers as add_camera_parsers, camera_arg, hold_to_camera_file,
                         record_camera_file, with_camera_file)
from .cli_scene import describe_lens, folder_scene
from .runner import MAX_FRAMES, MAX_SEED, MAX_SPP, finite, integer, run


def _describe(setup) -> str:
    cam, sen, st = setup.camera, setup.sensor, setup.strobe
    return (f"scene {setup.name} ({setup.source})\n"
            f"  camera {cam.width_px}x{cam.height_px} px, f = {cam.fx_px:g} px, at "
            f"{np.round(cam.position_m * 1e3, 2).tolist()} mm" + describe_lens(cam) + "\n"
            f"  eye r_c = {setup.eye.cornea_radius_m * 1e3:g} mm, r_co = "
            f"{setup.eye.cornea_offset_m * 1e3:.3f} mm, limbus {setup.eye.limbus_depth_m * 1e3:.3f} mm "
            f"behind the apex"
            + (f", asphericity Q = {setup.eye.cornea_asphericity:g}" if setup.eye.cornea_asphericity else "")
            + "\n"
            f"  {setup.lights.count} lights in {len(setup.lights.groups)} group(s): "
            + ", ".join(f"{g.name} ({g.kind}, {g.count})" for g in setup.lights.groups) + "\n"
            f"  sensor S = {sen.total_lines}, N = {sen.visible_lines}, frame {sen.frame_period_s * 1e3:g} ms, "
            f"exposure {sen.exposure_s * 1e6:g} us\n"
            f"  strobe {st.pulses_per_frame} pulses/frame of {st.pulse_s * 1e6:g} us every "
            f"{st.period_s * 1e6:g} us, phase {st.phase_s * 1e6:g} us"
            + ("" if setup.eyelids is None else _describe_lids(setup.eyelids)))


def _describe_lids(lids) -> str:
    return (f"\n  eyelids follow the eye: upper margin {np.degrees(lids.upper_margin_rad):.2f} deg"
            f" + {lids.upper_gain:g} x pitch, lower {np.degrees(lids.lower_margin_rad):.2f} deg + "
            f"{lids.lower_gain:g} x pitch; {lids.blink_rate_per_min:g} blinks/min, "
            f"{lids.lash_count} lashes")


def cmd_scenes(args) -> int:
    from estimator.scene import builtin_scenes, load_scene

    for name in builtin_scenes():
        setup = load_scene(name)
        print(f"{name:<20} {setup.description}")
    return 0


def cmd_scene(args) -> int:
    from estimator.scene import load_scene

    print(_describe(load_scene(args.scene)))
    return 0


def cmd_bands_measure(args) -> int:
    """``scet bands --measure CAPTURE_DIR``: the capture's timing, measured from its bands."""
    import json

    from estimator.capture import CaptureFolder
    from estimator.capture.timing import measure_capture
    from estimator.formats import atomic_write

    if getattr(args, "follow", False):
        # Live: one line a frame as the capture is written (scet capture / scet run).
        def live(fb):
            print(f"frame {fb.index}: " + (f"phase {fb.phase_rows:.2f} rows, pitch {fb.pitch_rows:.3f}"
                                           if fb.status == "bands" else fb.status), flush=True)

        m = measure_capture(args.measure, follow=True, timeout_s=args.follow_timeout,
                            on_frame=live)
    else:
        total = max(CaptureFolder(args.measure).index) + 1
        bar, update = progress_bar(total, "frame", "measuring bands")
        try:
            m = measure_capture(args.measure, progress=update)
        finally:
            bar.close()
    line_us = m.frame_period_s / m.total_lines * 1e6
    rows = [["total lines S", f"{m.total_lines:.3f}", f"{m.total_lines_sd:.3f}", "lines"],
            ["exposure", f"{m.exposure_s * 1e6:.2f}", f"{m.exposure_s_sd * 1e6:.2f}", "us"],
            ["pulse width", f"{m.pulse_s * 1e6:.2f}", f"{m.pulse_s_sd * 1e6:.2f}", "us"],
            ["band pitch", f"{m.pitch_rows:.4f}", f"{m.pitch_rows_sd:.4f}", "rows"],
            ["drift per frame", f"{m.drift_rows_per_frame:.4f}",
             f"{m.drift_rows_per_frame_sd:.4f}", "rows"],
            ["strobe clock", f"{m.clock_ppm:+.2f}", f"{m.clock_ppm_sd:.2f}", "ppm"],
            ["phase, first frame", f"{m.phase_s[0] * 1e6:.2f}", f"{m.phase_s_sd[0] * 1e6:.2f}",
             "us"],
            ["line time", f"{line_us:.4f}", "", "us"]]
    print(f"timing of {args.measure}: {sum(f.status == 'bands' for f in m.frames)} of "
          f"{len(m.frames)} frames with bands, {m.periods_per_frame} strobe periods a frame")
    print_table(rows, ["quantity", "value", "sd", "unit"])
    for f in m.frames:
        if f.status != "bands":
            print(f"frame {f.index}: {f.status} ({f.detail})")
    for note in m.notes:
        print(f"note: {note}")
    if args.json:
        atomic_write(args.json, json.dumps(m.to_dict(), indent=1) + "\n")
        print(f"written to {args.json}")
    return 0


def cmd_bands(args) -> int:
    if getattr(args, "measure", None) is not None:  # cmd_demo calls this with its own args
        return cmd_bands_measure(args)
    from estimator.banding import band_gap_rows, band_height, partial_lines
    from estimator.scene import load_scene
    from scet_render.band_diagram import band_table, draw_band_diagram

    setup = load_scene(args.scene)
    sen, st = setup.sensor, setup.strobe
    table = band_table(sen, st, args.frame)
    rows = [[r["strobe"], f"{r['time_us']:.2f}", f"{r['frame_time_us']:.2f}", f"{r['k_first']:.2f}",
             r["first_row"], r["last_row"], r["partial_rows"], "yes" if r["visible"] else "no",
             f"{r['fraction_visible']:.2f}"] for r in table]
    print(f"band layout of frame {args.frame}, scene {setup.name}: Eq. (7) band height "
          f"{band_height(sen, st.pulse_s):.2f} rows, Eq. (5) partial lines {partial_lines(sen, st.pulse_s):.2f}, "
          f"gap between bands {band_gap_rows(sen, st):.2f} rows (negative: overlap)")
    print_table(rows, ["strobe", "time_us", "in_frame_us", "k_j", "first_row", "last_row",
                        "partial_rows", "visible", "visible_share"])
    n_vis = sum(r["visible"] for r in table)
    share = sum(r["fraction_visible"] for r in table)
    print(f"{n_vis} bands touch the {sen.visible_lines} visible rows; visible share {share:.2f} "
          f"(pulses x N / S = {st.pulses_per_frame * sen.visible_lines / sen.total_lines:.2f})")
    if args.png:
        path = draw_band_diagram(sen, st, args.png, frame_index=args.frame, frames=args.frames)
        print(f"diagram written to {path}")
    return 0


def cmd_simulate(args) -> int:
    from estimator.scene import load_scene
    from scet_render.simulate import (
        glint_statistics,
        parse_targets,
        save_observations,
        simulate_glints,
    )

    setup = load_scene(args.scene)
    targets = parse_targets(args.targets, setup)
    obs = simulate_glints(setup, targets, noise_px=args.noise, noise_model=args.noise_model, rng=args.seed)
    path = save_observations(args.out, obs, setup)
    stats = glint_statistics(obs)
    print(f"{stats['targets']} targets x {stats['lights']} lights, e_f = {args.noise:g} px "
          f"({args.noise_model}), seed {args.seed}: visible glints per target min {stats['visible_min']}, "
          f"mean {stats['visible_mean']:.2f}, max {stats['visible_max']}; written to {path}")
    return 0


def cmd_export_mitsuba(args) -> int:
    from estimator.scene import load_scene

    from .render import SceneOptions, export_mitsuba

    setup = load_scene(args.scene)
    options = SceneOptions(channels="grey", cornea=args.cornea)
    path = export_mitsuba(setup, args.out, options, yaw_rad=np.radians(args.yaw_deg),
                          pitch_rad=np.radians(args.pitch_deg), spp=args.spp)
    print(f"Mitsuba scene written to {path} (render it with: mitsuba {path})"
          + (f"; it renders the undistorted image, the lens distortion is in "
             f"{path.parent / 'camera.json'}" if setup.camera.has_distortion else ""))
    return 0


def cmd_calibrate(args) -> int:
    from estimator.folders import calibrate_from_folder, save_calibration
    from estimator.inputs import input_files, refuse_overwriting_inputs

    refuse_overwriting_inputs(args.out, input_files(args.dir))
    setup = with_camera_file(folder_scene(args.dir, args.scene, "scet calibrate"), args.camera)
    cal = calibrate_from_folder(args.dir, setup, cornea_model=args.cornea_model,
                                light_model=args.light_model)
    path = save_calibration(record_camera_file(cal, args.camera), args.out)
    q = cal.quality
    conic = f"conic cornea Q = {cal.cornea_asphericity:.4f}, " if cal.conic else ""
    print(f"calibration written to {path}: {conic}r_c = {cal.cornea_radius_m * 1e3:.3f} mm, "
          f"r_co = {cal.orbit_radius_m * 1e3:.3f} mm, glint RMS {q.get('rms_px', float('nan')):.3f} px, "
          f"{q.get('frames_used', '?')} of {q.get('frames_total', '?')} frames")
    for name, why in sorted(q.get("mappings_skipped", {}).items()):
        print(f"mapping {name} skipped: {why} (fitted: {', '.join(sorted(cal.mappings)) or 'none'}; "
              f"recorded in {path}, quality.mappings_skipped)")
    for w in cal.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if cal.warnings:
        print(f"scet calibrate: {len(cal.warnings)} plausibility check(s) failed; they are "
              f"recorded in {path} (quality.warnings)", file=sys.stderr)
    return 0


def cmd_compare(args) -> int:
    import json

    from estimator.folders import load_calibration
    from estimator.formats import atomic_write

    from .compare import compare_capture
    from .compare.report import write_report

    setup = with_camera_file(folder_scene(args.dir, args.scene, "scet compare"), args.camera)
    cal = load_calibration(args.calibration) if args.calibration is not None else None
    bars = StageBars()
    try:
        result = compare_capture(args.dir, setup, calibration=cal, method=args.method,
                                 frames=args.frames, spp=args.spp, cornea=args.cornea,
                                 seed=args.seed, progress=bars.update)
    finally:
        bars.close()
    if args.camera is not None:
        result.notes.append(f"camera file {args.camera}: its intrinsics and lens distortion "
                            "replace the scene's; the capture's detections are undistorted "
                            "and the render is made through the same lens")
    path = write_report(result, args.report_dir)
    if args.json is not None:
        atomic_write(args.json, json.dumps(result.to_dict(), indent=1, allow_nan=False,
                                           default=str) + "\n")
    flagged = result.flagged
    print(f"{len(result.rows)} quantities compared over frames {result.frames}, "
          f"{len(flagged)} flagged" + (": " + ", ".join(f"{r.quantity} ({r.cause})"
                                                        for r in flagged) if flagged else ""))
    print(f"report: {path}")
    return 0


def cmd_track(args) -> int:
    from estimator.folders import track_folder
    from estimator.live import track_following

    setup = with_camera_file(folder_scene(args.dir, args.scene, "scet track"), args.camera)
    cal = args.calibration  # the path: --out naming it is refused, errors name it
    hold_to_camera_file(cal, args.camera)
    bar, update = progress_bar(0, "frame", "track")
    try:
        if args.follow:
            summary = track_following(args.dir, setup, cal, args.out, method=args.method,
                                      timeout_s=args.timeout, progress=update,
                                      flag_cut_glints=args.flag_cut_glints)
        else:
            summary = track_folder(args.dir, setup, cal, args.out, method=args.method,
                                   progress=update, flag_cut_glints=args.flag_cut_glints)
    finally:
        bar.close()
    if args.events is not None:  # issue 34: saccades and microsaccades beside the samples
        from estimator.events import NO_GATE, SampleGate, events_from_samples_csv

        gate = NO_GATE if args.events_ungated else SampleGate()
        events, left_out = events_from_samples_csv(summary.path, setup, args.events, gate=gate)
        print(f"{events.count} events ({int((events.kind == 'saccade').sum())} saccades) written "
              f"to {args.events}; {left_out} samples left out as poor fits")
    print(f"{len(summary.samples)} gaze samples from {summary.frames} frames "
          f"({summary.n_ok} estimated) written to {summary.path}")
    print(f"throughput: {summary.samples_per_s:.0f} samples/s, "
          f"{summary.frames / summary.seconds if summary.seconds > 0 else float('nan'):.1f} "
          f"frames/s ({summary.seconds:.2f} s tracking, one core)")
    if summary.internal_errors:
        where = "above" if args.run_log.debug else f"in {args.run_log.file()}"
        print(f"scet track: internal error in {summary.internal_errors} frame(s): their samples "
              f"are NaN (reason internal_error:...), tracebacks {where}; this is a bug in SCET, "
              "please report it", file=sys.stderr)
        return 1
    return 0


def cmd_validate(args) -> int:
    from .validate import run_validation, table_markdown

    bars = StageBars()
    try:
        result = run_validation(args.scene, quick=args.quick, out_dir=args.out, seed=args.seed,
                                progress=bars.update, report_dir=args.report_dir,
                                workers=args.workers, address=args.ray_address)
    finally:
        bars.close()
    print(table_markdown(result.rows))
    print(f"glint identities right: {100 * result.identity_rate:.2f} % of {result.n_identified}; "
          f"rendered feature noise {result.feature_noise_px:.3f} px RMS")
    print("stage times: " + ", ".join(f"{k} {v:.1f} s" for k, v in result.timings_s.items()))
    print(f"report written to {result.report}")
    return 0


def cmd_reproduce(args) -> int:
    from .reproduce import run_reproduction

    bars = StageBars()
    try:
        path = run_reproduction(args.out, quick=args.quick, seed=args.seed,
                                progress=lambda done, total, label="": bars.update("reproduce", done, total, label),
                                workers=args.workers, address=args.ray_address)
    finally:
        bars.close()
    print(f"report written to {path}")
    return 0


def cmd_demo(args) -> int:
    from estimator.scene import load_scene
    from scet_render.band_diagram import band_glint_counts
    from scet_render.simulate import glint_statistics, parse_targets, simulate_glints

    setup = load_scene(args.scene)
    print(_describe(setup))
    print()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rc = cmd_bands(argparse.Namespace(scene=args.scene, frame=0, frames=1, png=out / "bands.png"))
    targets = parse_targets("grid:24x15", setup)
    obs = simulate_glints(setup, targets, noise_px=0.5, rng=args.seed)
    stats = glint_statistics(obs)
    print()
    print(f"feature-level simulation, 24 x 15 screen grid, e_f = 0.5 px uniform, seed {args.seed}:")
    print(f"  visible glints per target: min {stats['visible_min']}, mean {stats['visible_mean']:.2f}, "
          f"max {stats['visible_max']} of {stats['lights']}; targets with none: {stats['targets_without_glints']}")
    print(f"  glint spread per target: {stats['spread_u_px_mean']:.1f} px across, "
          f"{stats['spread_v_px_mean']:.1f} px down (mean)")
    print("  glints per target inside each visible band of frame 0:")
    table = band_glint_counts(setup, obs)
    print_table([[r["strobe"], f"{r['rows'][0]}-{r['rows'][1]}", f"{r['glints_mean']:.2f}", r["glints_min"],
                   f"{100 * r['share_none']:.1f}", f"{100 * r['share_ge3']:.1f}"] for r in table],
                 ["strobe", "rows", "mean", "min", "% none", "% >= 3"])
    path = out / "glints.npz"
    from scet_render.simulate import save_observations

    save_observations(path, obs, setup)
    print(f"\nglints written to {path}, band diagram to {out / 'bands.png'}")
    return rc


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="scet", description="Stroboscopic catadioptric eye tracking toolkit.")
    ap.add_argument("--debug", action="store_true",
                    help="print the traceback of an internal error instead of logging it to a file")
    sub = ap.add_subparsers(dest="command", required=True)
    scene_help = "scene file or built-in scene name (default: paper_sim)"
    folder_scene_help = ("scene file or built-in scene name (default: the scene the folder "
                         "records: its manifest.json, scene.toml or capture.json; a --scene "
                         "that differs from it is used, with a warning)")

    p = sub.add_parser("scenes", help="list the built-in scenes")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("scene", help="load (and so validate) a scene file and describe it")
    p.add_argument("scene", nargs="?", help=scene_help)
    p.set_defaults(func=cmd_scene)

    p = sub.add_parser("bands", help="band layout of a frame (table) and a diagram like the paper's Fig. 2")
    p.add_argument("scene", nargs="?", help=scene_help)
    p.add_argument("--frame", type=integer(0, MAX_FRAMES), default=0, help="frame index (default 0)")
    p.add_argument("--frames", type=integer(1, 1000), default=1, help="frames drawn in the diagram (default 1)")
    p.add_argument("--png", type=Path, help="write the diagram to this PNG")
    p.add_argument("--measure", type=Path, metavar="CAPTURE_DIR",
                   help="measure S, exposure, pulse width, phase and strobe clock of a capture "
                        "folder from its bands (no scene needed)")
    p.add_argument("--json", type=Path, metavar="OUT", help="with --measure: write the result here")
    p.add_argument("--follow", action="store_true",
                   help="with --measure: read the capture while it is written, a line a frame")
    p.add_argument("--follow-timeout", type=finite(0.01, 3600.0), default=5.0,
                   help="with --follow: seconds without a new frame before stopping (default 5)")
    p.set_defaults(func=cmd_bands)

    p = sub.add_parser("simulate", help="feature-level simulation: glints of every light for every target")
    p.add_argument("scene", nargs="?", help=scene_help)
    p.add_argument("--targets", default="grid:24x15",
                   help="grid:COLSxROWS (cell centres), calib:COLSxROWS (edge to edge), centre, or a CSV "
                        "of x_m,y_m,z_m (default grid:24x15)")
    p.add_argument("--noise", type=finite(0.0, 100.0), default=0.5, help="feature position error e_f in px (default 0.5)")
    p.add_argument("--noise-model", choices=("uniform", "gaussian"), default="uniform")
    p.add_argument("--seed", type=integer(0, MAX_SEED), default=1)
    p.add_argument("--out", type=Path, required=True, help="output file, .npz or .csv")
    p.set_defaults(func=cmd_simulate)

    add_render_parser(sub, scene_help)

    p = sub.add_parser("export-mitsuba", help="write a Mitsuba XML scene (+ meshes) of a scene file")
    p.add_argument("scene", nargs="?", help=scene_help)
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--yaw-deg", type=finite(-90.0, 90.0), default=0.0, help="eye yaw (Fick, degrees, + toward +x)")
    p.add_argument("--pitch-deg", type=finite(-90.0, 90.0), default=0.0, help="eye pitch (Fick, degrees, + up)")
    p.add_argument("--spp", type=integer(1, MAX_SPP), default=64)
    p.add_argument("--cornea", choices=("dielectric", "plain_dielectric", "conductor"),
                   default="dielectric")
    p.set_defaults(func=cmd_export_mitsuba)

    p = sub.add_parser("calibrate", help="calibrate from a folder of single-pulse calibration frames")
    p.add_argument("dir", type=Path, help="folder of frames (frames/NNNNNN.png, labels.jsonl, timing)")
    p.add_argument("--scene", help=folder_scene_help)
    p.add_argument("--out", type=Path, required=True, help="calibration file (JSON)")
    camera_arg(p)
    p.add_argument("--cornea-model", choices=("sphere", "conic"), default="sphere",
                   help="the tracker's cornea: the paper's sphere (default), or a conic about "
                        "the optical axis whose conic constant Q is calibrated too (recorded in "
                        "the file; scet track then tracks with it)")
    p.add_argument("--light-model", choices=("points", "wire_mirror"), default="points",
                   help="wire_mirror: a wire_mirror light group's glints are the LED's "
                        "highlights on the turns, which move with the cornea (recorded in the "
                        "file; scet track then fits them); default: fixed point lights")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("track", help="track a folder of banded frames: one gaze sample per lit band")
    p.add_argument("dir", type=Path, help="folder of frames with a timing sidecar (or a rendered dataset)")
    p.add_argument("--scene", help=folder_scene_help)
    p.add_argument("--calibration", type=Path, required=True, help="calibration file from scet calibrate")
    p.add_argument("--method", choices=("polynomial", "geometric"), default="polynomial")
    camera_arg(p)
    p.add_argument("--out", type=Path, required=True, help="samples CSV")
    p.add_argument("--events", type=Path, default=None,
                   help="also write the saccades and microsaccades found in the samples to this "
                        "CSV (format scet-events 1; estimator.events), leaving out poor fits")
    p.add_argument("--events-ungated", action="store_true",
                   help="with --events: keep the poor fits (estimator.events.quality) too")
    p.add_argument("--follow", action="store_true",
                   help="track the frames as they are written (live): stop on an 'end' file, a "
                        "dataset's last frame or --timeout seconds without a new frame")
    p.add_argument("--timeout", type=finite(0.001, 86400.0), default=5.0,
                   help="with --follow: seconds without a new frame before stopping (default 5)")
    p.add_argument("--flag-cut-glints", action=argparse.BooleanOptionalAction, default=None,
                   help="drop glints whose flux is far below the calibration's expected flux "
                        "and off where the fitted pose puts them (cut by a lash), and do the "
                        "band again without them; default: where the calibration has "
                        "glint_flux (one from this version's scet calibrate, sphere or "
                        "conic); --flag-cut-glints refuses a calibration without it")
    p.set_defaults(func=cmd_track)

    add_dataset_parsers(sub)

    p = sub.add_parser("compare", help="a capture folder against renders of the same frames: "
                                       "timing, sensor, glints, background, tracker")
    p.add_argument("dir", type=Path, help="capture folder (capture.json, frames.jsonl, frames/)")
    p.add_argument("--scene", help=folder_scene_help)
    p.add_argument("--calibration", type=Path, help="calibration file (default: the scene's "
                                                     "nominal geometry)")
    p.add_argument("--method", choices=("polynomial", "geometric"), default="geometric")
    camera_arg(p)
    p.add_argument("--report-dir", type=Path, default=Path("reports"),
                   help="where compare.md and its figures (compare/) go (default reports/)")
    p.add_argument("--frames", type=integer(1, 1000), default=8, help="banded frames compared")
    p.add_argument("--spp", type=integer(1, MAX_SPP), default=16)
    p.add_argument("--cornea", choices=("dielectric", "plain_dielectric", "conductor"),
                   default="dielectric")
    p.add_argument("--seed", type=integer(0, MAX_SEED), default=0)
    p.add_argument("--json", type=Path, help="also write the rows and findings as JSON")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("validate", help="the main job: render, calibrate, track and compare with "
                                        "ground truth and with the feature-level simulation")
    p.add_argument("scene", nargs="?", help=scene_help)
    p.add_argument("--quick", action="store_true", help="reduced size: under 3 minutes on 2 cores")
    p.add_argument("--seed", type=integer(0, MAX_SEED), default=0)
    p.add_argument("--out", type=Path, default=Path("out/validate"), help="work folder for renders")
    p.add_argument("--report-dir", type=Path, default=Path("reports"), help="where validation.md goes")
    add_cluster_arguments(p, "render on")
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("reproduce", help="reproduce the paper's Section 3 side by side with ours")
    p.add_argument("--quick", action="store_true", help="fewer trials: under 2 minutes on 2 cores")
    p.add_argument("--seed", type=integer(0, MAX_SEED), default=0)
    p.add_argument("--out", type=Path, default=Path("reports"), help="report folder (default reports/)")
    add_cluster_arguments(p, "run the trials on")
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("demo", help="feature-level summary of a scene: band layout and glint statistics")
    p.add_argument("scene", nargs="?", help=scene_help)
    p.add_argument("--seed", type=integer(0, MAX_SEED), default=1)
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.set_defaults(func=cmd_demo)

    from scet_hardware.cli import register as register_hardware

    register_hardware(sub)   # scet strobe, scet capture, scet hardware

    from scet_render.cli_studies import add_parsers

    add_parsers(sub)      # scet design-lights, scet study events
    add_camera_parsers(sub)   # scet camera calibrate
    return ap


def main(argv: list[str] | None = None) -> int:
    """Run ``scet``: exit status 0, 2 for bad input (one line naming the file and key), 1 for
    an internal error (:mod:`scet_render.runner`)."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # argparse refused a flag (status 2), or --help (0)
        return int(exc.code or 0)
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
