"""Tracking a folder while it is being written (``scet track --follow``): live use on the Pi,
where the capture writes ``frames/NNNNNN.png`` one after another and the tracker keeps up.

:func:`follow_frames` yields the frames of a folder of PNG frames (a rendered dataset, or
frames with a ``timing.json`` sidecar) as they appear, in index order, and stops

- at a clear end: an ``end`` file in the folder (:data:`END_NAME`, written by the producer
  when it is done), or a rendered dataset's last frame (its manifest's frame count);
- or after ``timeout_s`` with no new frame.

A capture folder (``capture.json``, written by ``scet capture`` / ``scet run`` as frames
arrive) is followed through :class:`estimator.capture.CaptureFollower`: frames in time-stamp
order as their lines reach ``frames.jsonl``, dropped ones as None, the end when
``capture.json`` leaves the state ``capturing``.

A frame that is not there while a later one is was dropped: it comes as None with "missing"
(the tracker gives its bands NaN samples). A file that does not decode yet (being written) is
read again until it does or the timeout passes. Frame starts come from ``timing.json`` where
it has the frame (read again when it grows), else f Δt.

:func:`track_following` runs :class:`estimator.tracker.Tracker` over them and writes
``samples.csv`` at the end (atomically, as :func:`estimator.folders.track_folder`).
"""

from __future__ import annotations

import logging
import re
import time
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from .capture import CaptureError, CaptureFollower, is_capture_folder
from .formats import FRAMES_DIR, MANIFEST_NAME, TIMING_NAME, read_json
from .folders import (
    TrackSummary,
    frame_path,
    read_frame,
    read_timing,
    track_frame,
    tracking_calibration,
    write_samples_csv,
)
from .setup import Setup
from .tracking import Tracker, TrackerInputError

log = logging.getLogger(__name__)

#: The producer's end marker: a file of this name in the folder means no frame follows.
END_NAME = "end"
_FRAME = re.compile(r"^(\d+)\.png$")


def _first_index(folder: Path) -> int | None:
    sub = folder / FRAMES_DIR
    where = sub if sub.is_dir() else folder
    found = [int(m.group(1)) for p in where.glob("*.png") if (m := _FRAME.match(p.name))]
    return min(found) if found else None


def _expected_frames(folder: Path) -> int | None:
    """A rendered dataset's frame count (its manifest, written first), else None."""
    path = folder / MANIFEST_NAME
    if not path.is_file():
        return None
    try:
        return int(read_json(path, TrackerInputError)["frames"])
    except (TrackerInputError, KeyError, TypeError, ValueError):
        return None


class _Starts:
    """Frame starts from ``timing.json`` (read again when a frame is not in it), else f Δt."""

    def __init__(self, folder: Path, setup: Setup):
        self.folder, self.setup, self.known = folder, setup, {}

    def __call__(self, f: int) -> float:
        if f not in self.known and (self.folder / TIMING_NAME).is_file():
            try:
                self.known = read_timing(self.folder, self.setup).frame_start_s
            except TrackerInputError:  # being rewritten: the default this time
                pass
        return self.known.get(f, f * self.setup.sensor.frame_period_s)


def follow_frames(folder, setup: Setup, *, timeout_s: float = 5.0, poll_s: float = 0.005,
                  clock: Callable[[], float] = time.monotonic,
                  sleep: Callable[[float], None] = time.sleep
                  ) -> Iterator[tuple[int, float, np.ndarray | None, str | None]]:
    """(frame index, frame start s, frame or None, error or None) as frames appear (module
    docstring); ``clock`` and ``sleep`` are the waiting's (tests pass their own)."""
    folder = Path(folder)
    if not timeout_s > 0 or not poll_s > 0:
        raise ValueError(f"timeout_s and poll_s must be positive, got {timeout_s!r}, {poll_s!r}")
    starts = _Starts(folder, setup)
    expected = _expected_frames(folder)
    f, last = None, clock()
    while True:
        if f is None and is_capture_folder(folder):
            yield from _follow_capture(folder, setup, timeout_s, poll_s, clock, sleep)
            return
        if f is None:
            f = _first_index(folder)
        if f is not None and expected is not None and f >= expected:
            return
        path = None if f is None else frame_path(folder, f)
        if path is not None and path.is_file():
            try:
                img = read_frame(path, (setup.camera.width_px, setup.camera.height_px))
            except TrackerInputError as exc:
                if clock() - last <= timeout_s:
                    sleep(poll_s)  # still being written
                    continue
                img, err = None, str(exc)
            else:
                err = None
            yield f, starts(f), img, err
            f, last = f + 1, clock()
            continue
        if f is not None and frame_path(folder, f + 1).is_file():
            yield f, starts(f), None, f"{path}: missing"
            f += 1
            continue
        if (folder / END_NAME).exists() or clock() - last > timeout_s:
            return
        sleep(poll_s)


def _follow_capture(folder: Path, setup: Setup, timeout_s, poll_s, clock, sleep):
    follower = CaptureFollower(folder, black_level_out_dn=setup.sensor.black_level_dn,
                               size_px=(setup.camera.width_px, setup.camera.height_px),
                               timeout_s=timeout_s, poll_s=poll_s, clock=clock, sleep=sleep)
    try:
        for fr in follower.frames():
            yield fr.index, fr.start_s, fr.image, fr.reason
    except CaptureError as exc:
        raise TrackerInputError(str(exc)) from None


def track_following(folder, setup: Setup, calibration, out_csv, *, method: str = "polynomial",
                    mapping: str | None = None, timeout_s: float = 5.0, poll_s: float = 0.005,
                    progress: Callable[[int, int], None] | None = None,
                    flag_cut_glints: bool | None = None, **wait) -> TrackSummary:
    """Track a folder's frames as they are written (:func:`follow_frames`) and write
    ``samples.csv`` when it ends; ``progress(done, total)`` after every frame (total: the
    frames so far, or a dataset's count). Other arguments as
    :func:`estimator.folders.track_folder`; ``wait`` goes to :func:`follow_frames`."""
    calibration, mapping = tracking_calibration(folder, calibration, out_csv, method=method,
                                                mapping=mapping, flag_cut_glints=flag_cut_glints,
                                                n_lights=setup.lights.count)
    tracker = Tracker(setup, calibration, method, mapping=mapping,
                      flag_cut_glints=flag_cut_glints)
    expected = _expected_frames(Path(folder))
    samples, done, busy = [], 0, 0.0
    for f, t0, img, err in follow_frames(folder, setup, timeout_s=timeout_s, poll_s=poll_s,
                                         **wait):
        t = time.perf_counter()
        samples.extend(track_frame(tracker, f, t0, img, err))
        busy += time.perf_counter() - t
        done += 1
        if progress is not None:
            progress(done, max(done, expected or 0))
    path = write_samples_csv(Path(out_csv), samples)
    return TrackSummary(path, tuple(samples), done, busy)
