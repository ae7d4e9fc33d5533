"""The tracker's cheap path (issue 15) against the hypothesis search it shortcuts: on simulated
banded frames of an eye making saccades both give the same samples (reasons, identities,
estimates), the compiled projection and small fit give what their numpy counterparts give,
and the cheap path declines what it cannot verify."""

import numpy as np
import pytest

from estimator.cornea import fit_cornea, fit_small
from estimator.gaze import calibrated_problems
from estimator.geometry import (camera_arrays, glint_jacobians, glints_and_rows_one_pose,
                                glints_one_pose, project_glints)
import estimator.matching.kernels as kernels
from estimator.matching import BandFollower, GlintMatcher
from estimator.tracker import Tracker
from tests.estimator.test_tracker import calibration, draw_frame, setup  # noqa: F401 fixtures


def test_the_projection_of_one_pose_is_project_glints(setup):
    rng = np.random.default_rng(4)
    eye, arrays = setup.eye, camera_arrays(setup.camera)
    for yaw, pitch in rng.uniform(-0.6, 0.6, (200, 2)):
        c, axis = eye.cornea_center(yaw, pitch), eye.cornea_center(yaw, pitch) - eye.rotation_center_m
        axis = axis / np.linalg.norm(axis)
        kw = dict(cornea_axis=axis, cap_cos_min=eye.cap_cos_min)
        g0, v0 = project_glints(setup.camera, c, eye.cornea_radius_m, setup.lights_world_m, **kw)
        g1, v1 = glints_one_pose(setup.camera, c, eye.cornea_radius_m, setup.lights_world_m,
                                 arrays=arrays, **kw)
        assert np.array_equal(v0, v1)
        f = np.isfinite(g0[:, 0])
        assert np.array_equal(f, np.isfinite(g1[:, 0]))
        # The same arithmetic one light at a time: rounding differences only (1e-9 px).
        assert np.abs(g0[f] - g1[f]).max(initial=0.0) < 1e-9


def test_the_compiled_rows_are_the_closed_form_jacobian(setup, calibration):  # noqa: F811
    """d glint / d centre of the compiled projection is glint_jacobians' (1e-12 relative: the
    same closed form, rounding only) and the central differences of the glints (1e-6 relative:
    the differences' own truncation at 1 um); the matcher's d glint / d (yaw, pitch) through
    the orbit is the central differences of its own predictions (1e-6 relative)."""
    rng = np.random.default_rng(6)
    eye = setup.eye
    for yaw, pitch in rng.uniform(-0.5, 0.5, (30, 2)):
        c = eye.cornea_center(yaw, pitch)
        g, vis, J = glints_and_rows_one_pose(setup.camera, c, eye.cornea_radius_m,
                                             setup.lights_world_m)
        g0, v0, J0, _, _ = glint_jacobians(setup.camera, c, eye.cornea_radius_m,
                                           setup.lights_world_m, radius_and_lights=False)
        m = vis & v0
        scale = np.abs(J0[m]).max()
        assert np.abs(J[m] - J0[m]).max() < 1e-12 * scale
        h = 1e-6  # m
        fd = np.stack([(glints_one_pose(setup.camera, c + h * e, eye.cornea_radius_m,
                                        setup.lights_world_m)[0]
                        - glints_one_pose(setup.camera, c - h * e, eye.cornea_radius_m,
                                          setup.lights_world_m)[0]) / (2 * h)
                       for e in np.eye(3)], axis=-1)
        assert np.abs(J[m] - fd[m]).max() < 1e-6 * scale
    m = GlintMatcher(setup, calibration=calibration)
    for yaw, pitch in rng.uniform(-0.4, 0.4, (10, 2)):
        g, vis, J = m._predict_one_rows(yaw, pitch)
        h = 1e-6  # rad
        fd = np.stack([(m._predict_one(yaw + dy, pitch + dp)[0]
                        - m._predict_one(yaw - dy, pitch - dp)[0]) / (2 * h)
                       for dy, dp in ((h, 0.0), (0.0, h))], axis=-1)
        assert np.abs(J[vis] - fd[vis]).max() < 1e-6 * np.abs(J[vis]).max()


