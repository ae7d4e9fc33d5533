"""Folders of frames: reading rendered datasets and prototype captures, calibrating and
tracking them with :class:`estimator.tracker.Tracker`, and the samples CSV.

Folders (rendered datasets, or prototype captures)::

    frames/NNNNNN.png   sensor output (8- or 16-bit grey), NNNNNN the frame index
    timing.json         {"format": "scet-timing", "version": 1,
                         "frames": {"<index>": <frame start t0_f, s>, ...},
                         optional "exposure_s" and "strobe" {pulses_per_frame, pulse_s,
                         period_s, phase_s}: the timing the frames were taken with, when it
                         differs from the scene's (single-pulse calibration frames)}
    manifest.json       a rendered dataset: without timing.json, t0_f = f Δt for its frames
    labels.jsonl        calibration folders: the fixated ``target_m`` of each frame

:func:`calibrate_from_folder` turns a folder of single-pulse calibration frames (every row lit
by the same pulse, i.e. the same instant) into a :class:`~estimator.calibration.Calibration`;
:func:`track_folder` writes ``samples.csv`` (format ``scet-samples``, version 2: version 1
plus the ``prior`` column) atomically; :func:`read_samples_csv` reads both versions.
"""

from __future__ import annotations

import json
import logging
import math
import re
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from .banding import NO_PULSE, row_strobe
from .calibration import Calibration, calibrate_joint, calibration_warnings, fit_gaze_mapping
from .capture import CaptureError, CaptureFolder, is_capture_folder
from .formats import (
    FRAMES_DIR,
    LABELS_NAME,
    MANIFEST_NAME,
    TIMING_FORMAT,
    TIMING_NAME,
    TIMING_VERSION,
    atomic_write,
    check_format,
    read_json,
)
from .gaze import fit_cornea_centers
from .glints import NO_BAND, detect_glints
from .matching import GlintMatcher
from .setup import Setup
from .samples import SAMPLE_COLUMNS, read_samples_csv, samples_csv, write_samples_csv  # noqa: F401
from .tracker import MIN_GLINTS, MISSING_FRAME, UNREADABLE_FRAME, Tracker, TrackerInputError

log = logging.getLogger(__name__)


_FRAME_NAME = re.compile(r"^(\d+)\.png$")

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
    """

    frame_start_s: dict
    exposure_s: float | None
    strobe: dict | None
    source: Path

    def apply(self, setup: Setup) -> Setup:
        """``setup`` with the sidecar's exposure and strobe, where it gives them."""
        sensor = setup.sensor if self.exposure_s is None else replace(setup.sensor,
                                                                      exposure_s=self.exposure_s)
        strobe = setup.strobe if self.strobe is None else replace(setup.strobe, **self.strobe)
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
                         for k in ("pulses_per_frame", "pulse_s", "period_s", "phase_s")}
    return json.dumps(doc, indent=1) + "\n"


def read_timing(folder, setup: Setup) -> FolderTiming:
    """The timing of a frames folder: ``timing.json``, or a rendered dataset's manifest.

    Raises
    ------
    TrackerInputError
        Neither file, or a malformed one (the message names the file and key).
    """
    folder = Path(folder)
    if is_capture_folder(folder):
        return _capture_timing(_open_capture(folder, setup))
    path = folder / TIMING_NAME
    if path.is_file():
        return _parse_timing(path)
    manifest = folder / MANIFEST_NAME
    if manifest.is_file():
        data = read_json(manifest, TrackerInputError)
        try:
            frames = int(data["frames"])
            width, height = int(data["image"]["width_px"]), int(data["image"]["height_px"])
        except (KeyError, TypeError, ValueError) as exc:
            raise TrackerInputError(f"{manifest}: malformed dataset manifest ({exc!r})") from None
        want = (setup.camera.width_px, setup.camera.height_px)
        if (width, height) != want:
            raise TrackerInputError(f"{manifest}: frames are {width}x{height} px, the setup's "
                                    f"camera is {want[0]}x{want[1]}")
        dt = setup.sensor.frame_period_s
        return FolderTiming({f: f * dt for f in range(frames)}, None, None, manifest)
    raise TrackerInputError(f"{folder}: no {TIMING_NAME} (frame index -> frame start time) and "
                            f"no {MANIFEST_NAME}; cannot time the frames")


def _open_capture(folder: Path, setup: Setup) -> CaptureFolder:
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
    exposure = cap.header.get("exposure_s")
    strobe = cap.header.get("strobe_model")
    return FolderTiming(dict(sorted(starts.items())),
                        float(exposure) if isinstance(exposure, (int, float)) else None,
                        strobe if isinstance(strobe, dict) else None, cap.path / "capture.json")


