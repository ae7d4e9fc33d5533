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
:func:`track_folder` writes ``samples.csv`` (format ``scet-samples``, version 3: version 1
plus the ``prior`` column (2) and ``flux_flagged`` (3)) atomically; :func:`read_samples_csv`
reads all three.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from .banding import NO_PULSE, row_strobe
from .calibration import (MAPPING_TERMS, Calibration, calibrate_joint, calibrate_joint_conic,
                          calibrate_wire, calibration_warnings, fit_gaze_mapping, fit_glint_flux,
                          identify_on_conic, reidentify_on_conic)
from .capture import is_capture_folder
from .checks import load_json
from .cornea import check_conic
from .formats import atomic_write
from .gaze import calibrated_lights, fit_cornea_centers
from .glints import NO_BAND, detect_glints
from .lens import ideal_setup
from .inputs import (
    BAD_TIMESTAMP,
    FolderTiming,
    frame_path,
    frame_reason,
    input_files,
    open_capture,
    read_frame,
    read_targets,
    read_timing,
    refuse_overwriting_inputs,
    timing_document,
)
from .matching import GlintMatcher, MatchParams
from .reasons import Reason
from .setup import Setup
from .tracking import (  # noqa: F401 (the samples CSV: re-exported)
    MIN_GLINTS, SAMPLE_COLUMNS, Tracker, TrackerInputError, read_samples_csv, same_points,
    samples_csv, write_samples_csv)

log = logging.getLogger(__name__)

__all__ = ["FolderTiming", "timing_document", "read_timing", "frame_path", "read_frame",
           "read_targets", "iter_folder", "CalibrationGlints", "SINGLE_PULSE_MIN_WEIGHT",
           "glints_on_conic", "calibrate_glint_flux",
           "MAKE_CALIBRATION_FRAMES", "check_single_pulse", "calibration_glints",
           "CALIBRATION_MAPPINGS", "fit_supported_mappings", "calibrate_from_folder",
           "calibrate_from_glints",
           "save_calibration", "load_calibration", "SAMPLE_COLUMNS", "TrackSummary",
           "track_folder", "samples_csv", "write_samples_csv", "read_samples_csv",
           "BAD_TIMESTAMP"]


def iter_folder(folder, setup: Setup, timing: FolderTiming | None = None
                ) -> Iterator[tuple[int, float, np.ndarray | None, str | None]]:
    """(frame index, frame start s, frame or None, error message or None) for every frame
    of the timing sidecar, in index order. A missing or unreadable frame, one whose PNG header
    gives another size than the scene's camera, or whose time stamp the sidecar flags, yields
    None and why (:func:`estimator.inputs.frame_reason` gives the samples' reason code).

    A capture folder (``capture.json``, :mod:`estimator.capture`) gives every frame slot from
    its SensorTimestamps; dropped frames and bad ones come as None with the reason."""
    if is_capture_folder(folder):
        for fr in open_capture(Path(folder), setup).frames():
            yield fr.index, fr.start_s, fr.image, fr.reason
        return
    timing = read_timing(folder, setup) if timing is None else timing
    size = (setup.camera.width_px, setup.camera.height_px)
    for f in sorted(timing.frame_start_s):
        t0 = timing.frame_start_s[f]
        if f in timing.problems:
            yield f, t0, None, timing.problems[f]
            continue
        path = frame_path(folder, f)
        if not path.is_file():
            yield f, t0, None, f"{path}: missing"
            continue
        try:
            yield f, t0, read_frame(path, size), None
        except TrackerInputError as exc:
            yield f, t0, None, str(exc)


# --------------------------------------------------------------------------- calibration