def test_the_closed_form_2x2_inverse_and_prior_growth():
    """inverse_2x2 is np.linalg.inv (1e-12 relative) on positive definite matrices and None on
    singular ones; BandPrior.predict's closed-form largest eigenvalue decides as eigvalsh does
    on 2,000 random covariances around its 0.75 deg limit."""
    from estimator.tracking import BandPrior, inverse_2x2

    rng = np.random.default_rng(9)
    for _ in range(200):
        L = rng.normal(size=(2, 2))
        A = L @ L.T + 0.1 * np.eye(2)
        assert np.allclose(inverse_2x2(A), np.linalg.inv(A), rtol=1e-12, atol=0)
    assert inverse_2x2(np.array([[1.0, 2.0], [2.0, 4.0]])) is None
    prior = BandPrior()
    limit = np.radians(prior.max_sd_deg) ** 2
    for _ in range(2000):
        L = rng.normal(size=(2, 2)) * np.sqrt(limit) * 0.6
        cov = L @ L.T
        dt = rng.uniform(0, 1.2e-3)
        grown = cov + (np.radians(prior.eye_speed_max_deg_s) * dt) ** 2 * np.eye(2)
        want = np.linalg.eigvalsh(grown)[-1] <= limit
        assert (prior.predict(cov, dt) is not None) == want


@pytest.mark.parametrize("model", ["orbit", "center"])
def test_the_small_fit_reaches_fit_cornea_minimum(setup, calibration, model):  # noqa: F811
    from dataclasses import replace
    problems = calibrated_problems(setup, calibration)
    problem = problems.orbit if model == "orbit" else problems.center
    rng = np.random.default_rng(5)
    eye = setup.eye
    for _ in range(40):
        a = rng.uniform(-0.3, 0.3, 2)
        g, vis = project_glints(setup.camera, eye.cornea_center(*a), eye.cornea_radius_m,
                                problem.lights_world_m)
        sel = np.flatnonzero(vis)[:8]
        glints = g[sel] + rng.normal(0.0, 0.4, (sel.size, 2))
        x0 = a + 0.01 if model == "orbit" else eye.cornea_center(*(a + 0.01))
        ours = fit_small(problem, glints, problem.lights_world_m[sel], x0, model=model)
        ref = fit_cornea(replace(problem, lights_world_m=problem.lights_world_m[sel]),
                         glints[None], None, x0, model=model)
        x_ref = (ref.angles_rad if model == "orbit" else ref.center_m)[0]
        assert ours.ok and ref.ok[0]
        # Both stop within ~1e-9 m of the minimum (fit_cornea's 1e-7 m Gauss-Newton stop
        # leaves <= 4e-10 m): 1e-4 of the scatter 0.5 px of noise leaves in the centre.
        scale = eye.cornea_offset_m if model == "orbit" else 1.0
        assert np.abs(ours.x - x_ref).max() * scale < 5e-9
        assert abs(ours.rms_px - ref.rms_px[0]) < 1e-6


def saccade_frames(setup, n=8, seed=2):
    """Banded frames of an eye moving 3 deg per frame (180 deg/s) with a few glints hidden."""
    rng = np.random.default_rng(seed)
    out = []
    for f in range(n):
        yaw, pitch = np.radians(-6.0 + 3.0 * f), np.radians(2.0 - 1.0 * f)
        out.append(draw_frame(setup, f, yaw, pitch, rng, hide=rng.choice(40, 3, replace=False)))
    return out


@pytest.mark.parametrize("method", ["polynomial", "geometric"])
def test_cheap_path_gives_the_search_samples(setup, calibration, method):  # noqa: F811
    frames = saccade_frames(setup)
    out = {}
    for cheap in (False, True):
        tr = Tracker(setup, calibration, method, cheap=cheap)
        out[cheap] = [s for f, img in enumerate(frames) for s in tr.process(img, f)]
        if cheap:
            counts = tr.counts
    assert counts["cheap"] > counts["search"] > 0, "most bands take the cheap path, the first not"
    # Same glints, same model: the fits' minima agree to ~1e-9 m (test above); 1e-7 m of
    # cornea centre is 1e-3 deg of gaze at most.
    assert_same_samples(out[False], out[True], center_m=1e-7, screen_m=1e-5)


