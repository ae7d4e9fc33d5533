"""The rendered pupil and its image through the cornea: the ground truth of the dataset's
pupil labels (``pupil_center_px``, ``pupil_ellipse_px``).

The renderer's pupil is a disk of the pupil's diameter centred on the optical axis,
:data:`~scet_render.render.layout.PUPIL_OFFSET_M` in front of the limbus plane (the iris,
:func:`~scet_render.render.meshes.eye_part_transforms`). The camera sees it through the
cornea: its centre at the projection of the point where the ray from the centre refracts
toward the camera (:func:`estimator.geometry.refraction.project_through_cornea`, exact on the
sphere and the conic), its edge as the refracted images of :data:`BOUNDARY_POINTS` points of
the circle, to which an ellipse is fitted (``cv2.fitEllipse``). The projection is
``Camera.project``, the one every glint label goes through.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.eye import gaze_direction
from estimator.geometry import project_through_cornea
from estimator.setup import Setup

from .layout import PUPIL_OFFSET_M, eye_layout

#: Points of the pupil's edge refracted for its ellipse: the refracted circle is an ellipse to
#: within a few thousandths of a pixel on paper_sim, and 64 points pin the fit far below that.
BOUNDARY_POINTS = 64


@dataclass(frozen=True, slots=True)
class PupilImage:
    """The pupil as the camera sees it through the cornea, for a batch of poses.

    Attributes
    ----------
    center_px : (..., 2) float
        The image of the pupil's centre (refracted), NaN where its ray does not reach the
        camera through the corneal cap.
    center_visible : (...,) bool
        The centre's refracted ray exists, crosses the cap and lands in the image.
    ellipse_px : (..., 5) float
        ``[u, v, major, minor, angle_deg]``: the ellipse fitted to the refracted edge (centre,
        full axis lengths in px, the major axis's angle from +u toward +v in [0, 180) deg);
        NaN where any edge point is not visible.
    diameter_m : (...,) float
        The pupil's diameter.
    surface_m : (..., 1 + BOUNDARY_POINTS, 3) float
        Where the rays of the centre (first) and the edge points leave the cornea toward the
        camera (world frame, m; NaN where that ray does not exist): the start of the path a
        lid or lash can block (:meth:`~scet_render.render.occlusion.LidOccluder.toward_camera`).
    """

    center_px: np.ndarray
    center_visible: np.ndarray
    ellipse_px: np.ndarray
    diameter_m: np.ndarray
    surface_m: np.ndarray


def pupil_points(setup: Setup, yaw_rad, pitch_rad, diameter_m, count: int = BOUNDARY_POINTS):
    """The rendered pupil's centre (..., 3) and ``count`` edge points (..., count, 3), world
    frame (m), for Fick angles and diameters of one batch shape."""
    yaw, pitch, d = np.broadcast_arrays(np.asarray(yaw_rad, dtype=np.float64),
                                        np.asarray(pitch_rad, dtype=np.float64),
                                        np.asarray(diameter_m, dtype=np.float64))
    g = gaze_direction(yaw, pitch)
    plane = eye_layout(setup).limbus_plane_m + PUPIL_OFFSET_M
    center = setup.eye.rotation_center_m + plane * g
    helper = np.where(np.abs(g[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = np.cross(g, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(g, e1)
    phi = 2.0 * np.pi * np.arange(count) / count
    r = 0.5 * d[..., None, None]
    edge = (center[..., None, :] + r * np.cos(phi)[:, None] * e1[..., None, :]
            + r * np.sin(phi)[:, None] * e2[..., None, :])
    return center, edge


def fit_ellipse_px(points_px) -> np.ndarray:
    """(5,) ``[u, v, major, minor, angle_deg]`` of ``cv2.fitEllipse`` on (m, 2) points (m >= 5),
    with the axes ordered major first and the angle that of the major axis in [0, 180)."""
    import cv2

    (u, v), (w, h), angle = cv2.fitEllipse(np.asarray(points_px, dtype=np.float32).reshape(-1, 1, 2))
    if w < h:
        w, h, angle = h, w, angle + 90.0
    return np.array([u, v, w, h, angle % 180.0])


def pupil_image(setup: Setup, yaw_rad, pitch_rad, diameter_m=None, *,
                refractive_index: float | None = None) -> PupilImage:
    """The pupil's image through the cornea at eye poses (module docstring).

    Parameters
    ----------
    setup : Setup
    yaw_rad, pitch_rad : (...) float
        Fick angles.
    diameter_m : (...) float, optional
        Pupil diameters (default: the scene's ``eye.pupil_diameter_m``).
    refractive_index : float, optional
        Overrides the cornea's index (1: the unrefracted projection).

    Returns
    -------
    PupilImage
    """
    eye = setup.eye
    d = eye.pupil_diameter_m if diameter_m is None else diameter_m
    center, edge = pupil_points(setup, yaw_rad, pitch_rad, d)
    g = gaze_direction(*np.broadcast_arrays(np.asarray(yaw_rad, dtype=np.float64),
                                            np.asarray(pitch_rad, dtype=np.float64)))
    g = np.broadcast_to(g, center.shape)
    apex = eye.rotation_center_m + (eye.cornea_offset_m + eye.cornea_radius_m) * g
    n = eye.refractive_index if refractive_index is None else float(refractive_index)
    points = np.concatenate([center[..., None, :], edge], axis=-2)
    px, visible, surface = project_through_cornea(setup.camera, apex, g, eye.cornea_radius_m,
                                                  eye.cornea_asphericity, n, points,
                                                  limbus_depth_m=eye.limbus_depth_m,
                                                  return_points=True)
    batch = center.shape[:-1]
    ellipse = np.full(batch + (5,), np.nan)
    edge_ok = visible[..., 1:].all(axis=-1)
    for idx in zip(*np.nonzero(edge_ok)) if batch else ([()] if edge_ok else []):
        ellipse[idx] = fit_ellipse_px(px[idx][1:])
    return PupilImage(px[..., 0, :], visible[..., 0], ellipse,
                      np.broadcast_to(np.asarray(d, dtype=np.float64), batch).copy(),
                      np.where(visible[..., None], surface, np.nan))
