"""Capture folders (``scet-capture``, version 1): prototype frames as picamera2 delivers them,
read and written here so that the Pi-side tracker, the capture program and the renderer's
``--raw`` output share one format and one reader.

Layout::

    capture.json    {"format": "scet-capture", "version": 1,
                     "camera": {"model", "sensor_mode": {...}},       picamera2's names
                     "raw": {"format": "SGBRG10_CSI2P" | "SGBRG10" (any Bayer order),
                             "size": [W, H], "stride": bytes per row},
                     "controls": {"FrameDurationLimits": [us, us], "ExposureTime": us,
                                  "AnalogueGain": x, "AeEnable": false, "AwbEnable": false},
                     "strobe": firmware settings or null, "software": {...},
                     optional "channel_gains": [R, Gr, Gb, B] (default 1),
                     optional "timestamp_offset_s": first row's readout - SensorTimestamp}
    frames.jsonl    one line per frame: {"file": "frames/NNNNNN.raw", "SensorTimestamp": ns,
                     "ExposureTime": us, "FrameDuration": us, "AnalogueGain": x,
                     "SensorBlackLevels": [R, Gr, Gb, B] on a 16-bit scale, ...}
    frames/NNNNNN.raw   the raw buffer: H rows of ``stride`` bytes
    labels.jsonl    optional: calibration targets, as in rendered datasets

Version 1: ``capture.json`` is written last, a folder that has it is complete. Version 2
(:mod:`estimator.capture.writer`): ``capture.json`` is written first with ``"state":
"capturing"`` and again at the end with the final state and a ``summary``; frames are listed
as they are written, so a capture cut short keeps what it wrote (the reader reads it and logs
that the capture did not finish), and :mod:`estimator.capture.follow` reads one while it is
being written. Frames are indexed by time:
frame f is the one whose SensorTimestamp is f frame periods after the first (the period is the
median difference of consecutive timestamps), so dropped frames leave gaps in the indices.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from ..checks import MAX_ABS, parse_json
from ..errors import InputError
from ..formats import FRAMES_DIR, atomic_write, check_format, frame_name, read_json
from .raw import RawFormat, decode_raw, encode_raw, min_stride, parse_raw_format, row_bytes, to_tracker_frame

log = logging.getLogger(__name__)

__all__ = ["CAPTURE_FORMAT", "CAPTURE_VERSION", "CAPTURE_NAME", "FRAMES_LIST_NAME",
           "METADATA_KEYS", "CaptureError", "CaptureFrame", "CaptureFolder", "is_capture_folder",
           "capture_header", "write_capture"]

CAPTURE_FORMAT, CAPTURE_VERSION = "scet-capture", 1
#: Versions read: 1 (capture.json last) and 2 (first, with a state; estimator.capture.writer).
CAPTURE_VERSIONS = (1, 2)
CAPTURE_NAME, FRAMES_LIST_NAME = "capture.json", "frames.jsonl"
#: The values of ``capture.json``'s ``state`` (version 2; estimator.capture.writer writes it).
STATES = ("capturing", "complete", "interrupted", "failed")
#: picamera2 metadata every frame line must carry.
METADATA_KEYS = ("SensorTimestamp", "ExposureTime", "FrameDuration", "AnalogueGain",
                 "SensorBlackLevels")
#: A timestamp gap more than this far (in frame periods) from a whole number is not a run of
#: dropped frames but a broken clock: the frame is left out.
GAP_TOLERANCE_FRAMES = 0.25
#: A gap of more frame periods than this after the previous frame is not a run of dropped
#: frames (the capture program drops a few at a time) but a clock jump or a hostile time stamp:
#: the frame is left out, and the index never claims slots the folder does not hold.
MAX_GAP_FRAMES = 1000
#: Latest SensorTimestamp read (ns, ~146 years of uptime): time stamps are int64 nanoseconds.
MAX_TIMESTAMP_NS = 2 ** 62


class CaptureError(InputError):
    """A capture folder that cannot be read; the message names the file and key."""


@dataclass(frozen=True, slots=True)
class CaptureFrame:
    """One frame slot of a capture: ``image`` (H, W) uint16 in DN, or None with ``reason``
    (dropped, unreadable, bad metadata). ``start_s``: first row's readout time relative to the
    first frame (SensorTimestamp plus the header's offset)."""

    index: int
    start_s: float
    image: np.ndarray | None
    reason: str | None
    metadata: dict


def is_capture_folder(folder) -> bool:
    return (Path(folder) / CAPTURE_NAME).is_file()


def _number(d: dict, key: str, where: str, *, integer=False, positive=False):
    v = d.get(key)
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= MAX_ABS \
        and math.isfinite(v)  # abs first: math.isfinite overflows on integers like 10**400
    if ok and integer:
        ok = float(v).is_integer()
    if ok and positive:
        ok = v > 0
    if not ok:
        what = "a positive " if positive else "a "
        got = repr(v) if len(repr(v)) <= 60 else repr(v)[:57] + "..."
        raise CaptureError(f"{where}: key {key!r} must be {what}{'integer' if integer else 'number'}, "
                           f"got {got}")
    return int(v) if integer else float(v)


class CaptureFolder:
    """A capture folder, checked on opening (header, frame list) and read frame by frame.

    Parameters
    ----------
    folder : path
    black_level_out_dn : float
        Black level of the frames handed to the tracker (the scene's ``black_level_dn``).
    size_px : (W, H), optional
        Expected frame size (the scene camera's); a capture of another size is refused.
    """

    def __init__(self, folder, *, black_level_out_dn: float = 16.0, size_px=None,
                 read_list: bool = True):
        self.path = Path(folder)
        head = self.path / CAPTURE_NAME
        if not head.is_file():
            raise CaptureError(f"{self.path}: no {CAPTURE_NAME} (not a capture, or an incomplete one)")
        self.header = read_json(head, CaptureError)
        self.version = check_format(self.header, head, CAPTURE_FORMAT, CAPTURE_VERSIONS, CaptureError)
        self.state = self.header.get("state", "complete") if self.version >= 2 else "complete"
        if self.state not in STATES:
            raise CaptureError(f"{head}: key 'state' is {self.state!r}, expected one of {STATES}")
        raw = self.header.get("raw")
        if not isinstance(raw, dict):
            raise CaptureError(f"{head}: key 'raw' must be an object with format, size, stride")
        try:
            self.raw_format: RawFormat = parse_raw_format(raw.get("format"))
        except ValueError as exc:
            raise CaptureError(f"{head}: key 'raw.format': {exc}") from None
        size = raw.get("size")
        if not (isinstance(size, list) and len(size) == 2 and all(
                isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
            raise CaptureError(f"{head}: key 'raw.size' must be [width, height] in pixels, got {size!r}")
        self.width, self.height = size
        if size_px is not None and tuple(size_px) != (self.width, self.height):
            raise CaptureError(f"{head}: key 'raw.size' is {self.width}x{self.height}, the scene's "
                               f"camera is {size_px[0]}x{size_px[1]}")
        try:
            need = row_bytes(self.raw_format, self.width)
        except ValueError as exc:
            raise CaptureError(f"{head}: key 'raw.size': {exc}") from None
        self.stride = _number(raw, "stride", f"{head}: key 'raw'", integer=True, positive=True)
        if self.stride < need:
            raise CaptureError(f"{head}: key 'raw.stride' is {self.stride} bytes, shorter than one "
                               f"{self.raw_format.name} row of {self.width} px ({need} bytes)")
        gains = self.header.get("channel_gains", [1.0, 1.0, 1.0, 1.0])
        if not (isinstance(gains, list) and len(gains) == 4 and all(
                isinstance(g, (int, float)) and not isinstance(g, bool) and 0 < g <= 1e3
                for g in gains)):
            raise CaptureError(f"{head}: key 'channel_gains' must be 4 numbers in (0, 1000] "
                               "(R, Gr, Gb, B)")
        self.channel_gains = tuple(float(g) for g in gains)
        self.timestamp_offset_s = (0.0 if "timestamp_offset_s" not in self.header else
                                   _number(self.header, "timestamp_offset_s", str(head)))
        self.black_level_out_dn = float(black_level_out_dn)
        self._list = self.path / FRAMES_LIST_NAME
        if not read_list:
            return
        self.entries, self.problems = self._read_list()
        if self.state == "capturing":
            self.problems.insert(0, f"{head}: key 'state' is 'capturing': the capture was cut "
                                    f"short (or is still being written); the {len(self.entries)} "
                                    "frame(s) listed so far are read")
        elif self.state != "complete":
            why = (self.header.get("summary") or {}).get("stopped", "")
            self.problems.insert(0, f"{head}: the capture ended {self.state}"
                                    + (f" ({why})" if why else ""))
        self.frame_period_s, self.index = self._index()

    # ----------------------------------------------------------------------- frame list
    def _read_list(self):
        try:
            lines = self._list.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise CaptureError(f"{self._list}: cannot read the frame list ({exc})") from None
        entries, problems = [], []
        for number, line in enumerate(lines, start=1):
            entry, problem = parse_list_line(line, number, self._list)
            if problem is not None:
                problems.append(problem)
            elif entry is not None:
                entries.append(entry)
        if not entries:
            raise CaptureError(f"{self._list}: no frame with a SensorTimestamp"
                               + (f" ({problems[0]})" if problems else ""))
        return entries, problems

    def _index(self):
        """Frame period and frame index -> entry; lines whose timestamps go backwards, repeat
        or fall between frame slots are problems.

        The period is measured from the timestamps (HARDWARE.md Sec. 4: ``FrameDuration`` is
        the programmed value): each step is divided by its whole number of nominal frame
        durations, so dropped frames do not bias it, and the median taken."""
        ts = np.array([d["SensorTimestamp"] for _, d, _ in self.entries], dtype=np.int64)
        durations = [d["FrameDuration"] for _, d, p in self.entries if p is None]
        steps = np.diff(ts).astype(np.float64)
        steps = steps[steps > 0]
        nominal = float(np.median(durations)) * 1e3 if durations else (
            float(np.min(steps)) if steps.size else 0.0)
        if steps.size and nominal > 0:
            ratio = steps / nominal
            k = np.rint(ratio)
            on_slot = (k >= 1) & (np.abs(ratio - k) <= GAP_TOLERANCE_FRAMES)
            period_ns = float(np.median(steps[on_slot] / k[on_slot])) if on_slot.any() else nominal
        else:
            period_ns = nominal
        if not period_ns > 0:
            raise CaptureError(f"{self._list}: cannot tell the frame period (one frame and no "
                               f"'FrameDuration')")
        index, last_ts, last_f, t0 = {}, None, None, int(ts[0])
        for (number, d, problem), t in zip(self.entries, ts):
            where = f"{self._list}, line {number}: key 'SensorTimestamp'"
            if last_ts is not None and t <= last_ts:
                kind = "repeats" if t == last_ts else "goes back from"
                self.problems.append(f"{where} {t} {kind} the previous frame's {last_ts}; frame left out")
                continue
            k = (t - t0) / period_ns
            f = int(round(k))
            if last_f is not None and f - last_f > MAX_GAP_FRAMES:
                self.problems.append(f"{where} {t} lies {f - last_f} frame periods after the "
                                     f"previous frame, more than {MAX_GAP_FRAMES}: a clock jump, "
                                     "not dropped frames; frame left out")
                continue
            if abs(k - f) > GAP_TOLERANCE_FRAMES:
                self.problems.append(f"{where} {t} lies {k:.2f} frame periods after the first "
                                     f"frame, not on a frame slot; frame left out")
                continue
            if problem is not None:
                self.problems.append(problem)
            index[f] = (number, d, (t - t0) * 1e-9 + self.timestamp_offset_s, problem)
            last_ts, last_f = t, f
        for p in self.problems:
            log.warning("%s", p)
        return period_ns * 1e-9, index

    @property
    def dropped(self) -> list[int]:
        """Frame indices with no frame: timestamp gaps of k periods leave k - 1 of them."""
        last = max(self.index)
        return [f for f in range(last + 1) if f not in self.index]

    # ----------------------------------------------------------------------- frames
    def read_raw(self, file: str, where: str) -> np.ndarray:
        """The (H, W) uint16 mosaic of one raw file, checked against the header."""
        path = self.path / file
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise CaptureError(f"{path}: cannot read the frame ({exc.strerror})") from None
        want = self.stride * self.height
        if len(data) != want:
            raise CaptureError(f"{path}: {len(data)} bytes, expected {want} = raw.stride "
                               f"{self.stride} x {self.height} rows of {CAPTURE_NAME} ({where})")
        rows = np.frombuffer(data, dtype=np.uint8).reshape(self.height, self.stride)
        mosaic = decode_raw(rows, self.raw_format, self.width)
        if not self.raw_format.packed and int(mosaic.max()) > 1023:
            raise CaptureError(f"{path}: values above 1023 in a 10-bit unpacked frame (raw.format "
                               f"{self.raw_format.name} of {CAPTURE_NAME} does not fit the data)")
        return mosaic

    def tracker_frame(self, mosaic: np.ndarray, metadata: dict) -> np.ndarray:
        """The mosaic as the tracker's frame: per-channel black level from the frame's
        ``SensorBlackLevels`` (16-bit scale -> DN), channel gains, the scene's black level."""
        black = np.asarray(metadata["SensorBlackLevels"], dtype=np.float64) / 2.0 ** (16 - self.raw_format.bit_depth)
        return to_tracker_frame(mosaic, self.raw_format.bayer_order, black, self.channel_gains,
                                self.black_level_out_dn, self.raw_format.bit_depth)

    def frames(self) -> Iterator[CaptureFrame]:
        """Every frame slot from 0 to the last, in order; dropped and unreadable frames come
        as ``image=None`` with the reason (the stream goes on)."""
        last = max(self.index)
        for f in range(last + 1):
            if f not in self.index:
                yield CaptureFrame(f, f * self.frame_period_s + self.timestamp_offset_s, None,
                                   f"{self._list}: frame {f} dropped (a SensorTimestamp gap): missing", {})
                continue
            number, d, start, problem = self.index[f]
            if problem is not None:
                yield CaptureFrame(f, start, None, problem, d)
                continue
            yield self.frame_of_line(f, start, d, f"{self._list}, line {number}")

    def frame_of_line(self, f: int, start_s: float, line: dict, where: str) -> "CaptureFrame":
        """The :class:`CaptureFrame` of frame ``f`` from its ``frames.jsonl`` line (``where``
        names it in errors): its raw file decoded, or the reason it cannot be."""
        try:
            image = self.tracker_frame(self.read_raw(line["file"], where), line)
        except CaptureError as exc:
            return CaptureFrame(f, start_s, None, str(exc), line)
        return CaptureFrame(f, start_s, image, None, line)


def parse_list_line(line: str, number: int, path) -> tuple[tuple | None, str | None]:
    """One line of ``frames.jsonl``: ((line number, metadata, problem or None), None), or
    (None, why it is left out), or (None, None) for a blank line."""
    where = f"{path}, line {number}"
    if not line.strip():
        return None, None
    try:
        d = parse_json(line, where, CaptureError)
    except CaptureError as exc:
        return None, f"{exc}; frame left out"
    try:
        if not isinstance(d, dict):
            raise CaptureError(f"{where}: expected a JSON object")
        if "SensorTimestamp" not in d:
            raise CaptureError(f"{where}: metadata key 'SensorTimestamp' missing")
        if not 0 <= _number(d, "SensorTimestamp", where, integer=True) <= MAX_TIMESTAMP_NS:
            raise CaptureError(f"{where}: key 'SensorTimestamp' must be in [0, "
                               f"{MAX_TIMESTAMP_NS}] ns")
    except CaptureError as exc:
        return None, f"{exc}; frame left out"
    return (number, d, _frame_problem(d, where)), None


def _frame_problem(d: dict, where: str) -> str | None:
    """Why a frame line with a timestamp cannot be used (its slot is NaN), or None."""
    try:
        if not isinstance(d.get("file"), str):
            raise CaptureError(f"{where}: key 'file' missing or not a string")
        for key in METADATA_KEYS:
            if key not in d:
                raise CaptureError(f"{where}: metadata key {key!r} missing")
        _number(d, "ExposureTime", where, positive=True)
        _number(d, "FrameDuration", where, positive=True)
        _number(d, "AnalogueGain", where, positive=True)
        bl = d["SensorBlackLevels"]
        if not (isinstance(bl, list) and len(bl) == 4 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 65535
                for v in bl)):
            raise CaptureError(f"{where}: key 'SensorBlackLevels' must be 4 numbers in [0, 65535] "
                               "(R, Gr, Gb, B on a 16-bit scale)")
    except CaptureError as exc:
        return str(exc)
    return None


def capture_header(*, raw_format: str, size_px, stride: int, camera: dict, controls: dict,
                   strobe: dict | None, software: dict, source: str,
                   channel_gains=None, timestamp_offset_s: float | None = None) -> dict:
    """A ``capture.json`` document (checks the raw format and stride)."""
    fmt = parse_raw_format(raw_format)
    w, h = (int(v) for v in size_px)
    if stride < row_bytes(fmt, w):
        raise ValueError(f"stride {stride} is shorter than a {fmt.name} row of {w} px")
    doc = {"format": CAPTURE_FORMAT, "version": CAPTURE_VERSION, "source": source,
           "camera": camera, "raw": {"format": fmt.name, "size": [w, h], "stride": int(stride)},
           "controls": controls, "strobe": strobe, "software": software}
    if channel_gains is not None:
        doc["channel_gains"] = [float(g) for g in channel_gains]
    if timestamp_offset_s is not None:
        doc["timestamp_offset_s"] = float(timestamp_offset_s)
    return doc


def write_capture(folder, header: dict, frames: Iterable[tuple[np.ndarray, dict]],
                  labels_text: str | None = None, progress=None) -> Path:
    """Write a capture folder: each frame's raw rows ((H, stride) uint8, or an (H, W) mosaic
    to encode) and metadata; then ``frames.jsonl``, ``labels.jsonl`` and, last,
    ``capture.json``. Every file is written atomically."""
    folder = Path(folder)
    fmt = parse_raw_format(header["raw"]["format"])
    w, h = header["raw"]["size"]
    stride = header["raw"]["stride"]
    lines = []
    for n, (buf, meta) in enumerate(frames):
        a = np.asarray(buf)
        if a.dtype != np.uint8:
            a = encode_raw(a, fmt, stride)
        if a.shape != (h, stride):
            raise ValueError(f"frame {n}: raw buffer of shape {a.shape}, the header says "
                             f"({h}, {stride})")
        name = f"{FRAMES_DIR}/{frame_name(n, 'raw')}"
        atomic_write(folder / name, np.ascontiguousarray(a).tobytes())
        lines.append(json.dumps({"file": name, **meta}, sort_keys=True))
        if progress is not None:
            progress(n + 1)
    atomic_write(folder / FRAMES_LIST_NAME, "".join(line + "\n" for line in lines))
    if labels_text is not None:
        atomic_write(folder / "labels.jsonl", labels_text)
    atomic_write(folder / CAPTURE_NAME, json.dumps(header, indent=1, sort_keys=True) + "\n")
    return folder


# The Unicam stride rule, re-exported for writers that build headers.
unicam_stride = min_stride
