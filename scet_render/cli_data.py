"""``scet render``, ``scet dataset`` and ``scet score``: the dataset commands of :mod:`scet_render.cli`
(wired in by :func:`add_parsers`). Heavy imports happen inside the commands."""

from __future__ import annotations

import re
import sys
from pathlib import Path

from .cli_progress import print_table, progress_bar
from .runner import MAX_RENDER_FRAMES, MAX_SEED, MAX_SPP, finite, integer


def _grid_pattern(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"(\d+)x(\d+)", text or "")
    if not m or not (2 <= int(m.group(1)) <= 50 and 2 <= int(m.group(2)) <= 50):
        raise ValueError(f"--calibration: expected a pattern COLSxROWS such as 3x3, 5x5 or 6x6 "
                         f"(2-50 each), got {text!r}")
    return int(m.group(1)), int(m.group(2))


def cmd_render_calibration(args, setup) -> int:
    from .dataset import render_calibration

    cols, rows = _grid_pattern(args.calibration)
    bar, update = progress_bar(cols * rows, "frame", f"render calibration {setup.name}")
    try:
        out = render_calibration(setup, args.out, spp=args.spp, cornea=args.cornea,
                                 seed=args.seed, grid=(cols, rows), progress=update,
                                 workers=args.workers, address=args.ray_address)
    finally:
        bar.close()
    print(f"calibration frames {out}: {cols * rows} single-pulse frames of the eye fixating the "
          f"{cols}x{rows} pattern, their scene in {out / 'scene.toml'} (calibrate with: scet "
          f"calibrate {out} --out calibration.json)")
    return 0


def cmd_render_board(args, setup) -> int:
    from .render.board import render_board_frames

    if args.calibration is not None or args.raw or args.workers or args.ray_address:
        raise ValueError("--board renders board frames on this machine: leave out --calibration, "
                         "--raw, --workers and --ray-address")
    if args.frames is None:
        raise ValueError("--board needs --frames N (15-25 views make a calibration)")
    bar, update = progress_bar(args.frames, "frame", f"render {args.board} board {setup.name}")
    try:
        out = render_board_frames(setup, args.out, frames=args.frames, spp=args.spp,
                                  seed=args.seed, progress=update)
    finally:
        bar.close()
    print(f"board frames {out}: {args.frames} views of a {args.board} board through "
          f"{setup.name}'s lens; the board, the true camera and poses in {out / 'board.json'}")
    return 0


def cmd_render(args) -> int:
    from estimator.scene import load_scene

    from .dataset import render_dataset

    setup = load_scene(args.scene)
    if args.board is not None:
        return cmd_render_board(args, setup)
    if args.calibration is not None:
        if args.frames is not None or args.raw:
            raise ValueError("--calibration renders one frame per target: leave out --frames "
                             "and --raw")
        return cmd_render_calibration(args, setup)
    if args.frames is None:
        raise ValueError("--frames is required (or --calibration PATTERN for calibration frames)")
    bar, update = progress_bar(args.frames, "frame", f"render {setup.name}")
    kwargs = dict(frames=args.frames, spp=args.spp, trajectory=args.trajectory, seed=args.seed,
                  variant=args.variant, cornea=args.cornea, progress=update,
                  masks=not args.no_masks, pupil=_pupil_model(args))
    try:
        if args.workers is not None or args.ray_address is not None:
            from .dataset import render_dataset_ray

            summary = render_dataset_ray(setup, args.out, workers=args.workers,
                                         address=args.ray_address,
                                         cpus_per_worker=args.cpus_per_worker, **kwargs)
        else:
            summary = render_dataset(setup, args.out, **kwargs)
    finally:
        bar.close()
    print(f"dataset {summary.path}: {len(summary.frames_rendered)} frames rendered, "
          f"{len(summary.frames_skipped)} already complete")
    if args.raw:
        from scet_hardware.capture.replay import replay_dataset

        # The same folder becomes a capture folder too: frames/NNNNNN.raw as the sensor reads
        # them out, read back through the one capture reader by calibrate and track.
        replay_dataset(summary.path, summary.path, scene=args.scene, raw_format=args.raw)
        print(f"raw frames ({args.raw}, Bayer mosaic) and capture.json written to {summary.path}")
    return 0


def _pupil_model(args):
    """The pupil dynamics ``--pupil`` / ``--light-steps-per-min`` ask for (None: the scene's
    fixed size, as before)."""
    if args.pupil == "fixed":
        if args.light_steps_per_min is not None:
            raise ValueError("--light-steps-per-min needs --pupil dynamic")
        return None
    from .motion import PupilModel

    rate = 0.0 if args.light_steps_per_min is None else args.light_steps_per_min
    return PupilModel(light_steps_per_min=rate)


def cmd_dataset(args) -> int:
    from .dataset import open_dataset, verify_dataset

    if args.action == "verify":
        problems = verify_dataset(args.dir)
        for p in problems:
            print(f"scet dataset verify: {p}", file=sys.stderr)
        if problems:
            return 2
        print(f"{args.dir}: complete and intact")
        return 0
    ds = open_dataset(args.dir)
    m = ds.manifest
    render = m.get("render", {})
    llvm = (render.get("renderer") or {}).get("llvm") or {}
    size = sum(p.stat().st_size for p in Path(args.dir).rglob("*") if p.is_file())
    rows = [["scene", f"{m['scene'].get('name')} ({m['scene'].get('file')}, sha256 "
                      f"{m['scene'].get('sha256', '')[:12]})"],
            ["frames", f"{len(ds)} of {m['image']['width_px']}x{m['image']['height_px']} px, "
                       f"{ds.n_labels} strobe labels"],
            ["trajectory, seed", f"{m.get('trajectory')}, {m.get('seed')}"],
            ["render", f"{render.get('variant')}, {render.get('spp')} spp, cornea "
                       f"{render.get('cornea')}, LLVM vector width {llvm.get('vector_width', '-')}"],
            ["rendered on", (render.get("llvm_host") or {}).get("cpu", "-")],
            ["software", ", ".join(f"{k} {v}" for k, v in m.get("software", {}).items())],
            ["size on disk", f"{size / 1e6:.1f} MB"]]
    print_table(rows, ["", str(args.dir)])
    return 0


