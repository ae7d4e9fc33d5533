"""Banded renders: glints where the closed form puts them, bands where Eqs. (2)-(8) put them,
the fast band renderer against the full-frame reference, determinism, no recompilation.

Frame planning is tested without Mitsuba. Render tests skip without it, and run on whatever
variant :func:`scet_render.render.backend.activate` picks; under ``scalar_rgb``
(``SCET_MITSUBA_VARIANT=scalar_rgb``) the full-size banded frames are skipped, being ~10x slower.
"""

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest

from estimator.banding import band_layout, row_pulse_weights
from estimator.eye import eye_rotation_matrix
from estimator.geometry import Camera
from estimator.scene import load_scene
from estimator.setup import Strobe
from scet_render.motion import fixation_sequence
from scet_render.render import BandedRenderer, FrameRender, plan_frame
from scet_render.simulate import ground_truth_glints
from tests.scet_render.centroids import HALF_WINDOW_PX, glint_centroids


@dataclass(frozen=True)
class Tol:
    #: Glint centroid against project_glints at 640x480 (px), the issue's bounds. Measured
    #: with the conductor cornea at 16 spp: median ~0.05 px, max ~0.3 px (sampling noise of a
    #: 3x5 px glint, and the pixel-area integration of its edge).
    glint_median_px: float = 0.1
    glint_max_px: float = 0.5
    #: Lit rows against band_layout (rows): the issue's bound.
    lit_rows: int = 1
    #: Ambient quadrature weights sum to the exposure (s): float64 sums of ~20 terms of 1e-4 s.
    exposure_sum_s: float = 1e-15
    #: Fast vs reference: RMS over rows of the row-mean difference, relative to the same
    #: statistic between two fast renders with different seeds (pure Monte Carlo noise). Both
    #: are estimates from ~120 rows, so their ratio scatters by ~10 %; 1.5 leaves room for that
    #: and fails on any real bias larger than the noise.
    fast_vs_reference_noise_ratio: float = 1.5


TOL = Tol()
#: Closer glints touch (their blobs are up to 5 px long); the test leaves them out.
MIN_GLINT_SPACING_PX = 7.0


# --------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def paper():
    return load_scene("paper_sim")


def _small(setup):
    """paper_sim scaled to 160x120 with S = 196 lines: the same bands at a quarter of the rows."""
    cam = setup.camera
    small_cam = Camera(cam.position_m, cam.rotation, cam.fx_px / 4, cam.fy_px / 4,
                       (160 - 1) / 2, (120 - 1) / 2, 160, 120)
    sensor = dataclasses.replace(setup.sensor, total_lines=196, visible_lines=120)
    return dataclasses.replace(setup, camera=small_cam, sensor=sensor)


@pytest.fixture(scope="module")
def small(paper):
    return _small(paper)


def _saccade(setup, start_s=0.005):
    """A fixation, then a 20 deg saccade from the screen's top left toward its centre."""
    targets = setup.screen.grid(3, 3)[[0, 4]]
    return fixation_sequence(setup.eye, targets, [start_s, 0.5])


def _still(setup):
    return fixation_sequence(setup.eye, setup.screen.grid(3, 3)[[4]], [1.0])


