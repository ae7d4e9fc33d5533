"""Hostile input to the estimator's readers: timing sidecars, frames, manifests, calibration
files, labels and output paths. Each case builds the bad input and asserts the exact outcome:
the error type and the file and key it names, or the samples' reason code."""

from __future__ import annotations

import json
import logging
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from estimator.calibration import Calibration, fit_gaze_mapping
from estimator.errors import TrackerInputError
from estimator.folders import (
    BAD_TIMESTAMP,
    fit_supported_mappings,
    iter_folder,
    load_calibration,
    read_targets,
    read_timing,
    save_calibration,
    timing_document,
    track_folder,
)
from estimator.formats import PARTIAL_SUFFIX
from estimator.inputs import read_frame
from estimator.scene import load_scene
from estimator.tracker import INTERNAL_ERROR, MISSING_FRAME, UNREADABLE_FRAME, WRONG_FRAME_SIZE, Tracker

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def calibration(setup):
    return Calibration.ground_truth(setup)


def blank(setup, dtype=np.uint16):
    return np.full((setup.camera.height_px, setup.camera.width_px), 16, dtype=dtype)


def png_with_header(width: int, height: int, depth: int = 8, colour: int = 0) -> bytes:
    """A PNG whose IHDR claims ``width`` x ``height`` (the data after it is one empty row)."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(
            ">I", zlib.crc32(kind + data) & 0xFFFFFFFF)
    ihdr = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0"))
            + chunk(b"IEND", b""))


def folder_with(tmp_path, setup, n=3, timing=None, name="run"):
    path = tmp_path / name
    (path / "frames").mkdir(parents=True)
    for f in range(n):
        cv2.imwrite(str(path / "frames" / f"{f:06d}.png"), blank(setup))
    dt = setup.sensor.frame_period_s
    (path / "timing.json").write_text(timing if timing is not None else
                                      timing_document({f: f * dt for f in range(n)}))
    return path


# --------------------------------------------------------------------------- timing sidecar


@pytest.mark.parametrize("edit, key, words", [
    ({"frames": []}, "frames", "expected an object, got a list"),
    ({"frames": {"0": 10 ** 400}}, "frames.0", "too large for a float"),
    ({"frames": {"0": float("nan")}}, "frames.0", "finite number"),
    ({"frames": {"0": True}}, "frames.0", "expected a number, got true"),
    ({"frames": {"0": 0.0, "9" * 40: 1.0}}, "frames." + "9" * 40, "frame index"),
    ({"exposure_s": 5.0}, "exposure_s", "expected a value in"),
    ({"exposure_s": "1ms"}, "exposure_s", "expected a number"),
    ({"strobe": [1, 2]}, "strobe", "expected an object"),
    ({"strobe": {"pulse_s": 50.0}}, "strobe.pulse_s", "check the unit"),
    ({"strobe": {"pulses_per_frame": 0}}, "strobe.pulses_per_frame", "integer in"),
    ({"strobe": {"pulses": 3}}, "strobe.pulses", "unknown key"),
])
def test_a_bad_timing_field_is_refused_naming_the_key(tmp_path, setup, edit, key, words):
    doc = {"format": "scet-timing", "version": 1, "frames": {"0": 0.0}, **edit}
    path = folder_with(tmp_path, setup, 1, json.dumps(doc))
    with pytest.raises(TrackerInputError, match=words) as info:
        read_timing(path, setup)
    assert info.value.path == str(path / "timing.json") and info.value.key == key


def test_timing_that_does_not_fit_the_scene_is_refused(tmp_path, setup):
    long_exposure = timing_document({0: 0.0}, exposure_s=0.5)
    timing = read_timing(folder_with(tmp_path, setup, 1, long_exposure), setup)
    with pytest.raises(TrackerInputError, match="key 'exposure_s'.*longer than the scene's frame"):
        timing.apply(setup)


def test_repeated_and_backward_time_stamps_are_flagged(tmp_path, setup, calibration):
    dt = setup.sensor.frame_period_s
    text = timing_document({0: 0.0, 1: dt, 2: dt, 3: 0.5 * dt, 4: 4 * dt})
    path = folder_with(tmp_path, setup, 5, text)
    timing = read_timing(path, setup)
    assert sorted(timing.problems) == [2, 3]
    assert "key 'frames.2'" in timing.problems[2] and "repeats" in timing.problems[2]
    assert "goes back from" in timing.problems[3]
    summary = track_folder(path, setup, calibration, tmp_path / "s.csv", method="geometric")
    reasons = {s.frame_index: s.reason for s in summary.samples}
    assert reasons[2] == reasons[3] == BAD_TIMESTAMP
    assert reasons[0] != BAD_TIMESTAMP and reasons[4] != BAD_TIMESTAMP


def test_track_uses_the_sidecars_strobe(tmp_path, setup, calibration):
    # Single-pulse calibration frames: one sample per frame, not one per band of the scene.
    from estimator.banding import calibration_setup

    cal = calibration_setup(setup)
    dt = setup.sensor.frame_period_s
    text = timing_document({0: 0.0, 1: dt}, exposure_s=cal.sensor.exposure_s, strobe=cal.strobe)
    path = folder_with(tmp_path, setup, 2, text)
    summary = track_folder(path, setup, calibration, tmp_path / "s.csv", method="geometric")
    assert len(summary.samples) == 2 < setup.strobe.pulses_per_frame


# --------------------------------------------------------------------------- frames


def test_a_frame_header_claiming_an_enormous_size_is_refused_before_decoding(tmp_path, setup):
    p = tmp_path / "000000.png"
    p.write_bytes(png_with_header(20000, 20000))
    with pytest.raises(TrackerInputError, match="frame size 20000x20000 px in its PNG header, "
                                                "the scene's camera is 640x480"):
        read_frame(p, (640, 480))
    with pytest.raises(TrackerInputError, match="more than SCET reads"):
        read_frame(p)
    p.write_bytes(png_with_header(640, 480, depth=8, colour=2))
    with pytest.raises(TrackerInputError, match="colour type 2"):
        read_frame(p, (640, 480))
    p.write_bytes(b"GIF89a" + bytes(40))
    with pytest.raises(TrackerInputError, match="not a PNG"):
        read_frame(p)


def test_bad_frames_become_samples_with_their_reason(tmp_path, setup, calibration):
    path = folder_with(tmp_path, setup, 5)
    frames = path / "frames"
    (frames / "000001.png").write_bytes(png_with_header(20000, 20000))
    cv2.imwrite(str(frames / "000002.png"), np.zeros((240, 320), np.uint16))
    (frames / "000003.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 10)
    (frames / "000004.png").unlink()
    got = {f: err for f, _, img, err in iter_folder(path, setup)}
    assert got[0] is None and "frame size 20000x20000" in got[1] and "320x240" in got[2]
    summary = track_folder(path, setup, calibration, tmp_path / "s.csv", method="geometric")
    reasons = {s.frame_index: s.reason for s in summary.samples}
    assert (reasons[1], reasons[2], reasons[3], reasons[4]) == (
        WRONG_FRAME_SIZE, WRONG_FRAME_SIZE, UNREADABLE_FRAME, MISSING_FRAME)


# --------------------------------------------------------------------------- manifests


def manifest_folder(tmp_path, setup, frames_claimed, frames_held=2, **edit):
    path = tmp_path / "ds"
    (path / "frames").mkdir(parents=True)
    for f in range(frames_held):
        cv2.imwrite(str(path / "frames" / f"{f:06d}.png"), blank(setup))
    doc = {"format": "scet-dataset", "version": 1, "frames": frames_claimed,
           "image": {"width_px": 640, "height_px": 480, "png_bit_depth": 16}, **edit}
    (path / "manifest.json").write_text(json.dumps(doc))
    return path


def test_a_frame_count_the_folder_does_not_back_is_refused_not_iterated(tmp_path, setup):
    path = manifest_folder(tmp_path, setup, 10 ** 7)
    with pytest.raises(TrackerInputError, match="claims 10000000 frames, but the last one "
                                                r"\(9999999.png\) is not in the folder, which "
                                                "holds 2") as info:
        read_timing(path, setup)
    assert info.value.key == "frames"
    assert len(read_timing(manifest_folder(tmp_path / "b", setup, 2), setup).frame_start_s) == 2


def test_a_sidecar_listing_far_more_frames_than_the_folder_holds_is_refused(tmp_path, setup):
    text = timing_document({f: f * 0.0166 for f in range(5000)})
    with pytest.raises(TrackerInputError, match="lists 5000 frames, the folder holds 2") as info:
        read_timing(folder_with(tmp_path, setup, 2, text), setup)
    assert info.value.key == "frames"


@pytest.mark.parametrize("edit, key", [
    ({"format": "scet-other"}, "format"), ({"version": 7}, "version"), ({"frames": "2"}, "frames"),
    ({"frames": 2.5}, "frames"), ({"image": [640, 480]}, "image"),
    ({"image": {"width_px": 640, "height_px": 480, "png_bit_depth": 8}}, "image.png_bit_depth"),
])
def test_a_manifest_is_checked_before_its_frames_are_timed(tmp_path, setup, edit, key):
    with pytest.raises(TrackerInputError) as info:
        read_timing(manifest_folder(tmp_path, setup, 2, **edit), setup)
    assert "manifest.json" in str(info.value) and info.value.key == key


# --------------------------------------------------------------------------- calibration files


def calibration_with_mapping(setup) -> Calibration:
    """The ground-truth calibration with a 9-target Eq. (1) mapping (the hostile-input and
    fuzz tests' calibration file)."""
    targets = setup.screen.grid(3, 3, margin=0.0)
    centers = np.array([setup.eye.cornea_center(*np.ravel(a)) for a in
                        zip(*setup.eye.angles_toward(targets))])
    return Calibration.ground_truth(setup).with_mappings(
        eq1_9=fit_gaze_mapping(centers, targets, "eq1", degenerate="min_norm"))


def calibration_doc(setup):
    return calibration_with_mapping(setup).to_dict()


@pytest.mark.parametrize("edit, key, words", [
    (lambda d: d.update(cornea_radius_m=7.8), "cornea_radius_m", "check the unit"),
    (lambda d: d.update(orbit_radius_m=float("nan")), "orbit_radius_m", "finite"),
    (lambda d: d.update(mappings=[]), "mappings", "expected an object, got a list"),
    (lambda d: d["mappings"]["eq1_9"]["coefficients"][3].__setitem__(1, float("nan")),
     "mappings.eq1_9.coefficients[3][1]", "finite"),
    (lambda d: d["mappings"]["eq1_9"].update(kind="cubic"), "mappings.eq1_9.kind", "expected one of"),
    (lambda d: d["lighting_correction"].update(rotation=np.eye(3).tolist()[:2]),
     "lighting_correction.rotation", "expected 3 entries"),
    (lambda d: d["lighting_correction"].update(rotation=(2 * np.eye(3) / 2.1).tolist()),
     "lighting_correction.rotation", "proper rotation"),
    (lambda d: d.update(eye_center_m=[0, 0, 10 ** 400]), "eye_center_m[2]", "too large"),
    (lambda d: d.update(quality={"warnings": "none"}), "quality.warnings", "expected a list"),
])
def test_a_bad_calibration_file_names_the_file_and_key(tmp_path, setup, edit, key, words):
    doc = calibration_doc(setup)
    edit(doc)
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(TrackerInputError, match=words) as info:
        load_calibration(path)
    assert info.value.path == str(path) and info.value.key == key


def test_a_calibration_file_nested_too_deeply_is_refused(tmp_path):
    path = tmp_path / "cal.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(TrackerInputError, match="nested too deeply"):
        load_calibration(path)


# --------------------------------------------------------------------------- 9-point calibration


def test_a_3x3_pattern_fits_eq1_and_says_the_quadratic_was_skipped(setup):
    targets = setup.screen.grid(3, 3, margin=0.0)
    centers = np.array([setup.eye.cornea_center(*np.ravel(a)) for a in
                        zip(*setup.eye.angles_toward(targets))])
    maps, skipped = fit_supported_mappings(centers, targets)
    assert sorted(maps) == ["eq1_9"] and sorted(skipped) == ["quadratic_9"]
    assert "needs at least 10 calibration points; 9 were usable" in skipped["quadratic_9"]
    maps, skipped = fit_supported_mappings(centers[:7], targets[:7])
    assert maps == {} and sorted(skipped) == ["eq1_7", "quadratic_7"]


def test_tracking_with_no_mapping_for_the_method_is_a_clean_error(tmp_path, setup):
    cal = Calibration.ground_truth(setup).with_quality(mappings_skipped={"eq1_7": "too few"})
    path = save_calibration(cal, tmp_path / "cal.json")
    with pytest.raises(TrackerInputError, match=r"cal\.json: no gaze mapping.*skipped: \['eq1_7'\]"):
        track_folder(folder_with(tmp_path, setup, 1), setup, path, tmp_path / "s.csv")


# --------------------------------------------------------------------------- labels


@pytest.mark.parametrize("line, key, words", [
    ('{"frame": 0, "target_m": [0.1, 0.2]}', "target_m", "expected 3 entries"),
    ('{"frame": 0, "target_m": [150, 20, -700]}', "target_m[0]", "check the unit"),
    ('{"frame": -1, "target_m": [0, 0, -0.7]}', "frame", "integer in"),
    ('{"frame": "0", "target_m": [0, 0, -0.7]}', "frame", "expected an integer"),
    ('[0, [0, 0, -0.7]]', None, "expected an object"),
    ('{"frame": 0, "target_m": [0, NaN, -0.7]}', "target_m[1]", "finite"),
])
def test_a_bad_label_names_the_line_and_key(tmp_path, line, key, words):
    (tmp_path / "labels.jsonl").write_text('{"frame": 1, "target_m": [0, 0, -0.7]}\n' + line + "\n")
    with pytest.raises(TrackerInputError, match=words) as info:
        read_targets(tmp_path)
    assert info.value.path == f"{tmp_path / 'labels.jsonl'}, line 2" and info.value.key == key


# --------------------------------------------------------------------------- outputs


def test_an_output_that_is_an_input_is_refused_before_anything_is_written(tmp_path, setup,
                                                                          calibration):
    path = folder_with(tmp_path, setup, 1)
    cal = save_calibration(calibration, tmp_path / "cal.json")
    before = cal.read_bytes()
    for out in (cal, path / "timing.json", path / "frames" / "000000.png", path / "frames"):
        with pytest.raises(TrackerInputError, match="is one of the inputs|is a folder|like a frame"):
            track_folder(path, setup, cal, out)
    assert cal.read_bytes() == before
    assert not list(tmp_path.rglob(f"*{PARTIAL_SUFFIX}"))


def test_a_full_disk_leaves_no_partial_and_names_the_file(tmp_path):
    # A file-size limit makes the write fail as a full disk does (EFBIG instead of ENOSPC).
    # The limit is set after the import: a limited interpreter would truncate its .pyc files.
    script = ("import resource, signal, sys\n"
              "from estimator.formats import atomic_write\n"
              "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
              "resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))\n"
              "try:\n    atomic_write(sys.argv[1], 'x' * 5000)\n"
              "except OSError as exc:\n    print(exc.filename, exc.strerror)\n")
    out = tmp_path / "samples.csv"
    proc = subprocess.run([sys.executable, "-c", script, str(out)], capture_output=True,
                          text=True, cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PYTHONDONTWRITEBYTECODE": "1"},
                          timeout=120)
    assert proc.stdout.strip() == f"{out} cannot write (File too large)", proc.stderr
    assert list(tmp_path.iterdir()) == []


def test_an_unwritable_folder_is_a_clean_os_error(tmp_path, setup, calibration):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(OSError) as info:
        track_folder(folder_with(tmp_path, setup, 1), setup, calibration, blocker / "s.csv",
                     method="geometric")
    assert str(blocker) in str(info.value)


# --------------------------------------------------------------------------- internal errors


def test_an_exception_in_a_frame_is_logged_with_its_traceback(setup, calibration, caplog):
    tr = Tracker(setup, calibration, "geometric")
    with caplog.at_level(logging.ERROR, logger="estimator.tracker"):
        out = tr.process(blank(setup).astype(np.complex128), 0)  # complex pixels: a bug's input
    assert out and all(s.reason == f"{INTERNAL_ERROR}:ValueError" for s in out)
    record = next(r for r in caplog.records if "internal error" in r.getMessage())
    assert record.levelno == logging.ERROR and record.exc_info is not None
    assert "frame 0: internal error ValueError: frame must be" in record.getMessage()


def test_the_track_summary_counts_the_frames_with_internal_errors(setup, calibration, tmp_path):
    from estimator.folders import TrackSummary

    tr = Tracker(setup, calibration, "geometric")
    samples = tr.process(blank(setup).astype(np.complex128), 0) + tr.process(blank(setup), 1)
    summary = TrackSummary(tmp_path / "s.csv", tuple(samples), 2)
    assert summary.internal_errors == 1 and summary.n_ok == 0


@pytest.mark.parametrize("raw, words", [
    (b"# scet-samples 2\nframe\n\xff\xfe", "not UTF-8"),
    (b"# scet-samples 2\nframe,reason\n0,\"" + b"x" * 200_000 + b"\"\n", "not a samples CSV"),
    (b"frame,reason\n", "expected first line"),
])
def test_a_bad_samples_csv_names_the_file(tmp_path, raw, words):
    from estimator.folders import read_samples_csv

    path = tmp_path / "samples.csv"
    path.write_bytes(raw)
    with pytest.raises(TrackerInputError, match=words) as info:
        read_samples_csv(path)
    assert str(path) in str(info.value)
