"""The estimator's JSON readers fuzzed like the scene loader (tests/estimator/test_scene.py):
hostile versions of a valid timing sidecar, calibration file, manifest and labels file, and
only the project's own error (TrackerInputError naming the file) may escape; what loads is
finite and usable."""

from __future__ import annotations

import json
import os
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimator.errors import TrackerInputError
from estimator.folders import load_calibration, read_targets, read_timing, timing_document
from estimator.scene import load_scene
from tests.estimator.hostile_json import hostile_text, write_text
from tests.estimator.test_hostile_inputs import calibration_with_mapping

#: Examples per fuzz test (SCET_FUZZ_EXAMPLES=3000 for a long run; each reader passed 3000).
EXAMPLES = settings(max_examples=int(os.environ.get("SCET_FUZZ_EXAMPLES", 150)),
                    deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_readers")


def only_tracker_input_errors(read, named):
    """``read()``'s value, or None after a TrackerInputError that names ``named``."""
    try:
        return read()
    except TrackerInputError as exc:
        assert str(named) in str(exc), exc
        return None


@pytest.fixture(scope="module")
def timing_doc(setup):
    from estimator.banding import calibration_setup

    cal = calibration_setup(setup)
    dt = setup.sensor.frame_period_s
    return json.loads(timing_document({f: f * dt for f in range(3)},
                                      exposure_s=cal.sensor.exposure_s, strobe=cal.strobe))


@given(data=st.data())
@EXAMPLES
def test_fuzz_timing_sidecar(work, setup, timing_doc, data):
    folder = work / "timing"
    folder.mkdir(exist_ok=True)
    write_text(folder / "timing.json", hostile_text(data, timing_doc))
    timing = only_tracker_input_errors(lambda: read_timing(folder, setup), folder / "timing.json")
    if timing is None:
        return
    assert all(math.isfinite(t) for t in timing.frame_start_s.values())
    applied = only_tracker_input_errors(lambda: timing.apply(setup), folder / "timing.json")
    if applied is not None:
        st_ = applied.strobe
        assert st_.pulses_per_frame >= 1 and 0 < st_.pulse_s <= setup.sensor.frame_period_s
        assert 0 < applied.sensor.exposure_s <= setup.sensor.frame_period_s


@pytest.fixture(scope="module")
def calibration_doc(setup):
    cal = calibration_with_mapping(setup).with_quality(rms_px=0.2, warnings=[])
    return json.loads(cal.to_json())


@given(data=st.data())
@EXAMPLES
def test_fuzz_calibration_file(work, calibration_doc, data):
    path = work / "cal.json"
    write_text(path, hostile_text(data, calibration_doc))
    cal = only_tracker_input_errors(lambda: load_calibration(path), path)
    if cal is None:
        return
    # What loads is physical: no NaN geometry that would silently give no estimates.
    assert 1e-3 <= cal.cornea_radius_m <= 0.05
    assert np.isfinite(cal.lighting_correction.rotation).all()
    for m in cal.mappings.values():
        assert np.isfinite(m.coefficients).all() and (m.scale_m > 0).all()
    assert all(isinstance(w, str) for w in cal.warnings)


@given(data=st.data())
@EXAMPLES
def test_fuzz_labels_targets(work, data):
    folder = work / "labels"
    folder.mkdir(exist_ok=True)
    lines = [{"frame": f, "strobe": 0, "target_m": [0.01 * f, -0.02, -0.7]} for f in range(3)]
    text = "\n".join(hostile_text(data, line) if data.draw(st.booleans(), label="hit") else
                     json.dumps(line) for line in lines)
    write_text(folder / "labels.jsonl", text)
    targets = only_tracker_input_errors(lambda: read_targets(folder), folder / "labels.jsonl")
    if targets is not None:
        assert all(t.shape == (3,) and np.isfinite(t).all() for t in targets.values())


@given(data=st.data())
@EXAMPLES
def test_fuzz_manifest_timing(work, setup, data):
    import cv2

    folder = work / "dataset"
    (folder / "frames").mkdir(parents=True, exist_ok=True)
    for f in range(2):
        if not (folder / "frames" / f"{f:06d}.png").exists():
            cv2.imwrite(str(folder / "frames" / f"{f:06d}.png"), np.zeros((480, 640), np.uint16))
    doc = {"format": "scet-dataset", "version": 1, "frames": 2, "seed": 0,
           "trajectory": "fixations", "scene": {"toml": ""},
           "image": {"width_px": 640, "height_px": 480, "png_bit_depth": 16}}
    write_text(folder / "manifest.json", hostile_text(data, doc))
    timing = only_tracker_input_errors(lambda: read_timing(folder, setup), folder / "manifest.json")
    if timing is not None:
        assert 1 <= len(timing.frame_start_s) <= 2  # the frames the folder holds
