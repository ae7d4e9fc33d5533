"""A folder's input files, read and checked: the timing sidecar (or a rendered dataset's
manifest, or a capture's header), the frames, the calibration targets; and the check that an
output does not overwrite one of them.

Each reader refuses a bad file with :class:`~estimator.errors.TrackerInputError` naming the
file and the key (:mod:`estimator.checks`); a bad frame is not an error of the folder but of
its samples: :func:`read_frame` refuses it by its PNG header, before decoding, and
:func:`frame_reason` turns the refusal into the samples' reason code.
"""

from __future__ import annotations

import json
import logging
import os
import re
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from .capture import CAPTURE_NAME, FRAMES_LIST_NAME, CaptureError, CaptureFolder, is_capture_folder
from .checks import Doc, iter_json_lines
from .errors import TrackerInputError
from .formats import (
    DATASET_FORMAT,
    DATASET_VERSION,
    FRAMES_DIR,
    LABELS_NAME,
    MANIFEST_NAME,
    TIMING_FORMAT,
    TIMING_NAME,
    TIMING_VERSION,
    check_format,
    read_json,
)
from .setup import Setup
from .tracker import MISSING_FRAME, UNREADABLE_FRAME, WRONG_FRAME_SIZE

log = logging.getLogger(__name__)

__all__ = ["FolderTiming", "timing_document", "read_timing", "frame_path", "read_frame",
           "frame_reason", "read_targets", "input_files", "refuse_overwriting_inputs",
           "BAD_TIMESTAMP", "MAX_FRAME_PX", "MAX_FRAMES", "MAX_POSITION_M"]

#: Reason code of a frame whose time stamp in the timing sidecar repeats or goes back from the
#: previous frame's: the sample times would be wrong, so the frame is left out (NaN samples).
BAD_TIMESTAMP = "bad_timestamp"
#: Largest frame a header may announce without a scene to check it against (pixels; 8192 x
#: 8192): the decoder is never asked for more.
MAX_FRAME_PX = 8192 * 8192
#: Most frames a folder's timing may list (a day at 1 kHz): counts beyond are not real.
MAX_FRAMES = 100_000_000
#: Most frames a timing sidecar may list that its folder does not hold (missing frames are
#: NaN samples; a sidecar listing far more frames than there are is not this folder's).
MAX_MISSING_FRAMES = 1000
#: Targets and positions must lie within this distance of the origin (m), as in scene files.
MAX_POSITION_M = 100.0
#: Frame start times must lie within this many seconds of zero (~30 years).
MAX_TIME_S = 1e9

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_WRONG_SIZE = "frame size"   # in every message that refuses a frame for its size
_STROBE_KEYS = ("pulses_per_frame", "pulse_s", "period_s", "phase_s")


@dataclass(frozen=True, slots=True)
class FolderTiming:
    """A folder's timing sidecar.

    Attributes
    ----------
    frame_start_s : dict[int, float]
        Frame index -> frame start t0_f (s).
    exposure_s : float or None
    strobe : dict or None
        Strobe fields the frames were taken with (overriding the scene's).
    source : Path
        The file the timing was read from.
    problems : dict[int, str]
        Frames whose start repeats or goes back from the previous frame's (flagged: their
        samples are NaN with :data:`BAD_TIMESTAMP`), and why.
    """

    frame_start_s: dict
    exposure_s: float | None
    strobe: dict | None
    source: Path
    problems: dict = field(default_factory=dict)

    def apply(self, setup: Setup) -> Setup:
        """``setup`` with the sidecar's exposure and strobe, where it gives them, checked
        against the scene's sensor (an exposure longer than the frame, a pulse longer than
        the frame are refused)."""
        frame_s = setup.sensor.frame_period_s
        if self.exposure_s is not None and not self.exposure_s <= frame_s:
            raise TrackerInputError(f"{self.exposure_s:g} s is longer than the scene's frame "
                                    f"period {frame_s:g} s", path=self.source, key="exposure_s")
        strobe = setup.strobe if self.strobe is None else replace(setup.strobe, **self.strobe)
        if not strobe.pulse_s <= frame_s:
            raise TrackerInputError(f"{strobe.pulse_s:g} s is longer than the scene's frame "
                                    f"period {frame_s:g} s", path=self.source, key="strobe.pulse_s")
        if strobe.pulses_per_frame > 1 and not strobe.pulse_s <= strobe.period_s:
            raise TrackerInputError(f"pulses of {strobe.pulse_s:g} s every {strobe.period_s:g} s "
                                    "overlap", path=self.source, key="strobe.pulse_s")
        sensor = setup.sensor if self.exposure_s is None else replace(setup.sensor,
                                                                      exposure_s=self.exposure_s)
        return replace(setup, sensor=sensor, strobe=strobe)


