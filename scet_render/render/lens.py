"""Camera rays through the Setup's lens (:class:`estimator.geometry.Camera`) for the renderer.

Mitsuba's ``perspective`` sensor is a pinhole, and its ``thinlens`` sensor has no principal
point offset, so a camera with a lens gets its rays here, inside the renderer's frozen kernels
(:func:`band_rays`):

* distortion: the film position (OpenCV pixel u = film x - 0.5) is undistorted by Newton's
  method on OpenCV's model (:func:`estimator.geometry.lens_map`, the function
  :meth:`Camera.project` evaluates, so pixel (u, v) sees exactly the ray whose projection is
  (u, v)); :data:`NEWTON_STEPS` unrolled steps from the distorted point, in the variant's
  float32;
* thin lens: the ray leaves a point of the entrance pupil (a disc of radius f / (2 N) around the
  centre of projection, sampled uniformly with the concentric map) toward the pixel's point on
  the focus plane z = d_f (the chief ray through the undistorted point, met at depth d_f), as
  Mitsuba's ``thinlens`` does.

Everything the kernels need is a Python float, so the camera's numbers are literals of the
recorded kernel: eye poses still replay it without recompiling.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.geometry import Camera, full_coefficients, lens_jacobian, lens_map, tilt_matrix

from .layout import SCENE_UNITS_PER_M

#: Newton steps of the undistortion inside the kernels. Measured in float64 from the distorted
#: point over a 641 x 481 grid of a stock M12 lens (k1 = -0.30, k2 = 0.12 at 643 px, corners
#: moved ~10 px): the largest step is 9e-2, 3e-3, 5e-6, 1e-11, 4e-16 at steps 1-5 (float32's
#: resolution is ~6e-8); 8 leave margin for stronger lenses.
NEWTON_STEPS = 8


@dataclass(frozen=True)
class LensRays:
    """The numbers of a camera's lens as Python floats (literals in a recorded kernel)."""

    k: tuple
    fx: float
    fy: float
    cx: float
    cy: float
    inverse_tilt: tuple | None
    distorted: bool
    aperture_radius: float  # scene units; 0: pinhole
    focus_distance: float   # scene units
    axes: tuple             # rows of the world-to-camera rotation (camera x, y, z in world)
    origin: tuple           # scene units

    @classmethod
    def of(cls, camera: Camera, *, pinhole: bool = False) -> "LensRays | None":
        """The lens of ``camera``; None for a pinhole (the sensor's own rays) unless ``pinhole``."""
        if not (pinhole or camera.has_distortion or camera.is_thin_lens):
            return None
        k = full_coefficients(camera.distortion)
        tilt = None
        if k[12] or k[13]:
            tilt = tuple(float(v) for v in np.linalg.inv(tilt_matrix(k[12], k[13])).ravel())
        return cls(tuple(float(v) for v in k), camera.fx_px, camera.fy_px, camera.cx_px,
                   camera.cy_px, tilt, camera.has_distortion,
                   camera.aperture_radius_m * SCENE_UNITS_PER_M,
                   (camera.focus_distance_m or 0.0) * SCENE_UNITS_PER_M,
                   tuple(tuple(float(v) for v in row) for row in camera.rotation),
                   tuple(float(v) * SCENE_UNITS_PER_M for v in camera.position_m))

    @property
    def thin(self) -> bool:
        return self.aperture_radius > 0

    def ideal_normalized(self, mi, film_px):
        """Undistorted normalised image coordinates (x', y') of Mitsuba film positions (pixels)."""
        xd = (film_px.x - (0.5 + self.cx)) * (1.0 / self.fx)
        yd = (film_px.y - (0.5 + self.cy)) * (1.0 / self.fy)
        if not self.distorted:
            return xd, yd
        if self.inverse_tilt is not None:
            t = self.inverse_tilt
            w = 1.0 / (t[6] * xd + t[7] * yd + t[8])
            xd, yd = (t[0] * xd + t[1] * yd + t[2]) * w, (t[3] * xd + t[4] * yd + t[5]) * w
        x, y = mi.Float(xd), mi.Float(yd)
        for _ in range(NEWTON_STEPS):
            fx, fy = lens_map(self.k, x, y)
            a, b, c, d = lens_jacobian(self.k, x, y)
            inv = 1.0 / (a * d - b * c)
            ex, ey = fx - xd, fy - yd
            x, y = x - (d * ex - b * ey) * inv, y - (a * ey - c * ex) * inv
        return x, y

    def rays(self, mi, film_px, aperture_sample=None):
        """World rays (origins, unit directions; scene units) through film positions (pixels).

        ``aperture_sample`` (mi.Point2f in [0, 1)^2) picks the point of the pupil; required for a
        thin lens, ignored by a pinhole.
        """
        import drjit as dr

        x, y = self.ideal_normalized(mi, film_px)
        ex, ey, ez = (mi.Vector3f(*row) for row in self.axes)
        if self.thin:
            disk = mi.warp.square_to_uniform_disk_concentric(aperture_sample) * self.aperture_radius
            # From the pupil point (disk.x, disk.y, 0) to the focus point (x d_f, y d_f, d_f).
            dx = x * self.focus_distance - disk.x
            dy = y * self.focus_distance - disk.y
            o = mi.Point3f(*self.origin) + ex * disk.x + ey * disk.y
            d = dr.normalize(ex * dx + ey * dy + ez * self.focus_distance)
        else:
            o = mi.Point3f(*self.origin)
            d = dr.normalize(ex * x + ey * y + ez)
        return o, d


def band_rays(mi, sensor, row0, seed, lanes, spp: int, W: int, H: int,
               lens: "LensRays | None" = None):
    """Camera rays of a band's samples (``spp`` a pixel, rows from ``row0``, one lane each
    of ``lanes``): a seeded independent sampler, a jittered film position and a wavelength
    from it; returns (sampler, ray, weight).

    With a ``lens`` (:class:`~scet_render.render.lens.LensRays`: distortion, thin lens) the
    ray's origin and direction are the lens's, for the same film position; a thin lens draws
    its pupil point from the sampler next. Without one, the sensor's pinhole ray as always."""
    import drjit as dr

    n = dr.width(lanes)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    pixel = dr.arange(mi.UInt32, n) // spp
    film = mi.Point2f(mi.Float(pixel % W), mi.Float(pixel // W + row0))
    film += sampler.next_2d()
    wavelength = sampler.next_1d()
    ray, weight = sensor.sample_ray_differential(
        0.0, wavelength, film * mi.ScalarVector2f(1.0 / W, 1.0 / H), mi.Point2f(0.5, 0.5))
    if lens is not None:
        ray.o, ray.d = lens.rays(mi, film, sampler.next_2d() if lens.thin else None)
        ray.has_differentials = False
    return sampler, ray, weight
