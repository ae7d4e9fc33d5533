"""Camera in the OpenCV convention: a pinhole with OpenCV's lens distortion and a thin lens.

Camera frame: x right, y down, z forward. Pixel (u, v) = (0, 0) is the *centre* of the top-left
pixel (DESIGN.md); Mitsuba's film puts pixel centres at i + 0.5 and the renderer converts at one
place only.

The lens model is OpenCV's (``cv2.projectPoints``, calib3d's "Detailed Description"): a point
(x, y, z) in the camera frame has the ideal normalised coordinates x' = x / z, y' = y / z,
r^2 = x'^2 + y'^2, and lands at

    x'' = x' (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
          + 2 p1 x'y' + p2 (r^2 + 2 x'^2) + s1 r^2 + s2 r^4
    y'' = y' (same ratio) + p1 (r^2 + 2 y'^2) + 2 p2 x'y' + s3 r^2 + s4 r^4

then, with the tilted-sensor terms (tauX, tauY), through OpenCV's tilt homography, and
u = fx x''' + cx, v = fy y''' + cy. The coefficients are stored in OpenCV's order
(k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tauX tauY]]]]); an empty array is the pinhole and takes
exactly the code path the pinhole always took.

Defocus is a thin lens: the entrance pupil is a disc of diameter A = f / N centred on the centre
of projection, and every ray through a pixel passes through that pixel's point on the focus
plane z = ``focus_distance_m``. ``fx_px`` is the pinhole-equivalent focal length that a
calibration measures, the lens-to-sensor distance v of the focused lens in pixels; the focal
length is then f = v d_f / (v + d_f) (1/f = 1/v + 1/d_f). A point at depth d is blurred into a
disc of diameter c = A |d - d_f| / d * v / d_f on the sensor (= A |d - d_f| / d * f / (d_f - f)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rigid import as_points, normalize

#: Coefficient counts OpenCV accepts (0 is the pinhole).
DISTORTION_COUNTS = (0, 4, 5, 8, 12, 14)
#: Newton's stopping step in normalised image coordinates for :meth:`Camera.undistort_px`:
#: 1e-14 of a focal length is ~1e-11 px at 1300 px, far below the 1e-6 px the round trip promises.
UNDISTORT_STEP = 1e-14
#: Most Newton iterations :meth:`Camera.undistort_px` takes (a point in the frame of a monotonic
#: lens converges in 3-6 from the distorted point; points that do not converge are NaN).
UNDISTORT_MAX_ITER = 50
#: Largest undistorted radius (tan of the field angle, here 87 deg) searched for the frame's
#: corners when checking that a radial map does not fold.
_FOLD_SEARCH_R = 20.0


def tilt_matrix(tau_x: float, tau_y: float) -> np.ndarray:
    """(3, 3) OpenCV's tilted-sensor homography (calib3d ``computeTiltProjectionMatrix``)."""
    cx, sx, cy, sy = np.cos(tau_x), np.sin(tau_x), np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    rot_xy = rot_y @ rot_x
    proj_z = np.array([[rot_xy[2, 2], 0.0, -rot_xy[0, 2]], [0.0, rot_xy[2, 2], -rot_xy[1, 2]],
                       [0.0, 0.0, 1.0]])
    return proj_z @ rot_xy


def full_coefficients(dist) -> np.ndarray:
    """(14,) OpenCV coefficients (0 to 14 of them) padded with zeros to OpenCV's full model."""
    dist = np.asarray(dist, dtype=np.float64).reshape(-1)
    full = np.zeros(14)
    full[:dist.size] = dist
    return full


def lens_map(k, x, y):
    """OpenCV's lens map without the tilt: ideal normalised x, y -> x'', y''.

    Generic over the array type: numpy arrays, or Dr.Jit arrays (the renderer's rays) when ``k``
    is a sequence of 14 Python floats (:func:`full_coefficients`).
    """
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = (1 + k[0] * r2 + k[1] * r4 + k[4] * r6) / (1 + k[5] * r2 + k[6] * r4 + k[7] * r6)
    xy2 = 2 * x * y
    xd = x * radial + k[2] * xy2 + k[3] * (r2 + 2 * x * x) + k[8] * r2 + k[9] * r4
    yd = y * radial + k[2] * (r2 + 2 * y * y) + k[3] * xy2 + k[10] * r2 + k[11] * r4
    return xd, yd


