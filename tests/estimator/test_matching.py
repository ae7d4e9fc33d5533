"""Glint identification on realistic band inputs: which light made which glint.

Inputs are simulated (:func:`tests.estimator.simulated.simulate_glints`) the way a band shows
them: only the glints whose rows fall within a 48-row band, 0.3-0.5 px of Gaussian feature
noise, 5-10 % of the glints dropped, 1-3 spurious blobs per band in the band's rows near the
cornea, and glints closer than 3 px merged into one blob (the detector cannot split them: two
σ = 1 px spots 3 px apart show no saddle; any light whose glint lies within 3 px of a blob
is then a correct identity). Both with a prior (the previous sample's eye rotation, up to 0.5°
off: a saccade's turn in the 1 ms between bands) and cold (coarse search), on paper_sim (40
lights) and paper_sim_doubled (80 lights, two arcs sharing their first light).
"""

from __future__ import annotations

from dataclasses import FrozenInstanceError

import numpy as np
import pytest

import estimator.matching.kernels as kernels
from estimator.banding import band_layout
from estimator.glints import detect_glints
from estimator.matching import NO_HYPOTHESIS, OK, TOO_FEW_GLINTS, GlintMatcher, MatchParams, match_glints
from estimator.scene import load_scene
from tests.estimator.simulated import ground_truth_glints, simulate_glints
from tests.estimator.test_glints import banded_frame

# --------------------------------------------------------------------------- tolerances
#: The brief's target share of correct identities (a spurious blob is correct when unmatched).
TARGET_RATE = 0.99
#: Glints closer than this are one blob (px).
MERGE_PX = 3.0
#: Refit cornea centre from one band (m): ~8 glints at <= 0.5 px on the orbit locate the
#: angles to ~0.06°, 4 µm of centre; a few microns of margin for the bands with 3-4 glints.
CENTER_MEDIAN_M = 20e-6
BANDS = 50


