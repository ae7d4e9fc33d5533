"""Glints cut by a lash: the expected-flux model, its calibration file key, the flag and the
band done again without the flagged glints (estimator.calibration.flux,
estimator.tracking.cut_glints, Tracker.band)."""

import json
from dataclasses import replace

import numpy as np
import pytest

import estimator.tracking.cut_glints as cut_glints
import estimator.matching.kernels as match_kernels
from estimator.banding import band_rows
from estimator.calibration import Calibration, GlintFlux, fit_glint_flux, model_flux
from estimator.calibration.flux import fresnel_reflectance
from estimator.errors import InputError
from estimator.gaze import polynomial_gaze
from estimator.geometry import project_glints
from estimator.scene import load_scene
from estimator.tracking import (MIN_GLINTS, StreamState, Tracker, read_samples_csv,
                                write_samples_csv)
from tests.estimator.simulated import ground_truth_calibration
from tests.estimator.test_tracker import draw_frame
from tests.tolerances import TOL


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


def test_fresnel_at_normal_and_grazing_incidence():
    n = 1.376
    assert fresnel_reflectance(1.0) == pytest.approx(((n - 1) / (n + 1)) ** 2, rel=1e-12)
    assert fresnel_reflectance(1e-9) == pytest.approx(1.0, abs=1e-6)
    # The glints' 40-55 deg incidence: 0.030-0.050, rising with the angle.
    f = fresnel_reflectance(np.cos(np.radians([40.0, 55.0])))
    assert 0.028 < f[0] < f[1] < 0.06


def test_model_is_the_far_field_mirror_law_far_from_the_cornea(setup):
    cam = setup.camera
    r = 7.8e-3
    center = cam.position_m + 10.0 * cam.optical_axis  # camera and light metres away
    light = center + np.array([0.0, 10.0, 0.0])
    g, vis = project_glints(cam, center, r, light[None])
    assert vis[0]
    m = model_flux(cam, center, r, light[None], g, "constant")[0]
    # At 10 m the vergence terms are r / d ~ 1e-3 of the far-field r² / (4 d_L² d_C²).
    d_c = np.linalg.norm(center - cam.position_m) - r  # nearly: the glint is r from the centre
    far = r ** 2 / (4.0 * np.linalg.norm(light - center) ** 2 * d_c ** 2)
    assert m == pytest.approx(far, rel=3e-3)


def _glint_flux(setup, cal, log_sd=0.1, noise_px=0.2):
    return GlintFlux(np.zeros(setup.lights.count), "dielectric", log_sd, noise_px)


@pytest.fixture(scope="module")
def band(setup):
    """A sample of a clean drawn frame (the flag off) and its band's detections."""
    cal = ground_truth_calibration(setup)
    cal = replace(cal, glint_flux=_glint_flux(setup, cal))
    rng = np.random.default_rng(3)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    tr = Tracker(setup, cal, "polynomial", flag_cut_glints=False)
    for f in range(3):
        out = tr.process(draw_frame(setup, f, float(yaw[0]), float(pitch[0]), rng), f)
        ok = [s for s in out if s.ok and not s.prior_assisted and s.n_glints >= MIN_GLINTS + 2]
        if ok:
            return tr, cal, ok[0]
    pytest.fail("no dense band in the drawn frames")


def _expected(tr, cal, sample):
    return cal.glint_flux.expected(tr.setup.camera, sample.cornea_center_m, cal.cornea_radius_m,
                                   tr.context.problems.center.lights_world_m, sample.light_index,
                                   sample.glints_px)


def _flagged(tr, cal, sample, flux):
    # The band's detections: the sample's glints among others (their order shuffled).
    rng = np.random.default_rng(0)
    g = np.concatenate([sample.glints_px, rng.uniform(0, 400, (5, 2))])
    f = np.concatenate([flux, rng.uniform(1, 9, 5)])
    order = rng.permutation(g.shape[0])
    return cut_glints.flagged(cal, tr.setup.camera, tr.context.problems.center.lights_world_m, sample,
                              g[order], f[order])


