"""The expected-flux model of glints (estimator.calibration.flux) on lashless Mitsuba renders:
each light's power calibrated from rendered calibration frames, the banded frames' glints at
~1 of their expected flux within the calibrated spread, and the cut-glint flag (Tracker
``flag_cut_glints``) firing on (almost) no glint where no lash cuts one."""

import numpy as np
import pytest

pytest.importorskip("mitsuba", reason="renders with Mitsuba 3")

from estimator.banding import scaled_setup  # noqa: E402
from estimator.calibration.flux import model_flux  # noqa: E402
from estimator.folders import calibrate_from_folder, calibration_glints, iter_folder  # noqa: E402
from estimator.gaze import fit_cornea_centers  # noqa: E402
from estimator.glints import detect_glints  # noqa: E402
from estimator.scene import load_scene  # noqa: E402
from estimator.tracker import Tracker  # noqa: E402
from scet_render.dataset import render_calibration, render_dataset  # noqa: E402


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The quick validation's render settings (320 x 240, 4 spp, conductor cornea, static
    lids, no lashes): 5 x 5 calibration frames and 16 banded frames of saccades."""
    setup = scaled_setup(load_scene("paper_sim"), 2)
    out = tmp_path_factory.mktemp("flux")
    cal_dir = render_calibration(setup, out / "calibration", spp=4, cornea="conductor", seed=0)
    render_dataset(setup, out / "test", frames=16, spp=4, trajectory="saccades", seed=0,
                   cornea="conductor")
    return setup, cal_dir, out / "test", calibrate_from_folder(cal_dir, setup)


@pytest.mark.slow  # ~20 s of rendering on 2 cores
def test_model_spreads_less_than_a_constant_flux_per_light(rendered):
    setup, cal_dir, _, cal = rendered
    gf = cal.glint_flux
    assert gf is not None and np.isfinite(gf.log_power).sum() >= 30
    # Measured 0.21 (the Monte Carlo noise of a sub-pixel glint at 4 spp) against 0.23 for
    # each light's median flux alone.
    s, cg = calibration_glints(cal_dir, setup)
    lr = np.log(cg.flux) - np.nanmedian(np.log(cg.flux), axis=0)
    lr = lr[np.isfinite(lr)]
    reference = 1.4826 * np.median(np.abs(lr - np.median(lr)))
    assert 0.05 < gf.log_sd < reference < 0.35
    assert cal.glint_flux.noise_px == pytest.approx(cal.quality["rms_px"])


@pytest.mark.slow
def test_banded_glints_have_their_expected_flux(rendered):
    setup, _, test_dir, cal = rendered
    tr = Tracker(setup, cal, "geometric")
    lights = cal.lights_world_m(setup.lights_world_m)
    ratios = []
    for f, t0, img, err in iter_folder(test_dir, setup):
        det = detect_glints(img, setup, f)
        for s in tr.process(img, f, t0):
            if not s.ok:
                continue
            d = np.hypot(det.u_px[:, None] - s.glints_px[None, :, 0],
                         det.v_px[:, None] - s.glints_px[None, :, 1])
            k, near = d.argmin(axis=0), d.min(axis=0) < 0.05
            m = model_flux(setup.camera, s.cornea_center_m, cal.cornea_radius_m,
                           lights[s.light_index], s.glints_px, cal.glint_flux.fresnel)
            e = m * np.exp(cal.glint_flux.log_power[s.light_index])
            ratios.append(np.log(det.intensity[k] / e)[near])
    lr = np.concatenate(ratios)
    assert lr.size > 200
    # Measured median -0.01, robust SD 0.22 (the calibration frames': 0.21).
    assert abs(np.median(lr)) < 0.1
    assert 1.4826 * np.median(np.abs(lr - np.median(lr))) < 1.5 * cal.glint_flux.log_sd


@pytest.mark.slow
def test_the_flag_fires_on_few_glints_without_lashes(rendered):
    setup, _, test_dir, cal = rendered
    frames = [(f, t0, img) for f, t0, img, err in iter_folder(test_dir, setup)]
    off, on = (Tracker(setup, cal, "geometric", flag_cut_glints=flag) for flag in (False, True))
    a = [s for f, t0, img in frames for s in off.process(img, f, t0)]
    b = [s for f, t0, img in frames for s in on.process(img, f, t0)]
    used = sum(s.n_glints for s in a if s.ok)
    flagged = sum(s.flux_flagged.size for s in b)
    # Measured on 16 such frames: 17 of 621 clear glints (2.7 %), 4 of 80 samples lost.
    assert flagged <= 0.06 * used
    assert sum(s.ok for s in b) >= 0.9 * sum(s.ok for s in a)


@pytest.mark.slow  # ~25 s: 25 frames rendered, the conic calibration's re-identification
def test_a_conic_calibration_records_the_conic_glints_flux(tmp_path):
    """A conic calibration (Q = -0.45, quick render settings) records each light's power on
    the conic's model, from the glints identified on the calibrated conic: they spread less
    about it than about the sphere's model at the same centres (measured 0.177 against 0.195;
    what is left is the 4-spp Monte Carlo noise, 0.21 on a spherical eye)."""
    from dataclasses import replace

    from estimator.calibration import fit_glint_flux
    from estimator.folders import glints_on_conic

    base = scaled_setup(load_scene("paper_sim"), 2)
    setup = replace(base, eye=replace(base.eye, cornea_asphericity=-0.45))
    cal_dir = render_calibration(setup, tmp_path / "calibration", spp=4, cornea="conductor",
                                 seed=0)
    cal = calibrate_from_folder(cal_dir, setup, cornea_model="conic")
    gf = cal.glint_flux
    assert cal.conic and gf is not None and np.isfinite(gf.log_power).sum() >= 30
    assert gf.noise_px == pytest.approx(cal.quality["rms_px"])
    s, cg = calibration_glints(cal_dir, setup)
    g, flux = glints_on_conic(cal, s, cg)
    c = fit_cornea_centers(s, cal, g, np.isfinite(g).all(axis=-1))
    sphere = fit_glint_flux(s.camera, cal.cornea_radius_m, cal.lights_world_m(s.lights_world_m),
                            np.where(c.ok[:, None], c.center_m, np.nan), g, flux)
    assert gf.log_sd < sphere.log_sd and gf.log_sd < 0.25