def assert_same_samples(a, b, *, center_m, screen_m):
    """Samples ``a`` and ``b`` of one stream agree: reasons, identities, and the estimates
    to ``center_m`` (cornea centre) and ``screen_m`` (screen point)."""
    assert len(a) == len(b) > 0
    for x, y in zip(a, b):
        assert x.reason == y.reason
        assert np.array_equal(x.light_index, y.light_index)
        if x.ok:
            assert np.abs(x.cornea_center_m - y.cornea_center_m).max() < center_m
            assert np.abs(x.screen_xy_m - y.screen_xy_m).max() < screen_m


def test_cheap_path_declines_a_prior_two_lights_off(setup, calibration):  # noqa: F811
    """A prior 2 deg from the truth (about one light along the arcs) lands the fit outside the
    cheap path's reach, or a shifted chain's rival close: it declines; the search decides."""
    problems = calibrated_problems(setup, calibration)
    m = GlintMatcher(setup, calibration=calibration, problem=problems.orbit)
    fo = BandFollower(m)
    truth = np.radians([4.0, -2.0])
    g, vis = fo.predict(truth)
    rows = (g[vis, 1].min() - 1, g[vis, 1].min() + 60)
    inband = vis & (g[:, 1] >= rows[0]) & (g[:, 1] <= rows[1])
    det = g[inband] + np.random.default_rng(0).normal(0, 0.2, (inband.sum(), 2))
    assert fo.follow(det, rows, truth + np.radians([0.2, 0.1])) is not None
    assert fo.follow(det, rows, truth + np.radians([2.0, 0.0])) is None


def test_the_small_fit_with_a_prior_reaches_fit_cornea_map(setup, calibration):  # noqa: F811
    """With a Gaussian prior on the angles (a sparse band's 1-3 glints, as the tracker's
    prior-assisted bands): the same maximum a posteriori rotation as the batched fit."""
    from dataclasses import replace
    orbit = calibrated_problems(setup, calibration).orbit
    rng = np.random.default_rng(8)
    eye = setup.eye
    checked = 0
    for _ in range(30):
        a = rng.uniform(-0.3, 0.3, 2)
        g, vis = project_glints(setup.camera, eye.cornea_center(*a), eye.cornea_radius_m,
                                orbit.lights_world_m)
        sel = rng.choice(np.flatnonzero(vis), rng.integers(1, 4), replace=False)
        glints = g[sel] + rng.normal(0.0, 0.4, (sel.size, 2))
        mean = a + rng.normal(0, 0.004, 2)
        info = 0.5 ** 2 * np.linalg.inv(np.diag([0.005, 0.008]) ** 2)
        ours = fit_small(orbit, glints, orbit.lights_world_m[sel], mean, model="orbit",
                         prior_mean=mean, prior_information=info)
        ref = fit_cornea(replace(orbit, lights_world_m=orbit.lights_world_m[sel]),
                         glints[None], None, mean, model="orbit", prior_mean=mean,
                         prior_information=info)
        assert ours.ok and ref.ok[0]
        # As without a prior: both within ~1e-9 m of the same minimum (r_co ~ 1 cm per rad).
        assert np.abs(ours.x - ref.angles_rad[0]).max() * eye.cornea_offset_m < 5e-9
        # fit_cornea's last Gauss-Newton step reports its linearised cost: 1e-5 px of RMS,
        # against the 0.1 px that would matter (MAX_RESIDUAL_PX is 2 px).
        assert abs(ours.rms_px - ref.rms_px[0]) < 1e-5
        checked += 1
    assert checked == 30


def test_the_small_fit_refuses_a_half_given_prior(setup, calibration):  # noqa: F811
    orbit = calibrated_problems(setup, calibration).orbit
    with pytest.raises(ValueError, match="together"):
        fit_small(orbit, np.zeros((3, 2)), orbit.lights_world_m[:3], np.zeros(2),
                  model="orbit", prior_mean=np.zeros(2))


