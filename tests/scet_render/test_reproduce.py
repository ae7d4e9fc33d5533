"""The paper reproduction: a quick run end to end, determinism, and physical sanity checks."""

import re

import numpy as np
import pytest

from estimator.calibration import CORNEA_RADIUS_BOUNDS_M
from estimator.gaze import geometric_gaze
from estimator.metrics import angular_error_deg
from scet_render.reproduce import (
    ReproductionConfig,
    band_rows,
    calibration_trial,
    fit_center_radius,
    fit_orbit_prior,
    make_context,
    orbit_covariance,
    rows_mask,
    run_experiments,
    run_reproduction,
    trial_rng,
)
from scet_render.reproduce.paper_numbers import FIGURES
from scet_render.simulate import simulate_glints

HEADINGS = ("# SCET paper reproduction", "## Summary", "## Setup and protocol",
            "## Fig. 5: system geometric calibration (Sec. 3.1)", "## Sec. 3.2: geometric and polynomial gaze",
            "## Fig. 6: error over the screen", "## Fig. 7 and 8", "## Fig. 9: banding",
            "### Single lighting", "### Doubled lighting", "## Beating the paper",
            "## Solver check", "## Differences from the paper, and why")


@pytest.fixture(scope="module")
def ctx():
    return make_context()


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduction")
    calls = []
    path = run_reproduction(out, quick=True, seed=0, progress=lambda d, t, label: calls.append((d, t, label)))
    return path, path.read_text(encoding="utf-8"), calls


def _section(text, heading):
    """The text under ``heading`` up to the next heading of the same or a higher level."""
    start = text.index(heading)
    level = len(heading) - len(heading.lstrip("#"))
    pattern = re.compile(r"^#{1,%d} " % level, re.MULTILINE)
    nxt = pattern.search(text, start + len(heading))
    return text[start:nxt.start() if nxt else None]


def test_quick_run_writes_every_section(quick_run):
    path, text, _ = quick_run
    assert path.name == "paper-reproduction.md"
    for heading in HEADINGS:
        assert heading in text, heading


def test_quick_run_writes_every_figure(quick_run):
    path, text, _ = quick_run
    for name in FIGURES.values():
        png = path.parent / "figures" / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert f"figures/{name}" in text


def test_quick_run_numbers_are_finite_where_expected(quick_run):
    _, text, _ = quick_run
    for heading in ("## Summary", "## Sec. 3.2", "## Beating the paper", "## Solver check",
                    "## Fig. 5", "### Single lighting", "### Doubled lighting"):
        section = _section(text, heading)
        assert "n/a" not in section and "nan" not in section, heading
    # The claims against the paper, measured in the same run.
    beat = _section(text, "## Beating the paper")
    assert beat.count("PASS") == 3, beat


def test_quick_run_reports_progress(quick_run):
    _, _, calls = quick_run
    done = [d for d, _, _ in calls]
    assert done == list(range(1, len(calls) + 1)) and calls[-1][1] == len(calls)


def _same(a, b):
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, (np.ndarray, float, np.floating)):
        return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    return a == b


def _tiny(seed):
    return ReproductionConfig(True, seed, (0.5,), 1, 0, 2, 4, 1, (1.0,), 1, (20,))


def test_tiny_run_is_deterministic(ctx):
    assert _same(run_experiments(_tiny(3)), run_experiments(_tiny(3)))
    # ... and the seed matters.
    a, _ = calibration_trial(ctx, 0.5, trial_rng(3, 5, 0, 0), with_gaze=False)
    b, _ = calibration_trial(ctx, 0.5, trial_rng(4, 5, 0, 0), with_gaze=False)
    assert a["ce_ours_joint"] != b["ce_ours_joint"]


def test_geometric_gaze_with_ground_truth_is_exact_without_noise(ctx):
    obs = simulate_glints(ctx.arc, ctx.targets_grid, lights_world_m=ctx.true_lights(ctx.arc))
    est = geometric_gaze(ctx.arc, ctx.truth(), obs.glints_px, obs.visible)
    assert np.nanmax(angular_error_deg(est.point_m, ctx.targets_grid, ctx.eye_center)) < 1e-6