@pytest.mark.skipif(not match_kernels.ENABLED, reason="Numba is not installed")
def test_compiled_log_ratios_are_the_numpy_model(band):
    tr, cal, sample = band
    flux = _expected(tr, cal, sample) * np.exp(np.linspace(-1.0, 1.0, sample.n_glints))
    cam = tr.setup.camera
    for fresnel in ("dielectric", "constant"):
        gf = GlintFlux(np.linspace(-2, 2, tr.setup.lights.count), fresnel, 0.1, 0.2)
        want = np.log(flux / gf.expected(cam, sample.cornea_center_m, cal.cornea_radius_m,
                                         tr.context.problems.center.lights_world_m,
                                         sample.light_index, sample.glints_px))
        got = cut_glints.log_ratios(
            cam.position_m, cam.rotation, np.array([cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px]),
            sample.cornea_center_m, cal.cornea_radius_m, tr.context.problems.center.lights_world_m,
            sample.light_index, sample.glints_px, sample.glints_px[::-1], flux[::-1],
            gf.log_power, fresnel == "dielectric", 1.376)
        assert np.allclose(got, want, rtol=0, atol=1e-12)


def _cut(sample, i, shift_px):
    """``sample`` with its glint i moved by ``shift_px`` along u (where a lash moves it)."""
    g = sample.glints_px.copy()
    g[i, 0] += shift_px
    return replace(sample, glints_px=g)


def _band_of(tr, sample):
    """(pulse, (first row, last row)) of ``sample``'s band."""
    pulses, _, first, last = band_rows(tr.setup.sensor, tr.setup.strobe, sample.frame_index)
    k = list(pulses).index(sample.strobe_index)
    return int(pulses[k]), (int(first[k]), int(last[k]))



def _flagged_and_reference(tr, sample, g, flux, drop, time_s=None):
    """The band of detections g with flux, the flag on, from ``tr``'s present state; the same
    band without the detections ``drop`` (bool) and the flag off, from the same state; and the
    tracker state after each."""
    band, t = _band_of(tr, sample), sample.time_s if time_s is None else time_s
    before = tr.state
    out = tr.band(sample.frame_index, g, band, t, flux)
    after = tr.state
    tr.state = before
    ref = tr.band(sample.frame_index, g[~drop], band, t)
    ref_after = tr.state
    tr.state = before
    return out, after, ref, ref_after


def _same_state(a, b, atol=0.0):
    """Stream states a and b equal, or within ``atol`` (rotations in rad, centres in m;
    covariances to a relative 1e3 x atol)."""
    assert (a.last is None) == (b.last is None)
    if a.last is not None:
        assert a.last.time_s == b.last.time_s
        assert np.allclose(a.last.angles_rad, b.last.angles_rad, rtol=0, atol=atol)
        assert np.allclose(a.last.cov_rad2, b.last.cov_rad2, rtol=1e3 * atol, atol=0)
    for x, y in ((a.prior_angles_rad, b.prior_angles_rad), (a.start, b.start),
                 (a.velocity_rad_s, b.velocity_rad_s)):
        assert (x is None and y is None) or np.allclose(x, y, rtol=0, atol=atol)


