"""Camera calibration from views of a ChArUco board (``scet camera calibrate``).

Steps:

1. every image is read as 8-bit grey (16-bit and colour images converted) and the board's
   corners found with OpenCV's own detector (``cv2.aruco.CharucoDetector.detectBoard``: ArUco
   markers, then the chessboard corners between them, refined to sub-pixel);
2. a view is kept when it has at least ``min_corners`` corners that are not on one line
   (``CharucoBoard.checkCharucoCornersCollinear``); the others are skipped with a warning;
3. fewer than ``min_views`` kept views is refused (OpenCV's calibration tutorial asks for at
   least 10 views; 8 is the default floor here);
4. ``cv2.calibrateCameraExtended`` (Zhang 2000, "A flexible new technique for camera
   calibration", IEEE TPAMI 22(11)) fits K and the distortion: 5 coefficients (k1, k2, p1, p2,
   k3) by default, or the rational model's 8 (``CALIB_RATIONAL_MODEL``);
5. the result is checked: views all within :data:`MIN_TILT_DEG` of fronto-parallel are
   refused (parallel planes leave the focal length undetermined: Zhang 2000, Sec. 3.3, the
   degenerate configurations); coverage of the frame by the corners (a grid of
   :data:`COVERAGE_GRID` cells) and the focal length's standard deviation give warnings.

Bad input is one :class:`CalibrationError` naming the folder or file and what is wrong.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ..errors import InputError
from .board import BoardSpec
from .camera_file import CameraFile

__all__ = ["CalibrationError", "BoardView", "IMAGE_SUFFIXES", "MIN_TILT_DEG", "COVERAGE_GRID",
           "MODELS", "read_grey", "detect_board", "calibrate_views", "calibrate_from_folder"]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm")
#: A calibration whose every view is tilted less than this from fronto-parallel is refused: at
#: 10 deg the perspective across a 20 mm board at 35 mm is ~5 px, barely above the corners'
#: noise, and Zhang's method needs the planes' orientations to differ.
MIN_TILT_DEG = 10.0
#: Coverage cells (columns, rows): each should hold corners, or the distortion in it is
#: extrapolated.
COVERAGE_GRID = (4, 3)
#: A focal length whose standard deviation exceeds this share of it is warned of.
FOCAL_SD_WARN = 0.005
#: Distortion models: name -> (coefficients, OpenCV flags).
MODELS = {"opencv5": (5, 0), "rational8": (8, None)}


class CalibrationError(InputError):
    """Board images that cannot give a calibration (none found, too few views, degenerate)."""


@dataclass(frozen=True)
class BoardView:
    """One image's detected board corners.

    Attributes
    ----------
    name : str
    ids : (k,) int
        ChArUco corner ids.
    image_px : (k, 2) float
        Detected corners (pixel-centre convention).
    board_m : (k, 3) float
        The same corners on the board (metres, z = 0).
    """

    name: str
    ids: np.ndarray
    image_px: np.ndarray
    board_m: np.ndarray


def read_grey(path) -> np.ndarray:
    """(H, W) uint8 image of ``path`` (colour -> grey; 16-bit scaled by its maximum)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CalibrationError("cannot read the image", path=str(path))
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        a = img.astype(np.float64)
        a = a * (255.0 / max(float(a.max()), 1e-12))
        img = np.clip(np.rint(a), 0, 255).astype(np.uint8)
    return img


def detect_board(image, spec: BoardSpec, name: str = "", detector=None) -> BoardView:
    """The ChArUco corners of ``spec`` in ``image`` (H, W) uint8 (possibly none)."""
    import cv2

    board = spec.cv_board()
    det = detector if detector is not None else cv2.aruco.CharucoDetector(board)
    corners, ids, _, _ = det.detectBoard(image)
    if ids is None or len(ids) == 0:
        return BoardView(name, np.zeros(0, int), np.zeros((0, 2)), np.zeros((0, 3)))
    ids = np.asarray(ids).ravel().astype(int)
    obj = spec.corners_m()[ids]
    return BoardView(name, ids, np.asarray(corners, dtype=np.float64).reshape(-1, 2), obj)


def _tilt_deg(rvec) -> float:
    import cv2

    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    return math.degrees(math.acos(min(1.0, abs(float(R[2, 2])))))


def _coverage(views, width: int, height: int) -> tuple[float, list]:
    """(share of :data:`COVERAGE_GRID` cells holding corners, the empty cells (col, row))."""
    nx, ny = COVERAGE_GRID
    hit = np.zeros((ny, nx), bool)
    for v in views:
        c = np.clip((v.image_px[:, 0] + 0.5) * nx / width, 0, nx - 1e-9).astype(int)
        r = np.clip((v.image_px[:, 1] + 0.5) * ny / height, 0, ny - 1e-9).astype(int)
        hit[r, c] = True
    empty = [(int(c), int(r)) for r, c in zip(*np.nonzero(~hit))]
    return float(hit.mean()), empty