def _parse_timing(path: Path) -> FolderTiming:
    data = read_json(path, TrackerInputError)
    check_format(data, path, TIMING_FORMAT, TIMING_VERSION, TrackerInputError)
    frames = data.get("frames")
    if not isinstance(frames, dict) or not frames:
        raise TrackerInputError(f"{path}: key 'frames' must be a non-empty object "
                                "{frame index: frame start time in s}")
    out = {}
    for k, v in frames.items():
        if not re.fullmatch(r"\d+", str(k)) or isinstance(v, bool) or not isinstance(v, (int, float)) \
                or not math.isfinite(v):
            raise TrackerInputError(f"{path}: key 'frames': entry {k!r}: {v!r} is not "
                                    "<frame index>: <finite time in s>")
        out[int(k)] = float(v)
    exposure = data.get("exposure_s")
    if exposure is not None and (isinstance(exposure, bool) or not isinstance(exposure, (int, float))
                                 or not exposure > 0):
        raise TrackerInputError(f"{path}: key 'exposure_s' must be a positive number, got {exposure!r}")
    strobe = data.get("strobe")
    if strobe is not None:
        keys = {"pulses_per_frame", "pulse_s", "period_s", "phase_s"}
        if not isinstance(strobe, dict) or not set(strobe) <= keys or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in strobe.values()):
            raise TrackerInputError(f"{path}: key 'strobe' must map some of {sorted(keys)} to numbers")
    return FolderTiming(out, None if exposure is None else float(exposure), strobe, path)


def frame_path(folder, frame_index: int) -> Path:
    """Where frame ``frame_index`` of a folder lives (``frames/`` if the folder has one)."""
    folder = Path(folder)
    sub = folder / FRAMES_DIR
    return (sub if sub.is_dir() else folder) / f"{int(frame_index):06d}.png"


def read_frame(path) -> np.ndarray:
    """A grey 8- or 16-bit PNG frame as (H, W) uint8 or uint16.

    Raises
    ------
    TrackerInputError
        Missing, corrupt or truncated file, or not a single-channel image.
    """
    path = Path(path)
    try:
        data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
    except OSError as exc:
        raise TrackerInputError(f"{path}: cannot read the frame ({exc.strerror})") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        raise TrackerInputError(f"{path}: not a readable PNG (corrupt or truncated)")
    if img.ndim != 2:
        raise TrackerInputError(f"{path}: expected a single-channel frame, got shape {img.shape}")
    return img


def iter_folder(folder, setup: Setup) -> Iterator[tuple[int, float, np.ndarray | None, str | None]]:
    """(frame index, frame start s, frame or None, error message or None) for every frame
    of the timing sidecar, in index order. A missing or unreadable frame yields None and why.

    A capture folder (``capture.json``, :mod:`estimator.capture`) gives every frame slot from
    its SensorTimestamps; dropped frames and bad ones come as None with the reason."""
    if is_capture_folder(folder):
        for fr in _open_capture(folder, setup).frames():
            yield fr.index, fr.start_s, fr.image, fr.reason
        return
    timing = read_timing(folder, setup)
    for f in sorted(timing.frame_start_s):
        path = frame_path(folder, f)
        if not path.is_file():
            yield f, timing.frame_start_s[f], None, f"{path}: missing"
            continue
        try:
            yield f, timing.frame_start_s[f], read_frame(path), None
        except TrackerInputError as exc:
            yield f, timing.frame_start_s[f], None, str(exc)


# --------------------------------------------------------------------------- calibration


def read_targets(folder) -> dict:
    """Frame index -> fixated target (3,) m, from a folder's ``labels.jsonl`` (``frame`` and
    ``target_m`` of each line)."""
    path = Path(folder) / LABELS_NAME
    out = {}
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackerInputError(f"{path}: cannot read the calibration targets ({exc})") from None
    for number, line in enumerate(lines, start=1):
        try:
            d = json.loads(line)
            t = np.asarray(d["target_m"], dtype=np.float64).reshape(3)
            out.setdefault(int(d["frame"]), t)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise TrackerInputError(f"{path}, line {number}: malformed label ({exc!r})") from None
    if not out:
        raise TrackerInputError(f"{path}: no calibration targets")
    return out


