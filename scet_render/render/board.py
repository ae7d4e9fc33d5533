"""Frames of a ChArUco calibration board seen through the scene's camera and lens.

``scet render SCENE --board charuco --frames N --out DIR`` renders what a camera calibration
(``scet camera calibrate``) is given: a printed ChArUco board (OpenCV's ``cv2.aruco``
``CharucoBoard``, drawn by OpenCV's ``generateImage``) held at the scene's working distance in
``N`` poses spread over the field, seen through the Setup's :class:`~estimator.geometry.Camera`
with its distortion and thin lens (defocus), exactly as the eye renders are
(:class:`~scet_render.render.lens.LensRays`). Beside the frames, ``board.json`` records the
board, the true intrinsics and lens, and every frame's true board pose, so that a calibration
can be scored against the truth.

The board is a matte print under uniform, unoccluded illumination: its radiance is proportional
to its albedo, so each camera ray's sample is the albedo where the ray meets the board's plane
(bilinear in a texture finer than the camera's pixel footprint), and the surround's albedo
elsewhere. No light transport is needed for that exact answer; the only sampling is over the
pixel (box filter) and, for a thin lens, the pupil. The frames are 8-bit grey PNG, albedo 1 at
:data:`WHITE_DN`.

Board frame (OpenCV's): origin at the board's top-left corner, x along its columns, y down its
rows, z into the board (away from the camera when the board faces it). A frame's pose is
``rvec, tvec`` with X_camera = R(rvec) X_board + tvec (metres), as ``cv2.calibrateCamera``
returns it.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.formats import atomic_file, atomic_write
from estimator.geometry import Camera, rotation_matrix
from estimator.setup import Setup

from estimator.lens.board import board_for_setup, working_distance_m

from .lens import LensRays

log = logging.getLogger(__name__)

FORMAT = "scet-board-frames"
VERSION = 1
#: The board file beside the frames.
BOARD_NAME = "board.json"
#: Albedos of the print: white paper, black toner (laser print ~0.05), and the table around it.
WHITE_ALBEDO, BLACK_ALBEDO, SURROUND_ALBEDO = 0.90, 0.05, 0.30
#: 8-bit value of albedo 1 (white paper at 0.9 reads 211: headroom, no clipping).
WHITE_DN = 235.0
#: Texels per board square: at the prototype's 23 mm a 643 px camera's pixel covers 0.036 mm
#: and :func:`spec_for`'s squares are 1.3 mm, ~36 pixels; 200 texels keep the texture ~5x
#: finer than a pixel (and the bilinear texture lookup below the pixel's box filter).
TEXELS_PER_SQUARE = 200
#: Rows rendered at once (bounds the Dr.Jit arrays to rows * width * spp lanes).
ROWS_PER_CHUNK = 48


@dataclass(frozen=True)
class CharucoSpec:
    """A ChArUco board: ``squares`` (columns, rows), square and marker sides (m), dictionary."""

    squares: tuple[int, int] = (11, 8)
    square_m: float = 3.0e-3
    marker_m: float = 2.2e-3
    dictionary: str = "DICT_4X4_50"

    @property
    def size_m(self) -> tuple[float, float]:
        return self.squares[0] * self.square_m, self.squares[1] * self.square_m

    def cv_board(self):
        import cv2

        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, d)

    def albedo_image(self) -> np.ndarray:
        """(rows * T, cols * T) float32 albedo of the print, T = :data:`TEXELS_PER_SQUARE`."""
        t = TEXELS_PER_SQUARE
        img = self.cv_board().generateImage((self.squares[0] * t, self.squares[1] * t),
                                            marginSize=0, borderBits=1)
        return np.where(img > 127, WHITE_ALBEDO, BLACK_ALBEDO).astype(np.float32)

    def as_dict(self) -> dict:
        return {"type": "charuco", "squares": list(self.squares), "square_m": self.square_m,
                "marker_m": self.marker_m, "dictionary": self.dictionary}


def spec_for(setup: Setup) -> CharucoSpec:
    """The board ``scet hardware board --scene`` prints for ``setup``
    (:func:`estimator.lens.board_for_setup`: 11 x 8 squares, many corners near each view's
    edge, spanning 60 % of the field's width at the working distance)."""
    b = board_for_setup(setup)
    tenths_mm = round(b.square_mm * 10)  # metres exactly as the tenths give them
    return CharucoSpec((b.squares_x, b.squares_y), tenths_mm / 1e4, 0.75 * tenths_mm / 1e4,
                       b.dictionary)


#: Where the board's centre goes, in units of the half image (x, y): the four corners first
#: (a calibration must see the corners to pin the distortion there), then the edges, the centre.
ANCHORS = ((-1, -1), (1, 1), (1, -1), (-1, 1), (0, 0), (0, -1), (1, 0), (0, 1), (-1, 0))


def board_poses(setup: Setup, spec: CharucoSpec, frames: int, seed: int) -> list[tuple]:
    """``frames`` (rvec, tvec) poses spread over the field: frame i holds the board toward
    anchor i mod 9 (:data:`ANCHORS`; at a corner the board's own corner pokes ~15 % of its size
    out of the frame, so its outermost corners land near the image's corner), jittered, at the
    working distance +-10 %, tilted 10-30 deg about a random axis in the board plane (the tilt
    fixes the focal length) and turned up to +-17 deg in its plane."""
    rng = np.random.default_rng(seed)
    cam = setup.camera
    wd = working_distance_m(setup)
    half_img = np.array([cam.width_px / 2, cam.height_px / 2])
    poses = []
    for i in range(frames):
        depth = wd * rng.uniform(0.9, 1.1)
        half_board = np.array(spec.size_m) / 2 * cam.fx_px / depth  # px
        anchor = np.array(ANCHORS[i % len(ANCHORS)], dtype=np.float64)
        reach = np.maximum(half_img - 0.7 * half_board, 0.0)
        uv = half_img + anchor * reach + rng.uniform(-0.05, 0.05, 2) * half_img
        centre = np.array([(uv[0] - cam.cx_px) / cam.fx_px, (uv[1] - cam.cy_px) / cam.fy_px,
                           1.0]) * depth
        axis_angle = rng.uniform(0, 2 * math.pi)
        tilt = math.radians(rng.uniform(10.0, 30.0))
        R = rotation_matrix(np.array([math.cos(axis_angle), math.sin(axis_angle), 0.0]), tilt)
        R = R @ rotation_matrix(np.array([0.0, 0.0, 1.0]), rng.uniform(-0.3, 0.3))
        half = np.array([spec.size_m[0] / 2, spec.size_m[1] / 2, 0.0])
        poses.append((_rotation_vector(R), centre - R @ half))
    return poses


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].reshape(3)


