"""Reading a capture folder while it is written (``scet track --follow``, ``scet bands
--measure --follow``): frames come out in index order as their lines reach ``frames.jsonl``.

The writer (:mod:`estimator.capture.writer`) writes each raw file before its line and each
line in one write; only lines that end in a newline are read, so a line being written is
read on the next poll. Indices come from the time stamps as in
:class:`estimator.capture.CaptureFolder`, with the frame period estimated from the frames so
far (the programmed ``FrameDuration`` until two frames are in, then the mean step over the
whole run, which a dropped frame does not bias: its index counts it); a gap of k periods
yields the k - 1 missing slots first, as ``image=None`` with "missing". The stream ends when
``capture.json`` leaves the state ``capturing`` and every line is read, or after
``timeout_s`` without a new line (a writer that was killed: logged).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Callable, Iterator

from .folder import (CAPTURE_NAME, FRAMES_LIST_NAME, GAP_TOLERANCE_FRAMES, MAX_GAP_FRAMES,
                     CaptureError, CaptureFolder, CaptureFrame, parse_list_line)

log = logging.getLogger(__name__)

__all__ = ["CaptureFollower", "follow_capture"]


class CaptureFollower:
    """A capture folder being written, read frame by frame (module docstring).

    Parameters
    ----------
    folder : path
    black_level_out_dn, size_px
        As :class:`estimator.capture.CaptureFolder`.
    timeout_s : float
        Seconds without a new line (or, at the start, without ``capture.json``) before the
        stream ends.
    poll_s : float
        Seconds between looks at the list.
    """

    def __init__(self, folder, *, black_level_out_dn: float = 16.0, size_px=None,
                 timeout_s: float = 5.0, poll_s: float = 0.005,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep):
        if not timeout_s > 0 or not poll_s > 0:
            raise ValueError(f"timeout_s and poll_s must be positive, got {timeout_s!r}, {poll_s!r}")
        self.path = Path(folder)
        self.timeout_s, self.poll_s = float(timeout_s), float(poll_s)
        self._clock, self._sleep = clock, sleep
        self._kw = {"black_level_out_dn": black_level_out_dn, "size_px": size_px}
        self.cap: CaptureFolder | None = None
        self.problems: list[str] = []
        self.frame_period_s: float | None = None
        self.ended = None        # why the stream ended

    def _open(self) -> bool:
        if not (self.path / CAPTURE_NAME).is_file():
            return False
        self.cap = CaptureFolder(self.path, read_list=False, **self._kw)
        return True

    def _state(self) -> str:
        try:
            return CaptureFolder(self.path, read_list=False, **self._kw).state
        except CaptureError:
            return "capturing"    # being rewritten this instant

    def wait_open(self) -> CaptureFolder:
        """The capture's header, once ``capture.json`` is there (waiting up to ``timeout_s``)."""
        start = self._clock()
        while self.cap is None and not self._open():
            if self._clock() - start > self.timeout_s:
                raise CaptureError(f"{self.path}: no {CAPTURE_NAME} within {self.timeout_s:g} s "
                                   "(not a capture, or its writer has not started)")
            self._sleep(self.poll_s)
        return self.cap

    def frames(self) -> Iterator[CaptureFrame]:
        """Every frame slot as it arrives (module docstring)."""
        cap = self.wait_open()
        last_seen = self._clock()
        list_path = self.path / FRAMES_LIST_NAME
        offset, number, pending = 0, 0, b""
        t0 = last_ts = last_f = None
        nominal_ns = None
        while True:
            try:
                with open(list_path, "rb") as fh:
                    fh.seek(offset)
                    chunk = fh.read()
            except FileNotFoundError:
                chunk = b""
            except OSError as exc:
                raise CaptureError(f"{list_path}: cannot read the frame list ({exc.strerror})") from None
            offset += len(chunk)
            pending += chunk
            *lines, pending = pending.split(b"\n")
            if not lines:
                state = self._state() if cap.version >= 2 else "complete"
                if state != "capturing" and self._drained(list_path, offset):
                    self.ended = f"the capture ended {state}"
                    return
                if self._clock() - last_seen > self.timeout_s:
                    self.ended = (f"no new frame for {self.timeout_s:g} s and {CAPTURE_NAME} still "
                                  "says 'capturing': the writer stopped (killed?)")
                    log.warning("%s: %s", self.path, self.ended)
                    return
                self._sleep(self.poll_s)
                continue
            last_seen = self._clock()
            for raw in lines:
                number += 1
                try:
                    text = raw.decode("utf-8")
                except UnicodeDecodeError:
                    self._problem(f"{list_path}, line {number}: not UTF-8; frame left out")
                    continue
                entry, problem = parse_list_line(text, number, list_path)
                if problem is not None:
                    self._problem(problem)
                if entry is None:
                    continue
                _, d, bad = entry
                t = int(d["SensorTimestamp"])
                if t0 is None:
                    t0 = t
                    fd = d.get("FrameDuration")
                    nominal_ns = float(fd) * 1e3 if bad is None and fd else None
                if last_ts is not None and t <= last_ts:
                    self._problem(f"{list_path}, line {number}: key 'SensorTimestamp' {t} does not "
                                  f"follow the previous frame's {last_ts}; frame left out")
                    continue
                period = self._period(t0, last_ts, last_f, nominal_ns, t)
                k = (t - t0) / period if period else 0.0
                f = int(round(k))
                if abs(k - f) > GAP_TOLERANCE_FRAMES or (last_f is not None and (
                        f <= last_f or f - last_f > MAX_GAP_FRAMES)):
                    self._problem(f"{list_path}, line {number}: key 'SensorTimestamp' {t} lies "
                                  f"{k:.2f} frame periods after the first frame, not on a free "
                                  "frame slot; frame left out")
                    continue
                start0 = cap.timestamp_offset_s
                for missing in range((last_f + 1) if last_f is not None else f, f):
                    yield CaptureFrame(missing, missing * period * 1e-9 + start0, None,
                                       f"{list_path}: frame {missing} dropped (a SensorTimestamp "
                                       "gap): missing", {})
                start = (t - t0) * 1e-9 + start0
                last_ts, last_f = t, f
                if f > 0:
                    self.frame_period_s = (t - t0) * 1e-9 / f
                if bad is not None:
                    yield CaptureFrame(f, start, None, bad, d)
                    continue
                yield cap.frame_of_line(f, start, d, f"{list_path}, line {number}")

    @staticmethod
    def _period(t0, last_ts, last_f, nominal_ns, t) -> float:
        """ns per frame: the run's mean step so far, else the programmed FrameDuration, else
        the first step."""
        if last_f:
            return (last_ts - t0) / last_f
        if nominal_ns:
            return nominal_ns
        return float(t - t0) if last_ts is not None else 0.0

    def _drained(self, list_path: Path, offset: int) -> bool:
        try:
            return list_path.stat().st_size <= offset
        except OSError:
            return True

    def _problem(self, text: str) -> None:
        self.problems.append(text)
        log.warning("%s", text)


def follow_capture(folder, **kw) -> Iterator[CaptureFrame]:
    """The frames of :class:`CaptureFollower` (keyword arguments as its)."""
    return CaptureFollower(folder, **kw).frames()
