"""Measuring a capture's timing (issue 13, part 1) on captures the measurement is not told the
truth of: static scenes composed with the production row weights (tests/.../banded.py)."""

import json
import math

import numpy as np
import pytest

from estimator.capture import CaptureError
from estimator.capture.timing import measure_capture

from .banded import make_capture

FRAMES = 60


def check(m, sensor, strobe, ppm):
    line_s = sensor.frame_period_s / sensor.total_lines
    # The accuracy: S within 0.5 line, exposure within one line, clock within 20 ppm;
    # and honest SDs: the truth within 3 of them.
    assert abs(m.total_lines - sensor.total_lines) < 0.5
    assert abs(m.total_lines - sensor.total_lines) < 3 * m.total_lines_sd
    assert abs(m.exposure_s - sensor.exposure_s) < line_s
    assert abs(m.exposure_s - sensor.exposure_s) < 3 * m.exposure_s_sd
    # the pulse is only ~1 line: within a third of a line, and its SD honest
    assert abs(m.pulse_s - strobe.pulse_s) < line_s / 3
    assert abs(m.pulse_s - strobe.pulse_s) < 3 * m.pulse_s_sd
    assert abs(m.clock_ppm - ppm) < 20
    assert abs(m.clock_ppm - ppm) < 3 * m.clock_ppm_sd
    # frame n's phase: the first onset after its first readout, modulo the true period
    per = strobe.period_s
    for n, ph in enumerate(m.phase_s[:: 17]):
        true = (strobe.phase_s + (17 * n) * (strobe.pulses_per_frame * per
                                             - sensor.frame_period_s)) % per
        err = (ph - true + per / 2) % per - per / 2
        assert abs(err) < 0.2 * line_s  # a fifth of a line (a few µs)


@pytest.mark.parametrize("S,ppm", [(524, 0.0), (786, -2000.0)])
def test_measures_S_exposure_phase_and_clock(tmp_path, S, ppm):
    sensor, strobe = make_capture(tmp_path / "c", S=S, ppm=ppm, phase_s=2e-4, frames=FRAMES)
    m = measure_capture(tmp_path / "c")
    check(m, sensor, strobe, ppm)
    assert len(m.phase_s) == FRAMES and not m.notes


@pytest.mark.slow
@pytest.mark.parametrize("S,ppm", [(524, 300.0), (524, -300.0), (786, 0.0), (524, -2000.0)])
def test_measures_more_mismatches(tmp_path, S, ppm):
    sensor, strobe = make_capture(tmp_path / "c", S=S, ppm=ppm, phase_s=5e-4, frames=FRAMES)
    check(measure_capture(tmp_path / "c"), sensor, strobe, ppm)


def test_too_few_frames_for_drift_is_reported(tmp_path):
    sensor, _ = make_capture(tmp_path / "c", S=524, frames=2)
    m = measure_capture(tmp_path / "c")
    assert math.isnan(m.clock_ppm) and "too few for the drift" in m.notes[0]
    # S from the nominal clock only: right here, but its SD admits the resonator's 3,000 ppm
    assert abs(m.total_lines - 524) < 0.5 and m.total_lines_sd > 1.0
    assert json.loads(json.dumps(m.to_dict()))["clock_ppm"] is None


def test_dark_and_calibration_frames_are_recognised(tmp_path):
    make_capture(tmp_path / "dark", S=524, frames=3, level=0.0)
    with pytest.raises(CaptureError, match=r"no frame with bands.*3 dark"):
        measure_capture(tmp_path / "dark")
    # single pulse, exposure 0.9 of the frame: the whole frame lit by one pulse
    make_capture(tmp_path / "cal", S=524, frames=3, single=True, exposure_s=0.9 / 60)
    with pytest.raises(CaptureError, match=r"3 whole frame"):
        measure_capture(tmp_path / "cal")
    # single pulse, short exposure: one band
    make_capture(tmp_path / "one", S=524, frames=3, single=True, phase_s=4e-3)
    with pytest.raises(CaptureError, match=r"3 single band"):
        measure_capture(tmp_path / "one")


def test_saturated_frames_are_flagged(tmp_path):
    make_capture(tmp_path / "c", S=524, frames=4, level=8.0)
    with pytest.raises(CaptureError, match=r"4 saturated"):
        measure_capture(tmp_path / "c")


def test_no_strobe_settings(tmp_path):
    make_capture(tmp_path / "c", S=524, frames=3)
    head = tmp_path / "c" / "capture.json"
    doc = json.loads(head.read_text())
    doc["strobe"] = None
    head.write_text(json.dumps(doc))
    with pytest.raises(CaptureError, match=r"capture.json: key 'strobe'"):
        measure_capture(tmp_path / "c")


def test_many_bright_glints_do_not_hide_the_bands(tmp_path):
    # Glints on an arc of ~60 rows at 700 DN over skin at ~45 DN, as a rendered eye's: the
    # row profile clips them (GLINT_CLIP_FACTOR), which must leave the bands' shape intact.
    # (Rendered 320x240 frames, which failed the band fit before the clip, are measured in
    # tests/scet_render/test_compare.py; this smooth synthetic scene passes either way.)
    from .banded import scene_image

    rng = np.random.default_rng(4)
    img = 0.25 * scene_image(640, 480, seed=2)
    y, x = np.mgrid[0:480, 0:640].astype(np.float64)
    for _ in range(60):  # the ring of lights: glints on an arc across ~60 rows
        a = rng.uniform(0, np.pi)
        gx, gy = 320 + 120 * np.cos(a), 200 + 60 * np.sin(a)
        img += 700 * np.exp(-((x - gx) ** 2 + (y - gy) ** 2) / 3.0)
    sensor, strobe = make_capture(tmp_path / "c", S=524, frames=6, image=np.minimum(img, 900),
                                  phase_s=2e-4)
    m = measure_capture(tmp_path / "c")
    line_s = sensor.frame_period_s / sensor.total_lines
    assert abs(m.total_lines - 524) < 0.5  # the half a line
    assert abs(m.exposure_s - sensor.exposure_s) < line_s  # the one line

