"""Small rigid-body helpers: rotations, poses, look-at frames.

Conventions (DESIGN.md): SI units, right-handed world frame of the SCET paper's Fig. 3 (origin
at the eyeball rotation centre, y up, the eye looking along -z).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def as_points(x, name: str = "points") -> np.ndarray:
    """Coerce ``x`` to a float64 array whose last axis has length 3."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got {a.shape}")
    return a


def normalize(v: np.ndarray, axis: int = -1) -> np.ndarray:
    """Unit vectors along ``axis``; zero vectors stay zero instead of turning into NaN."""
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def rotation_matrix(axis, angle_rad: float) -> np.ndarray:
    """(3, 3) rotation by ``angle_rad`` about ``axis`` (right-hand rule, Rodrigues' formula)."""
    k = as_points(axis, "axis")
    norm = np.linalg.norm(k)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"rotation axis must be a finite non-zero vector, got {k}")
    k = k / norm
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * kx + (1 - np.cos(angle_rad)) * (kx @ kx)


def rotation_from_vector(rotvec) -> np.ndarray:
    """(3, 3) rotation from a rotation vector (axis times angle in radians)."""
    r = as_points(rotvec, "rotvec")
    angle = float(np.linalg.norm(r))
    if angle == 0.0:
        return np.eye(3)
    return rotation_matrix(r / angle, angle)


def rotation_to_vector(rotation) -> np.ndarray:
    """Rotation vector (axis times angle in radians) of a (3, 3) rotation matrix."""
    R = np.asarray(rotation, dtype=np.float64)
    # 2 sin(angle) times the axis, from the antisymmetric part; the angle from atan2 of sine and
    # cosine (arccos of the trace alone loses small angles: cos(1e-8) rounds to 1).
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    sin2 = np.linalg.norm(axis)
    angle = np.arctan2(sin2 / 2.0, (np.trace(R) - 1.0) / 2.0)
    if sin2 == 0.0 and angle < 1.0:
        return np.zeros(3)
    if np.pi - angle < 1e-6:
        # Near 180 degrees the antisymmetric part vanishes; read the axis off R + I.
        M = (R + np.eye(3)) / 2.0
        return normalize(M[np.argmax(np.diag(M))]) * angle
    return axis * (angle / sin2)


def look_at_rotation(eye_m, target_m, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World-to-camera rotation of a camera at ``eye_m`` looking at ``target_m``.

    Rows are the camera axes in world coordinates, OpenCV convention: x right, y down,
    z forward. ``up`` is the world direction that should appear upward in the image.
    """
    eye_m, target_m, up = as_points(eye_m), as_points(target_m), as_points(up)
    z = target_m - eye_m
    if np.linalg.norm(z) == 0:
        raise ValueError("look-at target coincides with the camera position")
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)  # image right = forward x up, so that y = z x x points down
    if np.linalg.norm(x) < 1e-12:
        raise ValueError("camera up vector is parallel to its viewing direction")
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


@dataclass(frozen=True, slots=True)
class RigidPose:
    """A rigid transform ``p_world = rotation @ p_local + translation``."""

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation_m: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        R = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3)
        t = as_points(self.translation_m, "translation_m").reshape(3)
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("RigidPose.rotation must be a proper rotation matrix")
        R.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "translation_m", t)

    @classmethod
    def from_rotvec(cls, rotvec, translation_m) -> "RigidPose":
        return cls(rotation_from_vector(rotvec), translation_m)

    def apply(self, points_local) -> np.ndarray:
        """Map (..., 3) points from the local frame to the world frame."""
        return as_points(points_local) @ self.rotation.T + self.translation_m

    def compose(self, inner: "RigidPose") -> "RigidPose":
        """The pose ``self ∘ inner``: apply ``inner`` first, then ``self``."""
        return RigidPose(self.rotation @ inner.rotation, self.apply(inner.translation_m))

    def inverse(self) -> "RigidPose":
        return RigidPose(self.rotation.T, -self.rotation.T @ self.translation_m)


def rotations_from_vectors(rotvecs) -> np.ndarray:
    """(..., 3, 3) rotations from (..., 3) rotation vectors, vectorised (Rodrigues' formula).

    Zero vectors give the identity; non-finite vectors give NaN matrices (no exception), so a
    batch with failed samples stays a batch.
    """
    r = as_points(rotvecs, "rotvecs")
    angle = np.linalg.norm(r, axis=-1)
    small = angle < 1e-12
    safe = np.where(small, 1.0, angle)
    k = r / safe[..., None]
    zero = np.zeros_like(angle)
    kx = np.stack([zero, -k[..., 2], k[..., 1], k[..., 2], zero, -k[..., 0], -k[..., 1], k[..., 0], zero],
                  axis=-1).reshape(r.shape[:-1] + (3, 3))
    s = np.where(small, 0.0, np.sin(angle))[..., None, None]
    c = np.where(small, 0.0, 1 - np.cos(angle))[..., None, None]
    return np.eye(3) + s * kx + c * (kx @ kx)
