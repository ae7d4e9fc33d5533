"""Eye model: a sphere rotating about its centre with an off-centre spherical corneal cap.

Böhme et al. (2008), as used in Sec. 2.1 of the SCET paper: the cornea is a sphere of radius
r_c whose centre sits r_co in front of the eyeball rotation centre c_e, so a rotation of the eye
moves the cornea (a moving spherical mirror). The cap ends at the limbus, ``limbus_depth_m``
behind the corneal apex. The optical and visual axes coincide here (no angle kappa), as in the
paper's simulation. The cornea may also be aspheric (``cornea_asphericity`` Q != 0): a conic
of revolution about the optical axis with apex radius r_c and its apex where the sphere's is,
whose glints :mod:`estimator.geometry.conic` computes exactly; the cornea centre stays the
apex's centre of curvature.

Eye rotations are Fick angles: ``yaw`` about the world vertical (positive toward +x), then
``pitch`` about the rotated horizontal axis (positive up). At yaw = pitch = 0 the eye looks
along -z, toward the screen.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import as_points, project_glints, project_glints_conic

#: Böhme et al. (2008) eye: corneal radius, rotation-centre-to-cornea-centre distance and
#: limbus depth behind the apex, all in metres. Other corneal radii scale the last two.
BOHME_CORNEA_RADIUS_M = 7.98e-3
BOHME_CORNEA_OFFSET_M = 4.35e-3
BOHME_LIMBUS_DEPTH_M = 3.54e-3
CORNEA_REFRACTIVE_INDEX = 1.376
#: Fastest eye rotation the estimator allows for (deg/s): saccade peak speeds follow the main
#: sequence up to ~500 deg/s (Baloh et al. 1975, the asymptote :mod:`scet_render.motion`
#: renders) and reach 600-700 deg/s in the largest saccades; 600 deg/s covers them.
EYE_SPEED_MAX_DEG_S = 600.0
#: Accepted corneal asphericity Q (conic constant; 0 is the sphere): -1 < Q <= 1. Q <= -1 is a
#: paraboloid or hyperboloid, not a closed cornea (and no ellipsoid for the renderer); Q > 1 an
#: oblate cap flatter than any measured cornea. Human corneas measure Q = -0.26 +/- 0.18 (SD;
#: Kiely et al. 1982); Navarro's model eye uses -0.26, PyEtSimul's conic cornea -0.10 and
#: gkaModelEye's -0.454.
ASPHERICITY_MIN = -1.0
ASPHERICITY_MAX = 1.0
#: Entrance pupil diameter the renders used before it was a scene key (m): 4 mm, mid-range of
#: the 2-8 mm a human pupil spans from bright to dark adaptation (Watson & Yellott 2012,
#: "A unified formula for light-adapted pupil size", J. Vision 12(10):12).
PUPIL_DIAMETER_M = 4.0e-3


def gaze_direction(yaw_rad, pitch_rad) -> np.ndarray:
    """(..., 3) unit optical-axis directions for Fick angles (radians)."""
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    pitch = np.asarray(pitch_rad, dtype=np.float64)
    cp = np.cos(pitch)
    return np.stack(np.broadcast_arrays(cp * np.sin(yaw), np.sin(pitch), -cp * np.cos(yaw)), axis=-1)


def fick_angles(direction) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`gaze_direction`: (yaw, pitch) in radians of (..., 3) directions."""
    d = as_points(direction, "direction")
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    pitch = np.arcsin(np.clip(d[..., 1], -1.0, 1.0))
    yaw = np.arctan2(d[..., 0], -d[..., 2])
    return yaw, pitch


