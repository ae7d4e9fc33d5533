"""Rendered datasets (``scet-dataset``, version 1): ``format`` (names, errors, label
type), ``labels`` (ground truth, EXR frames), ``manifest`` (what made a dataset, resume
checks), ``writer`` (:func:`render_dataset`), ``calibration`` (single-pulse calibration
frames).
"""

from .calibration import CALIB_FIXATION_S, render_calibration
from .format import (
    FIXATION_S,
    FORMAT,
    FRAMES_DIR,
    GRID_COLS,
    GRID_ROWS,
    LABELS_NAME,
    MANIFEST_NAME,
    PARTIAL_SUFFIX,
    PNG_COMPRESSION,
    SACCADE_FIXATION_RANGE_S,
    TRAJECTORY_KINDS,
    VERSION,
    DatasetError,
    DatasetMismatchError,
    RenderSummary,
    StrobeLabel,
    counts_png,
)
from .labels import ExrFrame, frame_labels, iter_labels, read_exr, visible_bands
from .writer import dataset_trajectory, render_dataset

__all__ = [
    "CALIB_FIXATION_S", "render_calibration", "FORMAT", "VERSION", "MANIFEST_NAME",
    "LABELS_NAME", "FRAMES_DIR", "PARTIAL_SUFFIX", "TRAJECTORY_KINDS", "GRID_COLS", "GRID_ROWS",
    "FIXATION_S", "SACCADE_FIXATION_RANGE_S", "PNG_COMPRESSION", "DatasetError",
    "DatasetMismatchError", "RenderSummary", "StrobeLabel", "counts_png", "visible_bands",
    "frame_labels", "ExrFrame", "read_exr", "iter_labels", "dataset_trajectory",
    "render_dataset"
]
