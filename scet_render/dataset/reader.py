"""Reading a rendered dataset: frames with their per-strobe labels, lazily; and checking one.

:func:`open_dataset` is for users of the datasets (training and testing glint detectors,
sweeping lighting designs). Nothing is decoded until asked for::

    from scet_render.dataset import open_dataset

    ds = open_dataset("work/test")
    for frame in ds:                       # frames in index order
        counts = frame.counts()            # (H, W) uint16 sensor counts (PNG), as the tracker sees
        for label in frame.labels:         # one StrobeLabel per lit band
            rows = slice(*label.full_rows) # rows that collect the whole pulse
            glints = label.glints_px[label.glints_visible]   # ground-truth (u, v) of the band
            pupil = label.pupil_center_px  # the pupil's centre as imaged through the cornea
        mask = frame.mask()                # (H, W) uint8 classes, scet_render.render.MASK_CLASSES

    # A training loop over batches of (image, target) pairs:
    batch = [(f.counts() / 1023.0, f.labels) for f in ds[0:8]]

:func:`verify_dataset` checks every frame is there and intact, the labels complete and in
order, and the manifest consistent with the folder (``scet dataset verify``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from estimator.errors import TrackerInputError
from estimator.formats import frame_name
from estimator.inputs import MAX_MISSING_FRAMES, read_frame

from .format import FRAMES_DIR, LABELS_NAME, MASK_SUFFIX, DatasetError, mask_name
from .jobs import frame_intact
from .labels import iter_labels, read_exr
from .manifest import read_manifest


@dataclass(frozen=True)
class DatasetFrame:
    """One frame of a dataset: its labels now, its images on demand."""

    index: int
    labels: tuple
    folder: Path
    size_px: tuple | None = None    # (W, H) from the manifest: frames of another size refused

    def counts(self) -> np.ndarray:
        """(H, W) sensor counts (uint16 for bit depths above 8, else uint8) from the PNG,
        refused by its header when not of the manifest's size."""
        path = self.folder / FRAMES_DIR / frame_name(self.index, "png")
        try:
            return read_frame(path, self.size_px)
        except TrackerInputError as exc:
            raise DatasetError(str(exc)) from None

    def radiance(self) -> np.ndarray:
        """(H, W) float32 linear radiance from the EXR, as rendered."""
        return read_exr(self.folder / FRAMES_DIR / frame_name(self.index, "exr"),
                        self.size_px).radiance

    def mask(self) -> np.ndarray:
        """(H, W) uint8 segmentation mask (indices into
        :data:`scet_render.render.MASK_CLASSES`) from ``frames/NNNNNN_mask.png``.

        Raises
        ------
        DatasetError
            No mask (a dataset rendered without masks, or before they existed), or not one of
            the manifest's size.
        """
        import cv2

        path = self.folder / FRAMES_DIR / mask_name(self.index)
        try:
            data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
        except OSError as exc:
            raise DatasetError(f"{path}: no segmentation mask ({exc.strerror or exc}); render "
                               "the dataset with masks") from None
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
        want = None if self.size_px is None else (self.size_px[1], self.size_px[0])
        if img is None or img.dtype != np.uint8 or img.ndim != 2 or (want and img.shape != want):
            raise DatasetError(f"{path}: not an 8-bit one-channel PNG"
                               + (f" of {want[1]}x{want[0]} px" if want else ""))
        return img