def render_board(camera: Camera, spec: CharucoSpec, rvec, tvec, *, spp: int = 16,
                 seed: int = 0, mi=None) -> np.ndarray:
    """(H, W) float32 albedo-proportional image of the board at pose (rvec, tvec).

    Every pixel averages ``spp`` rays of :class:`LensRays` (jittered over the pixel, and over the
    pupil for a thin lens) that meet the board's plane; Dr.Jit runs them (a JIT variant).
    """
    import cv2
    import drjit as dr

    from .backend import activate, is_jit_variant

    mi = mi or activate(None)
    if not is_jit_variant(mi.variant()):
        raise ValueError(f"board renders need a JIT Mitsuba variant (llvm_ad_rgb); this one "
                         f"runs {mi.variant()}")
    lens = LensRays.of(camera, pinhole=True)
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    t = np.asarray(tvec, dtype=np.float64).reshape(3)
    # The board plane in world coordinates (scene units): origin, x and y axes, normal.
    to_world = camera.rotation.T
    scale = 100.0  # LensRays' scene units per metre
    origin = (camera.position_m + to_world @ t) * scale
    bx, by = to_world @ R[:, 0], to_world @ R[:, 1]
    normal = np.cross(bx, by)
    origin, bx, by, normal = ([float(v) for v in a] for a in (origin, bx, by, normal))
    albedo = spec.albedo_image()
    tex = mi.Texture2f(mi.TensorXf(albedo[..., None]))
    T = TEXELS_PER_SQUARE / spec.square_m  # texels per metre
    size = np.array(albedo.shape[::-1], dtype=np.float64)
    W, H = camera.width_px, camera.height_px
    out = np.empty((H, W), dtype=np.float32)
    for row0 in range(0, H, ROWS_PER_CHUNK):
        rows = min(ROWS_PER_CHUNK, H - row0)
        n = rows * W * spp
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(int(np.random.SeedSequence([seed, row0]).generate_state(1)[0]), n)
        pixel = dr.arange(mi.UInt32, n) // spp
        film = mi.Point2f(mi.Float(pixel % W), mi.Float(pixel // W + row0)) + sampler.next_2d()
        o, d = lens.rays(mi, film, sampler.next_2d() if lens.thin else None)
        nrm = mi.Vector3f(*normal)
        dist = dr.dot(mi.Point3f(*origin) - o, nrm) / dr.dot(d, nrm)
        p = (o + d * dist - mi.Point3f(*origin)) * (1.0 / scale)  # metres from the board origin
        u = dr.dot(p, mi.Vector3f(*bx)) * T  # texels (edges at integers)
        v = dr.dot(p, mi.Vector3f(*by)) * T
        inside = (dist > 0) & (u >= 0) & (v >= 0) & (u <= size[0]) & (v <= size[1])
        value = tex.eval(mi.Point2f(u / size[0], v / size[1]))[0]
        value = dr.select(inside, value, SURROUND_ALBEDO)
        img = dr.block_sum(value, spp) * (1.0 / spp)
        out[row0:row0 + rows] = np.asarray(img, dtype=np.float32).reshape(rows, W)
    return out


def render_board_frames(setup: Setup, out, *, frames: int, spp: int = 16, seed: int = 0,
                        spec: CharucoSpec | None = None, progress=None) -> Path:
    """Render ``frames`` board frames into ``out/frames/NNNNNN.png`` with ``out/board.json``
    (the board, the true camera and lens, and the true poses). Returns ``out``.
    ``progress(done, total)`` is called after each frame."""
    import cv2

    from .backend import activate

    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ValueError(f"frames must be an integer >= 1, got {frames!r}")
    out = Path(out)
    spec = spec or spec_for(setup)
    cam = setup.camera
    mi = activate(None)
    poses = board_poses(setup, spec, frames, seed)
    records = []
    for i, (rvec, tvec) in enumerate(poses):
        img = render_board(cam, spec, rvec, tvec, spp=spp, seed=seed * 100003 + i, mi=mi)
        dn = np.clip(np.rint(img * WHITE_DN), 0, 255).astype(np.uint8)
        name = f"frames/{i:06d}.png"
        with atomic_file(out / name) as tmp:
            ok, buf = cv2.imencode(".png", dn)
            tmp.write_bytes(buf.tobytes())
        records.append({"file": name, "rvec": [float(v) for v in rvec],
                        "tvec_m": [float(v) for v in tvec]})
        if progress is not None:
            progress(i + 1, frames)
    doc = {"format": FORMAT, "version": VERSION, "scene": setup.name, "board": spec.as_dict(),
           "camera": {"width_px": cam.width_px, "height_px": cam.height_px,
                      "fx_px": cam.fx_px, "fy_px": cam.fy_px, "cx_px": cam.cx_px,
                      "cy_px": cam.cy_px, **cam.lens_dict()},
           "working_distance_m": working_distance_m(setup), "spp": spp, "seed": seed,
           "frames": records}
    atomic_write(out / BOARD_NAME, json.dumps(doc, indent=1) + "\n")
    log.info("board frames: %d in %s", frames, out)
    return out