def timing_document(frame_start_s: dict, *, exposure_s: float | None = None,
                    strobe=None) -> str:
    """The text of a timing sidecar (``strobe``: a :class:`~estimator.setup.Strobe` or None)."""
    doc = {"format": TIMING_FORMAT, "version": TIMING_VERSION,
           "frames": {str(int(k)): float(v) for k, v in sorted(frame_start_s.items())}}
    if exposure_s is not None:
        doc["exposure_s"] = float(exposure_s)
    if strobe is not None:
        doc["strobe"] = {k: (int if k == "pulses_per_frame" else float)(getattr(strobe, k))
                         for k in _STROBE_KEYS}
    return json.dumps(doc, indent=1) + "\n"


def read_timing(folder, setup: Setup) -> FolderTiming:
    """The timing of a frames folder: ``timing.json``, a capture's ``capture.json``, or a
    rendered dataset's manifest (frames at f Δt).

    Raises
    ------
    TrackerInputError
        Neither file, or a malformed one (the message names the file and key); a manifest
        whose frame count the folder does not back, or whose frames are of another size.
    """
    folder = Path(folder)
    if is_capture_folder(folder):
        return _capture_timing(open_capture(folder, setup))
    path = folder / TIMING_NAME
    if path.is_file():
        timing = _parse_timing(path)
        held = _count_frames(folder)
        if len(timing.frame_start_s) - held > MAX_MISSING_FRAMES:
            raise TrackerInputError(f"lists {len(timing.frame_start_s)} frames, the folder holds "
                                    f"{held}: more than {MAX_MISSING_FRAMES} would be missing",
                                    path=path, key="frames")
        return timing
    manifest = folder / MANIFEST_NAME
    if manifest.is_file():
        return _manifest_timing(folder, manifest, setup)
    raise TrackerInputError(f"{folder}: no {TIMING_NAME} (frame index -> frame start time) and "
                            f"no {MANIFEST_NAME}; cannot time the frames")


def _manifest_timing(folder: Path, manifest: Path, setup: Setup) -> FolderTiming:
    data = read_json(manifest, TrackerInputError)
    check_format(data, manifest, DATASET_FORMAT, DATASET_VERSION, TrackerInputError)
    doc = Doc(data, manifest, error=TrackerInputError)
    frames = doc.integer("frames", lo=1, hi=MAX_FRAMES)
    image = doc.obj("image")
    width, height = image.integer("width_px", lo=1), image.integer("height_px", lo=1)
    want = (setup.camera.width_px, setup.camera.height_px)
    if (width, height) != want:
        raise TrackerInputError(f"frames are {width}x{height} px, the setup's camera is "
                                f"{want[0]}x{want[1]}", path=manifest, key="image")
    depth = image.integer("png_bit_depth", required=False)
    if depth is not None and depth != (8 if setup.sensor.bit_depth <= 8 else 16):
        raise TrackerInputError(f"{depth}-bit frames, the scene's {setup.sensor.bit_depth}-bit "
                                "sensor writes " + ("8" if setup.sensor.bit_depth <= 8 else "16")
                                + "-bit PNGs", path=manifest, key="image.png_bit_depth")
    # The count is the manifest's claim: the folder must back it before it is iterated.
    last = frame_path(folder, frames - 1)
    if not last.is_file():
        held = _count_frames(folder)
        raise TrackerInputError(f"claims {frames} frames, but the last one ({last.name}) is not "
                                f"in the folder, which holds {held}", path=manifest, key="frames")
    dt = setup.sensor.frame_period_s
    return FolderTiming({f: f * dt for f in range(frames)}, None, None, manifest, {})


def _count_frames(folder: Path) -> int:
    sub = folder / FRAMES_DIR
    try:
        with os.scandir(sub if sub.is_dir() else folder) as it:
            return sum(1 for e in it if e.name.endswith(".png"))
    except OSError:
        return 0


