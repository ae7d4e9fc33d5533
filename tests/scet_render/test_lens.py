"""The lens in the renderer (:mod:`scet_render.render.lens`): a distorted camera's pixels see the
rays :meth:`estimator.geometry.Camera.project` says they see, and a thin lens blurs a point into
the disc the thin-lens formula gives.

Small renders only: a 320x240 paper_sim frame (conductor cornea: exact glints at 32 spp) and a
48x48 image of one small sphere.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from estimator.banding.plan import scaled_setup
from estimator.geometry import Camera
from estimator.scene import load_scene
from scet_render.simulate import ground_truth_glints
from tests.scet_render.centroids import glint_centroids

mi_available = pytest.importorskip("mitsuba", reason="the renderer's tests need Mitsuba")

#: Lens rays against Camera.undistort_px (px): the kernel runs Newton in float32 on normalised
#: coordinates of ~0.3-0.6, whose resolution is ~4e-8, i.e. ~3e-5 px at 650 px; 1e-3 px leaves
#: 12x for the Jacobian's rounding. Measured: 8e-5 px.
LENS_VS_CAMERA_PX = 1e-3
#: Rendered glint centroids against the distorted labels, median (px): DESIGN.md's tenth of a
#: pixel (the pinhole's own check, measured 0.08 px at this size); measured 0.064 px.
CENTROID_MEDIAN_PX = 0.1
#: Blur disc diameter against the thin-lens formula (relative): the disc's second moment from
#: ~1e5 Monte Carlo hits has a ~1 % standard error; 4 % is four of them. Measured: -0.8 % at
#: 25 mm (14.70 px against 14.82), -0.2 % at 50 mm (11.09 against 11.11).
BLUR_DIAMETER_REL = 0.04

#: The distortion of the glint test: corners move 11 px at 320x240 (k1 = -0.5 at 650 px), the
#: glints of the test pose 0.5-1.8 px (median 1.5): fifteen times the centroid bound.
K1 = -0.5


def _lens_camera(cam, distortion=(), **lens):
    return Camera(cam.position_m, cam.rotation, cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px,
                  cam.width_px, cam.height_px, distortion, **lens)


@pytest.fixture(scope="module")
def mi():
    from scet_render.render.backend import activate, is_jit_variant

    mi = activate(None)
    if not is_jit_variant(mi.variant()):
        pytest.skip("lens rays need a JIT variant (no LLVM found)")
    return mi


@pytest.fixture(scope="module")
def half():
    return scaled_setup(load_scene("paper_sim"), 2)


def test_pinhole_has_no_lens_rays(half):
    from scet_render.render.lens import LensRays

    assert LensRays.of(half.camera) is None  # the sensor's own rays: today's frames unchanged


def test_lens_rays_see_what_the_camera_projects(mi, half):
    from scet_render.render.lens import LensRays

    cam = _lens_camera(half.camera, [K1, 0.08, 0.002, -0.001, 0.01])
    lens = LensRays.of(cam)
    rng = np.random.default_rng(0)
    px = np.column_stack([rng.uniform(-0.5, cam.width_px - 0.5, 4000),
                          rng.uniform(-0.5, cam.height_px - 0.5, 4000)])
    film = mi.Point2f(mi.Float(px[:, 0] + 0.5), mi.Float(px[:, 1] + 0.5))  # Mitsuba's film
    o, d = lens.rays(mi, film)
    d = np.array(d, dtype=np.float64).reshape(3, -1).T / 100.0
    o = np.array(o, dtype=np.float64).reshape(3, -1).T / 100.0
    np.testing.assert_allclose(o, np.broadcast_to(cam.position_m, o.shape), atol=1e-7)
    seen, _ = cam.project(cam.position_m + 0.04 * d / np.linalg.norm(d, axis=1, keepdims=True))
    err = np.abs(seen - px)
    print(f"lens rays vs Camera.project: max {err.max():.2e} px")
    assert err.max() < LENS_VS_CAMERA_PX, err.max()
    assert np.abs(cam.undistort_px(px) - px).max() > 5.0  # the lens moves the corners


def test_thin_lens_rays_meet_on_the_focus_plane(mi, half):
    import drjit as dr

    from scet_render.render.lens import LensRays

    cam = _lens_camera(half.camera, [K1, 0.0, 0.0, 0.0], f_number=2.0, focus_distance_m=0.04,
                       pixel_pitch_m=11.2e-6)
    lens = LensRays.of(cam)
    n = 2000
    film = mi.Point2f(mi.Float(np.full(n, 250.25)), mi.Float(np.full(n, 30.75)))
    rng = np.random.default_rng(1)
    pupil = mi.Point2f(mi.Float(rng.random(n)), mi.Float(rng.random(n)))
    o, d = lens.rays(mi, film, pupil)
    dr.eval(o, d)
    o = np.array(o, dtype=np.float64).reshape(3, -1).T / 100.0
    d = np.array(d, dtype=np.float64).reshape(3, -1).T
    oc = (o - cam.position_m) @ cam.rotation.T
    dc = d @ cam.rotation.T
    assert np.abs(oc[:, 2]).max() < 1e-7  # origins on the pupil plane ...
    r = np.hypot(oc[:, 0], oc[:, 1])
    assert r.max() <= cam.aperture_radius_m * (1 + 1e-5) and r.max() > 0.95 * cam.aperture_radius_m
    focus = oc + dc * ((0.04 - oc[:, 2]) / dc[:, 2])[:, None]  # ... and meet at the focus point
    chief = cam.undistort_px(np.array([[249.75, 30.25]]))[0]
    target = np.array([(chief[0] - cam.cx_px) / cam.fx_px, (chief[1] - cam.cy_px) / cam.fy_px]) * 0.04
    np.testing.assert_allclose(focus[:, :2], np.broadcast_to(target, (n, 2)), atol=1e-8)


def _blur_image(mi, cam, center_cam_m, radius_m, spp, seed=7):
    """(H, W) share of each pixel's lens samples that hit a sphere (camera-frame centre)."""
    import drjit as dr

    from scet_render.render.lens import LensRays, band_rays
    from scet_render.render.scene import sensor_dict

    center = cam.position_m + np.asarray(center_cam_m) @ cam.rotation
    scene = mi.load_dict({"type": "scene", "ball": {
        "type": "sphere", "center": (center * 100.0).tolist(), "radius": radius_m * 100.0}})
    d = sensor_dict(cam, spp)
    d["to_world"] = mi.ScalarTransform4f(d["to_world"])
    sensor = mi.load_dict(d)
    W, H = cam.width_px, cam.height_px
    _, ray, _ = band_rays(mi, sensor, mi.UInt32(0), mi.UInt32(seed),
                          dr.zeros(mi.UInt32, W * H * spp), spp, W, H, LensRays.of(cam))
    hit = dr.select(scene.ray_intersect(ray).is_valid(), 1.0, 0.0)
    return np.array(dr.block_sum(mi.Float(hit), spp), dtype=np.float64).reshape(H, W) / spp