def realistic_bands(setup, n_bands, rng, *, band_rows=48, noise_px=(0.3, 0.5),
                    drop=(0.05, 0.10), spurious=(1, 3), prior_error_deg=0.5):
    """Bands of simulated detections. Each: detections (k, 2), the set of correct labels of
    each (-1 for spurious), band rows, a prior (the true rotation perturbed) and the truth."""
    screen = setup.screen
    targets = np.stack([rng.uniform(*screen.x_range_m, n_bands),
                        rng.uniform(*screen.y_range_m, n_bands), np.full(n_bands, screen.z_m)], 1)
    obs = simulate_glints(setup, targets)
    bands = []
    for b in range(n_bands):
        vis, g = obs.visible[b], obs.glints_true_px[b]
        v = g[vis, 1]
        lo = rng.uniform(v.min() - band_rows + 8, v.max() - 8)  # overlaps the pattern
        hi = lo + band_rows
        inside = np.flatnonzero(vis & (g[:, 1] >= lo) & (g[:, 1] < hi))
        kept = inside[rng.random(inside.size) >= rng.uniform(*drop)]
        groups, free = [], np.ones(kept.size, dtype=bool)
        for a in range(kept.size):
            if free[a]:
                close = np.linalg.norm(g[kept] - g[kept[a]], axis=1) < MERGE_PX
                members = np.flatnonzero(free & close)
                free[members] = False
                groups.append(kept[members])
        det = np.array([g[m].mean(axis=0) for m in groups]).reshape(-1, 2)
        det = det + rng.normal(0.0, rng.uniform(*noise_px), det.shape)
        # Any light whose glint lies within MERGE_PX of the blob's could have made it (in
        # paper_sim_doubled lights i and 40 + i, i < 8, sit within 1 mm of each other).
        near = [np.flatnonzero(vis & (np.linalg.norm(g[:, None] - g[m][None], axis=-1) < MERGE_PX)
                               .any(axis=1)) for m in groups]
        labels = [set(n.tolist()) for n in near]
        n_sp = int(rng.integers(spurious[0], spurious[1] + 1))
        u0, u1 = g[vis, 0].min() - 20, g[vis, 0].max() + 20
        blobs = np.stack([rng.uniform(u0, u1, n_sp), rng.uniform(lo, hi, n_sp)], axis=1)
        det = np.concatenate([det, blobs])
        labels += [{-1}] * n_sp
        order = rng.permutation(len(labels))
        truth = np.array([obs.yaw_rad[b], obs.pitch_rad[b]])
        # The previous sample's rotation: off by up to a saccade's turn in the 1 ms between
        # bands (0.5° at 500°/s), in a random direction.
        turn = np.radians(prior_error_deg) * np.sqrt(rng.random()) * np.array(
            [np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
        bands.append(dict(det=det[order], labels=[labels[i] for i in order], rows=(lo, hi - 1),
                          prior=truth + turn,
                          truth=truth, center=obs.cornea_center_m[b]))
    return bands


def score(results, bands):
    """Share of correct labels over all detections, over detections of bands with >= 3 glints,
    and over claimed identities (precision); refit centre errors of the bands matched."""
    correct, total, correct3, total3, claimed, claimed_ok, center_err = 0, 0, 0, 0, 0, 0, []
    for r, bd in zip(results, bands):
        ok = np.array([light in s for light, s in zip(r.light_index, bd["labels"])])
        n_glints = sum(s != {-1} for s in bd["labels"])
        correct += ok.sum()
        total += ok.size
        if n_glints >= 3:
            correct3 += ok.sum()
            total3 += ok.size
        claimed += r.matched.sum()
        claimed_ok += (ok & r.matched).sum()
        if r.ok:
            center_err.append(np.linalg.norm(r.cornea_center_m - bd["center"]))
    return correct / total, correct3 / total3, claimed_ok / claimed, np.array(center_err)


@pytest.fixture(scope="module")
def matchers():
    return {name: GlintMatcher(load_scene(name)) for name in ("paper_sim", "paper_sim_doubled")}


@pytest.fixture(scope="module")
def band_sets(matchers):
    return {name: realistic_bands(m.setup, BANDS, np.random.default_rng(2024))
            for name, m in matchers.items()}


# --------------------------------------------------------------------------- identity rates


@pytest.mark.parametrize("scene", ["paper_sim", "paper_sim_doubled"])
@pytest.mark.parametrize("mode", ["prior", "cold"])
def test_identity_rate(matchers, band_sets, scene, mode):
    m, bands = matchers[scene], band_sets[scene]
    results = [m.match(bd["det"], bd["rows"], bd["prior"] if mode == "prior" else None)
               for bd in bands]
    rate, rate3, precision, center_err = score(results, bands)
    # Every identity claimed: >= 99 % right.
    assert precision >= TARGET_RATE
    if mode == "prior":
        # With the previous sample, every detection, clutter included, gets its right label.
        assert rate >= TARGET_RATE
    else:
        # Cold, the matcher refuses what it cannot tell apart: bands of 1-2 glints (right only
        # ~40 % of the time, measured) and bands whose best two hypotheses score within
        # ``min_margin`` (mostly the chain shifted by one light). Measured on 2 x 150 bands:
        # 3.8-5.5 % (paper_sim) and 0.8-1.7 % (doubled) of the detections of bands with 3+
        # glints refused; 9 % on these 50 (paper_sim), one refused band weighing ~2 %.
        assert rate3 >= 0.88
    assert np.median(center_err) < CENTER_MEDIAN_M


def test_noise_free_full_pattern_is_exact(matchers):
    m = matchers["paper_sim"]
    g, vis, center = ground_truth_glints(m.setup, 0.2, -0.1)
    r = m.match(g[vis])
    assert r.ok
    assert np.array_equal(r.light_index, np.flatnonzero(vis))
    # The orbit fit of exact glints stops within 1e-10 m steps (cornea.py); 1e-8 m is far below
    # anything a pixel can resolve.
    assert np.linalg.norm(r.cornea_center_m - center) < 1e-8
    assert r.rms_px < 1e-4
    assert (r.confidence > 0.9).all()


def test_stale_prior_falls_back_to_the_search(matchers, band_sets):
    """A prior 12° off (after a blink) is no worse than none."""
    m = matchers["paper_sim"]
    for bd in band_sets["paper_sim"][:6]:
        stale = bd["truth"] + np.radians([12.0, -8.0])
        a = m.match(bd["det"], bd["rows"], stale)
        b = m.match(bd["det"], bd["rows"], None)
        assert np.array_equal(a.light_index, b.light_index)


def test_center_model(band_sets):
    setup = load_scene("paper_sim")
    m = GlintMatcher(setup, MatchParams(model="center"))
    bands = band_sets["paper_sim"][:20]
    results = [m.match(bd["det"], bd["rows"], bd["prior"]) for bd in bands]
    _, rate3, precision, center_err = score(results, bands)
    # The free centre (3 unknowns) lets a shifted chain fit a little better than on the orbit.
    assert precision >= 0.98 and rate3 >= 0.9
    # A band's few glints hardly constrain the centre's depth along the camera axis without
    # the orbit (measured median 0.1 mm): the reason "orbit" is the default.
    assert np.median(center_err) < 0.5e-3


# --------------------------------------------------------------------------- confidence


def test_blob_in_place_of_a_missing_glint_has_low_confidence(matchers):
    m = matchers["paper_sim"]
    g, vis, _ = ground_truth_glints(m.setup, 0.0, 0.0)
    lights = np.flatnonzero(vis & (g[:, 1] >= 150) & (g[:, 1] < 198))
    assert lights.size >= 5
    missing = lights[2]
    noise = np.random.default_rng(0).normal(0, 0.3, (lights.size - 1, 2))
    det = g[np.setdiff1d(lights, missing)] + noise
    det = np.vstack([det, g[missing] + [2.0, 0.0]])  # a blob 2 px from where it should be
    r = m.match(det, (150, 197))
    assert r.ok
    assert r.light_index[-1] == missing  # indistinguishable from a glint, but:
    assert r.confidence[-1] < 0.5 < np.median(r.confidence[:-1])


def test_ambiguous_runner_up_lowers_confidence(matchers, band_sets):
    """Cold bands: confidences of wrong identities are lower than of right ones on average."""
    m = matchers["paper_sim"]
    right, wrong = [], []
    for bd in realistic_bands(m.setup, 20, np.random.default_rng(77), band_rows=20):
        r = m.match(bd["det"], bd["rows"])
        ok = np.array([light in s for light, s in zip(r.light_index, bd["labels"])])
        right += list(r.confidence[ok & r.matched])
        wrong += list(r.confidence[~ok & r.matched])
    assert np.mean(right) > 0.5
    if wrong:
        assert np.mean(wrong) < np.mean(right)


# --------------------------------------------------------------------------- edge cases


def test_clutter_only_band_matches_nothing(matchers):
    m = matchers["paper_sim"]
    det = np.array([[5.0, 5.0], [630.0, 10.0], [620.0, 470.0], [10.0, 460.0]])
    r = m.match(det)
    assert not r.ok and r.reason in (NO_HYPOTHESIS, TOO_FEW_GLINTS)
    assert (r.light_index == -1).all() and (r.confidence == 0).all()
    assert np.isnan(r.cornea_center_m).all()


def test_empty_band(matchers):
    r = matchers["paper_sim"].match(np.zeros((0, 2)), (100, 147))
    assert r.reason == TOO_FEW_GLINTS and r.light_index.shape == (0,)


def test_result_is_immutable(matchers):
    g, vis, _ = ground_truth_glints(matchers["paper_sim"].setup, 0.0, 0.0)
    r = matchers["paper_sim"].match(g[vis][:10])
    assert r.ok and r.reason == OK
    with pytest.raises(FrozenInstanceError):
        r.reason = "x"


@pytest.mark.parametrize("glints, rows, prior, message", [
    (np.zeros((3, 3)), None, None, r"shape \(k, 2\)"),
    (np.array([[1.0, np.nan]]), None, None, "finite"),
    (np.zeros((3, 2)), (50, 10), None, "rows"),
    (np.zeros((3, 2)), None, [np.nan, 0.0], "prior"),
])
def test_bad_input(matchers, glints, rows, prior, message):
    with pytest.raises(ValueError, match=message):
        matchers["paper_sim"].match(glints, rows, prior)


@pytest.mark.parametrize("kwargs", [dict(model="full"), dict(gate_px=0), dict(hypotheses=0)])
def test_bad_params(kwargs):
    with pytest.raises(ValueError):
        MatchParams(**kwargs)


def test_order_along_the_arc_is_enforced(matchers):
    """Two matches whose detections run against their lights' order on the same arc: the worse
    one is dropped."""
    m = matchers["paper_sim"]
    pred = np.zeros((40, 2))
    pred[:5] = np.stack([np.arange(5) * 10.0, np.zeros(5)], axis=1)
    g = pred[:5].copy()
    g[2], g[3] = pred[3] + [0.2, 0], pred[2] + [-0.1, 0]  # detections of lights 2 and 3 swapped
    assign = m._enforce_order(g, pred, np.arange(5))
    assert (assign == -1).sum() == 1 and assign[2] == -1  # the one with the larger residual


# --------------------------------------------------------------------------- with the detector


def test_detect_then_match_a_banded_frame():
    """Synthetic banded frame -> detect_glints -> bands by strobe -> cold match per band."""
    setup = load_scene("paper_sim")
    m = GlintMatcher(setup)
    rng = np.random.default_rng(31)
    g, vis, _ = ground_truth_glints(setup, -0.15, 0.05)
    lights = np.flatnonzero(vis)
    frame = banded_frame(setup, g[vis], rng.uniform(0.6, 1.2, lights.size),
                         rng.uniform(250, 500, lights.size), rng)
    det = detect_glints(frame, setup)
    assert len(det) == lights.size
    bands = {b.pulse_index: b for b in band_layout(setup.sensor, setup.strobe, 0)}
    right = total = 0
    for j in np.unique(det.strobe_index):
        band = det.of_strobe(j)
        r = m.match(band.glints_px, (bands[j].first_row, bands[j].last_row))
        d = np.linalg.norm(g[vis][None] - band.glints_px[:, None], axis=-1)
        truth = lights[d.argmin(axis=1)]
        if len(band) >= 3:
            assert r.ok
            right += (r.light_index == truth).sum()
            total += len(band)
    assert total >= 30 and right / total >= TARGET_RATE


# --------------------------------------------------------------------------- calibrated geometry


def displaced(setup, correction):
    """``setup`` whose whole light rig is moved by a world-frame ``correction``."""
    from dataclasses import replace

    from estimator.setup import LightRig

    return replace(setup, lights=LightRig(tuple(g.moved(correction.compose(g.pose))
                                                for g in setup.lights.groups)))


def test_calibrated_geometry_identifies_a_displaced_rig():
    """The prototype's lighting sits millimetres off its nominal pose: glints predicted from
    the nominal rig miss by pixels, those from the calibrated one do not."""
    from dataclasses import replace

    from estimator.calibration import Calibration, pose_correction

    nominal = load_scene("paper_sim")
    # 2-3 mm and ~1.5° of rotation about the rig's centroid: within the assembly tolerance
    # the lighting calibration bounds (5 mm, 5°).
    correction = pose_correction(np.radians([1.0, -1.0, 0.5]), [2e-3, -2e-3, 1e-3],
                                 nominal.lights_world_m.mean(axis=0))
    true = displaced(nominal, correction)
    bands = realistic_bands(true, 40, np.random.default_rng(7))
    cal = replace(Calibration.ground_truth(nominal), lighting_correction=correction)
    calibrated = GlintMatcher(nominal, calibration=cal)
    assert np.allclose(calibrated.lights_world_m, true.lights_world_m, atol=1e-12)
    rates = {}
    for name, m in (("nominal", GlintMatcher(nominal)), ("calibrated", calibrated)):
        rates[name] = score([m.match(b["det"], b["rows"], b["prior"]) for b in bands], bands)
    rate, _, precision, _ = rates["calibrated"]
    assert rate >= TARGET_RATE and precision >= TARGET_RATE
    # Measured: 26 % of the labels and 10 % of the claimed identities right with the
    # nominal rig.
    assert rates["nominal"][0] < 0.5 and rates["nominal"][2] < 0.5


def test_calibrated_eye_replaces_the_nominal_one():
    from estimator.calibration import Calibration
    from estimator.matching import calibrated_eye

    setup = load_scene("paper_sim")
    cal = Calibration(cornea_radius_m=7.6e-3, eye_center_m=[1e-3, 0.0, 0.0], orbit_radius_m=4e-3)
    eye = calibrated_eye(setup.eye, cal)
    assert eye.cornea_radius_m == 7.6e-3 and eye.cornea_offset_m == 4e-3
    assert np.allclose(eye.rotation_center_m, [1e-3, 0.0, 0.0])
    assert np.isclose(eye.cap_cos_min, setup.eye.cap_cos_min)  # same cap angle
    no_orbit = calibrated_eye(setup.eye, Calibration(cornea_radius_m=7.6e-3))
    assert np.allclose(no_orbit.rotation_center_m, setup.eye.rotation_center_m)
    assert calibrated_eye(setup.eye, None) is setup.eye


# --------------------------------------------------------------------------- sparse bands


def _sparse_matches(m, n, seed, prior_error_deg, spurious, prior_sd_deg):
    """Bands of 12 rows holding a glint or more, matched by ``match_near`` with a prior of
    SD ``prior_sd_deg`` per axis."""
    bands = realistic_bands(m.setup, n, np.random.default_rng(seed), band_rows=12,
                            prior_error_deg=prior_error_deg, spurious=spurious)
    bands = [b for b in bands if b["labels"]]
    cov = np.eye(2) * np.radians(prior_sd_deg) ** 2
    return [m.match_near(b["det"], b["prior"], cov, b["rows"]) for b in bands], bands


def test_sparse_bands_are_identified_from_a_prior(matchers):
    """Bands of 12 rows (1-3 glints, up to one blob) with the previous sample's rotation off by
    up to 0.6° (a 600°/s saccade over one band period at 16 pulses per frame) and that much
    prior SD (:class:`estimator.tracker.BandPrior`)."""
    results, bands = _sparse_matches(matchers["paper_sim"], 150, 5, 0.6, (0, 1), 0.62)
    rate, _, precision, _ = score(results, bands)
    # Measured: 99.6 % of 261 claimed identities right, 91 % of the bands identified (the
    # others "ambiguous" or clutter alone), 94 % of all labels right.
    assert precision >= TARGET_RATE
    assert np.mean([r.ok for r in results]) > 0.85
    one = [r for r, b in zip(results, bands) if r.ok and r.matched.sum() == 1]
    assert one, "a single glint is identified with a prior"


def test_a_wide_prior_refuses_rather_than_guesses(matchers):
    """A prior as wide as the step between neighbouring glints cannot tell a chain from its
    shift: the matcher says so instead of claiming identities."""
    results, _ = _sparse_matches(matchers["paper_sim"], 60, 6, 0.0, (0, 0), 3.0)
    assert sum(r.reason == "ambiguous" for r in results) > 0.5 * len(results)


@pytest.mark.parametrize("prior, cov, message", [
    ((0.0, 0.0), np.zeros((2, 2)), "positive definite"),
    ((0.0, np.nan), np.eye(2), "finite"),
    ((0.0, 0.0), np.eye(3), r"\(2, 2\)"),
])
def test_match_near_bad_input(matchers, prior, cov, message):
    with pytest.raises(ValueError, match=message):
        matchers["paper_sim"].match_near(np.zeros((1, 2)), prior, cov)


def test_prior_window_is_the_grid_nodes_near_the_prior(matchers):
    """The search's grid nodes near a prior (``GlintMatcher._near``, by axis) are exactly those
    whose larger angle difference is within the window: priors anywhere on the eye's range
    and on the window's edge (a node plus or minus the window: the same float comparison)."""
    m = matchers["paper_sim"]
    w = np.radians(m.params.prior_window_deg)
    rng = np.random.default_rng(3)
    nodes = m.grid_angles_rad[rng.integers(0, len(m.grid_angles_rad), 300)]
    priors = np.concatenate([rng.uniform(-0.7, 0.7, (300, 2)),
                             nodes + rng.choice([-w, 0.0, w], (300, 2))])
    for p in priors:
        want = np.abs(m.grid_angles_rad - p).max(axis=1) <= w
        assert np.array_equal(m._near(p, w), want)
    assert m._near(np.zeros(2), w).sum() == (2 * int(m.params.prior_window_deg) + 1) ** 2


def test_search_shortcuts_give_the_same_floats(matchers):
    """The search's exact shortcuts (issue 31 seventh pass): the grid's local minima by
    running minima in place are those of the stacked neighbours' minimum, ties and
    unscored (inf) nodes included; the few-pose prediction written in place and a refinement's
    reused predictions give the bits of predicting the batch anew."""
    m = matchers["paper_sim"]
    rng = np.random.default_rng(7)
    g = np.zeros((40, 2))
    for _ in range(20):
        score = np.round(rng.uniform(0, 30, m.grid_angles_rad.shape[0]))  # ties
        score[rng.random(score.size) < 0.3] = np.inf
        grid = score.reshape(m._grid_shape)
        padded = np.pad(grid, 1, constant_values=np.inf)
        h, w = grid.shape
        nb = np.min([padded[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx]
                     for dy in (-1, 0, 1) for dx in (-1, 0, 1) if dy or dx], axis=0).ravel()
        minima = np.flatnonzero((score <= nb) & (score < g.shape[0] * m.params.unmatched_cost))
        want = minima[np.argsort(score[minima], kind="stable")][:12]
        got = m._minima(g, score, 12)
        assert len(got) == len(want)
        assert all(np.array_equal(a, m.grid_angles_rad[i]) for a, i in zip(got, want))
    X = rng.uniform(-0.4, 0.4, (9, 2))
    lo, hi = 150.0, 260.0
    pred, cand, inside = m._candidates(X, lo, hi)
    for h in range(X.shape[0] if kernels.ENABLED else 0):  # one pose at a time with Numba alone
        one, vis = m._predict_one(float(X[h, 0]), float(X[h, 1]))
        assert np.array_equal(pred[h], one) and np.array_equal(cand[h] & ~vis, np.zeros_like(vis))
    last = [(pred[h], cand[h]) if h % 2 else None for h in range(X.shape[0])]
    for a, b in zip(m._candidates_kept(X, last, lo, hi), (pred, cand, inside)):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert cand.any() and inside.any() and (cand & ~inside).any()