def open_capture(folder: Path, setup: Setup) -> CaptureFolder:
    """The capture folder, checked against the scene's camera (errors as TrackerInputError)."""
    try:
        return CaptureFolder(folder, black_level_out_dn=setup.sensor.black_level_dn,
                             size_px=(setup.camera.width_px, setup.camera.height_px))
    except CaptureError as exc:
        raise TrackerInputError(str(exc)) from None


def _capture_timing(cap: CaptureFolder) -> FolderTiming:
    """A capture's frame starts (SensorTimestamp, the first row's readout on the Pi), and
    the exposure and strobe model it records (``exposure_s``, ``strobe_model``)."""
    starts = {f: start for f, (_, _, start, _) in cap.index.items()}
    starts.update({f: f * cap.frame_period_s + cap.timestamp_offset_s for f in cap.dropped})
    head = Doc(cap.header, cap.path / CAPTURE_NAME, error=TrackerInputError)
    exposure = head.number("exposure_s", lo=1e-9, hi=1.0, required=False)
    strobe = _strobe(head, "strobe_model")
    return FolderTiming(dict(sorted(starts.items())), exposure, strobe, cap.path / CAPTURE_NAME,
                        {})


def _strobe(doc: Doc, name: str) -> dict | None:
    st = doc.obj(name, required=False)
    if st is None:
        return None
    st.only(_STROBE_KEYS)
    out = {}
    if "pulses_per_frame" in st.data:
        out["pulses_per_frame"] = st.integer("pulses_per_frame", lo=1, hi=100_000)
    for key, lo, hi in (("pulse_s", 1e-9, 1.0), ("period_s", 1e-9, 1.0), ("phase_s", -1.0, 1.0)):
        if key in st.data:
            out[key] = st.number(key, lo=lo, hi=hi)
    return out


def _parse_timing(path: Path) -> FolderTiming:
    data = read_json(path, TrackerInputError)
    check_format(data, path, TIMING_FORMAT, TIMING_VERSION, TrackerInputError)
    doc = Doc(data, path, error=TrackerInputError)
    frames = doc.obj("frames")
    if not frames.data:
        raise doc.error("frames", "must be a non-empty object {frame index: frame start time in s}")
    out = {}
    for k in frames.keys():
        if not re.fullmatch(r"\d{1,9}", k):
            raise frames.error(k, "expected a frame index (digits) as the key")
        out[int(k)] = frames.number(k, lo=-MAX_TIME_S, hi=MAX_TIME_S)
    problems, last = {}, None
    for f in sorted(out):
        if last is not None and out[f] <= out[last]:
            kind = "repeats" if out[f] == out[last] else "goes back from"
            problems[f] = (f"{path}, key 'frames.{f}': frame start {out[f]!r} s {kind} frame "
                           f"{last}'s {out[last]!r} s; frame left out ({BAD_TIMESTAMP})")
            log.warning("%s", problems[f])
            continue
        last = f
    exposure = doc.number("exposure_s", lo=1e-9, hi=1.0, required=False)
    return FolderTiming(out, exposure, _strobe(doc, "strobe"), path, problems)


def frame_path(folder, frame_index: int) -> Path:
    """Where frame ``frame_index`` of a folder lives (``frames/`` if the folder has one)."""
    folder = Path(folder)
    sub = folder / FRAMES_DIR
    return (sub if sub.is_dir() else folder) / f"{int(frame_index):06d}.png"


def _png_header(path: Path, head: bytes) -> tuple[int, int, int, int]:
    """(width, height, bit depth, colour type) of a PNG's IHDR chunk."""
    if len(head) < 26 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise TrackerInputError(f"{path}: not a PNG (no PNG signature and IHDR header)")
    width, height = struct.unpack(">II", head[16:24])
    return width, height, head[24], head[25]