@pytest.mark.parametrize("depth_m", [0.025, 0.050])
def test_defocus_disc_matches_the_thin_lens_formula(mi, depth_m):
    """A small sphere off the focus plane images as a uniform disc of diameter
    c = A |d - d_f| / d * f / (d_f - f) (in pixels / pitch), convolved with the sphere's own
    image and the pixel: the variances add, per axis c^2 / 16 + s^2 / 16 + 1 / 12."""
    pitch, n, df = 5.6e-6, 1.0, 0.035
    cam = Camera([0.0, 0.0, 0.0], np.eye(3), 500.0, 500.0, 23.5, 23.5, 48, 48, (), n, df, pitch)
    f = cam.focal_length_m
    expected = (f / n) * abs(depth_m - df) / depth_m * f / (df - f) / pitch
    assert 10.0 < expected < 16.0
    radius = 1.0 * depth_m / cam.fx_px  # its sharp image is a disc of s = 2 rho f_px / d = 2 px
    s = 2 * radius * cam.fx_px / depth_m
    img = _blur_image(mi, cam, [0.0, 0.0, depth_m], radius, spp=1024)
    v, u = np.mgrid[:48, :48]
    total = img.sum()
    mu, mv = (img * u).sum() / total, (img * v).sum() / total
    np.testing.assert_allclose([mu, mv], [23.5, 23.5], atol=0.1)  # on the axis: the disc's centre
    var = ((img * ((u - mu) ** 2 + (v - mv) ** 2)).sum() / total) / 2  # per axis
    measured = np.sqrt(16 * (var - s * s / 16 - 1 / 12))
    print(f"blur disc at {depth_m * 1e3:.0f} mm: {measured:.3f} px, formula {expected:.3f} px")
    assert measured == pytest.approx(expected, rel=BLUR_DIAMETER_REL), (measured, expected)
    assert img[0].max() == 0 and img[:, 0].max() == 0  # the whole disc is in the image