@dataclass(frozen=True, slots=True)
class CalibrationGlints:
    """Identified glints of the calibration frames: (m, n, 2) NaN where missing, targets
    (m, 3) m, and the frame indices used."""

    glints_px: np.ndarray
    targets_m: np.ndarray
    frames: tuple


#: Calibration frames: the least share of a pulse every visible row must collect (a row that
#: collects less is lit at the frame's instant but dimmer, which the detector's noise model
#: does not expect; calibration_setup's frames collect all of it).
SINGLE_PULSE_MIN_WEIGHT = 0.99
#: How calibration frames are made, for the message that refuses banded ones.
MAKE_CALIBRATION_FRAMES = (
    "calibration needs single-pulse frames, every visible row lit by the same whole pulse "
    "(Sec. 2.4): render them with `scet render SCENE --calibration 5x5 --out DIR`, or capture "
    "them with the strobe in single-pulse mode (hardware/README.md)")


def check_single_pulse(folder, setup: Setup, timing: FolderTiming) -> None:
    """Refuse a folder whose timing is not that of single-pulse calibration frames.

    Every visible row of a calibration frame must collect the same pulse, whole (the frame is
    then one instant; Sec. 2.4 of the SCET paper). Banded frames (several pulses per frame, or
    one pulse that lights only a band) hold glints of several instants, or of some rows only,
    and give a wrong calibration (a 7.8 mm cornea came out as 7.27 mm from banded frames).
    """
    frames = sorted(timing.frame_start_s)
    f = frames[0] if frames else 0
    pulse, _, weight = row_strobe(setup.sensor, setup.strobe, f)
    lit = pulse != NO_PULSE
    source = timing.source or "the scene"
    if np.unique(pulse[lit]).size > 1:
        raise TrackerInputError(
            f"{folder}: frames are banded: {np.unique(pulse[lit]).size} strobe pulses light "
            f"frame {f} ({setup.strobe.pulses_per_frame} per frame, timing from {source}); "
            + MAKE_CALIBRATION_FRAMES)
    if not lit.all() or weight.min() < SINGLE_PULSE_MIN_WEIGHT:
        share = float(np.mean(weight >= SINGLE_PULSE_MIN_WEIGHT))
        raise TrackerInputError(
            f"{folder}: the strobe lights only {share:.0%} of the rows of frame {f} whole "
            f"(exposure {setup.sensor.exposure_s * 1e3:.3g} ms, pulse "
            f"{setup.strobe.pulse_s * 1e6:.4g} us, timing from {source}); " + MAKE_CALIBRATION_FRAMES)


def calibration_glints(folder, setup: Setup) -> tuple[Setup, CalibrationGlints]:
    """Detect and identify the glints of a folder of single-pulse calibration frames.

    Returns the setup with the sidecar's calibration timing, and the glints. Frames that cannot
    be read or matched are left out (logged)."""
    folder = Path(folder)
    timing = read_timing(folder, setup)
    cal_setup = timing.apply(setup)
    check_single_pulse(folder, cal_setup, timing)
    targets = read_targets(folder)
    matcher = GlintMatcher(cal_setup)
    n = cal_setup.lights.count
    rows, used_targets, frames = [], [], []
    for f, _, img, err in iter_folder(folder, cal_setup):
        if err is not None or f not in targets:
            log.warning("calibration frame %d left out: %s", f, err or "no target in labels")
            continue
        try:
            det = detect_glints(img, cal_setup, f)
        except ValueError as exc:
            log.warning("calibration frame %d left out: %s", f, exc)
            continue
        det = det.select(~det.has(NO_BAND))
        prior = np.array(cal_setup.eye.angles_toward(targets[f][None])).reshape(2)
        match = matcher.match(det.glints_px, prior_angles_rad=prior)
        if not match.ok or match.matched.sum() < MIN_GLINTS:
            log.warning("calibration frame %d left out: match %s", f, match.reason)
            continue
        g = np.full((n, 2), np.nan)
        g[match.light_index[match.matched]] = det.glints_px[match.matched]
        rows.append(g)
        used_targets.append(targets[f])
        frames.append(f)
    if len(rows) < 4:
        raise TrackerInputError(f"{folder}: only {len(rows)} usable calibration frames, need >= 4")
    return cal_setup, CalibrationGlints(np.array(rows), np.array(used_targets), tuple(frames))