def _distort(k: np.ndarray, x: np.ndarray, y: np.ndarray):
    """OpenCV's lens map of normalised (...) x, y with the (14,) coefficients ``k``, tilt included.

    Points far outside the field (|x| ~ 1e50, at the camera plane) overflow to inf or NaN
    pixels rather than warn: no lens model holds there."""
    with np.errstate(over="ignore", invalid="ignore"):
        xd, yd = lens_map(k, x, y)
    if k[12] or k[13]:
        xd, yd = _homography(tilt_matrix(k[12], k[13]), xd, yd)
    return xd, yd


def _homography(t: np.ndarray, x: np.ndarray, y: np.ndarray):
    """(3, 3) ``t`` applied to (...) points as OpenCV applies the tilt (w = 0 left unscaled)."""
    w = t[2, 0] * x + t[2, 1] * y + t[2, 2]
    with np.errstate(divide="ignore"):
        w = np.where(w != 0, 1.0 / w, 1.0)
    return (t[0, 0] * x + t[0, 1] * y + t[0, 2]) * w, (t[1, 0] * x + t[1, 1] * y + t[1, 2]) * w


def lens_jacobian(k, x, y):
    """d(x'', y'')/d(x', y') of :func:`lens_map`: four arrays a, b, c, d (the rows [a b; c d]).

    Generic over the array type as :func:`lens_map` is.
    """
    r2 = x * x + y * y
    num = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))
    den = 1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
    dnum = k[0] + r2 * (2 * k[1] + 3 * k[4] * r2)   # d num / d r2
    dden = k[5] + r2 * (2 * k[6] + 3 * k[7] * r2)
    radial = num / den
    drad = (dnum * den - num * dden) / (den * den)  # d radial / d r2; d r2 / dx = 2 x
    dpx = k[8] + 2 * k[9] * r2                      # d (s1 r2 + s2 r4) / d r2
    dpy = k[10] + 2 * k[11] * r2
    a = radial + 2 * x * x * drad + 2 * k[2] * y + 6 * k[3] * x + 2 * x * dpx
    b = 2 * x * y * drad + 2 * k[2] * x + 2 * k[3] * y + 2 * y * dpx
    c = 2 * x * y * drad + 2 * k[2] * x + 2 * k[3] * y + 2 * x * dpy
    d = radial + 2 * y * y * drad + 6 * k[2] * y + 2 * k[3] * x + 2 * y * dpy
    return a, b, c, d


def _undistort(k: np.ndarray, xd: np.ndarray, yd: np.ndarray):
    """Newton inverse of :func:`_distort` (see :meth:`Camera.undistort_normalized`)."""
    if k[12] or k[13]:
        xd, yd = _homography(np.linalg.inv(tilt_matrix(k[12], k[13])), xd, yd)
    x, y = xd.copy(), yd.copy()
    done = ~(np.isfinite(x) & np.isfinite(y))
    with np.errstate(all="ignore"):
        for _ in range(UNDISTORT_MAX_ITER):
            fx, fy = lens_map(k, x, y)
            a, b, c, d = lens_jacobian(k, x, y)
            det = a * d - b * c
            sx = np.where(done, 0.0, (d * (fx - xd) - b * (fy - yd)) / det)
            sy = np.where(done, 0.0, (a * (fy - yd) - c * (fx - xd)) / det)
            x, y = x - sx, y - sy
            done |= np.hypot(sx, sy) < UNDISTORT_STEP
            if done.all():
                break
        fx, fy = lens_map(k, x, y)
        ok = done & (np.hypot(fx - xd, fy - yd) < 1e-12) & (det > 0)
    return np.where(ok, x, np.nan), np.where(ok, y, np.nan)