def cmd_score(args) -> int:
    from .cli_scene import folder_scene
    from .validate import reasons_table, score_samples, score_table, write_score_report

    if args.markdown:
        from estimator.inputs import input_files, refuse_overwriting_inputs

        refuse_overwriting_inputs(args.markdown, [*args.samples, *input_files(args.dataset)],
                                  "--markdown")
    setup = folder_scene(args.dataset, args.scene, "scet score")
    score = score_samples(args.samples, args.dataset, setup=setup)
    print(score_table(score))
    print()
    print(reasons_table(score))
    if args.markdown:
        path = write_score_report(score, args.markdown, plots=not args.no_plots)
        print(f"report written to {path}")
    return 0


def add_cluster_arguments(p, what: str) -> None:
    """``--workers`` and ``--ray-address`` (:mod:`scet_render.cluster`), the same on every command."""
    p.add_argument("--workers", type=integer(1, 4096),
                   help=f"{what} a local Ray started for the run with this many workers; "
                        "the same results as without")
    p.add_argument("--ray-address", help=f"{what} an existing Ray cluster (ray start --head prints "
                                         "the address; 'auto' finds a local one). Whoever reaches a "
                                         "Ray cluster can run code on it: keep it on a private network")


def add_render_parser(sub, scene_help: str) -> None:
    """``scet render``."""
    p = sub.add_parser("render", help="render a labelled dataset of banded frames with Mitsuba 3")
    p.add_argument("scene", nargs="?", help=scene_help)
    p.add_argument("--frames", type=integer(1, MAX_RENDER_FRAMES),
                   help="number of frames (banded datasets)")
    add_cluster_arguments(p, "render on")
    p.add_argument("--cpus-per-worker", type=integer(1, 1024), default=1,
                   help="CPUs per worker; Dr.Jit's thread count (default 1)")
    p.add_argument("--calibration", metavar="PATTERN",
                   help="render single-pulse calibration frames instead: one per target of a "
                        "COLSxROWS fixation pattern (3x3, 5x5, 6x6) on the scene's screen")
    p.add_argument("--board", choices=("charuco",),
                   help="render --frames views of a ChArUco calibration board through the "
                        "scene's lens instead (poses spread over the field at the working "
                        "distance), with board.json: the board, true intrinsics and poses")
    p.add_argument("--out", type=Path, required=True, help="dataset folder (resumed if interrupted)")
    p.add_argument("--spp", type=integer(1, MAX_SPP), default=16, help="samples per pixel (default 16)")
    p.add_argument("--trajectory", choices=("fixations", "saccades", "grid"), default="fixations")
    p.add_argument("--seed", type=integer(0, MAX_SEED), default=0)
    p.add_argument("--variant", help="Mitsuba variant (default: llvm_ad_rgb when libLLVM >= 16 is found, "
                                     "else scalar_rgb)")
    p.add_argument("--cornea", choices=("dielectric", "plain_dielectric", "conductor"),
                   default="dielectric")
    p.add_argument("--pupil", choices=("fixed", "dynamic"), default="fixed",
                   help="the pupil's size over time: the scene's eye.pupil_diameter_mm throughout "
                        "(fixed, the default) or seeded hippus and light reflexes around it "
                        "(dynamic: scet_render.motion.pupil, recorded in the manifest and in "
                        "each sample's pupil_diameter_mm)")
    p.add_argument("--light-steps-per-min", type=finite(0.0, 600.0), metavar="RATE",
                   help="with --pupil dynamic: mean rate of random light changes the pupil "
                        "answers (default 0: hippus only)")
    p.add_argument("--no-masks", action="store_true",
                   help="write no segmentation masks (frames/NNNNNN_mask.png; they cost ~2-3 %% "
                        "of a frame's render)")
    p.add_argument("--raw", nargs="?", const="SGBRG10_CSI2P", metavar="FORMAT",
                   help="also write the frames as the OV5647 reads them out (SGBRG10_CSI2P, the "
                        "default, or SGBRG10), with capture.json, so they read as a capture")
    p.set_defaults(func=cmd_render)


def add_dataset_parsers(sub) -> None:
    """``scet dataset`` and ``scet score``."""
    p = sub.add_parser("dataset", help="a rendered dataset: what it holds (info) or whether "
                                       "it is complete and intact (verify)")
    p.add_argument("action", choices=("info", "verify"))
    p.add_argument("dir", type=Path, help="the dataset folder")
    p.set_defaults(func=cmd_dataset)

    p = sub.add_parser("score", help="score samples CSVs against a rendered dataset's ground truth")
    p.add_argument("samples", type=Path, nargs="+", help="samples CSV files (one per method)")
    p.add_argument("dataset", type=Path, help="the dataset folder the samples were tracked from")
    p.add_argument("--scene", help="scene file or built-in scene name (default: the scene the "
                                   "dataset's manifest records; one that differs from it is "
                                   "used, with a warning)")
    p.add_argument("--markdown", type=Path, help="write the tables (and a plot) to this .md file")
    p.add_argument("--no-plots", action="store_true", help="no figure beside --markdown")
    p.set_defaults(func=cmd_score)