def test_band_support_bounds_every_reachable_rotation(setup, calibration):  # noqa: F811
    """No rotation within the reach has more detections within the gate of its candidate
    glints on a band's rows than the band's support (300 random off-grid rotations per case,
    detections: one reachable rotation's glints jittered inside the gate, and clutter); a
    band's own glints at a reachable rotation are supported, clutter on the same rows where
    no reachable glint falls (lid, skin) is not, and rows the eye's glints cannot reach support nothing."""
    problems = calibrated_problems(setup, calibration)
    m = GlintMatcher(setup, calibration=calibration, problem=problems.orbit)
    rng = np.random.default_rng(5)
    b, gate = m.params.band_margin_px, m.params.gate_px
    H, W = setup.camera.height_px, setup.camera.width_px

    def within(center, reach, n):
        r = reach * np.sqrt(rng.random(n))
        phi = rng.uniform(0, 2 * np.pi, n)
        return center + np.stack([r * np.cos(phi), r * np.sin(phi)], axis=1)

    for center_deg, reach_deg in (((0.0, -15.0), 4.0), ((5.0, 5.0), 12.0), ((-10.0, 0.0), 2.0)):
        center, reach = np.radians(center_deg), np.radians(reach_deg)
        g_true, v_true = m.predict(within(center, reach, 1)[0])
        det = np.concatenate([g_true[v_true] + rng.uniform(-0.6, 0.6, (v_true.sum(), 2)) * gate,
                              rng.uniform([0, 0], [W, H], (30, 2))])
        g, vis = m.predict(within(center, reach, 300))
        for lo in range(0, H, H // 12):
            rows = (lo, lo + H // 12)
            support = m.band_support(rows, center, reach, det)
            if kernels.ENABLED:  # the numpy form (no Numba) bounds the same way, equally
                kernels.ENABLED = False
                try:
                    assert m.band_support(rows, center, reach, det) == support
                finally:
                    kernels.ENABLED = True
            cand = vis & (g[..., 1] >= rows[0] - b) & (g[..., 1] <= rows[1] + b)  # (300, n)
            d = np.linalg.norm(g[:, :, None] - det[None, None], axis=-1)  # (300, n, k)
            near = ((d <= gate) & cand[..., None]).any(axis=1).sum(axis=1)
            assert np.minimum(near, cand.sum(axis=1)).max() <= support, (center_deg, rows)
    # Looking 15 deg down, 4 deg of reach: the glints sit low in the frame.
    center, reach = np.radians([0.0, -15.0]), np.radians(4.0)
    g, vis = m.predict(center)
    holding = (g[vis, 1].min(), g[vis, 1].min() + 40)
    inside = vis & (g[:, 1] >= holding[0]) & (g[:, 1] <= holding[1])
    assert m.band_support(holding, center, reach, g[inside]) >= inside.sum() >= 5
    # Clutter on the same rows at the frame's left edge, where no reachable glint falls.
    assert g[vis, 0].min() > 60  # and a 4-deg turn moves a glint < 20 px
    clutter = np.stack([rng.uniform(0, 30, 12), rng.uniform(*holding, 12)], axis=1)
    assert m.band_support(holding, center, reach, clutter) < 5
    top = (0, g[vis, 1].min() - 10 * b - m.grid_drift_px)
    assert m.band_support(top, center, reach, rng.uniform([0, 0], [W, top[1]], (12, 2))) < 5


def test_a_band_out_of_reach_is_left_to_the_prior(setup, calibration):  # noqa: F811
    """Clutter blobs on the top bands while the eye looks down, its glints far below: the
    cheap path leaves those bands unsearched (``band_out_of_reach``, NaN or the prior's
    estimate), and every sample the search gives an estimate keeps it, identities and all."""
    from estimator.banding import band_layout
    from estimator.tracker import OUT_OF_REACH

    rng = np.random.default_rng(8)
    frames = []
    for f in range(5):
        img = draw_frame(setup, f, np.radians(2.0), np.radians(-14.0), rng).astype(float)
        bands = [bd for bd in band_layout(setup.sensor, setup.strobe, f)
                 if bd.visible and bd.last_row - bd.first_row >= 20]
        yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
        lo, hi = bands[0].first_row, bands[0].last_row
        for u, v in zip(rng.uniform(200, 440, 7), rng.uniform(lo + 3, hi - 3, 7)):
            img += 500.0 * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 1.2 ** 2))
        frames.append(np.clip(np.rint(img), 0, 1023).astype(np.uint16))
    out = {}
    for cheap in (False, True):
        tr = Tracker(setup, calibration, "polynomial", cheap=cheap)
        out[cheap] = [s for f, img in enumerate(frames) for s in tr.process(img, f)]
        counts = tr.counts
    assert counts["unfillable"] >= 3, counts
    relabelled = 0
    for a, b in zip(out[False], out[True]):
        if b.reason == OUT_OF_REACH:
            assert not a.ok and not b.ok
            relabelled += 1
            continue
        assert a.reason == b.reason and np.array_equal(a.light_index, b.light_index)
        if a.ok:
            assert np.abs(a.cornea_center_m - b.cornea_center_m).max() < 1e-7  # as above
    assert relabelled >= 3
    assert sum(s.ok for s in out[True]) == sum(s.ok for s in out[False]) > 0


