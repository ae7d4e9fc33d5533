"""The lens study at the gaze level (``scet study lens --gaze``): valid share and gaze error of
the tracker through the prototype's lens, per optics and per camera model the tracker uses.

Each render condition is a camera of :mod:`scet_render.study.lens` (focal length, working
distance, aperture, focus: :func:`~scet_render.study.lens.condition_camera`) on the scene's eye
and lights. For each, :func:`scet_render.validate.validate_setup` (the validation's own pipeline)
renders single-pulse calibration frames of the eye fixating a small calibration grid and a
banded test sequence (fixations of the 24 x 15 grid) through that lens, calibrates, tracks and
scores every band against the labels. The tracker is given one of three cameras
(:data:`TRACKERS`):

* ``lens`` (a): the rendered lens itself (intrinsics and distortion; detections undistorted,
  :meth:`estimator.glints.GlintDetections.undistorted`);
* ``pinhole`` (b): the same intrinsics without the distortion (what a tracker that ignores the
  lens does; :func:`estimator.lens.pinhole_of`);
* ``board`` (c): intrinsics and distortion from a camera calibration
  (:func:`estimator.lens.calibrate_from_folder`, ``scet camera calibrate``) of ChArUco board
  frames rendered through the same lens, defocus included
  (:func:`scet_render.render.board.render_board_frames`, ``scet render --board charuco``).

All three track the same renders (``tracker_camera`` of ``validate_setup``). The aperture
changes the defocus only: the dataset's sensor model collects the same electrons per unit
radiance at every f-number, which is the stock F2.9 exposure with the strobe power raised by
(N / 2.9)^2 (3.7x at F5.6); the glint-level tables of :mod:`scet_render.study.lens` give the
other end, the same strobe power and (2.9 / N)^2 of the light.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.banding import scaled_setup
from estimator.geometry import Camera
from estimator.setup import Setup

from ..validate import ValidationConfig
from .lens import LensCondition, condition_camera, glint_depth_m

log = logging.getLogger(__name__)

#: The camera models the tracker can be given (module docstring): (a), (b), (c).
TRACKERS = ("lens", "pinhole", "board")
#: The gaze-level runs' default size: full resolution (the 643 px eye is too small at half
#: size: neighbouring glints ~2.5 px apart), conductor cornea at 4 spp (exact glints at low spp,
#: as the quick validation), a 4 x 4 calibration grid and 24 banded test frames at 16 pulses
#: per frame (two fixations of the 24 x 15 grid, 15 frames each, 24 x 11 visible bands).
#: Measured on 2 cores shared with other jobs (load 9-15, 2026-12-04): the 7 conditions of
#: :func:`gaze_conditions` in 16-20 min, most of it rendering; a rerun on the same work folder
#: reuses the renders.
CONFIG = ValidationConfig(scale=1, spp=4, cornea="conductor", frames=24, calib_grid=(4, 4),
                          pulses_per_frame=(16,))
#: Board frames of the board calibration (c): 15-25 views make a calibration
#: (``scet render --board``); board frames are cheap (no light transport, ~0.6 s at 4 spp).
BOARD_FRAMES = 20
#: Samples per pixel of the board frames (box filter and the lens's pupil).
BOARD_SPP = 16


@dataclass(frozen=True)
class GazeCondition:
    """A render condition (:class:`~scet_render.study.lens.LensCondition`) and the tracker
    models it is tracked with (a subset of :data:`TRACKERS`, ``lens`` first)."""

    lens: LensCondition
    trackers: tuple = ("lens",)


@dataclass(frozen=True)
class GazeResult:
    """One tracked condition.

    Attributes
    ----------
    condition : LensCondition
    tracker : str
        One of :data:`TRACKERS`.
    camera : Camera
        The rendered camera.
    tracker_camera : Camera
        The camera the tracker used.
    blur_px : float
        Thin-lens blur disc at the glints' depth (px).
    stats : dict
        method ("polynomial", "geometric") -> :class:`scet_render.validate.ValidationRow`.
    identity_rate : float
    calibration_rms_px : float
        The calibration's glint RMS.
    board : dict or None
        For ``board``: focal length error (%), largest distortion difference over the frame
        (px), the board calibration's reprojection RMS (px) and views used.
    seconds : float
        Wall time of this result (renders included for the first tracker of a condition).
    render_s : float
        Of which rendering (eye and board frames; ~0 where a rerun found them in the folder).
    """

    condition: LensCondition
    tracker: str
    camera: Camera
    tracker_camera: Camera
    blur_px: float
    stats: dict
    identity_rate: float
    calibration_rms_px: float
    board: dict | None
    seconds: float
    render_s: float = 0.0


def gaze_conditions(setup: Setup) -> list:
    """The render conditions: the stock lens in focus on the glints tracked three ways, then
    (tracked with the right model) focus 2 and 5 mm beyond the glints, F5.6, the ~7.3 mm lens
    (the paper's 1300 px) at F2.9 and F5.6, and the stock lens 10 mm farther out."""
    cam = setup.camera
    wd = float(np.linalg.norm(cam.position_m - setup.eye.apex())) * 1e3
    stock = f"3.6 mm F2.9 at {wd:.0f} mm"
    out = [GazeCondition(LensCondition(stock + ", in focus", 643.0, None, 2.9), TRACKERS)]
    for mm in (2.0, 5.0):
        out.append(GazeCondition(LensCondition(f"{stock}, focus +{mm:g} mm", 643.0, None, 2.9,
                                               mm * 1e-3)))
    out.append(GazeCondition(LensCondition(f"3.6 mm F5.6 at {wd:.0f} mm", 643.0, None, 5.6)))
    for n in (2.9, 5.6):
        out.append(GazeCondition(LensCondition(f"7.3 mm F{n:g} at {wd:.0f} mm", 1300.0, None, n)))
    out.append(GazeCondition(LensCondition(f"3.6 mm F2.9 at {wd + 10:.0f} mm", 643.0,
                                           (wd + 10) * 1e-3, 2.9)))
    return out


def folder_name(label: str) -> str:
    """A work folder's name for a condition's label."""
    return re.sub(r"[^A-Za-z0-9.+-]+", "_", label).strip("_")


def board_camera(setup: Setup, out_dir, *, frames: int = BOARD_FRAMES, spp: int = BOARD_SPP,
                 seed: int = 0) -> tuple[Camera, dict]:
    """(c): render ``frames`` ChArUco board frames through ``setup``'s lens into ``out_dir``,
    calibrate them as ``scet camera calibrate`` does, and return the scene's camera with the
    calibrated intrinsics and distortion, and the calibration's scores against the truth."""
    from estimator.lens import (calibrate_from_folder, camera_from_file,
                                distortion_difference_px, read_board)

    from ..render.board import BOARD_NAME, render_board_frames

    out = Path(out_dir)
    if not (out / BOARD_NAME).is_file():
        render_board_frames(setup, out, frames=frames, spp=spp, seed=seed)
    cam_file = calibrate_from_folder(out / "frames", read_board(out / BOARD_NAME))
    truth = setup.camera
    camera = camera_from_file(truth, cam_file, out)
    K = np.array([[truth.fx_px, 0, truth.cx_px], [0, truth.fy_px, truth.cy_px], [0, 0, 1.0]])
    diff = distortion_difference_px(K, truth.distortion, cam_file.K, cam_file.distortion,
                                    truth.width_px, truth.height_px)
    scores = {"focal_error_pct": 100.0 * (cam_file.fx_px / truth.fx_px - 1.0),
              "distortion_diff_px": float(np.max(diff)),
              "rms_px": float(cam_file.rms_px), "views": len(cam_file.views)}
    return camera, scores


def tracker_camera(tracker: str, setup: Setup, out_dir, seed: int = 0) -> tuple:
    """(camera for ``validate_setup``'s ``tracker_camera`` (None: the rendered one), board
    scores or None) of one of :data:`TRACKERS`."""
    from estimator.lens import pinhole_of

    if tracker == "lens":
        return None, None
    if tracker == "pinhole":
        return pinhole_of(setup.camera), None
    if tracker == "board":
        return board_camera(setup, Path(out_dir) / "board", seed=seed)
    raise ValueError(f"tracker must be one of {TRACKERS}, got {tracker!r}")


def measure_gaze(setup: Setup, condition: GazeCondition, out_dir, *,
                 config: ValidationConfig = CONFIG, seed: int = 0, scene_text: str | None = None,
                 progress=None) -> list:
    """Render, calibrate, track and score one render condition with each of its trackers
    (module docstring); returns one :class:`GazeResult` per tracker."""
    from ..validate import validate_setup

    c = condition.lens
    camera = condition_camera(setup, c)
    s = scaled_setup(dataclasses.replace(setup, camera=camera), config.scale)
    folder = Path(out_dir) / folder_name(c.label)
    blur = float(camera.blur_diameter_px(glint_depth_m(setup, camera))) / config.scale
    results = []
    for tracker in condition.trackers:
        t = time.perf_counter()
        tcam, board = tracker_camera(tracker, s, folder, seed)
        board_s = time.perf_counter() - t
        run = validate_setup(s, config, folder, seed=seed, progress=progress,
                             scene_text=scene_text, tracker_camera=tcam, tracker_name=tracker)
        stats = {r.method: r for r in run.rows if r.source == "rendered"}
        results.append(GazeResult(c, tracker, s.camera, tcam or s.camera, blur, stats,
                                  run.correct / run.total if run.total else math.nan,
                                  float(run.calibration.quality.get("rms_px", math.nan)),
                                  board, time.perf_counter() - t,
                                  run.timings["render"] + board_s))
        g = stats.get("geometric")
        log.info("lens gaze %s / %s: valid %.2f, median %.3f deg", c.label, tracker,
                 g.valid if g else math.nan, g.median_deg if g else math.nan)
    return results


def run_gaze_study(setup: Setup, out_dir, *, config: ValidationConfig = CONFIG, seed: int = 0,
                   conditions=None, progress=None) -> list:
    """Every condition of :func:`gaze_conditions` (or ``conditions``); ``progress(done,
    total)`` after each. Renders are kept in ``out_dir`` and reused by a rerun."""
    conditions = gaze_conditions(setup) if conditions is None else list(conditions)
    text = Path(setup.source).read_text(encoding="utf-8") if setup.source else None
    results = []
    for i, c in enumerate(conditions):
        results.extend(measure_gaze(setup, c, out_dir, config=config, seed=seed,
                                    scene_text=text))
        if progress is not None:
            progress(i + 1, len(conditions))
    return results


def gaze_runner(setup: Setup, out_dir, *, config: ValidationConfig = CONFIG, seed: int = 0):
    """The ``gaze`` hook of :func:`scet_render.study.lens.run_study`: ``run(optics, progress)``
    runs :func:`run_gaze_study` and returns the report's gaze section (with the glint-level
    ``optics`` results beside the recommendation)."""
    from .lens_gaze_report import gaze_section

    def run(optics, progress=None) -> str:
        t = time.perf_counter()
        results = run_gaze_study(setup, out_dir, config=config, seed=seed, progress=progress)
        return gaze_section(results, config, time.perf_counter() - t, glints=optics)

    return run