@dataclass(frozen=True, slots=True)
class CalibrationGlints:
    """Identified glints of the calibration frames: (m, n, 2) NaN where missing, targets
    (m, 3) m, and the frame indices used; and every detected frame's detections, targets and
    indices (identified or not: what a re-identification starts from)."""

    glints_px: np.ndarray
    targets_m: np.ndarray
    frames: tuple
    detected: tuple = ()  # of (frame, target (3,), detections (k, 2), their flux (k,))
    flux: np.ndarray | None = None  # (m, n) the identified glints' flux (DN), NaN where missing

    @property
    def detections(self) -> list:
        """Each detected frame's detections (k_i, 2)."""
        return [d for _, _, d, _ in self.detected]

    @property
    def detected_targets_m(self) -> np.ndarray:
        """(k, 3) each detected frame's target."""
        return np.array([t for _, t, _, _ in self.detected]).reshape(-1, 3)


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
    # Detections through the lens into its ideal image, which the calibration then works in.
    lens, cal_setup = cal_setup.camera, ideal_setup(cal_setup)
    targets = read_targets(folder)
    matcher = GlintMatcher(cal_setup)
    n = cal_setup.lights.count
    rows, used_targets, frames, detected, fluxes = [], [], [], [], []
    for f, _, img, err in iter_folder(folder, cal_setup):
        if err is not None or f not in targets:
            log.warning("calibration frame %d left out: %s", f, err or "no target in labels")
            continue
        try:
            det = detect_glints(img, cal_setup, f).undistorted(lens)
        except ValueError as exc:
            log.warning("calibration frame %d left out: %s", f, exc)
            continue
        det = det.select(~det.has(NO_BAND))
        detected.append((f, np.asarray(targets[f], dtype=np.float64), det.glints_px,
                         det.intensity))
        prior = np.array(cal_setup.eye.angles_toward(targets[f][None])).reshape(2)
        match = matcher.match(det.glints_px, prior_angles_rad=prior)
        if not match.ok:
            log.warning("calibration frame %d left out: match %s", f, match.reason)
            continue
        if match.matched.sum() < MIN_GLINTS:
            log.warning("calibration frame %d left out: %d glints identified, fewer than %d",
                        f, int(match.matched.sum()), MIN_GLINTS)
            continue
        g = np.full((n, 2), np.nan)
        g[match.light_index[match.matched]] = det.glints_px[match.matched]
        flux = np.full(n, np.nan)
        flux[match.light_index[match.matched]] = det.intensity[match.matched]
        rows.append(g)
        fluxes.append(flux)
        used_targets.append(targets[f])
        frames.append(f)
    if len(rows) < 4:
        raise TrackerInputError(f"{folder}: only {len(rows)} usable calibration frames, need >= 4")
    return cal_setup, CalibrationGlints(np.array(rows), np.array(used_targets), tuple(frames),
                                        tuple(detected), np.array(fluxes))


def calibrate_from_folder(folder, setup: Setup, *, cornea_model: str = "sphere",
                          light_model: str = "points") -> Calibration:
    """Calibrate from a folder of single-pulse calibration frames (targets in labels.jsonl).

    Lighting pose, corneal radius, eye centre and orbit radius are fitted at once
    (:func:`estimator.calibration.calibrate_joint`, optical axis through the targets); the
    mappings from the fitted cornea centres: ``eq1_<m>`` (Eq. (1)) and ``quadratic_<m>``
    (minimum-norm where the orbit makes it rank deficient), m the number of frames used.
    ``cornea_model="conic"`` calibrates the conic constant Q with the rest
    (:func:`estimator.calibration.calibrate_joint_conic`) and records it in the file. The
    calibration also records each light's power for the glints' expected flux
    (``glint_flux``, :func:`calibrate_glint_flux`: the tracker's check for glints cut by a
    lash), a conic's from the glints identified on the calibrated conic. ``light_model``: as
    :func:`calibrate_from_glints` (``"wire_mirror"``: the wire turns' moving virtual sources).
    """
    check_conic(cornea_model, 0.0)
    cal_setup, cg = calibration_glints(folder, setup)
    total = len(read_targets(folder))
    cal = calibrate_from_glints(cal_setup, cg.glints_px, cg.targets_m, frames_total=total,
                                cornea_model=cornea_model, light_model=light_model)
    glints, flux = cg.glints_px, cg.flux
    if cornea_model == "conic":
        # The spherical matcher's identities of oblique glints are wrong on a conic cornea:
        # identify every detected frame again on the calibrated conic, and recalibrate.
        cal = reidentify_on_conic(
            cal, cal_setup, cg.detections, cg.detected_targets_m,
            lambda g, t: calibrate_from_glints(cal_setup, g, t, frames_total=total,
                                               cornea_model="conic"),
            gate_px=MatchParams().gate_px, min_glints=MIN_GLINTS)
        glints, flux = glints_on_conic(cal, cal_setup, cg)
    return replace(cal, glint_flux=calibrate_glint_flux(cal_setup, cal, glints, flux))


