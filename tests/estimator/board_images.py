"""Synthetic views of a ChArUco board through a known lens, made with OpenCV alone.

The board is OpenCV's image (``CharucoBoard.generateImage``); each output pixel (u, v) of the
camera is undistorted with the TRUE model (``cv2.undistortPoints``), its ray intersected
with the board's plane at the view's pose, and the board image sampled there (``cv2.remap``),
on a grid 2x finer than the pixels and averaged over each pixel (a box pixel). The image path
is real: the detector sees distorted, anti-aliased, noisy pixels, nothing it is told.
"""

from __future__ import annotations

import math

import numpy as np

#: The prototype's stock lens at VGA (HARDWARE.md Sec. 10) and a barrel distortion of ~10 px
#: at the frame's corners.
TRUE_K = np.array([[643.0, 0.0, 321.5], [0.0, 641.0, 236.0], [0.0, 0.0, 1.0]])
TRUE_DIST = np.array([-0.12, 0.09, 0.0008, -0.0005, 0.0])
SIZE = (640, 480)
BOARD_PX_PER_MM = 40
SUPERSAMPLE = 2
#: Fine pixels between exact evaluations of the map.
STEP = 8


def rotation(axis, angle_rad) -> np.ndarray:
    import cv2

    a = np.asarray(axis, dtype=np.float64)
    return cv2.Rodrigues(a / np.linalg.norm(a) * angle_rad)[0]


def poses(n: int, seed: int = 0, *, tilt_deg=(20.0, 40.0), distance_m=(0.030, 0.040),
          flat: bool = False):
    """``n`` (R, t) board poses, board centre spread over the frame (a 3x3 grid of aims and
    the centre), tilted about random in-plane axes (``flat``: no tilt)."""
    rng = np.random.default_rng(seed)
    aims = [(u, v) for v in (0.2, 0.5, 0.8) for u in (0.2, 0.5, 0.8)]
    out = []
    for k in range(n):
        au, av = aims[k % len(aims)]
        pix = np.array([au * SIZE[0], av * SIZE[1]])
        ray = np.array([(pix[0] - TRUE_K[0, 2]) / TRUE_K[0, 0],
                        (pix[1] - TRUE_K[1, 2]) / TRUE_K[1, 1], 1.0])
        d = rng.uniform(*distance_m)
        phi = rng.uniform(0, 2 * math.pi)
        theta = 0.0 if flat else math.radians(rng.uniform(*tilt_deg))
        R = rotation([math.cos(phi), math.sin(phi), 0.0], theta) if theta else np.eye(3)
        out.append((R, ray * d))
    return out


def board_view(spec, R, centre_m, *, K=TRUE_K, dist=TRUE_DIST, noise_dn=1.5, seed=0,
               blur_px=0.0) -> np.ndarray:
    """(480, 640) uint8: the board at pose R (board -> camera) with its centre at
    ``centre_m`` (camera frame), seen through K and ``dist``."""
    import cv2
    from scipy.ndimage import map_coordinates

    bw, bh = spec.size_mm
    ppm = BOARD_PX_PER_MM
    board = spec.cv_board().generateImage((int(round(bw * ppm)), int(round(bh * ppm))),
                                          marginSize=0, borderBits=1).astype(np.float32)
    s = SUPERSAMPLE
    w, h = SIZE
    # The map is smooth: computed exactly every STEP fine pixels, cubic between (< 0.002 px).
    gu, gv = np.arange(0, w * s + STEP, STEP), np.arange(0, h * s + STEP, STEP)
    u, v = np.meshgrid((gu + 0.5) / s - 0.5, (gv + 0.5) / s - 0.5)
    px = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(px, K, dist, criteria=
                             (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
                             ).reshape(-1, 2)
    c_b = np.array([bw / 2e3, bh / 2e3, 0.0])
    t = np.asarray(centre_m) - R @ c_b
    H = np.column_stack([R[:, 0], R[:, 1], t])
    q = np.linalg.solve(H, np.column_stack([xy, np.ones(len(xy))]).T)
    fi, fj = np.meshgrid(np.arange(w * s) / STEP, np.arange(h * s) / STEP)
    maps = []
    for coarse in (q[0] / q[2], q[1] / q[2]):  # metres on the board
        c = coarse.reshape(gv.size, gu.size) * 1e3 * ppm - 0.5
        maps.append(map_coordinates(c, [fj, fi], order=3).astype(np.float32))
    mx, my = maps
    fine = cv2.remap(board, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=255.0)
    img = fine.reshape(h, s, w, s).mean(axis=(1, 3))
    img = 30.0 + img * (200.0 / 255.0)  # dark ink, paper below full scale
    if blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_px)
    img = img + np.random.default_rng(seed).normal(0.0, noise_dn, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def write_views(folder, spec, n: int, seed: int = 0, **kw) -> list:
    """Write ``n`` views as ``view_NN.png`` into ``folder``; their poses."""
    import cv2

    ps = poses(n, seed, **{k: kw.pop(k) for k in ("tilt_deg", "distance_m", "flat") if k in kw})
    for i, (R, c) in enumerate(ps):
        cv2.imwrite(str(folder / f"view_{i:02d}.png"), board_view(spec, R, c, seed=seed + i, **kw))
    return ps