def test_rendered_glints_land_on_the_distorted_labels(mi, half):
    """DESIGN.md's check through a distorting lens: every glint lands where Camera.project (via
    the labels' distort_px) puts it, to a tenth of a pixel, and far from the pinhole's place."""
    from scet_render.render import BandedRenderer

    from scet_render.dataset.labels import frame_labels

    class Fixation:
        def angles_at(self, t):
            t = np.asarray(t, dtype=float)
            return np.full(t.shape, -0.12), np.full(t.shape, 0.04)

        def target_at(self, t):
            return np.zeros(np.shape(t) + (3,))

    setup = dataclasses.replace(half, camera=_lens_camera(half.camera, [K1, 0.0, 0.0, 0.0, 0.0]))
    g, vis, _ = ground_truth_glints(setup, -0.12, 0.04)
    ideal = g[vis]
    label = frame_labels(setup, Fixation(), 0)[0]  # any strobe: the eye holds still
    labels = np.array([p for p, v in zip(label["glints_px"], label["glints_visible"]) if v])
    np.testing.assert_array_equal(label["glints_visible"], vis)
    renderer = BandedRenderer(setup, spp=32, cornea="conductor", seed=3)
    img, _ = renderer.render_rows(-0.12, 0.04)
    cen, _ = glint_centroids(img, labels, labels)
    assert np.isfinite(cen).all()
    dist = np.hypot(*(cen - labels).T)
    print(f"glint centroids on distorted labels: median {np.median(dist):.3f} px, max {dist.max():.3f} px")
    assert np.median(dist) < CENTROID_MEDIAN_PX
    assert np.median(np.hypot(*(cen - ideal).T)) > 1.0  # the pinhole's glints are wrong here


def test_lens_kernels_replay_with_mnee(mi, half):
    """A lens camera (distortion and thin lens) through both frozen kernels, path tracing and
    MNEE (the default dielectric cornea): eye poses replay the recordings, and MNEE adds the
    strobe light it carries through the cornea (the iris lit) to the lens's frames too."""
    from scet_render.render import BandedRenderer

    cam = _lens_camera(half.camera, [K1, 0.0, 0.0, 0.0, 0.0], f_number=4.0,
                       focus_distance_m=0.035, pixel_pitch_m=11.2e-6)
    setup = dataclasses.replace(half, camera=cam)
    rows = (100, 140)
    lit = BandedRenderer(setup, spp=4, seed=5)
    assert lit.eye_scene.mnee_enabled
    for k in range(3):
        strobe, _ = lit.render_rows(-0.12 + 0.02 * k, 0.04, *rows, seed=k)
        assert np.isfinite(strobe).all()
    n = rows[1] - rows[0]
    assert lit._kernels[4, n].n_recordings <= 2  # recorded once (+ one re-record), then replayed
    assert lit._mnee.fronts[4, n].n_recordings <= 2  # MNEE's front kernel, as the path's
    assert lit._mnee.back.n_recordings <= 3  # as test_mnee's replay test: not one per pose
    dark = BandedRenderer(setup, spp=4, seed=5, options=dataclasses.replace(
        lit.options, strobe_through_cornea="none"))
    with_mnee = lit.render_rows(-0.12, 0.04, *rows, seed=9)[0]
    without = dark.render_rows(-0.12, 0.04, *rows, seed=9)[0]
    assert (with_mnee - without).sum() > 0.01 * with_mnee.sum()


@pytest.mark.slow  # two eye scenes built: ~20-40 s on 2 loaded cores
def test_thin_lens_chief_rays_are_the_pinholes(mi, half):
    """The pupil's centre is the centre of projection: region_labels (chief rays) of a thin-lens
    camera see exactly what the pinhole's pixel centres see."""
    from scet_render.render import BandedRenderer, region_labels

    cam = _lens_camera(half.camera, f_number=2.9, focus_distance_m=0.035, pixel_pitch_m=11.2e-6)
    pin = region_labels(BandedRenderer(half, spp=1), -0.12, 0.04)
    thin = region_labels(BandedRenderer(dataclasses.replace(half, camera=cam), spp=1), -0.12, 0.04)
    assert (pin >= 0).mean() > 0.3
    np.testing.assert_array_equal(thin, pin)