def test_a_dim_displaced_glint_is_flagged_and_the_band_done_again_without_it(band):
    tr, cal, clean = band
    sample = _cut(clean, 2, 0.6)  # 3 x the calibration's 0.2 px
    flux = _expected(tr, cal, sample)
    flux[2] *= 0.5  # log 0.5 = -0.69, beyond 2 x 0.1
    bad = _flagged(tr, cal, sample, flux)
    assert bad.tolist() == [i == 2 for i in range(sample.n_glints)]
    out, after, ref, ref_after = _flagged_and_reference(tr, sample, sample.glints_px, flux, bad)
    assert out.ok and ref.ok and not out.prior_assisted
    assert out.flux_flagged.tolist() == [int(sample.light_index[2])]
    assert sample.light_index[2] not in out.light_index
    # The sample and the prior the next band gets are those of the band without the cut glint:
    # the same glints and lights, fitted from another start (the first pass's rotation), so
    # equal to the fits' stopping error (TOL.refit_center_m; measured 2e-12 m on the screen
    # with the numpy LM, 1e-15 m compiled; 4e-13 rad). The screen point moves by about the
    # screen distance over r_co times the centre; rotations by the centre over r_co.
    r_co = cal.orbit_radius_m
    gain = abs(tr.setup.screen.z_m) / r_co
    assert out.light_index.tolist() == ref.light_index.tolist()
    assert np.allclose(out.screen_xy_m, ref.screen_xy_m, rtol=0, atol=TOL.refit_center_m * gain)
    assert np.allclose(out.cornea_center_m, ref.cornea_center_m, rtol=0, atol=TOL.refit_center_m)
    _same_state(after, ref_after, atol=TOL.refit_center_m / r_co)
    keep = ~bad
    glints = tr.context.band_glints(sample.glints_px[keep], sample.light_index[keep])
    est = polynomial_gaze(tr.setup, cal, glints, mapping=tr.mapping,
                          start=out.cornea_center_m, problems=tr.context.problems)
    assert np.allclose(out.cornea_center_m, est.cornea_center_m[0], rtol=0,
                       atol=TOL.refit_center_m)


def test_a_band_done_again_counts_once_and_follows_from_the_first_pass(band):
    tr, cal, clean = band
    sample = _cut(clean, 2, 0.6)
    flux = _expected(tr, cal, sample)
    flux[2] *= 0.5
    before, counts = tr.state, dict(tr.counts)
    tr.state = StreamState()  # a cold band: the first pass searches
    try:
        out = tr.band(sample.frame_index, sample.glints_px, _band_of(tr, sample), sample.time_s,
                      flux)
    finally:
        tr.state = before
    assert out.ok and out.flux_flagged.size == 1
    got = {k: tr.counts[k] - counts[k] for k in counts}
    # Searched once, then identified again by the cheap path from the first pass's rotation;
    # counted as one band, of the second pass's path.
    assert got == {"cheap": 1, "search": 0, "unfillable": 0, "again": 1}


def test_a_prior_assisted_band_is_fitted_again_with_its_prior(band):
    tr, cal, clean = band
    # Four glints, fewer than the tracker fits on their own: the band takes the prior.
    k = MIN_GLINTS - 1
    four = replace(_cut(clean, 2, 1.0), glints_px=_cut(clean, 2, 1.0).glints_px[:k],
                   light_index=clean.light_index[:k], confidence=clean.confidence[:k])
    flux = _expected(tr, cal, four)
    flux[2] *= 0.4
    t = tr.state.last.time_s + 1.0e-3  # the next band, 1 ms after the stream's last sample
    drop = np.arange(k) == 2
    out, after, ref, ref_after = _flagged_and_reference(tr, four, four.glints_px, flux, drop, t)
    assert out.ok and out.prior_assisted and ref.prior_assisted
    assert out.flux_flagged.tolist() == [int(clean.light_index[2])]
    assert out.light_index.tolist() == ref.light_index.tolist() and out.n_glints == k - 1
    assert np.array_equal(out.screen_xy_m, ref.screen_xy_m)
    _same_state(after, ref_after)


def test_too_few_glints_left_without_a_prior_is_a_nan_sample_with_a_reason(band):
    tr, cal, sample = band
    before = tr.state
    tr.state = StreamState()
    try:
        flux = _expected(tr, cal, sample)
        g = sample.glints_px.copy()
        many = np.arange(sample.n_glints) >= MIN_GLINTS - 1  # all but MIN_GLINTS - 1 cut
        # Each moved its own way (the fit cannot follow them all) by 0.9 px: 4.5 x the
        # calibration's 0.2 px, past RESIDUAL_FLAG x 0.2 however the fit leans, and within
        # the tracker's 1 px residual limit for the first pass.
        turn = np.linspace(0.0, 2.0 * np.pi, many.sum(), endpoint=False)
        g[many] += 0.9 * np.stack([np.cos(turn), np.sin(turn)], axis=1)
        flux[many] *= 0.3
        out = tr.band(sample.frame_index, g, _band_of(tr, sample), sample.time_s, flux)
    finally:
        tr.state = before
    if out.flux_flagged.size == 0:  # the cut glints pulled the fit too far to stand out
        pytest.fail(f"nothing flagged: {out.reason}")
    assert not out.ok and out.reason.startswith("flux_cut_glints_")
    assert np.isnan(out.screen_xy_m).all()


