"""Tests of the camera's lens (:class:`estimator.geometry.Camera`): OpenCV's distortion model, its
inverse, the rays a distorted pixel sees, the thin lens, and the scene's ``[camera]`` lens keys.

The distortion is checked against OpenCV itself (``cv2.projectPoints``, ``cv2.undistortPoints``),
which is the definition the calibration and the tracker share.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from estimator.errors import SceneError
from estimator.geometry import Camera, look_at_rotation
from estimator.scene import load_scene, parse_scene
from tests.estimator.test_scene import PAPER_SIM

#: Our numpy model against cv2.projectPoints (px): both evaluate the same polynomial in float64
#: in a different order; 1e-9 px leaves three orders of magnitude over the ~1e-12 px measured.
PROJECT_VS_OPENCV_PX = 1e-9
#: Undistort then distort again (px): the brief's bound; Newton stops at 1e-14 focal lengths
#: (~1e-11 px), measured <= 3e-13 px.
ROUND_TRIP_PX = 1e-6
#: Our inverse against OpenCV's iterative undistortPoints run to 1e-14 (px): OpenCV's fixed
#: point iteration converges to its own stopping step; 1e-6 px is the round-trip bound.
UNDISTORT_VS_OPENCV_PX = 1e-6
#: Thin-lens blur diameter against the textbook formula (relative): two algebraically equal
#: float64 expressions.
BLUR_REL = 1e-12

POSITION = np.array([0.012, 0.018, -0.035])
ROTATION = look_at_rotation(POSITION, [0.0, 0.0, 0.0])

#: A stock M12 3.6 mm lens at VGA (643 px): barrel distortion, corners moved ~10 px.
BARREL = [-0.30, 0.12, 0.001, -0.0005, -0.02]


def camera(distortion=(), fx=643.0, fy=643.0, **lens):
    return Camera(POSITION, ROTATION, fx, fy, 319.5, 239.5, 640, 480, distortion, **lens)


def random_coefficients(rng, n):
    """Small, non-folding coefficients of every kind OpenCV has (n of them)."""
    scale = np.array([0.1, 0.05, 0.002, 0.002, 0.01, 0.05, 0.02, 0.01, 0.002, 0.001, 0.002, 0.001,
                      0.01, 0.01])
    d = rng.normal(0.0, 1.0, n) * scale[:n]
    d[0] = -abs(d[0]) - 0.05
    return d


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_project_matches_opencv(n):
    rng = np.random.default_rng(n)
    for _ in range(5):
        d = random_coefficients(rng, n)
        cam = camera(d, fx=rng.uniform(400, 1400), fy=rng.uniform(400, 1400))
        # points in the field of view and a little beyond (normalised |x|, |y| < 0.8), 2-10 cm deep
        z = rng.uniform(0.02, 0.10, 2000)
        xy = rng.uniform(-0.8, 0.8, (2000, 2)) * z[:, None]
        points = np.column_stack([xy, z]) @ cam.rotation + cam.position_m
        ours, depth = cam.project(points)
        rvec, _ = cv2.Rodrigues(cam.rotation)
        theirs, _ = cv2.projectPoints(points, rvec, -cam.rotation @ cam.position_m, cam.K, d)
        np.testing.assert_allclose(depth, z, rtol=1e-12)
        np.testing.assert_array_less(np.abs(ours - theirs.reshape(-1, 2)), PROJECT_VS_OPENCV_PX)
    behind, _ = cam.project(cam.position_m - 0.01 * cam.optical_axis)
    assert np.all(np.isnan(behind))


def frame_grid(cam, n=41):
    u, v = np.meshgrid(np.linspace(-0.5, cam.width_px - 0.5, n), np.linspace(-0.5, cam.height_px - 0.5, n))
    return np.stack([u, v], axis=-1).reshape(-1, 2)


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_undistort_round_trip_and_opencv(n):
    rng = np.random.default_rng(100 + n)
    d = random_coefficients(rng, n)
    if n == 5:
        d = np.array(BARREL)
    cam = camera(d)
    grid = frame_grid(cam)
    ideal = cam.undistort_px(grid)
    assert np.all(np.isfinite(ideal))
    np.testing.assert_array_less(np.abs(cam.distort_px(ideal) - grid), ROUND_TRIP_PX)
    theirs = cv2.undistortPoints(grid.reshape(-1, 1, 2), cam.K, d, None, None, cam.K,
                                     (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 1000, 1e-14))
    np.testing.assert_array_less(np.abs(ideal - theirs.reshape(-1, 2)), UNDISTORT_VS_OPENCV_PX)


def test_barrel_moves_corners_and_rays_see_their_pixels():
    cam = camera(BARREL)
    grid = frame_grid(cam)
    ideal = cam.undistort_px(grid)
    shift = np.hypot(*(ideal - grid).T)
    assert shift.max() > 5.0  # the corners move several pixels: the test has teeth
    # Barrel: the ideal image of a corner lies further out than the pixel that sees it.
    centre = np.array([cam.cx_px, cam.cy_px])
    assert np.linalg.norm(ideal[-1] - centre) > np.linalg.norm(grid[-1] - centre)
    rays = cam.pixel_rays(grid)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-15)
    seen, _ = cam.project(cam.position_m + 0.04 * rays)
    np.testing.assert_array_less(np.abs(seen - grid), ROUND_TRIP_PX)


def test_pinhole_is_unchanged():
    pin = camera()
    zeros = camera([0.0, 0.0, 0.0, 0.0, 0.0])
    assert not pin.has_distortion and not zeros.has_distortion and not pin.is_thin_lens
    rng = np.random.default_rng(3)
    points = rng.normal(0.0, 0.01, (500, 3))
    pc = (points - POSITION) @ ROTATION.T
    inv = 1.0 / pc[:, 2]  # the pinhole's operations in its order (the code before the lens)
    expected = np.stack([643.0 * pc[:, 0] * inv + 319.5, 643.0 * pc[:, 1] * inv + 239.5], -1)
    front = pc[:, 2] > 0
    for cam in (pin, zeros):
        uv, _ = cam.project(points)
        assert np.array_equal(uv[front], expected[front])  # bit for bit: the pinhole's own path
        grid = frame_grid(cam)
        assert np.array_equal(cam.undistort_px(grid), grid)
    assert pin.blur_diameter_px(0.03) == 0.0


def test_distortion_is_read_only():
    cam = camera(BARREL)
    with pytest.raises(ValueError):
        cam.distortion[0] = 0.0
    assert cam.distortion.dtype == np.float64 and cam.distortion.shape == (5,)


@pytest.mark.parametrize("d, folds", [
    ([-0.30, 0.12, 0.0, 0.0, -0.02], False),
    ([-1.2, 0.0, 0.0, 0.0], True),            # r - 1.2 r^3 peaks at r_d = 0.35 < the corners' 0.62
    ([-0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.0], True),  # the rational denominator overtakes
    ([0.0, 0.0, 0.0, 0.0, 0.0, 5.0, 0.0, 0.0], True),   # 1 / (1 + 5 r^2): peaks at r_d = 0.22
])
def test_folding_distortion_is_refused(d, folds):
    if folds:
        with pytest.raises(ValueError, match="folds the image"):
            camera(d)
    else:
        camera(d)


def test_wrong_coefficient_count_is_refused():
    with pytest.raises(ValueError, match="0, 4, 5, 8, 12 or 14"):
        camera([0.1, 0.0, 0.0])


def test_thin_lens_blur_follows_the_lens_formula():
    pitch, n, df = 5.6e-6, 2.9, 0.035
    cam = camera(f_number=n, focus_distance_m=df, pixel_pitch_m=pitch)
    v = 643.0 * pitch
    f = 1.0 / (1.0 / v + 1.0 / df)
    assert cam.focal_length_m == pytest.approx(f, rel=1e-15)
    assert cam.aperture_radius_m == pytest.approx(f / (2 * n), rel=1e-15)
    d = np.array([0.025, 0.030, 0.035, 0.040, 0.050])
    textbook = (f / n) * np.abs(d - df) / d * f / (df - f) / pitch
    np.testing.assert_allclose(cam.blur_diameter_px(d), textbook, rtol=BLUR_REL)
    assert cam.blur_diameter_px(df) == 0.0
    # 5 mm behind focus at 3.5 cm with the stock F2.9 lens at VGA (5.6 um pixels): A = 1.13 mm,
    # c = 1.13 mm * 5/40 * 3.26/31.7 = 14.5 um = 2.6 px: the few-millimetre depth of field
    assert 2.0 < cam.blur_diameter_px(0.040) < 3.0


def test_thin_lens_needs_all_its_parts():
    with pytest.raises(ValueError, match="come together"):
        camera(f_number=2.9)
    with pytest.raises(ValueError, match="pixel_pitch_m"):
        camera(f_number=2.9, focus_distance_m=0.035)
    with pytest.raises(ValueError, match="f_number"):
        camera(f_number=200.0, focus_distance_m=0.035, pixel_pitch_m=5.6e-6)
    with pytest.raises(ValueError, match="focus_distance_m"):
        camera(f_number=2.9, focus_distance_m=0.003, pixel_pitch_m=5.6e-6)


def test_rescaled_camera_keeps_its_lens():
    cam = camera(BARREL, f_number=2.9, focus_distance_m=0.035, pixel_pitch_m=5.6e-6)
    half = cam.with_intrinsics(321.5, 321.5, 159.5, 119.5, 320, 240)
    np.testing.assert_array_equal(half.distortion, cam.distortion)
    assert half.aperture_radius_m == pytest.approx(cam.aperture_radius_m, rel=1e-15)
    points = np.array([[0.001, 0.002, 0.0], [0.004, -0.003, 0.001]])
    full_px, _ = cam.project(points)
    half_px, _ = half.project(points)
    np.testing.assert_allclose((half_px + 0.5) * 2 - 0.5, full_px, atol=1e-9)


# --------------------------------------------------------------------------- scene keys
def scene_with(extra: str) -> str:
    return PAPER_SIM.replace("[camera]\n", "[camera]\n" + extra + "\n", 1)


def test_scene_lens_keys():
    setup = parse_scene(scene_with("distortion = [-0.05, 0.01, 0.0, 0.0, 0.0]\nf_number = 2.9\n"
                                   "focus_distance_mm = 35.0\npixel_pitch_um = 2.8"))
    cam = setup.camera
    np.testing.assert_array_equal(cam.distortion, [-0.05, 0.01, 0.0, 0.0, 0.0])
    assert cam.f_number == 2.9 and cam.focus_distance_m == pytest.approx(0.035)
    assert cam.pixel_pitch_m == pytest.approx(2.8e-6)


def test_scene_without_lens_is_a_pinhole():
    cam = load_scene("paper_sim").camera
    assert not cam.has_distortion and not cam.is_thin_lens and cam.pixel_pitch_m is None


@pytest.mark.parametrize("extra, key, words", [
    ("distortion = [0.1, 0.0, 0.0]", "camera.distortion", "4, 5, 8, 12 or 14"),
    ("distortion = [-3.0, 0.0, 0.0, 0.0]", "camera.distortion", "folds the image"),
    ("distortion = [\"a\", 0.0, 0.0, 0.0]", "camera.distortion", "number"),
    ("f_number = 0.1\nfocus_distance_mm = 35.0\npixel_pitch_um = 2.8", "camera.f_number", "0.5"),
    ("f_number = 2.9\nfocus_distance_mm = 1.0\npixel_pitch_um = 2.8", "camera.focus_distance_mm", "value in"),
    ("f_number = 2.9\nfocus_distance_mm = 6.0\npixel_pitch_um = 5.6", "camera.focus_distance_mm",
     "lens-to-sensor"),
    ("f_number = 2.9\npixel_pitch_um = 2.8", "camera.focus_distance_mm", "both"),
    ("focus_distance_mm = 35.0", "camera.f_number", "both"),
    ("f_number = 2.9\nfocus_distance_mm = 35.0", "camera.pixel_pitch_um", "pixel pitch"),
    ("f_number = 2.9\nfocus_distance_mm = 35.0\npixel_pitch_um = 500", "camera.pixel_pitch_um", "value in"),
])
def test_bad_lens_keys_name_the_key(extra, key, words):
    with pytest.raises(SceneError) as err:
        parse_scene(scene_with(extra), source="lens.toml")
    message = str(err.value)
    assert "lens.toml" in message and key in message and words in message, message
    assert "\n" not in message
