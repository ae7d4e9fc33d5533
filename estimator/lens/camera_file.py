"""``camera.json``: a camera's intrinsics and lens distortion, as ``scet camera calibrate``
measures them and ``scet calibrate`` / ``scet track --camera`` read them.

The distortion is OpenCV's model (``cv2.projectPoints``; the OpenCV ``calib3d`` documentation,
after Brown 1966 and Heikkila & Silven 1997): for a point (x, y) = (X/Z, Y/Z) in front of the
camera, r² = x² + y²,

    x' = x (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶) + 2 p1 x y + p2 (r² + 2 x²)
    y' = y (...) / (...) + p1 (r² + 2 y²) + 2 p2 x y

(+ thin-prism s1..s4 and tilt τx, τy for 12 and 14 coefficients), u = fx x' + cx,
v = fy y' + cy; the coefficients in OpenCV's order (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4
[, τx, τy]]]]). Pixel (0, 0) is the centre of the top-left pixel, as OpenCV has it and as
SCET's camera has it (DESIGN.md). The format is documented in ``docs/formats/camera.md``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone

import numpy as np

from ..checks import Doc
from ..errors import InputError
from ..formats import atomic_write, check_format, read_json
from ..geometry.camera import Camera
from .board import BoardSpec, board_from_doc

__all__ = ["CAMERA_FORMAT", "CAMERA_VERSION", "DISTORTION_LENGTHS", "CameraFileError",
           "CameraFile", "read_camera_file", "write_camera_file", "radial_fold_radius",
           "distortion_effect_px", "distortion_difference_px", "pinhole_of", "ideal_setup",
           "camera_from_file", "camera_file_record", "check_camera_record"]

CAMERA_FORMAT, CAMERA_VERSION = "scet-camera", 1
#: Numbers of distortion coefficients OpenCV's model takes.
DISTORTION_LENGTHS = (4, 5, 8, 12, 14)


class CameraFileError(InputError):
    """A camera file (``camera.json``) is missing, malformed or describes an impossible lens."""


def _radial(d, r):
    d = np.concatenate([np.asarray(d, dtype=np.float64), np.zeros(14)])
    k1, k2, k3, k4, k5, k6 = d[0], d[1], d[4], d[5], d[6], d[7]
    r2 = r * r
    return r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))


def radial_fold_radius(distortion, r_max: float, samples: int = 4096) -> float | None:
    """The first undistorted radius r (x, y units) at which the radial map r -> r_d(r) stops
    increasing, looking until r_d reaches ``r_max``; None if it increases all the way.

    A map that folds there sends two rays to one pixel: no undistortion can invert it, and a
    lens whose fitted polynomial folds inside the frame was fitted beyond its data.
    """
    r = np.linspace(0.0, 4.0 * max(r_max, 1e-6), samples)
    rd = _radial(distortion, r)
    inside = np.flatnonzero(rd >= r_max)
    end = int(inside[0]) + 1 if inside.size else samples
    bad = np.flatnonzero(np.diff(rd[:end]) <= 0)
    return float(r[bad[0]]) if bad.size else None


def distortion_effect_px(K, distortion, width_px: int, height_px: int, *, K_ref=None,
                         distortion_ref=None, step_px: int = 16) -> np.ndarray:
    """(m, 2) the distortion's effect (distorted pixel - pinhole pixel) over a grid of the
    frame's pixels, each ``step_px``.

    The grid's rays are those of the reference model (``K_ref``, ``distortion_ref``; default
    the model itself), so two models' effects can be compared ray by ray.
    """
    import cv2

    K = np.asarray(K, dtype=np.float64)
    Kr = K if K_ref is None else np.asarray(K_ref, dtype=np.float64)
    dr = np.asarray(distortion if distortion_ref is None else distortion_ref, dtype=np.float64)
    u, v = np.meshgrid(np.arange(0, width_px, step_px, dtype=np.float64),
                       np.arange(0, height_px, step_px, dtype=np.float64))
    px = np.stack([u.ravel(), v.ravel()], axis=1)
    xy = cv2.undistortPoints(px.reshape(-1, 1, 2), Kr, dr, criteria=
                                 (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
                                 ).reshape(-1, 2)
    pts = np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)
    dist, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K,
                                np.asarray(distortion, dtype=np.float64))
    ideal = xy * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    return dist.reshape(-1, 2) - ideal


def distortion_difference_px(K_a, distortion_a, K_b, distortion_b, width_px: int,
                             height_px: int, *, step_px: int = 16) -> np.ndarray:
    """(m,) how far two lens models disagree about the distortion over the frame (px), per
    grid pixel: both undistort the pixel into model a's pinhole image, the best homography
    between the two (what a change of K and a small camera rotation can express, and the
    calibration's pose absorbs) is removed, and the rest is the distortion's disagreement.

    The raw difference of :func:`distortion_effect_px` also holds the principal point traded
    against the tangential terms (p1, p2), which the frame's corners show as a few tenths of a
    pixel that K takes back.
    """
    import cv2

    u, v = np.meshgrid(np.arange(0, width_px, step_px, dtype=np.float64),
                       np.arange(0, height_px, step_px, dtype=np.float64))
    px = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    Ka = np.asarray(K_a, dtype=np.float64)
    a = cv2.undistortPoints(px, Ka, np.asarray(distortion_a, dtype=np.float64), criteria=crit,
                            P=Ka).reshape(-1, 2)
    b = cv2.undistortPoints(px, np.asarray(K_b, dtype=np.float64),
                            np.asarray(distortion_b, dtype=np.float64), criteria=crit,
                            P=Ka).reshape(-1, 2)
    H, _ = cv2.findHomography(a, b, 0)
    ah = cv2.perspectiveTransform(a.reshape(-1, 1, 2), H).reshape(-1, 2)
    return np.hypot(ah[:, 0] - b[:, 0], ah[:, 1] - b[:, 1])


@dataclass(frozen=True)
class CameraFile:
    """A calibrated camera (``camera.json``).

    Attributes
    ----------
    K : (3, 3) float
        Intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels (no skew).
    distortion : (n,) float
        OpenCV coefficients, n in :data:`DISTORTION_LENGTHS` (module docstring).
    width_px, height_px : int
        Image size the calibration holds for.
    rms_px : float
        Reprojection RMS over every corner of every view (NaN: not measured).
    views : tuple of dict
        Per view: ``file``, ``corners``, ``rms_px``, ``tilt_deg``.
    board : BoardSpec or None
    date : str
        ISO 8601 UTC.
    model : str
        ``"opencv5"`` (k1, k2, p1, p2, k3) or ``"rational8"`` (+ k4, k5, k6), or ``"given"``.
    warnings : tuple of str
        What the calibration warned of (coverage, uncertain focal length).
    """

    K: np.ndarray
    distortion: np.ndarray
    width_px: int
    height_px: int
    rms_px: float = math.nan
    views: tuple = ()
    board: BoardSpec | None = None
    date: str = ""
    model: str = "given"
    warnings: tuple = field(default=())

    def __post_init__(self):
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3).copy()
        d = np.asarray(self.distortion, dtype=np.float64).ravel().copy()
        if d.size not in DISTORTION_LENGTHS:
            raise CameraFileError(f"distortion must have {DISTORTION_LENGTHS} coefficients, got "
                                  f"{d.size}", key="distortion")
        K.setflags(write=False)
        d.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "distortion", d)

    @property
    def fx_px(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy_px(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx_px(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy_px(self) -> float:
        return float(self.K[1, 2])

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.distortion != 0.0))

    def to_dict(self) -> dict:
        def f(x):
            return None if not math.isfinite(x) else float(x)

        return {"format": CAMERA_FORMAT, "version": CAMERA_VERSION,
                "image_size_px": [self.width_px, self.height_px],
                "K": self.K.tolist(), "distortion": self.distortion.tolist(),
                "distortion_model": self.model, "rms_px": f(self.rms_px),
                "views": [{**v, "rms_px": f(v.get("rms_px", math.nan)),
                           "tilt_deg": f(v.get("tilt_deg", math.nan))} for v in self.views],
                "board": None if self.board is None else self.board.to_dict(),
                "warnings": list(self.warnings),
                "date": self.date or datetime.now(timezone.utc).isoformat(timespec="seconds")}


def write_camera_file(camera: CameraFile, path) -> None:
    """Write ``camera`` to ``path`` (atomically)."""
    atomic_write(path, json.dumps(camera.to_dict(), indent=2) + "\n")


def read_camera_file(path) -> CameraFile:
    """Read a ``camera.json``; :class:`CameraFileError` naming the file and the key for
    malformed JSON, a wrong shape, NaN, a focal length or principal point off the frame, or a
    distortion whose radial map folds inside the frame."""
    data = read_json(path, CameraFileError)
    check_format(data, path, CAMERA_FORMAT, CAMERA_VERSION, CameraFileError)
    doc = Doc(data, path, "", CameraFileError)
    w, h = doc.integers("image_size_px", 2, lo=1, hi=100_000)
    K = doc.array("K", (3, 3), lo=-1e7, hi=1e7)
    if K[0, 1] != 0 or K[1, 0] != 0 or list(K[2]) != [0.0, 0.0, 1.0]:
        raise doc.error("K", "expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise doc.error("K", f"focal lengths must be positive, got fx {K[0, 0]:g}, "
                             f"fy {K[1, 1]:g}")
    if not (0 <= K[0, 2] <= w - 1 and 0 <= K[1, 2] <= h - 1):
        raise doc.error("K", f"principal point ({K[0, 2]:g}, {K[1, 2]:g}) px lies off the "
                             f"{w}x{h} frame")
    n = len(doc.items("distortion"))
    if n not in DISTORTION_LENGTHS:
        raise doc.error("distortion", f"expected {DISTORTION_LENGTHS} coefficients (OpenCV's "
                                      f"order), got {n}")
    d = doc.array("distortion", (n,), lo=-1e6, hi=1e6)
    corner = max(math.hypot((u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1])
                 for u in (-0.5, w - 0.5) for v in (-0.5, h - 0.5))
    fold = radial_fold_radius(d, corner)
    if fold is not None:
        raise doc.error("distortion", f"the radial map folds at r = {fold:.3f} (x, y units), "
                                      f"inside the frame (corner r_d = {corner:.3f}): two rays "
                                      "would reach one pixel")
    views = []
    for i, v in enumerate(doc.items("views", required=False)):
        vd = Doc(v, path, f"views[{i}]", CameraFileError)
        views.append({"file": vd.string("file", required=False, default=""),
                      "corners": vd.integer("corners", lo=0, required=False, default=0),
                      "rms_px": vd.number("rms_px", lo=0, required=False, default=math.nan),
                      "tilt_deg": vd.number("tilt_deg", lo=0, hi=180, required=False,
                                            default=math.nan)})
    board = doc.obj("board", required=False)
    return CameraFile(K, d, w, h,
                      rms_px=doc.number("rms_px", lo=0, required=False, default=math.nan),
                      views=tuple(views), board=None if board is None else board_from_doc(board),
                      date=doc.string("date", required=False, default=""),
                      model=doc.string("distortion_model", required=False, default="given"),
                      warnings=tuple(str(x) for x in doc.items("warnings", required=False)))


def pinhole_of(camera: Camera) -> Camera:
    """``camera`` without its distortion: the ideal (pinhole) image that undistorted points
    lie in and that the estimator's geometry (projection, rays, fits) works in; ``camera``
    itself when it has none."""
    if not camera.has_distortion:
        return camera
    return replace(camera, distortion=())


def ideal_setup(setup):
    """``setup`` (an :class:`estimator.setup.Setup`) with :func:`pinhole_of` its camera;
    ``setup`` itself for a pinhole."""
    if not setup.camera.has_distortion:
        return setup
    return replace(setup, camera=pinhole_of(setup.camera))


def camera_from_file(camera: Camera, camera_file: CameraFile, path=None) -> Camera:
    """``camera`` (a scene's: its pose, thin lens, pixel pitch) with the intrinsics and the
    distortion of ``camera_file`` in place of its own.

    Raises
    ------
    CameraFileError
        The file's image size is not the camera's (naming ``path`` and ``image_size_px``).
    """
    size = (camera_file.width_px, camera_file.height_px)
    if size != (camera.width_px, camera.height_px):
        raise CameraFileError(f"image size {size[0]}x{size[1]}, the scene's camera is "
                              f"{camera.width_px}x{camera.height_px}", path=path,
                              key="image_size_px")
    d = camera_file.distortion if camera_file.has_distortion else ()
    return replace(camera, fx_px=camera_file.fx_px, fy_px=camera_file.fy_px,
                   cx_px=camera_file.cx_px, cy_px=camera_file.cy_px, distortion=d)


def camera_file_record(path) -> dict:
    """``{"path": ..., "sha256": ...}``: which camera file a calibration was made with (the
    path as given, resolved, and the SHA-256 of its bytes), for the calibration file's
    ``camera_file`` key."""
    import hashlib
    from pathlib import Path

    p = Path(path)
    try:
        digest = hashlib.sha256(p.read_bytes()).hexdigest()
    except OSError as exc:
        raise CameraFileError(f"cannot read it: {exc.strerror or exc}", path=path) from None
    return {"path": str(p.resolve()), "sha256": digest}


def check_camera_record(record, camera_path, calibration_path) -> str | None:
    """Whether a calibration made with the camera file ``record`` (None: made without one)
    may be used with the camera file at ``camera_path`` (None: the scene's own camera).

    The calibration's lighting correction, corneal radius, eye centre and gaze mappings were
    fitted to glints undistorted through that camera; through another lens model they are off
    by as much as the models differ. So a calibration that records a camera file is refused
    with any other one (or none); files are the same when their contents are (the SHA-256),
    wherever they lie. A calibration without a record (made without ``--camera``, or before
    calibrations recorded it) used with a camera file gives a warning, returned.

    Raises
    ------
    CameraFileError
        Naming ``calibration_path`` and the key ``camera_file``.
    """
    if record is None:
        if camera_path is None:
            return None
        return (f"{calibration_path} records no camera file (calibrated through the scene's "
                f"own camera, or before calibrations recorded it); tracking through "
                f"{camera_path} instead")
    if camera_path is None:
        raise CameraFileError(f"the calibration was made with the camera file "
                              f"{record['path']} (sha256 {record['sha256'][:12]}); give it "
                              "with --camera", path=calibration_path, key="camera_file")
    given = camera_file_record(camera_path)
    if given["sha256"] != record["sha256"]:
        raise CameraFileError(f"the calibration was made with the camera file "
                              f"{record['path']} (sha256 {record['sha256'][:12]}), not with "
                              f"{camera_path} (sha256 {given['sha256'][:12]}): calibrate again "
                              "with this camera file", path=calibration_path,
                              key="camera_file.sha256")
    return None