def _saccade_frame(setup, traj) -> int:
    """The first frame whose exposure span contains the peak speed of the saccade."""
    seg = 1
    t_peak = traj.start_s[seg] + 0.5 * traj.segment_duration_s[seg]
    return int(t_peak // setup.sensor.frame_period_s)


@pytest.fixture(scope="module")
def mi():
    pytest.importorskip("mitsuba")
    from scet_render.render import activate

    return activate()


@pytest.fixture(scope="module")
def jit(mi):
    return not mi.variant().startswith("scalar")


@pytest.fixture(scope="module")
def glint_renderer(mi, paper):
    """Conductor cornea (exact glints at low spp), strobe light only."""
    return BandedRenderer(paper, cornea="conductor", spp=16, ambient=0.0, seed=11)


#: Ambient instants every ~0.5 px of motion: the small frames' saccade gets K = 2. The
#: conductor cornea keeps glints out of the Monte Carlo noise: a dielectric reflects ~2.5 % of
#: the samples, so its sub-pixel glints at 160x120 would dominate every row's variance.
SMALL = dict(spp=8, blur_step_px=0.5, cornea="conductor")


@pytest.fixture(scope="module")
def small_renderer(mi, small):
    return BandedRenderer(small, seed=7, **SMALL)


# --------------------------------------------------------------------------- planning


def test_plan_of_a_still_eye_renders_each_band_over_its_rows(paper):
    plan = plan_frame(paper, _still(paper), 3)
    j, s, w = row_pulse_weights(paper.sensor, paper.strobe, 3)
    lit = w.max(axis=0) > 0
    assert plan.instants_per_period == 1  # nothing moves: the strobe instants suffice
    assert plan.pulse_indices.tolist() == j[lit].tolist()
    assert np.array_equal(plan.row_weights, w[:, lit])
    assert np.allclose(plan.pulse_times_s, s[lit] + 0.5 * paper.strobe.pulse_s, rtol=0, atol=0)
    for k in np.flatnonzero(plan.pulse_column >= 0):
        rows = np.flatnonzero(plan.row_weights[:, plan.pulse_column[k]] > 0)
        assert (rows[0], rows[-1] + 1) == tuple(plan.rows[k])  # only the rows it lights
    sums = plan.ambient_weights_s.sum(axis=1)
    assert np.abs(sums - paper.sensor.exposure_s).max() < TOL.exposure_sum_s
    # Every visible band of the banding model, and nothing else.
    bands = [b.pulse_index for b in band_layout(paper.sensor, paper.strobe, 3) if b.visible]
    assert plan.pulse_indices.tolist() == bands


def test_plan_samples_the_ambient_densely_during_a_saccade(paper):
    traj = _saccade(paper)
    f = _saccade_frame(paper, traj)
    plan = plan_frame(paper, traj, f, blur_step_px=1.0, max_ambient_instants=8)
    assert plan.instants_per_period > 1
    assert np.sum(plan.pulse_column < 0) > 0  # ambient-only instants between the strobes
    assert np.all(np.diff(plan.times_s) > 0)
    sums = plan.ambient_weights_s.sum(axis=1)
    assert np.abs(sums - paper.sensor.exposure_s).max() < TOL.exposure_sum_s
    # Each ambient-only slice renders exactly the rows whose exposure window holds its instant.
    R = f * paper.sensor.frame_period_s + np.arange(480) * paper.sensor.line_time_s
    for k in np.flatnonzero(plan.pulse_column < 0):
        inside = np.flatnonzero((R - paper.sensor.exposure_s <= plan.times_s[k])
                                & (plan.times_s[k] <= R))
        assert (inside[0], inside[-1] + 1) == tuple(plan.rows[k])
    none = plan_frame(paper, traj, f, ambient=False)
    assert none.instants_per_period == 1 and np.all(none.pulse_column >= 0)


def test_plan_covers_the_dark_gaps_of_a_slow_strobe(paper):
    slow = dataclasses.replace(paper, strobe=Strobe(16, 100e-6, 1.5e-3))
    plan = plan_frame(slow, _still(slow), 0)
    lit = plan.row_weights.sum(axis=1) > 0
    assert not lit.all()  # dark rows between the bands...
    covered = np.zeros(480, bool)
    for start, stop in plan.rows:
        covered[start:stop] = True
    assert covered.all()  # ...still get their ambient light
    sums = plan.ambient_weights_s.sum(axis=1)
    assert np.abs(sums - slow.sensor.exposure_s).max() < TOL.exposure_sum_s


@pytest.mark.parametrize("kwargs, match", [
    ({"spp": 0}, "spp"), ({"seed": -1}, "seed"), ({"ambient_spp": 0}, "ambient_spp"),
    ({"blur_step_px": 0.0}, "blur_step_px"), ({"max_ambient_instants": 0}, "max_ambient"),
])
def test_renderer_rejects_bad_settings(paper, kwargs, match):
    with pytest.raises(ValueError, match=match):
        BandedRenderer(paper, **kwargs)


# --------------------------------------------------------------------------- glints


def _centroids(img: np.ndarray, pred_px: np.ndarray, all_px: np.ndarray) -> np.ndarray:
    """(n, 2) intensity-weighted centroids of the glints predicted at ``pred_px``
    (:func:`tests.scet_render.centroids.glint_centroids`)."""
    return glint_centroids(img, pred_px, all_px)[0]


def _isolated(glints_px, visible):
    """Visible glints at least MIN_GLINT_SPACING_PX from any other visible glint."""
    g = np.where(visible[:, None], glints_px, np.inf)
    d = np.linalg.norm(g[:, None] - g[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    return visible & (d.min(axis=1) > MIN_GLINT_SPACING_PX)


def strobe_centroids(renderer, setup, yaw, pitch, seed=5):
    """One strobe rendered over the rows of its isolated glints at the eye pose (yaw,
    pitch): their measured centroids (k, 2), their labels (k, 2) and which visible glints
    they are (n,) bool."""
    g, vis, _ = ground_truth_glints(setup, yaw, pitch)
    ok = _isolated(g, vis)
    h, w = setup.camera.height_px, setup.camera.width_px
    rows = (max(0, int(g[ok, 1].min()) - 8), min(h, int(g[ok, 1].max()) + 9))
    strobe, _ = renderer.render_rows(yaw, pitch, *rows, seed=seed)
    img = np.zeros((h, w), np.float32)
    img[rows[0]:rows[1]] = strobe
    return _centroids(img, g[ok], g[vis]), g[ok], ok


def test_single_strobe_glints_land_on_the_closed_form(glint_renderer, paper):
    errors = []
    for yaw, pitch in [(0.0, 0.0), (0.2, -0.12)]:
        c, labels, _ = strobe_centroids(glint_renderer, paper, yaw, pitch)
        errors.append(np.linalg.norm(c - labels, axis=1))
    e = np.concatenate(errors)
    assert np.isfinite(e).all() and e.size >= 30
    assert np.median(e) <= TOL.glint_median_px, f"median {np.median(e):.3f} px"
    assert e.max() <= TOL.glint_max_px, f"max {e.max():.3f} px"


@pytest.fixture(scope="module")
def saccade_frame(glint_renderer, paper, jit):
    if not jit:
        pytest.skip("a 640x480 banded frame takes minutes under scalar_rgb")
    traj = _saccade(paper)
    f = _saccade_frame(paper, traj)
    return traj, glint_renderer.render_frame(traj, f)


def test_banded_glints_land_on_the_closed_form_of_their_strobe(saccade_frame, paper):
    """Each band shows the glints at the pose of its own strobe instant (Eq. (2) timing)."""
    traj, frame = saccade_frame
    assert isinstance(frame, FrameRender) and frame.radiance.dtype == np.float32
    w = frame.row_weights
    errors, bands_used, moved = [], 0, []
    for col in range(w.shape[1]):
        # Plateau rows of this pulse alone: the whole pulse, no other pulse.
        only = (w[:, col] == 1.0) & (np.delete(w, col, axis=1).sum(axis=1) == 0)
        yaw, pitch = frame.yaw_rad[col], frame.pitch_rad[col]
        g, vis, _ = ground_truth_glints(paper, yaw, pitch)
        v = np.round(g[:, 1]).astype(int)
        inside = _isolated(g, vis) & (v >= HALF_WINDOW_PX) & (v < 480 - HALF_WINDOW_PX)
        inside[inside] &= [only[y - HALF_WINDOW_PX:y + HALF_WINDOW_PX + 1].all()
                           for y in v[inside]]
        if inside.any():
            bands_used += 1
            c = _centroids(frame.radiance, g[inside], g[vis])
            errors.append(np.linalg.norm(c - g[inside], axis=1))
            moved.append(g[inside])
    e = np.concatenate(errors)
    assert bands_used >= 3 and e.size >= 10
    assert np.median(e) <= TOL.glint_median_px, f"median {np.median(e):.3f} px"
    assert e.max() <= TOL.glint_max_px, f"max {e.max():.3f} px"
    # The eye really moved between the strobes: poses differ by more than a pixel's worth.
    assert np.ptp(frame.yaw_rad) + np.ptp(frame.pitch_rad) > 0.01
    assert np.allclose(traj.angles_at(frame.pulse_times_s), (frame.yaw_rad, frame.pitch_rad))


@pytest.fixture(scope="module")
def still_frames(glint_renderer, paper, jit):
    if not jit:
        pytest.skip("two 640x480 frames take minutes under scalar_rgb")
    traj = _still(paper)
    banded = glint_renderer.render_frame(traj, 2)
    yaw, pitch = traj.angles_at(1.0)
    return banded, glint_renderer.render_global(float(yaw), float(pitch), seed=99)


def test_lit_rows_follow_the_banding_equations(still_frames, paper):
    banded, _ = still_frames
    lit_rendered = banded.radiance.max(axis=1) > 0
    bands = [b for b in band_layout(paper.sensor, paper.strobe, 2) if b.visible]
    lit_model = np.zeros(480, bool)
    for b in bands:
        lit_model[b.first_row:min(b.last_row, 479) + 1] = True
    edges_r = np.flatnonzero(np.diff(lit_rendered.astype(int)))
    edges_m = np.flatnonzero(np.diff(lit_model.astype(int)))
    assert edges_r.size == edges_m.size
    assert np.abs(edges_r - edges_m).max(initial=0) <= TOL.lit_rows
    assert np.abs(lit_rendered.astype(int) - lit_model.astype(int)).sum() <= TOL.lit_rows * max(
        1, edges_m.size)


def test_rows_collect_their_pulse_fraction(still_frames):
    """Row by row, banded / global-shutter strobe light = Σ_j w_j(y) (Eqs. (2)-(3))."""
    banded, global_frame = still_frames
    expect = banded.row_weights.sum(axis=1)
    # Row means without the glints: a glint is sampled by a few of a pixel's 16 rays (the
    # emitter's reflection covers part of it), so a row through one carries its Monte Carlo
    # noise, up to F / F0 = 2.7 times brighter than the rest of the row's light.
    bright = np.maximum(banded.radiance, global_frame) > 0.2 * global_frame.max()
    row_b = np.where(bright, 0.0, banded.radiance).sum(axis=1)
    row_g = np.where(bright, 0.0, global_frame).sum(axis=1)
    rows = row_g > 0.05 * row_g.max()
    ratio = row_b[rows] / row_g[rows]
    # Per-row sums of ~640 px at 16 spp: a few % of Monte Carlo noise per row.
    assert rows.sum() > 100
    assert np.median(np.abs(ratio - expect[rows])) < 0.03
    assert np.abs(ratio - expect[rows]).max() < 0.25


@pytest.mark.slow
def test_mesh_cornea_glints_land_on_the_closed_form(mi, paper):
    from scet_render.render import SceneOptions

    r = BandedRenderer(paper, cornea="conductor", spp=16, ambient=0.0,
                       options=SceneOptions(cornea_geometry="mesh"))
    g, vis, _ = ground_truth_glints(paper, 0.1, -0.05)
    ok = _isolated(g, vis)
    strobe, _ = r.render_rows(0.1, -0.05, seed=2)
    e = np.linalg.norm(_centroids(strobe, g[ok], g[vis]) - g[ok], axis=1)
    assert np.median(e) <= TOL.glint_median_px and e.max() <= TOL.glint_max_px


# --------------------------------------------------------------------------- fast vs reference


@pytest.fixture(scope="module")
def small_frames(small_renderer, small):
    traj = _saccade(small)
    f = _saccade_frame(small, traj)
    fast = small_renderer.render_frame(traj, f)
    return traj, f, fast


def test_band_renderer_matches_the_full_frame_reference(small_frames, small_renderer, small):
    traj, f, fast = small_frames
    assert small_renderer.plan(traj, f).instants_per_period > 1  # ambient blur is exercised
    ref = small_renderer.render_frame_reference(traj, f)
    other = BandedRenderer(small, seed=8, **SMALL).render_frame(traj, f)
    for name in ("pulse_indices", "pulse_times_s", "row_weights", "yaw_rad", "pitch_rad",
                 "ambient_times_s"):
        assert np.array_equal(getattr(fast, name), getattr(ref, name)), name
    diff_ref = (fast.radiance - ref.radiance).mean(axis=1)
    diff_mc = (fast.radiance - other.radiance).mean(axis=1)
    rms_ref, rms_mc = np.sqrt(np.mean(diff_ref ** 2)), np.sqrt(np.mean(diff_mc ** 2))
    assert rms_mc > 0
    assert rms_ref <= TOL.fast_vs_reference_noise_ratio * rms_mc, (rms_ref, rms_mc)
    # No overall bias: the mean over rows is within 4 standard errors of the noise.
    assert abs(diff_ref.mean()) <= 4 * rms_mc / np.sqrt(diff_ref.size) * np.sqrt(2)


def test_same_seed_gives_identical_bytes(small_frames, small_renderer, small):
    traj, f, fast = small_frames
    again = small_renderer.render_frame(traj, f)
    assert again.radiance.tobytes() == fast.radiance.tobytes()
    # A fresh renderer gives the same slices (frames are compositions of seeded slices), so a
    # resumed dataset run matches an uninterrupted one. The warmed renderer replays its frozen
    # kernels after three poses, the fresh one traces them: a replay must see the moved eye.
    for k in range(4):
        small_renderer.render_rows(0.01 * k, 0.0, 30, 43, seed=k)
    a = small_renderer.render_rows(0.05, -0.02, 30, 43, seed=3)
    b = BandedRenderer(small, seed=7, **SMALL).render_rows(0.05, -0.02, 30, 43, seed=3)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(a, b))
    assert np.all(np.isfinite(fast.radiance)) and fast.radiance.min() >= 0


def assert_frame_compiles_nothing(renderer, traj, f):
    """Frame f + 2 of a saccade, after f + 1 has warmed every band height: the eye moves
    within it, and no kernel compiles (every one a cache hit)."""
    import drjit as dr

    renderer.render_frame(traj, f + 1)
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history_clear()
        frame = renderer.render_frame(traj, f + 2)
        history = dr.kernel_history([dr.KernelType.JIT])
    assert np.ptp(frame.yaw_rad) + np.ptp(frame.pitch_rad) > 0  # the eye moved
    assert history, "no kernel ran"
    compiled = [k for k in history if not k.get("cache_hit", True)]
    assert compiled == [], f"{len(compiled)} of {len(history)} kernels were compiled"


def test_moving_the_eye_does_not_recompile(small_frames, small_renderer, small, jit):
    if not jit:
        pytest.skip("scalar_rgb compiles no kernels")
    traj, f, _ = small_frames
    assert_frame_compiles_nothing(small_renderer, traj, f)


def test_eye_pose_matches_the_trajectory_rotation(small_frames):
    traj, _, fast = small_frames
    for t, yaw, pitch in zip(fast.pulse_times_s, fast.yaw_rad, fast.pitch_rad):
        d = traj.direction_at(t)
        assert np.allclose(eye_rotation_matrix(yaw, pitch) @ [0.0, 0.0, -1.0], d, atol=1e-12)
