"""The closed-form forward projection: law of reflection, brute force, degenerate geometry."""

import numpy as np
import pytest
from scipy.optimize import minimize

from estimator.geometry import Camera
from estimator.eye import gaze_direction
from estimator.geometry import look_at_rotation
from estimator.geometry import project_glints, reflect_pixel_rays, reflection_points
from estimator.geometry.roots import reflection_quartic
from estimator.scene import load_scene
from tests.tolerances import TOL


@pytest.fixture(scope="module")
def setup():
    return load_scene("paper_sim")


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


def random_rig(rng, m=50, n=40):
    """Cornea centres near the paper's eye and lights scattered around it (both outside)."""
    centers = rng.normal(0, 2e-3, size=(m, 3)) + [0, 0, -4.25e-3]
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[:, 2] = -np.abs(dirs[:, 2])  # in front of the eye, where lights are
    lights = dirs * rng.uniform(0.02, 0.06, size=(n, 1))
    return centers, lights


def reflection_errors(camera_pos, points, normals, lights):
    """Angle between incidence and reflection about the normal, and the out-of-plane angle."""
    to_cam = camera_pos - points
    to_cam /= np.linalg.norm(to_cam, axis=-1, keepdims=True)
    to_light = lights - points
    to_light /= np.linalg.norm(to_light, axis=-1, keepdims=True)
    a_in = np.arctan2(np.linalg.norm(np.cross(to_light, normals), axis=-1), np.sum(to_light * normals, -1))
    a_out = np.arctan2(np.linalg.norm(np.cross(to_cam, normals), axis=-1), np.sum(to_cam * normals, -1))
    # Coplanarity: the normal lies in the plane of the two rays.
    plane = np.cross(to_cam, to_light)
    plane_norm = np.linalg.norm(plane, axis=-1)
    off_plane = np.arcsin(np.clip(np.abs(np.sum(plane * normals, -1)) / np.maximum(plane_norm, 1e-300), 0, 1))
    return np.abs(a_in - a_out), np.where(plane_norm > 1e-12, off_plane, 0.0)


@pytest.mark.parametrize("solver", ["newton", "quartic"])
def test_law_of_reflection_holds_at_every_visible_glint(rng, solver):
    centers, lights = random_rig(rng)
    cam_pos = np.array([0.012, -0.008, -0.030])
    points, normals, ok = reflection_points(cam_pos, centers, 7.8e-3, lights, solver=solver)
    assert ok.sum() > 0.3 * ok.size, "the random rig should produce many valid reflections"
    angle, off_plane = reflection_errors(cam_pos, points, normals, np.broadcast_to(lights, points.shape))
    assert angle[ok].max() < TOL.reflection_angle_rad
    assert off_plane[ok].max() < TOL.reflection_angle_rad
    # Points lie on the sphere.
    assert np.abs(np.linalg.norm(points - centers[:, None], axis=-1) - 7.8e-3).max() < 1e-15


def test_paper_scene_glints_obey_reflection(setup):
    targets = setup.screen.grid(24, 15)
    yaw, pitch = setup.eye.angles_toward(targets)
    center = setup.eye.cornea_center(yaw, pitch)
    glints, visible, points = project_glints(
        setup.camera, center, setup.eye.cornea_radius_m, setup.lights_world_m,
        cornea_axis=gaze_direction(yaw, pitch), cap_cos_min=setup.eye.cap_cos_min, return_points=True)
    normals = (points - center[:, None]) / setup.eye.cornea_radius_m
    angle, off_plane = reflection_errors(setup.camera.position_m, points, normals,
                                         np.broadcast_to(setup.lights_world_m, points.shape))
    assert visible.sum() > 0.9 * visible.size
    assert angle[visible].max() < TOL.reflection_angle_rad
    assert off_plane[visible].max() < TOL.reflection_angle_rad
    # The glint is the image of the reflection point, and lies in the image.
    px, _ = setup.camera.project(points)
    assert np.abs(px - glints)[visible].max() < TOL.pixel_roundtrip_px
    assert np.all(setup.camera.in_image(glints[visible]))


