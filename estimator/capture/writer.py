"""Writing a capture folder as the frames arrive (``scet-capture`` version 2).

Version 2 is version 1 written in another order, so that a reader can follow a capture while
it is written and a capture cut short (SIGINT, SIGKILL, a full disk, a stalled camera) keeps
every frame written before the cut:

1. ``capture.json`` first, with ``"state": "capturing"``;
2. each frame's raw file (written atomically: a file that exists is whole), then its line
   appended to ``frames.jsonl`` in one write (a reader takes only lines that end in a
   newline, so a line being written, or torn by a kill, is not read);
3. ``capture.json`` again at the end, with the final ``state`` (``complete``,
   ``interrupted`` or ``failed``) and a ``summary`` (frames written, frames the camera
   dropped, frames lost to a full writer queue, why it stopped).

A folder whose state is still ``capturing`` and that nobody writes is a capture that was
killed: the reader reads what it holds and says so. Version 1 folders (``capture.json``
written last, no state) are read as before.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..formats import FRAMES_DIR, atomic_file, atomic_write, frame_name
from .folder import CAPTURE_NAME, FRAMES_LIST_NAME, STATES
from .raw import encode_raw, parse_raw_format

__all__ = ["CaptureWriter", "STATES"]

#: Seconds between flushes to the disk. A raw file is written under a temporary name and
#: renamed (so a file that exists is whole, whatever kills the process), but not fsynced one
#: by one: 60 fsyncs a second kept the writer behind a 60 fps camera on the soak machine
#: (benchmarks/bench_live_soak.py); once a second ``os.sync`` flushes the frames and then the
#: list. A power cut can lose the last second; a killed process loses nothing written.
SYNC_EVERY_S = 1.0


class CaptureWriter:
    """Write a capture folder frame by frame (module docstring).

    Parameters
    ----------
    folder : path
        A new folder, or an empty one: a folder that already holds a capture is refused, so
        that nothing captured earlier is overwritten.
    header : dict
        The ``capture.json`` document (:func:`estimator.capture.capture_header`); its
        ``version``, ``state`` and ``summary`` are set here.
    clock : callable
        Seconds, for the list's sync interval.

    Raises
    ------
    FileExistsError
        ``folder`` holds a ``capture.json`` already.
    OSError
        The folder or its first file cannot be written.
    """

    def __init__(self, folder, header: dict, *, clock=None):
        import time

        self.folder = Path(folder)
        self._head_path = self.folder / CAPTURE_NAME
        if self._head_path.exists():
            raise FileExistsError(f"{self._head_path}: the folder holds a capture already; "
                                  "choose a new --out")
        self.header = dict(header)
        self.header["version"] = 2
        self.header["state"] = "capturing"
        self.header.pop("summary", None)
        self._fmt = parse_raw_format(self.header["raw"]["format"])
        w, h = self.header["raw"]["size"]
        self._shape = (int(h), int(self.header["raw"]["stride"]))
        self._clock = clock or time.monotonic
        (self.folder / FRAMES_DIR).mkdir(parents=True, exist_ok=True)
        self._write_head()
        self._list = open(self.folder / FRAMES_LIST_NAME, "ab")
        self._synced = self._clock()
        self.frames = 0

    def _write_head(self) -> None:
        atomic_write(self._head_path, json.dumps(self.header, indent=1, sort_keys=True) + "\n")

    def write(self, buf, metadata: dict) -> str:
        """Write one frame: ``buf`` (H, stride) uint8 as the camera gave it, or an (H, W)
        mosaic to encode; its metadata line follows. The file name, relative to the folder.

        Raises
        ------
        OSError
            The disk is full or failed (the frames written before stay listed).
        ValueError
            A buffer of another shape than the header's.
        """
        a = np.asarray(buf)
        if a.dtype != np.uint8:
            a = encode_raw(a, self._fmt, self._shape[1])
        if a.shape != self._shape:
            raise ValueError(f"frame {self.frames}: raw buffer of shape {a.shape}, the header says "
                             f"{self._shape}")
        name = f"{FRAMES_DIR}/{frame_name(self.frames, 'raw')}"
        with atomic_file(self.folder / name, sync=False) as tmp:
            tmp.write_bytes(np.ascontiguousarray(a).tobytes())
        self._list.write((json.dumps({"file": name, **metadata}, sort_keys=True) + "\n").encode())
        self._list.flush()
        now = self._clock()
        if now - self._synced >= SYNC_EVERY_S:
            os.sync()
            self._synced = now
        self.frames += 1
        return name

    def finish(self, state: str, summary: dict, labels_text: str | None = None) -> Path:
        """Close the list and write ``capture.json`` with the final ``state`` and
        ``summary``. On a full disk the old ``capture.json`` (state ``capturing``) stays and
        the ``OSError`` is raised; the frames stay readable either way."""
        if state not in STATES[1:]:
            raise ValueError(f"state must be one of {STATES[1:]}, got {state!r}")
        try:
            self._list.flush()
            os.fsync(self._list.fileno())
        finally:
            self._list.close()
        if labels_text is not None:
            atomic_write(self.folder / "labels.jsonl", labels_text)
        self.header["state"] = state
        self.header["summary"] = dict(summary, frames_written=self.frames)
        self._write_head()
        return self.folder