def glints_on_conic(calibration: Calibration, setup: Setup, cg: CalibrationGlints):
    """The calibration frames' glints (m, n, 2) identified on a conic calibration
    (:func:`estimator.calibration.identify_on_conic`, every detected frame, no crowded glint
    left out) and their flux (m, n) (None where the frames had no detections)."""
    if not len(cg.detected):
        return np.empty((0, setup.lights.count, 2)), None
    glints = identify_on_conic(calibration, setup, cg.detections, cg.detected_targets_m,
                               gate_px=MatchParams().gate_px)
    return glints, np.stack([_flux_of(g, d, fx) for g, (_, _, d, fx) in zip(glints, cg.detected)])


def _flux_of(glints_px, detections, flux) -> np.ndarray:
    """(n,) the flux of each identified glint (n, 2): that of the detection (k, 2) it is (the
    identification copies detections: :func:`estimator.tracking.same_points`); NaN where
    none."""
    same = same_points(detections, glints_px)  # (k, n)
    hit = same.any(axis=0)
    out = np.full(glints_px.shape[0], np.nan)
    out[hit] = np.asarray(flux, dtype=np.float64)[same.argmax(axis=0)[hit]]
    return out


def calibrate_glint_flux(setup: Setup, calibration: Calibration, glints_px, flux):
    """Each light's power (:func:`estimator.calibration.fit_glint_flux`) from the calibration
    frames' identified glints (m, n, 2) and their flux (m, n), at the cornea centres the
    calibration fits them to (a conic's: on the conic, its axis from the calibrated eye
    centre); None without fluxes."""
    if flux is None or not len(flux):
        return None
    mask = np.isfinite(glints_px).all(axis=-1)
    centers = fit_cornea_centers(setup, calibration, glints_px, mask)
    c = np.where(centers.ok[:, None], centers.center_m, np.nan)
    conic = {"asphericity": calibration.cornea_asphericity,
             "eye_center_m": calibration.eye_center_m} if calibration.conic else {}
    return fit_glint_flux(setup.camera, calibration.cornea_radius_m,
                          calibrated_lights(setup, calibration), c, glints_px,
                          flux, float(calibration.quality.get("rms_px", np.nan)), **conic)