def brute_force_reflection(cam, center, r, light):
    """Fermat: the reflection point minimises |O - P| + |P - L| over the sphere (the smallest
    ellipsoid with foci O and L touches the convex mirror there). Dense sampling, then a simplex
    refinement in spherical angles: no use of the quartic or of the law of reflection."""
    n = 200_000
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = np.pi * (1 + 5 ** 0.5) * i
    s = np.sqrt(1 - z * z)
    u = np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)
    path = np.linalg.norm(center + r * u - cam, axis=1) + np.linalg.norm(center + r * u - light, axis=1)
    best = u[np.argmin(path)]

    def point(a):
        return center + r * np.array([np.sin(a[0]) * np.cos(a[1]), np.sin(a[0]) * np.sin(a[1]), np.cos(a[0])])

    def f(a):
        p = point(a)
        return np.linalg.norm(p - cam) + np.linalg.norm(p - light)

    a0 = np.array([np.arccos(np.clip(best[2], -1, 1)), np.arctan2(best[1], best[0])])
    res = minimize(f, a0, method="Nelder-Mead", options={"xatol": 1e-13, "fatol": 1e-16, "maxiter": 4000})
    return point(res.x)


def test_agrees_with_brute_force_search(setup):
    rng = np.random.default_rng(7)
    cam = setup.camera.position_m
    for _ in range(6):
        yaw, pitch = rng.uniform(-0.3, 0.3), rng.uniform(-0.25, 0.12)
        center = setup.eye.cornea_center(yaw, pitch)
        lights = setup.lights_world_m[rng.choice(setup.lights.count, 3, replace=False)]
        points, _, ok = reflection_points(cam, center, setup.eye.cornea_radius_m, lights)
        for p, good, light in zip(points, ok, lights):
            assert good
            q = brute_force_reflection(cam, center, setup.eye.cornea_radius_m, light)
            assert np.linalg.norm(p - q) < TOL.brute_force_point_m


def test_quartic_and_newton_solvers_agree(rng):
    centers, lights = random_rig(rng, m=200)
    cam = np.array([0.012, -0.008, -0.030])
    p1, n1, ok1 = reflection_points(cam, centers, 7.8e-3, lights, solver="newton")
    p2, n2, ok2 = reflection_points(cam, centers, 7.8e-3, lights, solver="quartic")
    assert np.array_equal(ok1, ok2)
    # arctan2 of |cross| and dot: arccos loses half the digits near zero angle.
    angle = np.arctan2(np.linalg.norm(np.cross(n1, n2), axis=-1), np.sum(n1 * n2, -1))
    assert angle[ok1].max() < TOL.solver_agreement_rad


def test_quartic_roots_are_reflections(rng):
    """Every root t = tan(θ/2) of the quartic satisfies the trigonometric condition (R)."""
    alpha, beta = rng.uniform(1.2, 8, 100), rng.uniform(1.2, 8, 100)
    phi = rng.uniform(0.1, 3.0, 100)
    for a, b, p, c in zip(alpha, beta, phi, reflection_quartic(alpha, beta, phi)):
        for t in np.roots(c):
            if abs(t.imag) < 1e-9:
                th = 2 * np.arctan(t.real)
                F = a * b * np.sin(p - 2 * th) + a * np.sin(th) - b * np.sin(p - th)
                assert abs(F) < 1e-8 * a * b


def test_light_behind_cornea_is_invisible_without_nan(setup):
    cam = setup.camera
    center = setup.eye.cornea_center(0.0, 0.0)
    behind = center + 0.03 * (center - cam.position_m) / np.linalg.norm(center - cam.position_m)
    almost = behind + [1e-4, 0, 0]
    glints, visible = project_glints(cam, center, setup.eye.cornea_radius_m, np.array([behind, almost]))
    assert not visible.any()
    assert not np.isnan(glints).any(), "points in front of the camera must project to finite pixels"


def test_light_on_camera_axis(setup):
    """A light on the line through the camera and the sphere centre reflects at the point
    nearest the camera, whether it sits between them or beyond the camera."""
    cam = setup.camera
    center = setup.eye.cornea_center(0.0, 0.0)
    d = (cam.position_m - center) / np.linalg.norm(cam.position_m - center)
    lights = np.array([center + 0.02 * d, center + 0.05 * d])
    glints, visible, points = project_glints(cam, center, setup.eye.cornea_radius_m, lights,
                                             return_points=True)
    expected = center + setup.eye.cornea_radius_m * d
    assert visible.all()
    assert np.abs(points - expected).max() < 1e-15
    assert np.all(np.isfinite(glints))


def test_grazing_reflections_do_not_leak_nan(setup):
    """Lights swept through the horizon of the cornea as seen from the glint: the reflection
    fades to invisible without NaN or warnings (pytest turns RuntimeWarnings into errors)."""
    cam = setup.camera
    center = setup.eye.cornea_center(0.0, 0.0)
    d = (cam.position_m - center) / np.linalg.norm(cam.position_m - center)
    perp = np.cross(d, [0, 1, 0])
    perp /= np.linalg.norm(perp)
    angles = np.linspace(0.0, np.pi, 2001)
    lights = center + 0.03 * (np.cos(angles)[:, None] * d + np.sin(angles)[:, None] * perp)
    glints, visible = project_glints(cam, center, setup.eye.cornea_radius_m, lights)
    assert visible[:100].all() and not visible[-100:].any()
    # Visibility switches off once, at the grazing angle, and stays off.
    assert np.count_nonzero(np.diff(visible.astype(int))) == 1
    assert np.all(np.isfinite(glints[visible]))


