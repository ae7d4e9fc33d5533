"""Rendered datasets (``scet-dataset``, version 1): ``format`` (names, errors, label
type), ``labels`` (ground truth, EXR frames), ``manifest`` (what made a dataset, resume
checks), ``jobs`` (prepare, intact frames, commit the manifest, finalize), ``writer``
(:func:`render_dataset`, one frame's render), ``distributed`` (the same on a Ray cluster),
``reader`` (:func:`open_dataset`, :func:`verify_dataset`), ``calibration`` (single-pulse
calibration frames).
"""

from .calibration import CALIB_FIXATION_S, render_calibration
from .distributed import (
    MAX_RESTARTS,
    MAX_TASK_RETRIES,
    NAMESPACE,
    FrameRenderer,
    render_dataset_ray,
)
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
from .jobs import DatasetPlan, commit_manifest, finalize_dataset, frame_intact, prepare_dataset
from .labels import ExrFrame, frame_labels, iter_labels, read_exr, visible_bands
from .reader import Dataset, DatasetFrame, open_dataset, verify_dataset
from .writer import dataset_trajectory, make_renderer, open_renderer, render_dataset, render_frame

__all__ = [
    "CALIB_FIXATION_S", "render_calibration", "MAX_RESTARTS", "MAX_TASK_RETRIES", "NAMESPACE",
    "FrameRenderer", "render_dataset_ray", "FORMAT", "VERSION", "MANIFEST_NAME", "LABELS_NAME",
    "FRAMES_DIR", "PARTIAL_SUFFIX", "TRAJECTORY_KINDS", "GRID_COLS", "GRID_ROWS", "FIXATION_S",
    "SACCADE_FIXATION_RANGE_S", "PNG_COMPRESSION", "DatasetError", "DatasetMismatchError",
    "RenderSummary", "StrobeLabel", "counts_png", "DatasetPlan", "frame_intact",
    "prepare_dataset", "commit_manifest", "finalize_dataset", "visible_bands", "frame_labels",
    "ExrFrame", "read_exr", "iter_labels", "DatasetFrame", "Dataset", "open_dataset",
    "verify_dataset", "dataset_trajectory", "render_dataset", "open_renderer", "make_renderer",
    "render_frame"
]