def test_the_shift_table_is_the_arcs_shift(setup, calibration):  # noqa: F811
    """_shift's table (steps of one and two lights) gives what the arcs give, on every light
    and on assignments with unmatched detections: a light moved off its arc's end is -1."""
    matcher = GlintMatcher(setup, calibration=calibration)
    n = matcher.lights_world_m.shape[0]
    rng = np.random.default_rng(3)
    cases = [np.arange(n)] + [np.where(rng.random(6) < 0.3, -1, rng.integers(0, n, 6))
                              for _ in range(50)]
    ends = 0
    for assign in cases:
        for step in (-2, -1, 1, 2):
            got = matcher._shift(assign, step)
            assert np.array_equal(got, matcher._shift_any(assign, step))
            ends += int(((assign >= 0) & (got < 0)).sum())
    assert ends > 0


@pytest.mark.parametrize("kind", ["eq1", "quadratic", "quadratic_da"])
def test_a_mappings_one_feature_form_is_its_batch_form(kind):
    """GazeMapping.predict_one (the tracker's per-sample form, plain floats) gives predict's
    screen point to 1e-12 relative: the same monomials, summed term by term."""
    from estimator.calibration import fit_gaze_mapping

    rng = np.random.default_rng(14)
    d = 4 if kind == "quadratic_da" else 3
    scale = np.array([2e-3, 2e-3, 1e-3, 0.05])[:d]  # cornea centres (m), a distance reading
    features = rng.normal(0.0, 1.0, (60, d)) * scale + np.array([0, 0, -4e-3, 0.6])[:d]
    screen = rng.uniform(-0.2, 0.2, (60, 2))
    mapping = fit_gaze_mapping(features, screen, kind)
    batch = mapping.predict(features)
    for f, want in zip(features, batch):
        assert np.allclose(mapping.predict_one(f), want, rtol=1e-12, atol=1e-15)


def test_the_closed_form_2x2_eigenvalues():
    """matcher._eig_2x2 gives eigvalsh's smaller and larger eigenvalues (1e-12 of the larger)
    of random symmetric 2 x 2 matrices, definite or not, one at a time and as arrays."""
    from estimator.matching.matcher import _eig_2x2

    rng = np.random.default_rng(15)
    A = rng.normal(size=(500, 2, 2))
    A = 0.5 * (A + np.swapaxes(A, 1, 2))
    lo, hi = _eig_2x2(A[:, 0, 0], A[:, 0, 1], A[:, 1, 1])
    w = np.linalg.eigvalsh(A)
    big = np.abs(w).max(axis=1)
    assert np.all(np.abs(lo - w[:, 0]) <= 1e-12 * big)
    assert np.all(np.abs(hi - w[:, 1]) <= 1e-12 * big)
    assert _eig_2x2(2.0, 0.0, 1.0) == (1.0, 2.0)
