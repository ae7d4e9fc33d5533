"""What `scet calibrate` checks: single-pulse timing of the folder, and the plausibility of the
fitted calibration (estimator.calibration.checks), recorded in the calibration file."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from estimator.banding import calibration_setup, strobe_setup
from estimator.calibration import (
    CORNEA_RADIUS_BOUNDS_M,
    POSE_BOUND_M,
    Calibration,
    LightingFit,
    OrbitFit,
    calibration_warnings,
    pose_correction,
)
from estimator.folders import FolderTiming, check_single_pulse
from estimator.tracker import TrackerInputError


def _fit(r_c=7.8e-3, rotvec=(0.0, 0.0, 0.0), shift=(0.0, 0.0, 0.0), rms=0.2, converged=True):
    w, t, pivot = np.array(rotvec), np.array(shift), np.zeros(3)
    return LightingFit(pose_correction(w, t, pivot), w, t, pivot, r_c, math.nan, np.zeros((25, 3)),
                       np.full(25, r_c), rms, "joint_targets", converged)


def _timing(frames=(0, 1, 2)):
    return FolderTiming({f: f * 0.016636 for f in frames}, None, None, Path("timing.json"))


def test_a_plausible_calibration_has_no_warning():
    orbit = OrbitFit(np.zeros(3), 4.25e-3, 1e-6, 10, "joint")
    assert calibration_warnings(_fit(), orbit, frames_used=25, frames_total=25) == []


@pytest.mark.parametrize("r_c_mm, words", [(7.274, "outside the central 95 %"),
                                           (8.3, "outside the central 95 %"),
                                           (CORNEA_RADIUS_BOUNDS_M[0] * 1e3, "solver's bound"),
                                           (float("nan"), "not finite")])
def test_the_corneal_radius_is_checked_against_read_et_al(r_c_mm, words):
    # 7.274 mm is what banded frames gave for a 7.8 mm eye (issue 19).
    (warning,) = calibration_warnings(_fit(r_c=r_c_mm * 1e-3))
    assert words in warning


def test_a_lighting_far_from_the_scene_is_flagged():
    # 3 mm is more than half the 5 mm the fit may move the rig; 1 mm is not.
    assert calibration_warnings(_fit(shift=(1e-3, 0.0, 0.0))) == []
    (warning,) = calibration_warnings(_fit(shift=(3e-3, 0.0, 0.0)))
    assert "far from the nominal pose" in warning and "3.00 mm" in warning
    (warning,) = calibration_warnings(_fit(shift=(POSE_BOUND_M, 0.0, 0.0)))
    assert "at the bound" in warning
    (warning,) = calibration_warnings(_fit(rotvec=(math.radians(3.0), 0.0, 0.0)))
    assert "3.00 deg" in warning


def test_residuals_frames_and_orbit_are_checked():
    assert "RMS" in calibration_warnings(_fit(rms=1.5))[0]
    assert "evaluation limit" in calibration_warnings(_fit(converged=False))[0]
    assert "14 of 25" in calibration_warnings(_fit(), frames_used=14, frames_total=25)[0]
    orbit = OrbitFit(np.zeros(3), 10e-3, 1e-6, 10, "joint")  # at ORBIT_RADIUS_BOUNDS_M[1]
    assert "r_co" in calibration_warnings(_fit(), orbit)[0]


def test_the_quality_is_written_to_the_calibration_file():
    cal = Calibration(cornea_radius_m=7.7e-3).with_quality(
        rms_px=0.3, frames_used=9, frames_total=9, warnings=["r_c = 7.274 mm ..."])
    back = Calibration.from_json(cal.to_json())
    assert back.quality == cal.quality and back.warnings == ["r_c = 7.274 mm ..."]
    # Files written before the quality record read as a calibration without warnings.
    doc = cal.to_dict()
    del doc["quality"]
    assert Calibration.from_dict(doc).warnings == []


def test_single_pulse_timing_passes(setup):
    check_single_pulse("cal", calibration_setup(setup), _timing())


@pytest.mark.parametrize("pulses", [4, 16])
def test_banded_frames_are_refused_with_how_to_make_calibration_frames(setup, pulses):
    with pytest.raises(TrackerInputError, match="frames are banded") as err:
        check_single_pulse("test", strobe_setup(setup, pulses), _timing())
    assert "scet render SCENE --calibration" in str(err.value)


def test_one_pulse_that_lights_only_a_band_is_refused(setup):
    # One pulse per frame with the scene's 1 ms exposure lights a band of rows, not the frame.
    one = replace(setup, strobe=replace(setup.strobe, pulses_per_frame=1,
                                        period_s=setup.sensor.frame_period_s))
    with pytest.raises(TrackerInputError, match="lights only"):
        check_single_pulse("one", one, _timing())
