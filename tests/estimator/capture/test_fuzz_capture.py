"""Capture folders fuzzed like the scene loader: hostile capture.json headers and frames.jsonl
lines; only CaptureError (naming the file) may escape, bad lines become reasoned frame slots,
and a time stamp far beyond the frames held never makes the reader claim (or iterate) the
slots in between."""

import json
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from estimator.capture import CaptureError, CaptureFolder
from estimator.capture.folder import MAX_GAP_FRAMES
from tests.estimator.capture.test_folder import PERIOD_NS, make
from tests.estimator.hostile_json import hostile_text, write_text

#: Examples per fuzz test (SCET_FUZZ_EXAMPLES=3000 for a long run).
EXAMPLES = settings(max_examples=int(os.environ.get("SCET_FUZZ_EXAMPLES", 100)), deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    folder = tmp_path_factory.mktemp("capture_fuzz")
    make(folder, n=2)
    return folder, (folder / "capture.json").read_text(), (folder / "frames.jsonl").read_text()


def read_all(folder):
    try:
        cap = CaptureFolder(folder, size_px=(640, 480))
    except CaptureError as exc:
        assert str(folder) in str(exc)
        return None
    slots = list(cap.frames())
    assert len(slots) <= MAX_GAP_FRAMES + 2
    for s in slots:
        assert (s.image is None) == (s.reason is not None)
        assert s.image is None or (s.image.shape == (480, 640) and np.isfinite(s.image).all())
    return slots


@given(data=st.data())
@EXAMPLES
def test_fuzz_capture_header(capture, data):
    folder, header, lines = capture
    write_text(folder / "capture.json", hostile_text(data, json.loads(header)))
    (folder / "frames.jsonl").write_text(lines)
    read_all(folder)


@given(data=st.data())
@EXAMPLES
def test_fuzz_frame_lines(capture, data):
    folder, header, lines = capture
    (folder / "capture.json").write_text(header)
    first, second = lines.splitlines()
    write_text(folder / "frames.jsonl", first + "\n" + hostile_text(data, json.loads(second)) + "\n")
    read_all(folder)


@pytest.mark.parametrize("line, words", [
    ("[" * 100_000, "nested too deeply"),
    ('{"SensorTimestamp": ' + "1" * 5000 + "}", "cannot read JSON"),
])
def test_a_hostile_frame_line_is_left_out_with_its_reason(tmp_path, line, words):
    make(tmp_path, n=2)
    lines = (tmp_path / "frames.jsonl").read_text()
    (tmp_path / "frames.jsonl").write_text(lines + line + "\n")
    cap = CaptureFolder(tmp_path)
    assert len(cap.index) == 2 and any(words in p and "line 3" in p for p in cap.problems)


def test_a_time_stamp_far_beyond_the_frames_is_a_clock_jump_not_a_billion_drops(tmp_path):
    t0 = 1_000_000_000
    make(tmp_path, n=3, ts=[t0, t0 + PERIOD_NS, t0 + 10 ** 9 * PERIOD_NS])
    cap = CaptureFolder(tmp_path)
    assert sorted(cap.index) == [0, 1] and cap.dropped == []
    assert any("frame periods after the previous frame" in p and "clock jump" in p
               for p in cap.problems)
    assert len(list(cap.frames())) == 2


def test_a_timestamp_too_large_for_a_float_is_a_reasoned_problem(tmp_path):
    make(tmp_path, n=2)
    lines = (tmp_path / "frames.jsonl").read_text()
    (tmp_path / "frames.jsonl").write_text(lines + json.dumps({"SensorTimestamp": 10 ** 400}) + "\n")
    cap = CaptureFolder(tmp_path)
    assert len(cap.index) == 2 and any("'SensorTimestamp' must be" in p for p in cap.problems)