def calibrate_views(views, spec: BoardSpec, size_px: tuple[int, int], *, model: str = "opencv5",
                    min_views: int = 8, min_corners: int = 8, where: str = "") -> CameraFile:
    """Calibrate from detected views (module docstring, steps 2-5).

    Parameters
    ----------
    views : list of BoardView
    spec : BoardSpec
    size_px : (width, height)
    model : {"opencv5", "rational8"}
    min_views, min_corners : int
    where : str
        The folder named in errors.

    Returns
    -------
    CameraFile
        With the per-view errors, the board and the warnings.
    """
    import cv2

    if model not in MODELS:
        raise ValueError(f"model must be one of {sorted(MODELS)}, got {model!r}")
    board = spec.cv_board()
    warnings, kept = [], []
    for v in views:
        if v.ids.size < min_corners:
            warnings.append(f"{v.name}: {v.ids.size} board corners (fewer than {min_corners}): "
                            "view skipped")
        elif board.checkCharucoCornersCollinear(v.ids.reshape(-1, 1).astype(np.int32)):
            warnings.append(f"{v.name}: the corners lie on one line: view skipped")
        else:
            kept.append(v)
    if not any(v.ids.size for v in views):
        raise CalibrationError(f"no board corners found in any of {len(views)} images (is it "
                               f"the board {spec.squares_x}x{spec.squares_y} {spec.dictionary}? "
                               "pass --board board.json)", path=where)
    if len(kept) < min_views:
        raise CalibrationError(f"{len(kept)} usable board views of {len(views)} images, at least "
                               f"{min_views} needed (each with >= {min_corners} corners not on "
                               "one line)", path=where)
    w, h = (int(size_px[0]), int(size_px[1]))
    n, flags = MODELS[model]
    flags = cv2.CALIB_RATIONAL_MODEL if flags is None else flags
    obj = [v.board_m.astype(np.float32) for v in kept]
    img = [v.image_px.astype(np.float32).reshape(-1, 1, 2) for v in kept]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, K, d, rvecs, _, sd_int, _, per_view = cv2.calibrateCameraExtended(
        obj, img, (w, h), None, None, flags=flags, criteria=crit)
    d = np.asarray(d, dtype=np.float64).ravel()[:n]
    tilts = [_tilt_deg(r) for r in rvecs]
    if max(tilts) < MIN_TILT_DEG:
        raise CalibrationError(f"degenerate views: all {len(kept)} are within "
                               f"{max(tilts):.1f} deg of fronto-parallel (at least one must be "
                               f"tilted by {MIN_TILT_DEG:g} deg or more; tilt the board by "
                               "20-45 deg in several directions)", path=where)
    share, empty = _coverage(kept, w, h)
    if empty:
        warnings.append(f"coverage: no corners in {len(empty)} of {np.prod(COVERAGE_GRID)} "
                        f"frame cells (col, row of a {COVERAGE_GRID[0]}x{COVERAGE_GRID[1]} grid: "
                        f"{empty}); the distortion there is extrapolated: add views with the "
                        "board in those parts of the frame")
    sd = np.asarray(sd_int, dtype=np.float64).ravel()
    if sd.size >= 2 and max(sd[0] / K[0, 0], sd[1] / K[1, 1]) > FOCAL_SD_WARN:
        warnings.append(f"focal length uncertain: SD {sd[0]:.2f} / {sd[1]:.2f} px "
                        f"({100 * sd[0] / K[0, 0]:.2f} %); add tilted views")
    for msg in warnings:
        log.info("%s", msg)  # the CLI prints them; a library caller reads .warnings
    per = np.asarray(per_view, dtype=np.float64).ravel()
    out_views = tuple({"file": v.name, "corners": int(v.ids.size), "rms_px": float(e),
                       "tilt_deg": float(t)} for v, e, t in zip(kept, per, tilts))
    K = np.asarray(K, dtype=np.float64)
    K[0, 1] = K[1, 0] = 0.0
    return CameraFile(K, d, w, h, rms_px=float(rms), views=out_views, board=spec,
                      date=datetime.now(timezone.utc).isoformat(timespec="seconds"),
                      model=model, warnings=tuple(warnings))


def calibrate_from_folder(folder, spec: BoardSpec, *, model: str = "opencv5",
                          min_views: int = 8, min_corners: int = 8) -> CameraFile:
    """Calibrate from every image in ``folder`` (:data:`IMAGE_SUFFIXES`, sorted by name; all of
    one size)."""
    import cv2

    folder = Path(folder)
    if not folder.is_dir():
        raise CalibrationError("not a folder of board images", path=str(folder))
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not paths:
        raise CalibrationError(f"no images ({', '.join(IMAGE_SUFFIXES)}) in the folder",
                               path=str(folder))
    detector = cv2.aruco.CharucoDetector(spec.cv_board())
    views, size = [], None
    for p in paths:
        img = read_grey(p)
        if size is None:
            size = (img.shape[1], img.shape[0])
        elif (img.shape[1], img.shape[0]) != size:
            raise CalibrationError(f"image size {img.shape[1]}x{img.shape[0]}, the first image "
                                   f"({paths[0].name}) is {size[0]}x{size[1]}", path=str(p))
        views.append(detect_board(img, spec, p.name, detector))
    return calibrate_views(views, spec, size, model=model, min_views=min_views,
                           min_corners=min_corners, where=str(folder))