def test_calibration_is_exact_without_noise(ctx):
    row, _ = calibration_trial(ctx, 0.0, trial_rng(0, 5, 0, 0), with_gaze=False)
    for key in ("ce_ours_joint", "ce_paper_c_los", "ce_paper_cr_los", "ce_joint_lighting_los"):
        assert row[key] < 1e-5, key  # mm
    for key in ("light_paper", "light_joint_lighting", "light_ours_joint"):
        assert row[key] < 1e-5, key  # mm
    assert abs(row["rc_ours_joint"] - 7.8) < 1e-6


def test_center_radius_fit_recovers_the_cornea(ctx):
    arc = ctx.arc
    obs = simulate_glints(arc, ctx.targets25)
    C, R = fit_center_radius(arc.camera, arc.lights_world_m, obs.glints_px, obs.visible,
                             center0_m=arc.eye.cornea_center(0.0, 0.0), radius0_m=7.77e-3,
                             radius_bounds_m=CORNEA_RADIUS_BOUNDS_M)
    assert np.abs(R - arc.eye.cornea_radius_m).max() < 1e-9
    assert np.abs(C - obs.cornea_center_m).max() < 1e-9


def _orbit_args(ctx):
    cal = ctx.truth()
    return (ctx.arc.camera, cal.lights_world_m(ctx.arc.lights_world_m), cal.cornea_radius_m, cal.eye_center_m,
            cal.orbit_radius_m)


def test_orbit_fit_without_prior_matches_the_estimator(ctx):
    obs = simulate_glints(ctx.arc, ctx.targets_grid, noise_px=0.5, rng=np.random.default_rng(7),
                          lights_world_m=ctx.true_lights(ctx.arc))
    mask = rows_mask(obs.glints_true_px, obs.visible, *band_rows(20))
    B = len(mask)
    angles, held = fit_orbit_prior(*_orbit_args(ctx), obs.glints_px, mask, prior_mean_rad=np.full((B, 2), np.nan),
                                   prior_cov_rad2=np.full((B, 2, 2), np.nan), sigma_px=0.3)
    ref = geometric_gaze(ctx.arc, ctx.truth(), obs.glints_px, mask).angles_rad
    assert not held.any()
    assert np.nanmax(np.abs(angles - ref)) < 1e-8  # rad


def test_prior_holds_an_empty_band_and_tightens_a_sparse_one(ctx):
    obs = simulate_glints(ctx.arc, ctx.targets_grid[:40], noise_px=0.5, rng=np.random.default_rng(8),
                          lights_world_m=ctx.true_lights(ctx.arc))
    truth = np.column_stack([obs.yaw_rad, obs.pitch_rad])
    one = np.zeros(obs.visible.shape, dtype=bool)
    one[np.arange(40), np.argmax(obs.visible, axis=1)] = True  # one glint per sample
    one[20:] = False  # the last 20 samples see no glint at all
    prior_cov = orbit_covariance(*_orbit_args(ctx), truth, obs.visible, 0.3)
    assert np.isfinite(prior_cov).all() and (np.linalg.eigvalsh(prior_cov) > 0).all()
    angles, held = fit_orbit_prior(*_orbit_args(ctx), obs.glints_px, one, prior_mean_rad=truth,
                                   prior_cov_rad2=prior_cov, sigma_px=0.3)
    assert held[20:].all() and not held[:20].any()
    assert np.array_equal(angles[20:], truth[20:])
    # With no glint and no prior there is nothing to estimate.
    nan_prior = np.full((40, 2), np.nan), np.full((40, 2, 2), np.nan)
    none, _ = fit_orbit_prior(*_orbit_args(ctx), obs.glints_px, one, prior_mean_rad=nan_prior[0],
                              prior_cov_rad2=nan_prior[1], sigma_px=0.3)
    assert np.isnan(none[20:]).all() and np.isfinite(none[:20]).all()
    # One glint and the prior: closer to the truth than the prior's own spread.
    err = np.abs(angles[:20] - truth[:20])
    assert (err < 3 * np.sqrt(np.diagonal(prior_cov[:20], axis1=1, axis2=2))).all()


def test_central_band_rows():
    assert band_rows(1) == (0.0, 480.0)
    assert band_rows(20) == (228.0, 252.0)
    first, stop = band_rows(16)
    assert stop - first == 30 and re.fullmatch(r"\d+\.0", str(first))