@dataclass(frozen=True, slots=True)
class Camera:
    """A calibrated camera: pinhole, OpenCV lens distortion and a thin lens.

    Attributes
    ----------
    position_m : (3,) float
        Centre of projection (the entrance pupil's centre) in the world frame.
    rotation : (3, 3) float
        World-to-camera rotation; its rows are the camera's x, y, z axes in world coordinates.
    fx_px, fy_px : float
        Focal lengths in pixels (pinhole-equivalent: the lens-to-sensor distance at focus).
    cx_px, cy_px : float
        Principal point in pixels (pixel-centre convention).
    width_px, height_px : int
        Image size; row 0 is the first row read out by the rolling shutter.
    distortion : (n,) float, n in :data:`DISTORTION_COUNTS`
        OpenCV distortion coefficients in OpenCV's order; empty for the pinhole. Read-only.
    f_number : float or None
        Aperture as f / entrance pupil diameter; None is a pinhole (no defocus).
    focus_distance_m : float or None
        Depth (camera z) of the plane in focus; None is a pinhole.
    pixel_pitch_m : float or None
        Size of one image pixel on the sensor (binning included); needed with ``f_number`` to
        turn the aperture into metres.
    """

    position_m: np.ndarray
    rotation: np.ndarray
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    width_px: int
    height_px: int
    distortion: np.ndarray = ()
    f_number: float | None = None
    focus_distance_m: float | None = None
    pixel_pitch_m: float | None = None

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
        self._init_lens()

    def _init_lens(self):
        d = np.array(self.distortion, dtype=np.float64).reshape(-1)
        if d.size not in DISTORTION_COUNTS:
            raise ValueError(f"distortion must have 0, 4, 5, 8, 12 or 14 coefficients "
                             f"(OpenCV's k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tauX tauY]]]]), "
                             f"got {d.size}")
        if not np.all(np.isfinite(d)):
            raise ValueError(f"distortion coefficients must be finite, got {d.tolist()}")
        if d.size and not np.any(d):
            d = np.zeros(0)  # all zeros is the pinhole: take its exact code path
        d.setflags(write=False)
        object.__setattr__(self, "distortion", d)
        if d.size:
            self._check_not_folded()
        lens = (self.f_number, self.focus_distance_m)
        if (lens[0] is None) != (lens[1] is None):
            raise ValueError("f_number and focus_distance_m come together (a thin lens needs both)")
        if self.f_number is not None:
            n, df = float(self.f_number), float(self.focus_distance_m)
            if not (0.5 <= n <= 64.0):
                raise ValueError(f"f_number must lie in [0.5, 64], got {n:g}")
            if self.pixel_pitch_m is None:
                raise ValueError("a thin lens (f_number) needs pixel_pitch_m to size its aperture")
            v = self.fx_px * float(self.pixel_pitch_m)
            if not (df > v and df <= 1e3):
                raise ValueError(f"focus_distance_m must lie beyond the lens-to-sensor distance "
                                 f"({v:g} m) and within 1000 m, got {df:g}")
            object.__setattr__(self, "f_number", n)
            object.__setattr__(self, "focus_distance_m", df)
        if self.pixel_pitch_m is not None:
            pitch = float(self.pixel_pitch_m)
            if not (1e-7 <= pitch <= 1e-4):
                raise ValueError(f"pixel_pitch_m must lie in [0.1, 100] um, got {pitch * 1e6:g} um")
            object.__setattr__(self, "pixel_pitch_m", pitch)

    def _check_not_folded(self):
        """Raise ValueError when the radial map r_d(r) is not increasing out to the frame's corners.

        r is the ideal normalised radius, r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 +
        k5 r^4 + k6 r^6). The corners' distorted radius r_dc is known from the pixel grid; the map
        folds the image when dr_d/dr <= 0 (or the denominator vanishes) before r_d reaches r_dc.
        Tangential, thin-prism and tilt terms are not part of this check.
        """
        k = full_coefficients(self.distortion)
        corners = np.array([[-0.5, -0.5], [self.width_px - 0.5, -0.5], [-0.5, self.height_px - 0.5],
                            [self.width_px - 0.5, self.height_px - 0.5]])
        rdc = np.hypot((corners[:, 0] - self.cx_px) / self.fx_px,
                       (corners[:, 1] - self.cy_px) / self.fy_px).max()
        r = np.linspace(0.0, _FOLD_SEARCH_R, 200_001)
        r2 = r * r
        num = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))
        den = 1 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
        with np.errstate(divide="ignore", invalid="ignore"):
            rd = r * num / den
        # sample i is good when the denominator is positive and r_d still rises to sample i + 1
        good = (den[:-1] > 0) & (den[1:] > 0) & (np.diff(rd) > 0)
        reached = np.nonzero(rd >= rdc)[0]
        end = reached[0] if reached.size else r.size - 1
        bad = ~good[:end]
        if bad.any() or not reached.size:
            at = r[np.argmax(bad)] if bad.any() else r[-1]
            raise ValueError(
                f"the distortion folds the image: the radial map r_d(r) stops increasing at "
                f"r = {at:.4g} (normalised), before it reaches the frame's corners (r_d = {rdc:.4g})")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        """True when the lens distorts (a non-empty coefficient array)."""
        return self.distortion.size > 0

    @property
    def is_thin_lens(self) -> bool:
        """True when the camera has an aperture (defocus); False for a pinhole."""
        return self.f_number is not None

    @property
    def focal_length_m(self) -> float:
        """Focal length f of the thin lens (m): 1/f = 1/v + 1/d_f, v = fx_px * pixel pitch."""
        if not self.is_thin_lens:
            raise ValueError("a pinhole camera has no focal length in metres")
        v = self.fx_px * self.pixel_pitch_m
        return v * self.focus_distance_m / (v + self.focus_distance_m)

    @property
    def aperture_radius_m(self) -> float:
        """Entrance pupil radius f / (2 N) in metres; 0 for a pinhole."""
        if not self.is_thin_lens:
            return 0.0
        return self.focal_length_m / (2.0 * self.f_number)

    def blur_diameter_px(self, depth_m) -> np.ndarray:
        """(...) diameter of the defocus disc of points at camera depth (...) in pixels (along x).

        Thin lens: c = A |d - d_f| / d * v / d_f on the sensor, with A = 2 * aperture radius and
        v = fx_px * pitch, so c / pitch = A |d - d_f| / d * fx_px / d_f. Zero for a pinhole.
        """
        d = np.asarray(depth_m, dtype=np.float64)
        if not self.is_thin_lens:
            return np.zeros_like(d)
        df = self.focus_distance_m
        return 2.0 * self.aperture_radius_m * np.abs(d - df) / d * self.fx_px / df

    @property
    def optical_axis(self) -> np.ndarray:
        """(3,) viewing direction in the world frame."""
        return self.rotation[2].copy()

    def world_to_camera(self, points_world) -> np.ndarray:
        """(..., 3) world points in the camera frame."""
        return (as_points(points_world, "points_world") - self.position_m) @ self.rotation.T

    def project(self, points_world) -> tuple[np.ndarray, np.ndarray]:
        """Project (..., 3) world points through the lens (as ``cv2.projectPoints`` does).

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
        if self.has_distortion:
            xd, yd = self.distort_normalized(pc[..., 0] * inv, pc[..., 1] * inv)
            return np.stack([self.fx_px * xd + self.cx_px, self.fy_px * yd + self.cy_px], axis=-1), z
        u = self.fx_px * pc[..., 0] * inv + self.cx_px
        v = self.fy_px * pc[..., 1] * inv + self.cy_px
        return np.stack([u, v], axis=-1), z

    def distort_normalized(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """OpenCV's distortion of ideal normalised coordinates (...), (...) -> distorted (...), (...)."""
        return _distort(full_coefficients(self.distortion), np.asarray(x, dtype=np.float64),
                        np.asarray(y, dtype=np.float64))

    def undistort_normalized(self, xd, yd) -> tuple[np.ndarray, np.ndarray]:
        """Invert :meth:`distort_normalized`: distorted normalised (...), (...) -> ideal.

        The tilt homography is inverted exactly; the rest by Newton's method with the analytic
        Jacobian, started at the distorted point, until the step is below
        :data:`UNDISTORT_STEP` (normalised units) or after :data:`UNDISTORT_MAX_ITER` steps.
        Points that do not converge (outside the region where the map is one to one) are NaN.
        """
        return _undistort(full_coefficients(self.distortion), np.asarray(xd, dtype=np.float64),
                          np.asarray(yd, dtype=np.float64))

    def undistort_px(self, pixels_px) -> np.ndarray:
        """(..., 2) distorted pixel positions -> (..., 2) ideal (pinhole) pixel positions.

        The inverse of :meth:`project`'s lens: ``undistort_px(project(X))`` is the pinhole image
        of X with the same intrinsics. Accuracy: Newton to a step below 1e-14 focal lengths; the
        round trip through :meth:`project` is better than 1e-6 px everywhere in the frame
        (tests/estimator/test_camera_lens.py). NaN where the inversion does not converge. The
        identity for a pinhole.
        """
        px = np.asarray(pixels_px, dtype=np.float64)
        if px.ndim == 0 or px.shape[-1] != 2:
            raise ValueError(f"pixels_px must have shape (..., 2), got {px.shape}")
        if not self.has_distortion:
            return px.copy()
        x, y = self.undistort_normalized((px[..., 0] - self.cx_px) / self.fx_px,
                                         (px[..., 1] - self.cy_px) / self.fy_px)
        return np.stack([self.fx_px * x + self.cx_px, self.fy_px * y + self.cy_px], axis=-1)

    def distort_px(self, pixels_px) -> np.ndarray:
        """(..., 2) ideal (pinhole) pixel positions -> (..., 2) pixel positions through the lens.

        The inverse of :meth:`undistort_px`; ``distort_px`` of a pinhole projection (for example
        :func:`~estimator.geometry.project_glints`, which works in ideal pixels) is what
        :meth:`project` gives. The identity for a pinhole.
        """
        px = np.asarray(pixels_px, dtype=np.float64)
        if px.ndim == 0 or px.shape[-1] != 2:
            raise ValueError(f"pixels_px must have shape (..., 2), got {px.shape}")
        if not self.has_distortion:
            return px.copy()
        x, y = self.distort_normalized((px[..., 0] - self.cx_px) / self.fx_px,
                                       (px[..., 1] - self.cy_px) / self.fy_px)
        return np.stack([self.fx_px * x + self.cx_px, self.fy_px * y + self.cy_px], axis=-1)

    def in_image(self, pixels_px) -> np.ndarray:
        """True where a pixel position lies on the sensor (within half a pixel of a centre)."""
        px = np.asarray(pixels_px, dtype=np.float64)
        u, v = px[..., 0], px[..., 1]
        return (u >= -0.5) & (u <= self.width_px - 0.5) & (v >= -0.5) & (v <= self.height_px - 0.5)

    def pixel_rays(self, pixels_px) -> np.ndarray:
        """(..., 3) unit world directions of the rays that (..., 2) pixel positions see.

        Through the lens: the ray through the undistorted point (NaN where the lens cannot be
        inverted). For a thin lens this is the chief ray, through the pupil's centre.
        """
        px = np.asarray(pixels_px, dtype=np.float64)
        if px.ndim == 0 or px.shape[-1] != 2:
            raise ValueError(f"pixels_px must have shape (..., 2), got {px.shape}")
        if self.has_distortion:
            x, y = self.undistort_normalized((px[..., 0] - self.cx_px) / self.fx_px,
                                             (px[..., 1] - self.cy_px) / self.fy_px)
            return normalize(np.stack([x, y, np.ones(px.shape[:-1])], axis=-1) @ self.rotation)
        d_cam = np.stack(
            [(px[..., 0] - self.cx_px) / self.fx_px, (px[..., 1] - self.cy_px) / self.fy_px,
             np.ones(px.shape[:-1])],
            axis=-1,
        )
        return normalize(d_cam @ self.rotation)

    def lens_dict(self) -> dict:
        """The lens as JSON-ready values (the keys a scene's ``[camera]`` table uses)."""
        return {"distortion": self.distortion.tolist(), "f_number": self.f_number,
                "focus_distance_m": self.focus_distance_m, "pixel_pitch_m": self.pixel_pitch_m}

    def with_intrinsics(self, fx_px, fy_px, cx_px, cy_px, width_px, height_px) -> "Camera":
        """The same pose and lens with other intrinsics (distortion is in normalised coordinates,
        so it carries over to a rescaled image; the pixel pitch scales with the focal length)."""
        pitch = None if self.pixel_pitch_m is None else self.pixel_pitch_m * self.fx_px / fx_px
        return Camera(self.position_m, self.rotation, fx_px, fy_px, cx_px, cy_px, width_px,
                      height_px, self.distortion, self.f_number, self.focus_distance_m, pitch)
