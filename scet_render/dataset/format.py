"""The dataset format (``scet-dataset``, version 1): names, constants, errors and the
label type; see :mod:`scet_render.dataset` for the layout on disk.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator import formats
from estimator.errors import InputError

#: The dataset's names on disk, from SCET's one list of them (:mod:`estimator.formats`).
FORMAT, VERSION = formats.DATASET_FORMAT, formats.DATASET_VERSION
MANIFEST_NAME, LABELS_NAME, FRAMES_DIR = formats.MANIFEST_NAME, formats.LABELS_NAME, formats.FRAMES_DIR
PARTIAL_SUFFIX = formats.PARTIAL_SUFFIX

TRAJECTORY_KINDS = ("fixations", "saccades", "grid")

#: The paper's accuracy grid (Sec. 3.2): 24 x 15 cell centres on the screen.
GRID_COLS, GRID_ROWS = 24, 15
#: Fixation length of the "fixations" and "grid" trajectories, s: long enough for a gaze
#: estimate per target, short enough that a 64-frame dataset (1.06 s) visits several targets.
FIXATION_S = 0.25
#: Fixation lengths of the "saccades" trajectory, s (uniform; typical reading/search values).
SACCADE_FIXATION_RANGE_S = (0.1, 0.3)
#: PNG zlib level: fixed, so that the bytes do not depend on OpenCV's default.
PNG_COMPRESSION = 3

# Independent random streams derived from the dataset seed.
_STREAM_TRAJECTORY = 0
_STREAM_RENDER = 1
_STREAM_SENSOR = 2
_STREAM_BLINKS = 3
_STREAM_PUPIL = 4

#: Suffix of a frame's segmentation mask beside its EXR and PNG: ``frames/NNNNNN_mask.png``
#: (uint8 indices into :data:`scet_render.render.MASK_CLASSES`).
MASK_SUFFIX = "_mask"


def mask_name(frame: int) -> str:
    """``NNNNNN_mask.png``: the file name of frame ``frame``'s segmentation mask."""
    return f"{int(frame):06d}{MASK_SUFFIX}.png"


def mask_png(mask) -> bytes:
    """PNG bytes of an (H, W) uint8 mask, compression :data:`PNG_COMPRESSION`."""
    import cv2

    ok, png = cv2.imencode(".png", np.asarray(mask, dtype=np.uint8),
                           [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
    if not ok:
        raise RuntimeError("OpenCV could not encode a mask as PNG")
    return png.tobytes()


class DatasetError(InputError):
    """A dataset folder or file is missing, malformed or of another format or version."""


class DatasetMismatchError(DatasetError):
    """A run was pointed at a folder holding a dataset made with other arguments."""


@dataclass(frozen=True, slots=True)
class RenderSummary:
    """What one :func:`render_dataset` call did.

    Attributes
    ----------
    path : Path
        The dataset folder.
    frames_rendered : tuple of int
        Frames rendered by this call.
    frames_skipped : tuple of int
        Frames already complete on disk (a resumed run).
    """

    path: Path
    frames_rendered: tuple[int, ...]
    frames_skipped: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class StrobeLabel:
    """One line of ``labels.jsonl`` (see the module docstring for the meaning of each field).

    Attributes
    ----------
    frame, strobe : int
    time_s, pulse_start_s : float
    first_row, last_row : int
    full_rows : (int, int)
        Half-open row range.
    target_m, cornea_center_m : (3,) float
    yaw_rad, pitch_rad : float
    glints_px : (n, 2) float
        NaN where the file holds null.
    glints_visible : (n,) bool
        For scenes with moving lids (``[eyelids]``), False also where a lid or lash hides the
        glint (:mod:`scet_render.render.occlusion`).
    lid_closure : float
        Upper lid closure of a blink at the strobe instant (moving lids; else 0).
    glints_occluder : tuple of str, optional
        Per light "none", "lid" or "lash": what blocks (part of) its glint; None for labels of
        scenes without moving lids (and every label written before they existed).
    glints_blocked_fraction : (n,) float, optional
        Fraction of each glint's light paths blocked: 1 hidden, in (0, 1) cut.
    pupil_center_px : (2,) float, optional
        The pupil's centre as imaged through the cornea (NaN where its ray does not reach the
        camera through the cap); None for datasets written before pupil labels existed.
    pupil_ellipse_px : (5,) float, optional
        ``[u, v, major, minor, angle_deg]``: the ellipse of the refracted pupil edge (full axis
        lengths, px; the major axis's angle from +u toward +v); NaN where part of the edge is
        not seen; None for older datasets.
    pupil_diameter_mm : float, optional
        The pupil's diameter at the strobe instant; None for older datasets.
    pupil_occluder : str, optional
        Moving lids only: "none", "lid" or "lash", what blocks the pupil centre's refracted
        ray to the camera; None without moving lids and for older datasets.
    pupil_edge_visible_fraction : float, optional
        Moving lids only: the share of the pupil edge's 64 points whose refracted ray reaches
        the camera unblocked (1: the whole outline is seen); None as above.
    """

    frame: int
    strobe: int
    time_s: float
    pulse_start_s: float
    first_row: int
    last_row: int
    full_rows: tuple[int, int]
    target_m: np.ndarray
    yaw_rad: float
    pitch_rad: float
    cornea_center_m: np.ndarray
    glints_px: np.ndarray
    glints_visible: np.ndarray
    lid_closure: float = 0.0
    glints_occluder: tuple | None = None
    glints_blocked_fraction: np.ndarray | None = None
    pupil_center_px: np.ndarray | None = None
    pupil_ellipse_px: np.ndarray | None = None
    pupil_diameter_mm: float | None = None
    pupil_occluder: str | None = None
    pupil_edge_visible_fraction: float | None = None


def _exr():
    import OpenEXR

    return OpenEXR


def _floats(v) -> list[float]:
    return [float(x) for x in np.asarray(v).ravel()]


def _check_int(name: str, value, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _check_kind(kind) -> str:
    if kind not in TRAJECTORY_KINDS:
        raise ValueError(f"trajectory must be one of {TRAJECTORY_KINDS}, got {kind!r}")
    return kind


def counts_png(dn, bit_depth: int) -> bytes:
    """PNG bytes of a frame of sensor counts: 8-bit for ``bit_depth`` <= 8, else 16-bit (a
    10-bit sensor's counts as they are, not scaled), compression :data:`PNG_COMPRESSION`."""
    import cv2

    word = np.uint8 if bit_depth <= 8 else np.uint16
    ok, png = cv2.imencode(".png", np.asarray(dn).astype(word),
                           [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
    if not ok:
        raise RuntimeError("OpenCV could not encode a frame as PNG")
    return png.tobytes()