def test_glints_at_their_expected_flux_or_in_place_are_not_flagged(band):
    tr, cal, clean = band
    spread = np.exp(np.linspace(-0.19, 0.19, clean.n_glints))  # within 2 x 0.1
    assert not _flagged(tr, cal, _cut(clean, 2, 0.6), _expected(tr, cal, clean) * spread).any()
    # Dimmed but where the pose puts it: a lash across part of the light's disk that leaves
    # the centroid is harmless to the fit.
    flux = _expected(tr, cal, clean)
    flux[2] *= 0.5
    assert not _flagged(tr, cal, _cut(clean, 2, 0.1), flux).any()


def test_fit_recovers_each_lights_power_from_noisy_frames(setup, rng=np.random.default_rng(5)):
    r = setup.eye.cornea_radius_m
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(5, 5))
    centers = np.array([setup.eye.cornea_center(a, b) for a, b in zip(yaw, pitch)])
    n = setup.lights.count
    power = rng.normal(0.0, 0.3, n)
    g = np.full((len(centers), n, 2), np.nan)
    flux = np.full((len(centers), n), np.nan)
    for k, c in enumerate(centers):
        px, vis = project_glints(setup.camera, c, r, setup.lights_world_m)
        g[k, vis] = px[vis]
        m = model_flux(setup.camera, c, r, setup.lights_world_m[vis], px[vis], "dielectric")
        flux[k, vis] = m * np.exp(power[vis] + rng.normal(0.0, 0.05, vis.sum()))
    gf = fit_glint_flux(setup.camera, r, setup.lights_world_m, centers, g, flux)
    seen = np.isfinite(gf.log_power)
    assert gf.fresnel == "dielectric" and seen.sum() >= n // 2
    assert np.abs(gf.log_power[seen] - power[seen]).max() < 0.1
    assert 0.03 < gf.log_sd < 0.08


def test_calibration_file_round_trip_and_old_files(setup):
    cal = ground_truth_calibration(setup)
    gf = GlintFlux(np.r_[np.nan, np.linspace(-1.0, 1.0, setup.lights.count - 1)], "constant",
                   0.2, 0.15)
    back = Calibration.from_json(replace(cal, glint_flux=gf).to_json())
    assert back.glint_flux.fresnel == "constant" and back.glint_flux.log_sd == 0.2
    assert back.glint_flux.noise_px == 0.15
    assert np.array_equal(back.glint_flux.log_power, gf.log_power, equal_nan=True)
    old = Calibration.from_json(cal.to_json())
    assert old.glint_flux is None and "glint_flux" not in json.loads(cal.to_json())
    with pytest.raises(ValueError, match="glint_flux"):
        Tracker(setup, cal, "polynomial", flag_cut_glints=True)
    short = replace(cal, glint_flux=GlintFlux(np.zeros(3), "constant", 0.2, 0.15))
    with pytest.raises(ValueError, match="40 lights"):  # the file holds another rig's lights
        Tracker(setup, short, "polynomial", flag_cut_glints=True)
    # By default the tracker flags where the calibration has the rig's glint flux.
    fluxed = replace(cal, glint_flux=gf)
    assert Tracker(setup, fluxed, "polynomial").flags_cut_glints
    assert not Tracker(setup, fluxed, "polynomial", flag_cut_glints=False).flags_cut_glints
    assert not Tracker(setup, cal, "polynomial").flags_cut_glints
    assert not Tracker(setup, short, "polynomial").flags_cut_glints