def calibrate_from_glints(setup: Setup, glints_px, targets_m, *,
                          frames_total: int | None = None, cornea_model: str = "sphere",
                          light_model: str = "points") -> Calibration:
    """:func:`calibrate_from_folder` on identified glints: (m, n, 2) px (NaN: not seen) of
    ``setup``'s lights with the eye fixating (m, 3) ``targets_m`` (the feature-level
    simulator's glints, or a folder's). ``frames_total``: the frames there were (default m).
    ``cornea_model``: ``"sphere"`` (the paper's) or ``"conic"`` (Q calibrated too).
    ``light_model``: ``"points"`` or ``"wire_mirror"`` (the wire turns' virtual sources, fitted
    from the point fit's answer: :func:`estimator.calibration.calibrate_wire`)."""
    check_conic(cornea_model, 0.0)
    glints_px = np.asarray(glints_px, dtype=np.float64)
    used = glints_px.shape[0]
    total = used if frames_total is None else int(frames_total)
    mask = np.isfinite(glints_px).all(axis=-1)
    center0 = setup.eye.cornea_center(0.0, 0.0)
    if cornea_model == "conic":
        lighting, orbit, q = calibrate_joint_conic(setup.camera, setup.lights_world_m, glints_px,
                                                   targets_m, mask, center0_m=center0)
        cal = replace(Calibration.from_fits(lighting, orbit), cornea_model="conic",
                      cornea_asphericity=q, light_model=light_model)
    else:
        lighting, orbit = calibrate_joint(setup.camera, setup.lights_world_m, glints_px,
                                          targets_m, mask, center0_m=center0)
        if light_model == "wire_mirror":
            lighting, orbit = calibrate_wire(setup, glints_px, targets_m, mask, (lighting, orbit))
        cal = replace(Calibration.from_fits(lighting, orbit), light_model=light_model)
    cal = cal.with_quality(
        rms_px=float(lighting.rms_px), frames_used=used, frames_total=total,
        warnings=calibration_warnings(lighting, orbit, frames_used=used, frames_total=total))
    centers = fit_cornea_centers(setup, cal, glints_px, mask)
    ok = centers.ok
    maps, skipped = fit_supported_mappings(centers.center_m[ok], np.asarray(targets_m)[ok])
    if skipped:
        cal = cal.with_quality(mappings_skipped=skipped)
    return cal.with_mappings(**maps)


#: The gaze mappings :func:`calibrate_from_folder` fits, each where the points support it.
CALIBRATION_MAPPINGS = ("eq1", "quadratic")


def fit_supported_mappings(centers_m, targets_m) -> tuple[dict, dict]:
    """The :data:`CALIBRATION_MAPPINGS` that ``m`` calibration points support, fitted
    (``<kind>_<m>``, minimum-norm where the points leave a term undetermined), and those
    skipped with why: a 3x3 pattern (9 points) fits Eq. (1) (8 terms), not the 10-term
    quadratic.

    Returns
    -------
    maps : dict[str, GazeMapping]
    skipped : dict[str, str]
        Mapping name -> reason (JSON-ready; recorded in the calibration's quality).
    """
    m = len(centers_m)
    maps, skipped = {}, {}
    for kind in CALIBRATION_MAPPINGS:
        k, name = len(MAPPING_TERMS[kind]), f"{kind}_{m}"
        if m < k:
            skipped[name] = (f"the {kind!r} mapping has {k} terms and needs at least {k} "
                             f"calibration points; {m} were usable")
            continue
        maps[name] = fit_gaze_mapping(centers_m, targets_m, kind, degenerate="min_norm")
    return maps, skipped


def save_calibration(calibration: Calibration, path) -> Path:
    """Write a calibration file (versioned JSON) atomically."""
    path = Path(path)
    atomic_write(path, calibration.to_json())
    return path


def load_calibration(path) -> Calibration:
    """Read and check a calibration file; errors (TrackerInputError) name the file and key."""
    path = Path(path)
    return Calibration.from_dict(load_json(path, TrackerInputError), path=path,
                                 error=TrackerInputError)


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

    @property
    def internal_errors(self) -> int:
        """Frames whose processing raised (a bug: logged with its traceback); their samples
        are NaN with reason ``internal_error:<exception>``."""
        return len({s.frame_index for s in self.samples if s.reason.startswith(Reason.INTERNAL_ERROR)})