def read_frame(path, size_px: tuple[int, int] | None = None) -> np.ndarray:
    """A grey 8- or 16-bit PNG frame as (H, W) uint8 or uint16.

    The PNG header is checked before the frame is decoded: its size must be ``size_px``
    (W, H; the scene camera's) when given, and at most :data:`MAX_FRAME_PX` pixels; it must be
    grey (colour type 0) of 8 or 16 bits. So a damaged or hostile header never makes the
    decoder allocate more than the frame SCET expects.

    Raises
    ------
    TrackerInputError
        Missing, corrupt or truncated file, a header of another size (the message says
        "frame size": :func:`frame_reason` gives :data:`~estimator.tracker.WRONG_FRAME_SIZE`),
        or not a single-channel image.
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(33)
            width, height, depth, colour = _png_header(path, head)
            if size_px is not None and (width, height) != tuple(size_px):
                raise TrackerInputError(f"{path}: {_WRONG_SIZE} {width}x{height} px in its PNG "
                                        f"header, the scene's camera is {size_px[0]}x{size_px[1]}")
            if width * height > MAX_FRAME_PX or not width or not height:
                raise TrackerInputError(f"{path}: {_WRONG_SIZE} {width}x{height} px in its PNG "
                                        f"header, more than SCET reads ({MAX_FRAME_PX} px)")
            if colour != 0 or depth not in (8, 16):
                raise TrackerInputError(f"{path}: a {depth}-bit PNG of colour type {colour}; "
                                        "expected a single-channel (grey) 8- or 16-bit frame")
            # Compressed data never exceeds the raw rows by much: a longer file is not a frame.
            limit = 2 * width * height * depth // 8 + (1 << 20)
            size = os.fstat(fh.fileno()).st_size
            if size > limit:
                raise TrackerInputError(f"{path}: {size} bytes, more than a {width}x{height} "
                                        f"{depth}-bit frame can take ({limit})")
            data = np.frombuffer(head + fh.read(), dtype=np.uint8)
    except OSError as exc:
        raise TrackerInputError(f"{path}: cannot read the frame ({exc.strerror})") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise TrackerInputError(f"{path}: not a readable PNG (corrupt or truncated)")
    if img.ndim != 2:
        raise TrackerInputError(f"{path}: expected a single-channel frame, got shape {img.shape}")
    return img


def frame_reason(error: str) -> str:
    """The samples' reason code of a frame :func:`estimator.folders.iter_folder` could not
    give: missing, of the wrong size, with a bad time stamp, or unreadable."""
    if error.endswith(": missing"):
        return MISSING_FRAME
    if f"({BAD_TIMESTAMP})" in error:
        return BAD_TIMESTAMP
    if f": {_WRONG_SIZE} " in error:
        return WRONG_FRAME_SIZE
    return UNREADABLE_FRAME


def read_targets(folder) -> dict:
    """Frame index -> fixated target (3,) m, from a folder's ``labels.jsonl`` (``frame`` and
    ``target_m`` of each line; the first line of a frame wins)."""
    path = Path(folder) / LABELS_NAME
    out = {}
    for where, data in iter_json_lines(path, TrackerInputError):
        line = Doc(data, where, error=TrackerInputError)
        frame = line.integer("frame", lo=0, hi=MAX_FRAMES)
        target = line.array("target_m", (3,), lo=-MAX_POSITION_M, hi=MAX_POSITION_M)
        out.setdefault(frame, target)
    if not out:
        raise TrackerInputError(f"{path}: no calibration targets")
    return out


def input_files(folder) -> list[Path]:
    """The files of a frames folder that calibration and tracking read."""
    folder = Path(folder)
    names = (TIMING_NAME, MANIFEST_NAME, LABELS_NAME, CAPTURE_NAME, FRAMES_LIST_NAME)
    return [folder / n for n in names] + [folder / FRAMES_DIR]


def refuse_overwriting_inputs(out, inputs, what: str = "--out") -> None:
    """Raise TrackerInputError if the output ``out`` is one of ``inputs`` (files, or folders
    whose contents are inputs), or an existing folder."""
    out = Path(out)
    target = out.resolve()
    if out.is_dir():
        raise TrackerInputError(f"{out}: is a folder; {what} names the file to write")
    if re.fullmatch(r"\d{6}\.(png|exr|raw)", out.name):
        raise TrackerInputError(f"{out}: is named like a frame; {what} must name another file")
    for p in inputs:
        p = Path(p).resolve()
        if target == p or (p.is_dir() and p in target.parents):
            raise TrackerInputError(f"{out}: is one of the inputs ({p}); {what} must name "
                                    "another file, or the input would be overwritten")