def eye_rotation_matrix(yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """(3, 3) rotation taking the primary-position eye frame to the rotated one (Fick order)."""
    cy, sy = np.cos(yaw_rad), np.sin(yaw_rad)
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    # Yaw about world y by -yaw (so that +yaw turns -z toward +x), then pitch about local x.
    Ry = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    return Ry @ Rx


@dataclass(frozen=True, slots=True)
class Eye:
    """Geometry of one eye (SI units)."""

    rotation_center_m: np.ndarray
    cornea_radius_m: float = 7.8e-3
    cornea_offset_m: float = BOHME_CORNEA_OFFSET_M * 7.8e-3 / BOHME_CORNEA_RADIUS_M
    limbus_depth_m: float = BOHME_LIMBUS_DEPTH_M * 7.8e-3 / BOHME_CORNEA_RADIUS_M
    refractive_index: float = CORNEA_REFRACTIVE_INDEX
    #: Conic constant Q of the corneal surface about the optical axis (0: the sphere). The apex
    #: stays where the sphere's is; ``cornea_radius_m`` is the apex radius of curvature and
    #: :meth:`cornea_center` the apex's centre of curvature (the sphere's centre).
    cornea_asphericity: float = 0.0
    #: Diameter of the pupil (the aperture in the iris, in the limbus plane), m. The renderer
    #: draws it and the dataset labels its image through the cornea; a trajectory may vary it
    #: over time (:mod:`scet_render.motion.pupil`), this is its value when none does.
    pupil_diameter_m: float = PUPIL_DIAMETER_M

    def __post_init__(self):
        c = as_points(self.rotation_center_m, "rotation_center_m").reshape(3).copy()
        c.setflags(write=False)
        object.__setattr__(self, "rotation_center_m", c)
        for name in ("cornea_radius_m", "cornea_offset_m", "limbus_depth_m", "refractive_index",
                     "cornea_asphericity", "pupil_diameter_m"):
            object.__setattr__(self, name, float(getattr(self, name)))
        if not 0 < self.limbus_depth_m < 2 * self.cornea_radius_m:
            raise ValueError("limbus depth must lie between 0 and the corneal diameter")
        q = self.cornea_asphericity
        if not ASPHERICITY_MIN < q <= ASPHERICITY_MAX:
            raise ValueError(f"cornea_asphericity (Q) must lie in ({ASPHERICITY_MIN:g}, "
                             f"{ASPHERICITY_MAX:g}], got {q}")
        if q != 0 and not self.limbus_depth_m < self.cornea_semi_axes_m[0]:
            # The conic's cap is the graph over the limbus disk only in front of its equator.
            raise ValueError(f"limbus depth {self.limbus_depth_m} m must lie in front of the "
                             f"conic cornea's equator ({self.cornea_semi_axes_m[0]} m behind "
                             "the apex)")
        d = self.pupil_diameter_m
        if not (np.isfinite(d) and 0 < d < 2 * self.limbus_radius_m):
            raise ValueError(f"pupil_diameter_m must be > 0 and smaller than the iris (the "
                             f"limbus circle, {2 * self.limbus_radius_m} m across), got {d}")

    @classmethod
    def scaled(cls, rotation_center_m, cornea_radius_m: float, **kwargs) -> "Eye":
        """Böhme's eye scaled to ``cornea_radius_m`` (offset and limbus depth scale with it)."""
        s = cornea_radius_m / BOHME_CORNEA_RADIUS_M
        kwargs.setdefault("cornea_offset_m", BOHME_CORNEA_OFFSET_M * s)
        kwargs.setdefault("limbus_depth_m", BOHME_LIMBUS_DEPTH_M * s)
        return cls(rotation_center_m, cornea_radius_m, **kwargs)

    @property
    def cap_cos_min(self) -> float:
        """Cosine of the cap's half angle: a surface point with unit normal n is on the cornea
        iff ``n · axis >= cap_cos_min``."""
        return 1.0 - self.limbus_depth_m / self.cornea_radius_m

    @property
    def cornea_semi_axes_m(self) -> tuple[float, float]:
        """(a, b): the conic cornea's ellipsoid semi-axes along and across the optical axis,
        R / (1 + Q) and R / sqrt(1 + Q); (R, R) for the sphere."""
        k = 1.0 + self.cornea_asphericity
        return self.cornea_radius_m / k, self.cornea_radius_m / float(np.sqrt(k))

    @property
    def limbus_radius_m(self) -> float:
        """Radius of the limbus circle, ``limbus_depth_m`` behind the apex on the corneal
        surface: r² = 2 R z - (1 + Q) z² (the sphere's R sin(cap angle) when Q = 0)."""
        if self.cornea_asphericity == 0:
            c = self.cap_cos_min
            return self.cornea_radius_m * float(np.sqrt(max(0.0, 1.0 - c * c)))
        z, R = self.limbus_depth_m, self.cornea_radius_m
        return float(np.sqrt(max(0.0, 2 * R * z - (1.0 + self.cornea_asphericity) * z * z)))

    def cornea_ellipsoid_center(self, yaw_rad=0.0, pitch_rad=0.0) -> np.ndarray:
        """(..., 3) centre of the conic cornea's ellipsoid, a = R / (1 + Q) behind the apex
        (the cornea centre when Q = 0)."""
        d = gaze_direction(yaw_rad, pitch_rad)
        a = self.cornea_semi_axes_m[0]
        return self.rotation_center_m + (self.cornea_offset_m + self.cornea_radius_m - a) * d

    def cornea_center(self, yaw_rad, pitch_rad) -> np.ndarray:
        """(..., 3) cornea centre for Fick angles."""
        return self.rotation_center_m + self.cornea_offset_m * gaze_direction(yaw_rad, pitch_rad)

    def apex(self, yaw_rad=0.0, pitch_rad=0.0) -> np.ndarray:
        """(..., 3) corneal apex for Fick angles."""
        d = gaze_direction(yaw_rad, pitch_rad)
        return self.rotation_center_m + (self.cornea_offset_m + self.cornea_radius_m) * d

    def glints(self, camera, lights_world_m, yaw_rad, pitch_rad, *,
               cornea_radius_m: float | None = None):
        """Noise-free glints of this eye rotated to (yaw, pitch) (Fick angles, any batch shape):
        the closed-form projection (:func:`estimator.geometry.project_glints`) with the corneal
        cap test, or for an aspheric cornea (Q != 0) the exact reflection on the conic
        (:func:`estimator.geometry.project_glints_conic`) with the cap ending at the limbus
        plane. ``cornea_radius_m`` overrides r_c (a calibrated or perturbed eye; with Q != 0 the
        apex radius, about the same centre).

        Returns ``(glints_px (..., n, 2), visible (..., n), cornea_center_m (..., 3))``; the
        cornea centre is the centre of curvature at the apex (the sphere's centre) for any Q.
        """
        r_c = self.cornea_radius_m if cornea_radius_m is None else float(cornea_radius_m)
        center = self.cornea_center(yaw_rad, pitch_rad)
        lights = np.asarray(lights_world_m, dtype=np.float64)
        if self.cornea_asphericity != 0:
            axis = gaze_direction(yaw_rad, pitch_rad)
            # As for the sphere, an overriding r_c keeps the centre (and the cap's angular
            # extent: the limbus depth scales with r_c).
            glints, visible = project_glints_conic(
                camera, center + r_c * axis, axis, r_c, self.cornea_asphericity, lights,
                limbus_depth_m=self.limbus_depth_m * r_c / self.cornea_radius_m)
            return glints, visible, center
        glints, visible = project_glints(camera, center, r_c,
                                         np.asarray(lights_world_m, dtype=np.float64),
                                         cornea_axis=gaze_direction(yaw_rad, pitch_rad),
                                         cap_cos_min=self.cap_cos_min)
        return glints, visible, center

    def angles_toward(self, targets_m) -> tuple[np.ndarray, np.ndarray]:
        """Fick angles (radians) that point the optical axis at (..., 3) world targets."""
        return fick_angles(as_points(targets_m, "targets_m") - self.rotation_center_m)
