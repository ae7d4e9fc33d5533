"""Rotations, poses, the eye model and the camera frame."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.eye import Eye, eye_rotation_matrix, fick_angles, gaze_direction
from estimator.geometry import RigidPose, look_at_rotation, rotation_from_vector, rotation_matrix, rotation_to_vector

angles = st.floats(-1.2, 1.2, allow_nan=False)


@given(yaw=angles, pitch=angles)
@settings(max_examples=200, deadline=None)
def test_fick_angles_round_trip(yaw, pitch):
    d = gaze_direction(yaw, pitch)
    assert np.isclose(np.linalg.norm(d), 1.0, atol=1e-15)
    y2, p2 = fick_angles(d)
    assert np.allclose([y2, p2], [yaw, pitch], atol=1e-12)
    # The rotation matrix carries the primary gaze (-z) onto the same direction.
    assert np.allclose(eye_rotation_matrix(yaw, pitch) @ [0, 0, -1], d, atol=1e-15)


def test_gaze_sign_conventions():
    # +yaw turns toward +x (nose side of the paper's left eye), +pitch looks up.
    assert gaze_direction(0.3, 0.0)[0] > 0
    assert gaze_direction(0.0, 0.3)[1] > 0
    assert np.allclose(gaze_direction(0.0, 0.0), [0, 0, -1])


def test_eye_points_at_targets():
    eye = Eye.scaled([0.001, -0.002, 0.0005], 7.8e-3)
    targets = np.array([[0.2, 0.1, -0.7], [-0.24, -0.2, -0.7]])
    yaw, pitch = eye.angles_toward(targets)
    center = eye.cornea_center(yaw, pitch)
    to_target = targets - eye.rotation_center_m
    to_target /= np.linalg.norm(to_target, axis=1, keepdims=True)
    along = (center - eye.rotation_center_m) / eye.cornea_offset_m
    assert np.allclose(along, to_target, atol=1e-14)
    # Böhme's eye scaled to 7.8 mm (DESIGN.md): r_co 4.35 and limbus 3.54 mm scaled by 7.8/7.98.
    assert np.isclose(eye.cornea_offset_m, 4.35e-3 * 7.8 / 7.98)
    assert np.isclose(eye.limbus_depth_m, 3.54e-3 * 7.8 / 7.98)
    assert 5.5e-3 < eye.limbus_radius_m < 7.0e-3  # a human limbus is 5.5-6.5 mm in radius


@given(st.lists(st.floats(-3, 3), min_size=3, max_size=3))
@settings(max_examples=200, deadline=None)
def test_rotation_vector_round_trip(v):
    v = np.array(v)
    if np.linalg.norm(v) > np.pi - 1e-3:
        v *= (np.pi - 1e-3) / np.linalg.norm(v)
    R = rotation_from_vector(v)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-14) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(rotation_to_vector(R), v, atol=1e-9)


def test_rotation_to_vector_near_pi():
    R = rotation_matrix([1.0, 2.0, -0.5], np.pi)
    v = rotation_to_vector(R)
    assert np.isclose(np.linalg.norm(v), np.pi)
    assert np.allclose(rotation_from_vector(v), R, atol=1e-9)


def test_rigid_pose_compose_and_inverse():
    a = RigidPose.from_rotvec([0.1, -0.2, 0.3], [0.01, 0.02, -0.03])
    b = RigidPose.from_rotvec([-0.4, 0.0, 0.2], [0.0, -0.01, 0.005])
    p = np.array([[0.01, 0.0, -0.02], [0.0, 0.03, 0.01]])
    assert np.allclose(a.compose(b).apply(p), a.apply(b.apply(p)), atol=1e-15)
    assert np.allclose(a.inverse().apply(a.apply(p)), p, atol=1e-15)
    with pytest.raises(ValueError, match="rotation"):
        RigidPose(np.diag([1.0, 1.0, -1.0]))


def test_look_at_is_opencv_frame():
    R = look_at_rotation([0.0, 0.0, -0.03], [0.0, 0.0, 0.0])
    # Looking along +z with world y up, world +x is on the image's left (right-handed frames).
    assert np.allclose(R[0], [-1, 0, 0])
    up_in_cam = R @ [0, 1, 0]
    assert up_in_cam[1] < 0, "world up must point to decreasing image rows (camera y down)"
    assert np.allclose(R[2], [0, 0, 1])
    assert np.isclose(np.linalg.det(R), 1.0)
    with pytest.raises(ValueError, match="parallel"):
        look_at_rotation([0, 0, 0], [0, 1, 0], up=[0, 1, 0])
    with pytest.raises(ValueError, match="coincides"):
        look_at_rotation([0, 0, 0], [0, 0, 0])


@pytest.mark.parametrize("angle", [1e-8, 1e-12, 3e-15])
def test_rotation_vector_keeps_tiny_angles(angle):
    # Found by hypothesis: arccos of the trace rounds cos(1e-8) to 1 and returned a zero vector.
    v = np.array([0.3, -0.4, 0.5]) / np.linalg.norm([0.3, -0.4, 0.5]) * angle
    assert np.allclose(rotation_to_vector(rotation_from_vector(v)), v, rtol=1e-6, atol=0)
