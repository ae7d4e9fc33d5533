"""``scet camera calibrate``: the camera's intrinsics and lens distortion from views of a
printed ChArUco board (:mod:`estimator.lens.calibrate`), written as ``camera.json``
(:mod:`estimator.lens.camera_file`, docs/formats/camera.md). Wired into :mod:`scet_render.cli`
by :func:`add_parsers`."""

from __future__ import annotations

import sys
from pathlib import Path

from .runner import integer

__all__ = ["add_parsers", "cmd_camera", "camera_arg", "with_camera_file", "record_camera_file",
           "hold_to_camera_file"]


def camera_arg(p) -> None:
    """The ``--camera camera.json`` flag of ``scet calibrate`` and ``scet track``."""
    p.add_argument("--camera", type=Path,
                   help="camera file from scet camera calibrate: its intrinsics and lens "
                        "distortion replace the scene's (the image size must be the scene's); "
                        "detected glints are undistorted before matching, calibration and gaze. "
                        "Calibrate and track with the same camera file")


def with_camera_file(setup, path):
    """``setup`` with the camera file at ``path`` (None: ``setup`` as it is)."""
    if path is None:
        return setup
    from dataclasses import replace

    from estimator.lens import camera_from_file, read_camera_file

    return replace(setup, camera=camera_from_file(setup.camera, read_camera_file(path), path))


def record_camera_file(calibration, path):
    """``scet calibrate --camera``: ``calibration`` with the camera file at ``path`` recorded
    (:func:`estimator.lens.camera_file_record`; None: unchanged)."""
    if path is None:
        return calibration
    from dataclasses import replace

    from estimator.lens import camera_file_record

    return replace(calibration, camera_file=camera_file_record(path))


def hold_to_camera_file(calibration_path, camera_path) -> None:
    """``scet track``: refuse a camera file other than the calibration's
    (:func:`estimator.lens.check_camera_record`, an InputError: one line, exit 2); print its
    warning for a calibration without a record."""
    from estimator.folders import load_calibration
    from estimator.lens import check_camera_record

    warning = check_camera_record(load_calibration(calibration_path).camera_file, camera_path,
                                  calibration_path)
    if warning:
        print(f"warning: {warning}", file=sys.stderr)


def cmd_camera(args) -> int:
    import numpy as np

    from estimator.inputs import refuse_overwriting_inputs
    from estimator.lens import DEFAULT_BOARD, read_board
    from estimator.lens.calibrate import IMAGE_SUFFIXES, calibrate_from_folder
    from estimator.lens.camera_file import distortion_effect_px, write_camera_file

    # A folder of rendered board frames (scet render --board): its frames/ and board.json.
    if args.board is None and (args.dir / "board.json").is_file():
        args.board = args.dir / "board.json"
    if (args.dir / "frames").is_dir() and not any(
            p.suffix.lower() in IMAGE_SUFFIXES for p in args.dir.iterdir()):
        args.dir = args.dir / "frames"
    spec = DEFAULT_BOARD if args.board is None else read_board(args.board)
    if args.dir.is_dir():
        refuse_overwriting_inputs(args.out, [p for p in args.dir.iterdir() if p.is_file()])
    cam = calibrate_from_folder(args.dir, spec, model=args.model, min_views=args.min_views,
                                min_corners=args.min_corners)
    write_camera_file(cam, args.out)
    shift = np.hypot(*distortion_effect_px(cam.K, cam.distortion, cam.width_px,
                                           cam.height_px).T)
    print(f"camera written to {args.out}: {cam.width_px}x{cam.height_px} px, fx {cam.fx_px:.2f} "
          f"fy {cam.fy_px:.2f} cx {cam.cx_px:.2f} cy {cam.cy_px:.2f} px, distortion "
          f"({cam.model}) [{', '.join(f'{d:.5g}' for d in cam.distortion)}], largest shift "
          f"{shift.max():.2f} px; reprojection RMS {cam.rms_px:.3f} px over {len(cam.views)} "
          f"views")
    for v in cam.views:
        print(f"  {v['file']}: {v['corners']} corners, RMS {v['rms_px']:.3f} px, tilt "
              f"{v['tilt_deg']:.1f} deg")
    for w in cam.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0


def add_parsers(sub) -> None:
    """Add ``scet camera`` to the ``scet`` parser's subparsers."""
    p = sub.add_parser("camera", help="camera intrinsics and lens distortion from views of a "
                                      "printed ChArUco board (scet hardware board)")
    p.add_argument("action", choices=("calibrate",))
    p.add_argument("dir", type=Path, help="folder of board images (.png, .jpg, .tif, ...), or "
                                          "the folder scet render --board wrote (its frames/ "
                                          "and board.json)")
    p.add_argument("--out", type=Path, required=True, help="camera file (camera.json)")
    p.add_argument("--board", type=Path, help="board.json of the printed board (default: DIR's "
                                              "board.json, else 11x8 squares of 2.5 mm; "
                                              "scet hardware board sizes its board to a "
                                              "scene's field: give its board.json)")
    p.add_argument("--model", choices=("opencv5", "rational8"), default="opencv5",
                   help="distortion model: k1 k2 p1 p2 k3 (default) or the rational model's 8")
    p.add_argument("--min-views", type=integer(3, 10_000), default=8,
                   help="fewest usable views (default 8)")
    p.add_argument("--min-corners", type=integer(6, 10_000), default=8,
                   help="fewest corners a view must show (default 8)")
    p.set_defaults(func=cmd_camera)