def test_camera_or_light_inside_sphere_is_invisible():
    cam = Camera([0, 0, -0.03], look_at_rotation([0, 0, -0.03], [0, 0, 0]), 1300, 1300, 319.5, 239.5, 640, 480)
    glints, visible = project_glints(cam, [0, 0, -0.028], 7.8e-3, [[0.01, 0.01, -0.04], [0, 0.001, -0.03]])
    assert not visible.any()
    glints, visible = project_glints(cam, [0, 0, 0], 7.8e-3, [[0.001, 0.001, 0.0]])
    assert not visible.any()


def test_cap_limits_glints_to_the_cornea(setup):
    cam = setup.camera
    center = setup.eye.cornea_center(0.0, 0.0)
    lights = setup.lights_world_m
    _, _, points = project_glints(cam, center, setup.eye.cornea_radius_m, lights, return_points=True)
    axis = np.array([0.0, 0.0, -1.0])
    cosines = (points - center) @ axis / setup.eye.cornea_radius_m
    limit = np.median(cosines)
    _, visible = project_glints(cam, center, setup.eye.cornea_radius_m, lights,
                                cornea_axis=axis, cap_cos_min=limit)
    assert np.array_equal(visible, cosines >= limit)
    with pytest.raises(ValueError, match="together"):
        project_glints(cam, center, setup.eye.cornea_radius_m, lights, cornea_axis=axis)


def test_batch_shapes_and_blocking(setup, rng):
    cam, r = setup.camera, setup.eye.cornea_radius_m
    lights = setup.lights_world_m
    centers = setup.eye.cornea_center(rng.uniform(-0.3, 0.3, 1000), rng.uniform(-0.2, 0.1, 1000))
    g_all, v_all = project_glints(cam, centers, r, lights)  # 40,000 pairs: several blocks
    assert g_all.shape == (1000, 40, 2) and v_all.shape == (1000, 40)
    g_one, v_one = project_glints(cam, centers[123], r, lights)
    assert g_one.shape == (40, 2)
    assert np.array_equal(g_one, g_all[123]) and np.array_equal(v_one, v_all[123])
    g_grid, _ = project_glints(cam, centers.reshape(10, 100, 3), np.full((10, 100), r), lights)
    assert np.array_equal(g_grid.reshape(1000, 40, 2), g_all)
    g_per, _ = project_glints(cam, centers[:5], r, np.broadcast_to(lights, (5, 40, 3)))
    assert np.array_equal(g_per, g_all[:5])
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        project_glints(cam, centers[:, :2], r, lights)
    with pytest.raises(ValueError, match="positive"):
        project_glints(cam, centers, -r, lights)


def test_back_projection_returns_the_reflected_ray(setup):
    cam, r = setup.camera, setup.eye.cornea_radius_m
    center = setup.eye.cornea_center(0.1, -0.05)
    glints, visible = project_glints(cam, center, r, setup.lights_world_m)
    hit, points, dirs = reflect_pixel_rays(cam, center, r, glints[visible])
    assert hit.all()
    to_light = setup.lights_world_m[visible] - points
    along = np.sum(to_light * dirs, axis=1)
    miss = np.linalg.norm(to_light - along[:, None] * dirs, axis=1)
    assert np.all(along > 0)
    assert miss.max() < 1e-9  # metres: the light lies on the reflected ray
    hit, points, _ = reflect_pixel_rays(cam, center, r, np.array([[0.0, 0.0]]))
    assert not hit[0] and np.isnan(points).all()


def test_pixel_centre_convention(setup):
    cam = setup.camera
    on_axis = cam.position_m + 0.05 * cam.optical_axis
    px, depth = cam.project(on_axis)
    assert np.allclose(px, [cam.cx_px, cam.cy_px], atol=TOL.pixel_roundtrip_px)
    assert cam.in_image([[-0.5, -0.5], [639.5, 479.5]]).all()
    assert not cam.in_image([[-0.51, 0], [0, 479.51]]).any()
    rays = cam.pixel_rays(np.array([[10.0, 20.0], [600.0, 400.0]]))
    back, _ = cam.project(cam.position_m + 0.1 * rays)
    assert np.abs(back - [[10, 20], [600, 400]]).max() < TOL.pixel_roundtrip_px
