"""Pinhole camera in the OpenCV convention.

Camera frame: x right, y down, z forward. Pixel (u, v) = (0, 0) is the *centre* of the top-left
pixel (DESIGN.md); Mitsuba's film puts pixel centres at i + 0.5 and the renderer converts at one
place only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rigid import as_points, normalize


@dataclass(frozen=True, slots=True)
class Camera:
    """A calibrated pinhole camera.

    Attributes
    ----------
    position_m : (3,) float
        Centre of projection in the world frame.
    rotation : (3, 3) float
        World-to-camera rotation; its rows are the camera's x, y, z axes in world coordinates.
    fx_px, fy_px : float
        Focal lengths in pixels.
    cx_px, cy_px : float
        Principal point in pixels (pixel-centre convention).
    width_px, height_px : int
        Image size; row 0 is the first row read out by the rolling shutter.
    """

    position_m: np.ndarray
    rotation: np.ndarray
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int

    def __post_init__(self):
        p = as_points(self.position_m, "position_m").reshape(3).copy()
        R = np.asarray(self.rotation, dtype=np.float64).reshape(3, 3).copy()
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            raise ValueError("Camera.rotation must be a proper rotation matrix")
        p.setflags(write=False)
        R.setflags(write=False)
        object.__setattr__(self, "position_m", p)
        object.__setattr__(self, "rotation", R)
        for name in ("fx_px", "fy_px", "cx_px", "cy_px"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if not (self.fx_px > 0 and self.fy_px > 0):
            raise ValueError("focal lengths must be positive")
        if int(self.width_px) <= 0 or int(self.height_px) <= 0:
            raise ValueError("image size must be positive")
        object.__setattr__(self, "width_px", int(self.width_px))
        object.__setattr__(self, "height_px", int(self.height_px))

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def optical_axis(self) -> np.ndarray:
        """(3,) viewing direction in the world frame."""
        return self.rotation[2].copy()

    def world_to_camera(self, points_world) -> np.ndarray:
        """(..., 3) world points in the camera frame."""
        return (as_points(points_world, "points_world") - self.position_m) @ self.rotation.T

    def project(self, points_world) -> tuple[np.ndarray, np.ndarray]:
        """Project (..., 3) world points.

        Returns
        -------
        pixels_px : (..., 2) float64
            Image coordinates; NaN for points at or behind the camera plane.
        depth_m : (..., ) float64
            z in the camera frame.
        """
        pc = self.world_to_camera(points_world)
        z = pc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(z > 0, 1.0 / z, np.nan)
        u = self.fx_px * pc[..., 0] * inv + self.cx_px
        v = self.fy_px * pc[..., 1] * inv + self.cy_px
        return np.stack([u, v], axis=-1), z

    def in_image(self, pixels_px) -> np.ndarray:
        """True where a pixel position lies on the sensor (within half a pixel of a centre)."""
        px = np.asarray(pixels_px, dtype=np.float64)
        u, v = px[..., 0], px[..., 1]
        return (u >= -0.5) & (u <= self.width_px - 0.5) & (v >= -0.5) & (v <= self.height_px - 0.5)

    def pixel_rays(self, pixels_px) -> np.ndarray:
        """(..., 3) unit world directions of the rays through (..., 2) pixel positions."""
        px = np.asarray(pixels_px, dtype=np.float64)
        if px.ndim == 0 or px.shape[-1] != 2:
            raise ValueError(f"pixels_px must have shape (..., 2), got {px.shape}")
        d_cam = np.stack(
            [(px[..., 0] - self.cx_px) / self.fx_px, (px[..., 1] - self.cy_px) / self.fy_px,
             np.ones(px.shape[:-1])],
            axis=-1,
        )
        return normalize(d_cam @ self.rotation)