@pytest.mark.parametrize("value, key", [
    ({"fresnel": "metal", "log_power": [0.0]}, "glint_flux.fresnel"),
    ({"fresnel": "constant", "log_power": ["1"]}, "glint_flux.log_power[0]"),
    ({"fresnel": "constant", "log_power": [1e300]}, "glint_flux.log_power[0]"),
    ({"fresnel": "constant", "log_power": [True]}, "glint_flux.log_power[0]"),
    ({"fresnel": "constant", "log_power": 3}, "glint_flux.log_power"),
    ({"fresnel": "constant", "log_power": [0.0], "log_sd": -1}, "glint_flux.log_sd"),
    ({"fresnel": "constant", "log_power": [0.0], "noise_px": "0.2"}, "glint_flux.noise_px"),
    ({"fresnel": "constant", "log_power": [0.0], "noise_px": float("inf")}, "glint_flux.noise_px"),
    ([1, 2], "glint_flux"),
])
def test_hostile_glint_flux_names_the_file_and_key(setup, value, key):
    doc = json.loads(ground_truth_calibration(setup).to_json())
    doc["glint_flux"] = value
    with pytest.raises(InputError) as exc:
        Calibration.from_dict(doc, path="cal.json")
    assert "cal.json" in str(exc.value) and key in str(exc.value)


def test_samples_csv_records_flagged_lights_and_reads_old_versions(band, tmp_path):
    tr, cal, sample = band
    flagged = replace(sample, flux_flagged=np.array([3, 7]))
    rows = read_samples_csv(write_samples_csv(tmp_path / "s.csv", [sample, flagged]))
    assert [r["flux_flagged"] for r in rows] == ["", "3;7"]
    text = (tmp_path / "s.csv").read_text().splitlines()
    old = ["# scet-samples 2", ",".join(text[1].split(",")[:-1])] + \
        [",".join(line.split(",")[:-1]) for line in text[2:]]
    (tmp_path / "old.csv").write_text("\n".join(old) + "\n")
    assert [r["flux_flagged"] for r in read_samples_csv(tmp_path / "old.csv")] == ["", ""]


@pytest.mark.skipif(not match_kernels.ENABLED, reason="Numba is not installed")
def test_compiled_flag_is_the_numpy_flag(band, monkeypatch):
    tr, cal, clean = band
    rng = np.random.default_rng(7)
    for _ in range(30):
        sample = replace(clean, glints_px=clean.glints_px + rng.normal(0, 0.3, (clean.n_glints, 2)))
        flux = _expected(tr, cal, sample) * np.exp(rng.normal(0.0, 0.25, sample.n_glints))
        compiled = _flagged(tr, cal, sample, flux)
        with monkeypatch.context() as m:
            m.setattr(match_kernels, "ENABLED", False)
            numpy_form = _flagged(tr, cal, sample, flux)
        assert np.array_equal(compiled, numpy_form)


def test_track_folder_passes_the_flag_on(tmp_path, setup):
    from estimator.folders import track_folder
    from tests.estimator.test_tracker import write_folder

    rng = np.random.default_rng(1)
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    folder = write_folder(tmp_path / "run", setup,
                          [draw_frame(setup, f, float(yaw[0]), float(pitch[0]), rng)
                           for f in range(2)])
    old = ground_truth_calibration(setup)
    # A spread so wide that nothing is flagged: the flag changes no sample.
    wide = replace(old, glint_flux=GlintFlux(np.zeros(setup.lights.count), "dielectric", 9.0,
                                             0.2))
    a = track_folder(folder, setup, wide, tmp_path / "a.csv").samples
    b = track_folder(folder, setup, wide, tmp_path / "b.csv", flag_cut_glints=True).samples
    assert [s.reason for s in a] == [s.reason for s in b] and sum(s.ok for s in b) > 0
    assert all(s.flux_flagged.size == 0 for s in b)
