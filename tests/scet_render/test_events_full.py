"""The full event study's parts (issue 34): band instants with the blanking gap, the
sample-level simulation against the rendered validation's valid shares, the scorer by hand,
and the band detector on a short simulated stream."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.events import detect_events
from estimator.scene import load_scene
from scet_render.study.events_score import (match_events, pool, poisson_rate, summarise,
                                            truth_events, wilson, Truth)
from scet_render.study.events_sim import (StreamSetting, band_instants, band_setting,
                                          simulate_stream, study_trajectory)

DESIGNED = "scenes/paper_sim_designed.toml"


@pytest.fixture(scope="module")
def designed():
    return load_scene(DESIGNED)


@pytest.fixture(scope="module")
def trajectory(designed):
    return study_trajectory(designed, 12, 6, seed=3)


@pytest.mark.parametrize("S, gap_ms", [(786, (6.0, 8.0)), (524, (1.0, 2.5))])
def test_band_instants_leave_the_blanking_gap(designed, S, gap_ms):
    st = band_setting("x", designed, 16, S, 0.0).setup
    t, first, last = band_instants(st, 0.2)
    gaps = np.diff(t) * 1e3
    # the invisible lines (S - N) / S of the 16.6 ms frame, plus the band period around them
    assert gap_ms[0] < gaps.max() < gap_ms[1]
    assert np.median(gaps) == pytest.approx(1e3 * st.strobe.period_s, rel=1e-6)
    assert (first <= last).all() and (last >= 0).all() and (first < 480).all()


def test_noise_free_all_valid_stream_is_the_trajectory(designed, trajectory):
    st = band_setting("clean", designed, 16, 524, 0.0, invalid_bands=False)
    t, pos = simulate_stream(st, trajectory, 1.0, seed=0)
    yaw, pitch = trajectory.angles_at(t)
    np.testing.assert_allclose(pos, np.degrees(np.column_stack([yaw, pitch])), atol=1e-12)


@pytest.mark.parametrize("scene, rendered_valid", [("paper_sim", 0.488), (DESIGNED, 0.849)])
def test_simulated_valid_share_near_the_rendered_validation(trajectory, scene, rendered_valid):
    """reports/full/validation.md and reports/design/..._full: rendered geometric samples valid
    at 16 pulses, S = 786 (fixations on the 24 x 15 grid): 48.8 % current, 84.9 % designed.
    The simulation's band validity (>= 5 glints in the band's rows, or a prior within
    1.25 ms) on the study's trajectory must land within 12 points (the trajectories differ:
    the validation's grid reaches the screen's corners)."""
    setup = load_scene(scene)
    st = band_setting("v", setup, 16, 786, 0.0)
    _, pos = simulate_stream(st, trajectory, trajectory.duration_s, seed=0)
    share = np.isfinite(pos).all(axis=1).mean()
    assert abs(share - rendered_valid) < 0.12, share


def test_scorer_by_hand():
    truth = Truth(np.array([1.0, 2.0, 3.0]), np.array([1.04, 2.03, 3.02]),
                  np.array([10.0, 2.5, 0.5]), np.array([300.0, 120.0, 30.0]))
    m = match_events([1.001, 2.5, 2.998], [1.042, 2.55, 3.03], [9.9, 1.0, 0.5],
                     [291.0, 50.0, 30.0], truth, 0.0005, 0.0, 4.0)
    assert list(m.match) == [0, -1, 2] and m.n_false == 1
    s = summarise(m)
    assert s["detected_1deg"][0] == pytest.approx(50.0)
    assert s["onset_mae_ms"][0] == pytest.approx(1.0)
    assert s["offset_mae_ms"][0] == pytest.approx(2.0)
    assert s["peak_rel_err_pct"][0] == pytest.approx(3.0)
    assert s["micro_detected"][0] == pytest.approx(100.0)
    assert s["false_per_min"][0] == pytest.approx(1 / ((4.0 - 0.1) / 60))


def test_pooled_streams_score_as_one():
    """Two streams scored apart and pooled: the pooled measures are those of all their events
    together (each stream's matches kept to its own detections)."""
    truth = Truth(np.array([1.0, 2.0, 3.0]), np.array([1.04, 2.03, 3.02]),
                  np.array([10.0, 2.5, 0.5]), np.array([300.0, 120.0, 30.0]))
    a = match_events([1.001, 2.5, 2.998], [1.042, 2.55, 3.03], [9.9, 1.0, 0.5],
                     [291.0, 50.0, 30.0], truth, 0.0005, 0.0, 4.0)
    b = match_events([0.997, 2.003], [1.04, 2.03], [10.0, 2.5], [300.0, 126.0], truth,
                     0.0005, 0.0, 4.0)
    m = pool([a, b])
    assert m.n_false == 1 and m.minutes == pytest.approx(2 * (4.0 - 0.1) / 60)
    assert list(m.match) == [0, -1, 2, 3, 4, -1]
    s = summarise(m)
    assert s["detected_1deg"][0] == pytest.approx(75.0)  # 3 of the 4 >= 1 deg
    assert s["onset_mae_ms"][0] == pytest.approx((1.0 + 3.0 + 3.0) / 3)
    assert s["peak_rel_err_pct"][0] == pytest.approx((3.0 + 0.0 + 5.0) / 3)
    assert s["false_per_min"][0] == pytest.approx(1 / m.minutes)


def test_intervals_known_values():
    # Wilson 0 of 10: upper z^2 / (n + z^2) = 0.2775; Garwood 0 events: upper 3.689
    assert wilson(0, 10)[2] == pytest.approx(0.27753, abs=1e-4)
    assert wilson(10, 10)[1] == pytest.approx(1 - 0.27753, abs=1e-4)
    assert poisson_rate(0, 1.0)[2] == pytest.approx(3.6889, abs=1e-3)
    lo, hi = poisson_rate(10, 2.0)[1:]
    assert lo == pytest.approx(4.7954 / 2, abs=1e-3) and hi == pytest.approx(18.3904 / 2, abs=1e-3)


def test_band_detector_on_a_simulated_goal_stream(designed):
    """Designed lighting, 16 pulses, S = 524, the rendered validation's per-sample noise, 40
    saccades: every one >= 1 deg found, onsets within 1.5 ms on average (the issue's goal is a
    1 ms mean over hundreds, which the study reports with its interval) and each within its
    stated uncertainty + 5 ms (the 3-SD boundary is crossed up to ~2 ms into the 12-ms
    accelerations of the largest saccades, and invalid bands beside an onset add more)."""
    traj = study_trajectory(designed, 40, 6, seed=3)
    st = band_setting("goal", designed, 16, 524, 0.018 / math.sqrt(math.pi / 2))
    t, pos = simulate_stream(st, traj, traj.duration_s, seed=0)
    ev = detect_events(t, pos)
    truth = truth_events(traj, t[0], t[-1])
    m = match_events(ev.onset_s, ev.offset_s, ev.amplitude_deg, ev.peak_velocity_deg_s, truth,
                     0.5e-3, t[0], t[-1])
    big = truth.amplitude_deg >= 1.0
    assert big.sum() >= 30 and (m.match[big] >= 0).all()
    j = m.match[big]
    err = np.abs(m.onset_s[j] - truth.onset_s[big])
    assert err.mean() < 1.5e-3, err.mean()
    assert (err <= ev.onset_uncertainty_s[j] + 5e-3).all(), err
    assert (ev.onset_s[1:] >= ev.offset_s[:-1]).all()  # events never overlap
    uniform = StreamSetting("1k", "uniform", designed, 0.0)
    t1, _ = simulate_stream(uniform, traj, 0.5, seed=0)
    np.testing.assert_allclose(np.diff(t1), 1e-3, atol=1e-12)


def test_simulation_is_deterministic_for_a_seed(designed, trajectory):
    st = band_setting("det", designed, 8, 786, 0.01)
    a = simulate_stream(st, trajectory, 0.5, seed=5)[1]
    b = simulate_stream(st, trajectory, 0.5, seed=5)[1]
    c = simulate_stream(st, trajectory, 0.5, seed=6)[1]
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(np.nan_to_num(a), np.nan_to_num(c))


@pytest.mark.parametrize("seed", range(9))
def test_study_trajectories_stay_on_the_screen(designed, seed):
    """The lighting is designed for gazes at the screen (scet design-lights' poses span it):
    the study's trajectories (200 saccades of 0.5-20 deg, 100 microsaccades) keep the gaze on
    it at every instant, fixational drift included. The earlier rule (mirrored once) left it
    (seed 2: 33 % of the time on it, reports/events.md)."""
    from scet_render.study.events_sim import on_screen_mask

    traj = study_trajectory(designed, 200, 100, seed)
    t = np.arange(0.0, traj.duration_s, 2e-3)
    assert on_screen_mask(designed, traj, t).all()
    if seed == 2:
        old = study_trajectory(designed, 200, 100, seed, keep_on_screen=False)
        assert on_screen_mask(designed, old, t).mean() < 0.5
    # the amplitudes are the drawn ones: none lost to the screen's edges
    amp = np.degrees(np.asarray(traj.amplitude_rad)[np.asarray(traj.kind) != 0])
    assert amp.size == 300 and amp.max() <= 20.0 + 0.5 and np.sum(amp >= 1.0) > 180


def test_a_screen_too_small_for_the_saccades_is_an_error(designed):
    from dataclasses import replace

    tiny = replace(designed, screen=replace(designed.screen, x_range_m=(-0.05, 0.05),
                                            y_range_m=(-0.05, 0.05)))
    with pytest.raises(ValueError, match="paper_sim_designed: no direction keeps a"):
        study_trajectory(tiny, 20, 0, seed=0)


def test_band_agreement_counts_each_band_once_by_its_instant():
    """The rendered and simulated validity are compared at the same instants (within 1 us),
    a rendered instant the simulation lacks is left out, and the bands valid only in the
    simulation carry the tracker's reasons."""
    from scet_render.study.events_full import band_agreement

    t = np.array([0.0010, 0.0020, 0.0030, 0.0040, 0.0050, 0.0061])
    ok_r = np.array([True, False, True, False, False, True])
    ts = np.array([0.0000, 0.0010 + 2e-7, 0.0020, 0.0030, 0.0040, 0.0050])  # no 6.1 ms
    ok_s = np.array([True, True, True, False, True, False])
    reasons = ["ok", "match_ambiguous", "ok", "band_out_of_reach", "match_ambiguous", "ok"]
    a = band_agreement(t, ok_r, ts, ok_s, reasons)
    assert a["bands"] == 5
    assert (a["both"], a["rendered only"], a["simulated only"], a["neither"]) == (1, 1, 2, 1)
    assert a["simulated only, reasons"] == [("match_ambiguous", 1), ("band_out_of_reach", 1)]


def test_agreement_text_gives_the_four_cases_as_shares_of_the_bands():
    from scet_render.study.events_full_report import agreement_text

    a = {"bands": 200, "both": 150, "rendered only": 10, "simulated only": 30, "neither": 10,
         "simulated only, reasons": [("match_ambiguous", 20), ("band_out_of_reach", 10)]}
    text = agreement_text({"agreement": a})
    assert "| rendered valid | 150 (75.0 %) | 10 (5.0 %) |" in text
    assert "| rendered invalid | 30 (15.0 %) | 10 (5.0 %) |" in text
    assert "match_ambiguous 20, band_out_of_reach 10" in text
    assert agreement_text(None) == "" and agreement_text({"agreement": None}) == ""


def test_residuals_by_speed_draw_each_error_from_its_own_speed_band(designed):
    """The third twin's errors come from valid samples of the same eye-speed band: errors
    planted as 0.01 deg in fixation and 0.3 deg above 300 deg/s come back in the same bands,
    and an invalid sample stays NaN."""
    from scet_render.dataset import dataset_trajectory
    from scet_render.study.events_errors import residuals_by_speed

    traj = dataset_trajectory(designed, "saccades", 60, 0)
    t = np.arange(0.0, 0.9, 0.001)
    y, p = traj.angles_at(t)
    truth = np.degrees(np.column_stack([y, p]))
    h = 1e-4
    y0, p0 = traj.angles_at(t - h)
    y1, p1 = traj.angles_at(t + h)
    speed = np.degrees(np.hypot(y1 - y0, p1 - p0)) / (2 * h)
    fast = speed >= 300
    assert fast.sum() >= 10 and (speed < 30).sum() >= 100
    planted = np.where(fast[:, None], 0.3, 0.01) * np.array([1.0, 0.0])
    ok = np.ones(t.size, dtype=bool)
    ok[5] = False
    pos = truth + planted
    out = residuals_by_speed(traj, t, pos, truth, ok, np.random.default_rng(0))
    err = out - truth + np.median(planted[ok], axis=0)
    assert np.isnan(out[5]).all()
    assert np.allclose(err[fast & ok], [0.3, 0.0], atol=1e-9)
    assert np.allclose(err[(speed < 30) & ok], [0.01, 0.0], atol=1e-9)


def test_rendered_errors_table_marks_each_value_against_its_goal():
    from scet_render.study.events_errors import rendered_errors_table

    summ = {"detected_1deg": (100.0, 98.5, 100.0), "false_per_min": (2.0, 0.5, 5.0),
            "onset_mae_ms": (0.9, 0.8, 0.95), "offset_mae_ms": (1.1, 1.0, 1.2),
            "peak_rel_err_pct": (2.5, 2.3, 2.8), "micro_detected": (97.0, 93.0, 99.0)}
    from scet_render.study.events_full_report import DET_NAMES, _met

    text = rendered_errors_table({"goal with rendered errors": {"scet": {"rendered errors": summ}}},
                                 DET_NAMES, _met)
    row = next(line for line in text.splitlines() if line.startswith("| band detector"))
    assert "rendered errors" in row and row.count("**no**") == 2  # false events, offset
    assert rendered_errors_table(None, DET_NAMES, _met) == ""