class Dataset:
    """A finished dataset (:func:`open_dataset`): a sequence of :class:`DatasetFrame`."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.manifest = read_manifest(self.folder)  # typed and ranged
        self.frames = int(self.manifest["frames"])
        image = self.manifest["image"]
        self.size_px = (int(image["width_px"]), int(image["height_px"]))
        problem = _unbacked(self.folder, self.frames)
        if problem:
            raise DatasetError(problem)
        by_frame: dict[int, list] = {f: [] for f in range(self.frames)}
        for lb in iter_labels(self.folder):
            if lb.frame not in by_frame:
                raise DatasetError(f"{self.folder / LABELS_NAME}: frame {lb.frame} is outside the "
                                   f"manifest's {self.frames} frames")
            by_frame[lb.frame].append(lb)
        self._labels = {f: tuple(v) for f, v in by_frame.items()}

    def __len__(self) -> int:
        return self.frames

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(self.frames))]
        i = int(i)
        if i < 0:
            i += self.frames
        if not 0 <= i < self.frames:
            raise IndexError(f"frame {i} of a {self.frames}-frame dataset")
        return DatasetFrame(i, self._labels[i], self.folder, self.size_px)

    def __iter__(self):
        return (self[i] for i in range(self.frames))

    @property
    def n_labels(self) -> int:
        return sum(len(v) for v in self._labels.values())


def _unbacked(folder: Path, frames: int) -> str | None:
    """Why the manifest's frame count is not this folder's (more than
    :data:`estimator.inputs.MAX_MISSING_FRAMES` of its frames absent), or None."""
    frames_dir = folder / FRAMES_DIR
    try:
        with os.scandir(frames_dir) as it:
            held = sum(1 for e in it if e.name.endswith(".png")
                       and not e.name.endswith(MASK_SUFFIX + ".png"))
    except OSError:
        held = 0
    if frames - held > MAX_MISSING_FRAMES:
        return (f"{folder}/manifest.json, key 'frames': claims {frames} frames, {frames_dir} holds "
                f"{held}")
    return None


def open_dataset(folder) -> Dataset:
    """A finished dataset's frames and labels (module docstring).

    Raises
    ------
    DatasetError
        Not a SCET dataset, or not finished (no ``labels.jsonl``).
    """
    return Dataset(folder)


def verify_dataset(folder) -> list[str]:
    """Every problem of a dataset folder, one sentence each (empty: complete and intact).

    Checks the manifest (format, version, frame count), every frame's EXR and PNG (present,
    decodable, the EXR naming its frame and the scene), the labels (present, every line
    readable, frames within the manifest's, in order), and files the manifest does not name.
    """
    folder = Path(folder)
    try:
        manifest = read_manifest(folder)
    except DatasetError as exc:
        return [str(exc)]
    problems = []
    try:
        frames = int(manifest["frames"])
        shape = (int(manifest["image"]["height_px"]), int(manifest["image"]["width_px"]))
        sha = str(manifest["scene"]["sha256"])
        masks = "mask" in manifest.get("files", {})
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        return [f"{folder}/manifest.json: malformed ({exc!r})"]
    frames_dir = folder / FRAMES_DIR
    unbacked = _unbacked(folder, frames)
    if unbacked:  # a count the folder does not back is reported, not iterated
        return [unbacked]
    bad = [f for f in range(frames)
           if not frame_intact(frames_dir, f, sha, shape, masks=masks)]
    if bad:
        problems.append(f"{frames_dir}: {len(bad)} of {frames} frames missing or damaged "
                        f"(first: {bad[:5]}); rerun `scet render` with the dataset's arguments")
    if frames_dir.is_dir():
        known = {frame_name(f, e) for f in range(frames) for e in ("exr", "png", "raw")}
        known |= {mask_name(f) for f in range(frames)} if masks else set()
        extra = sorted(p.name for p in frames_dir.iterdir() if p.name not in known)
        if extra:
            problems.append(f"{frames_dir}: {len(extra)} files the manifest does not name "
                            f"(first: {extra[:5]})")
    try:
        last = (-1, -(2 ** 62))
        for lb in iter_labels(folder):
            key = (lb.frame, lb.strobe)
            if not 0 <= lb.frame < frames:
                problems.append(f"{folder / LABELS_NAME}: frame {lb.frame} outside 0-{frames - 1}")
                break
            if key <= last:
                problems.append(f"{folder / LABELS_NAME}: frame {lb.frame} strobe {lb.strobe} out "
                                "of order or repeated")
                break
            last = key
    except DatasetError as exc:
        problems.append(str(exc))
    return problems