def calibrate_from_folder(folder, setup: Setup) -> Calibration:
    """Calibrate from a folder of single-pulse calibration frames (targets in labels.jsonl).

    Lighting pose, corneal radius, eye centre and orbit radius are fitted at once
    (:func:`estimator.calibration.calibrate_joint`, optical axis through the targets); the
    mappings from the fitted cornea centres: ``eq1_<m>`` (Eq. (1)) and ``quadratic_<m>``
    (minimum-norm where the orbit makes it rank deficient), m the number of frames used.
    """
    cal_setup, cg = calibration_glints(folder, setup)
    mask = np.isfinite(cg.glints_px).all(axis=-1)
    lighting, orbit = calibrate_joint(cal_setup.camera, cal_setup.lights_world_m, cg.glints_px,
                                      cg.targets_m, mask,
                                      center0_m=cal_setup.eye.cornea_center(0.0, 0.0))
    cal = Calibration.from_fits(lighting, orbit)
    total = len(read_targets(folder))
    cal = cal.with_quality(
        rms_px=float(lighting.rms_px), frames_used=len(cg.frames), frames_total=total,
        warnings=calibration_warnings(lighting, orbit, frames_used=len(cg.frames),
                                      frames_total=total))
    centers = fit_cornea_centers(cal_setup, cal, cg.glints_px, mask)
    ok = centers.ok
    m = int(ok.sum())
    maps = {f"eq1_{m}": fit_gaze_mapping(centers.center_m[ok], cg.targets_m[ok], "eq1",
                                         degenerate="min_norm"),
            f"quadratic_{m}": fit_gaze_mapping(centers.center_m[ok], cg.targets_m[ok],
                                               "quadratic", degenerate="min_norm")}
    return cal.with_mappings(**maps)


def save_calibration(calibration: Calibration, path) -> Path:
    """Write a calibration file (versioned JSON) atomically."""
    path = Path(path)
    atomic_write(path, calibration.to_json())
    return path


def load_calibration(path) -> Calibration:
    """Read and check a calibration file; errors name the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TrackerInputError(f"{path}: cannot read the calibration ({exc})") from None
    try:
        return Calibration.from_json(text)
    except ValueError as exc:
        raise TrackerInputError(f"{path}: {exc}") from None


# --------------------------------------------------------------------------- tracking a folder



@dataclass(frozen=True, slots=True)
class TrackSummary:
    """What :func:`track_folder` did: the CSV written, the samples, the frames, and the
    seconds spent tracking them (reading the frames not included)."""

    path: Path
    samples: tuple
    frames: int
    seconds: float = math.nan

    @property
    def samples_per_s(self) -> float:
        return len(self.samples) / self.seconds if self.seconds > 0 else math.nan

    @property
    def n_ok(self) -> int:
        return sum(s.ok for s in self.samples)


def track_folder(folder, setup: Setup, calibration, out_csv, *, method: str = "polynomial",
                 mapping: str | None = None,
                 progress: Callable[[int, int], None] | None = None) -> TrackSummary:
    """Track every frame of a folder and write ``samples.csv`` atomically.

    Parameters
    ----------
    folder : path
        Frames and timing sidecar (or a rendered dataset's manifest).
    setup : Setup
    calibration : Calibration or path
        A calibration, or the path of a calibration file.
    out_csv : path
        Written to ``<name>.partial`` and moved into place at the end: an existing file is
        replaced only by a complete one.
    method : {"polynomial", "geometric"}
    mapping : str, optional
        Polynomial mapping name; default the calibration's Eq. (1) mapping.
    progress : callable, optional
        ``progress(done, total)`` after every frame.
    """
    if not isinstance(calibration, Calibration):
        calibration = load_calibration(calibration)
    if mapping is None:
        eq1 = sorted(k for k in calibration.mappings if k.startswith("eq1"))
        mapping = eq1[-1] if eq1 else next(iter(calibration.mappings), "eq1_25")
    tracker = Tracker(setup, calibration, method, mapping=mapping)
    timing = read_timing(folder, setup)
    total = len(timing.frame_start_s)
    samples = []
    busy = 0.0
    for done, (f, t0, img, err) in enumerate(iter_folder(folder, setup), start=1):
        t = time.perf_counter()
        if err is not None:
            log.warning("frame %d: %s", f, err)
            reason = MISSING_FRAME if err.endswith(": missing") else UNREADABLE_FRAME
            tracker.reset()
            out = tracker.process(None, f, t0)
            out = [replace(s, reason=reason) for s in out]
        else:
            out = tracker.process(img, f, t0)
        busy += time.perf_counter() - t
        samples.extend(out)
        if progress is not None:
            progress(done, total)
    out_csv = Path(out_csv)
    write_samples_csv(out_csv, samples)
    return TrackSummary(out_csv, tuple(samples), total, busy)