def tracking_calibration(folder, calibration, out_csv, *, method: str = "polynomial",
                         mapping: str | None = None, flag_cut_glints: bool | None = None,
                         n_lights: int | None = None) -> tuple[Calibration, str]:
    """The checks of a folder run (:func:`track_folder`, :func:`estimator.live.track_following`)
    before anything is read: ``out_csv`` must not be one of the inputs, and the calibration (or
    its file, loaded) must hold what ``method`` needs, and with ``flag_cut_glints=True`` the
    glint flux of the rig's ``n_lights`` lights; ``mapping`` defaults to the calibration's Eq. (1)
    mapping. Returns the calibration and the mapping name."""
    inputs = input_files(folder)
    source = "the calibration"
    if not isinstance(calibration, Calibration):
        inputs.append(Path(calibration))
        source = str(calibration)
    refuse_overwriting_inputs(out_csv, inputs)
    if not isinstance(calibration, Calibration):
        calibration = load_calibration(calibration)
    if mapping is None:
        eq1 = sorted(k for k in calibration.mappings if k.startswith("eq1"))
        mapping = eq1[-1] if eq1 else next(iter(calibration.mappings), None)
    if method == "polynomial" and mapping not in calibration.mappings:
        skipped = calibration.quality.get("mappings_skipped") or {}
        raise TrackerInputError(
            f"{source}: no gaze mapping{' ' + repr(mapping) if mapping else ''} for polynomial "
            f"gaze (has "
            f"{sorted(calibration.mappings)}" + (f"; skipped: {sorted(skipped)}" if skipped else "")
            + "); track with --method geometric, or calibrate with more points")
    if method == "geometric" and not calibration.has_orbit:
        raise TrackerInputError(f"{source}: no eye centre and orbit radius, which --method "
                                "geometric needs")
    flux = calibration.glint_flux
    if flag_cut_glints and not calibration.flags_cut_glints(n_lights):
        have = "no glint_flux" if flux is None else \
            f"glint_flux of {flux.log_power.size} lights, not the rig's {n_lights}"
        raise TrackerInputError(f"{source}: {have}, which --flag-cut-glints needs (calibrate "
                                "again with this version, on this rig)")
    return calibration, mapping or ""


def track_frame(tracker: Tracker, frame: int, frame_start_s, image, error: str | None) -> list:
    """One frame of a folder through ``tracker``: its samples; a frame that could not be read
    (``error``, from :func:`iter_folder`) gives the frame's NaN samples with its reason and
    resets the stream."""
    if error is None:
        return tracker.process(image, frame, frame_start_s)
    log.warning("frame %d: %s", frame, error)
    reason = frame_reason(error)
    tracker.reset()
    return [replace(s, reason=reason) for s in tracker.process(None, frame, frame_start_s)]


def track_folder(folder, setup: Setup, calibration, out_csv, *, method: str = "polynomial",
                 mapping: str | None = None,
                 progress: Callable[[int, int], None] | None = None,
                 flag_cut_glints: bool | None = None,
                 focus_detection: bool = False) -> TrackSummary:
    """Track every frame of a folder and write ``samples.csv`` atomically.

    Parameters
    ----------
    folder : path
        Frames and timing sidecar (or a rendered dataset's manifest).
    flag_cut_glints : bool or None
        :class:`~estimator.tracker.Tracker`'s: drop glints a lash cuts (by their flux);
        None: where the calibration has ``glint_flux``, True: refuse one without it.
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
    focus_detection : bool
        :class:`~estimator.tracking.Tracker`'s: search each frame only around the glints the
        last frame's samples used (faster on frames with clutter; samples may differ where a
        glint appears outside the window).
    """
    calibration, mapping = tracking_calibration(folder, calibration, out_csv, method=method,
                                                mapping=mapping, flag_cut_glints=flag_cut_glints,
                                                n_lights=setup.lights.count)
    timing = read_timing(folder, setup)
    # The frames were taken with the sidecar's exposure and strobe where it gives them.
    setup = timing.apply(setup)
    tracker = Tracker(setup, calibration, method, mapping=mapping,
                      flag_cut_glints=flag_cut_glints, focus_detection=focus_detection)
    total = len(timing.frame_start_s)
    samples = []
    busy = 0.0
    for done, (f, t0, img, err) in enumerate(iter_folder(folder, setup, timing), start=1):
        t = time.perf_counter()
        samples.extend(track_frame(tracker, f, t0, img, err))
        busy += time.perf_counter() - t
        if progress is not None:
            progress(done, total)
    out_csv = Path(out_csv)
    write_samples_csv(out_csv, samples)
    return TrackSummary(out_csv, tuple(samples), total, busy)
