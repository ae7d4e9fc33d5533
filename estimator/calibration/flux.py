"""The expected flux of a glint, and each light's power calibrated from it.

A point light of intensity I_i (W/sr, isotropic: the renderer's lights are small spherical
emitters) reflected by the convex corneal sphere (radius r_c) at incidence θ is seen by the
camera through an astigmatic beam. After Coddington's equations for a spherical mirror the
reflected vergences are 1/d_L + 2/(r_c cos θ) (tangential) and 1/d_L + 2 cos θ / r_c
(sagittal), so the irradiance at the camera, d_C from the glint point and d_L from the light, is

    E = I_i F(θ) / (d_L² (1 + d_C/d_L + 2 d_C/(r_c cos θ)) (1 + d_C/d_L + 2 d_C cos θ / r_c)),

which far from the mirror is the textbook I_i F(θ) r_c² / (4 d_L² d_C²). The detector's flux
(:attr:`estimator.glints.GlintDetections.intensity`) is already divided by the share of the
strobe pulse the glint's rows collect (the banding model, Eqs. 2-8 of the SCET paper), and a
pinhole camera that reads radiance (the renderer's) sums a point source to E / Ω_pixel with
Ω_pixel ∝ cos³ φ (φ off the optical axis). So measured / (I_i model) is one constant per light:
:class:`GlintFlux` holds log I_i, fitted as the median over calibration frames.

A conic cornea (apex radius R, conic constant Q, its axis from the eye centre c_e through the
cornea centre c; :mod:`estimator.geometry.conic`) is not one sphere: at the reflection point its
principal radii are the sagittal R_s = sqrt(R² - Q h²) and the meridional R_t = R_s³ / R² (h the
distance from the axis), and the plane of incidence is in general not a principal plane. The
reflected wavefront's curvature then follows the generalised Coddington equation (Deschamps,
Proc. IEEE 60, 1972): with the surface's 2 x 2 curvature matrix K in the basis (in the plane of
incidence, across it) and P = diag(cos θ, 1),

    Q_r = I / d_L + 2 cos θ P⁻¹ K P⁻¹,     E = I_i F(θ) / (d_L² det(I + d_C Q_r)),

which for K = I / r_c is the sphere's formula above (:func:`conic_flux` below; a test holds it
to the irradiance found by moving the camera across the reflected beam on the exact conic
reflection).

F is the unpolarised Fresnel reflectance of the tear film (n = 1.376) for a real cornea and the
renderer's ``dielectric`` and ``conductor`` corneas (docs/guide/rendering.md, "The cornea"); ``fresnel="constant"``
models a mirror of one reflectance (the renderer's conductor before issue 14 was scaled by F(0)
only). The calibration fits both and keeps the one whose log ratios spread less (it is
recorded in the file).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..checks import Doc
from ..eye import CORNEA_REFRACTIVE_INDEX

FRESNEL_MODELS = ("dielectric", "constant")
#: Fewest calibration frames a light's power is taken from (its median).
MIN_FRAMES_PER_LIGHT = 3
#: Range of a file's log powers: the model is in SI units and DN, so log I_i is finite and
#: moderate; anything beyond ±200 is not a power (e^200).
LOG_POWER_LIMIT = 200.0


def fresnel_reflectance(cos_i, n: float = CORNEA_REFRACTIVE_INDEX) -> np.ndarray:
    """Unpolarised Fresnel reflectance (..,) of a dielectric of index n seen from air at
    incidence cosines cos_i (..,)."""
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    s2 = 1.0 - c * c
    ct = np.sqrt(np.maximum(1.0 - s2 / (n * n), 0.0))
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return 0.5 * (rs * rs + rp * rp)


def model_flux(camera, cornea_center_m, cornea_radius_m: float, lights_world_m, glints_px,
               fresnel: str = "dielectric", *, asphericity: float = 0.0,
               eye_center_m=None) -> np.ndarray:
    """Expected flux of glints per unit light intensity (module docstring).

    Parameters
    ----------
    camera : Camera
    cornea_center_m : (3,) float
        Fitted cornea centre (world; on a conic, the apex's centre of curvature).
    cornea_radius_m : float
        Radius (the apex radius R of a conic).
    lights_world_m : (k, 3) float
        The light of each glint.
    glints_px : (k, 2) float
        Detected glint centroids: the glint point is where the pixel ray meets the cornea.
    fresnel : {"dielectric", "constant"}
    asphericity : float
        Conic constant Q in (-1, 1]; 0: the sphere.
    eye_center_m : (3,) float
        The eye centre the conic's axis points from (needed where Q is not 0).

    Returns
    -------
    (k,) float
        NaN where the ray misses the cornea.
    """
    g = np.asarray(glints_px, dtype=np.float64).reshape(-1, 2)
    L = np.asarray(lights_world_m, dtype=np.float64).reshape(-1, 3)
    if L.shape[0] != g.shape[0]:
        raise ValueError(f"lights_world_m must have shape ({g.shape[0]}, 3), got {L.shape}")
    if fresnel not in FRESNEL_MODELS:
        raise ValueError(f"fresnel must be one of {FRESNEL_MODELS}, got {fresnel!r}")
    d = camera.pixel_rays(g)
    pinhole = (d @ camera.rotation[2]) ** -3  # 1 / cos³ φ, φ off the optical axis
    if asphericity != 0.0:
        if eye_center_m is None:
            raise ValueError("a conic cornea's flux needs eye_center_m (its axis)")
        e, cos_i = conic_flux(camera.position_m, d, cornea_center_m, eye_center_m,
                              cornea_radius_m, asphericity, L)
    else:
        e, cos_i = _sphere_flux(camera.position_m, d, cornea_center_m, cornea_radius_m, L)
    f = fresnel_reflectance(cos_i) if fresnel == "dielectric" else 1.0
    return f * e * pinhole


def _sphere_flux(camera_position_m, d, cornea_center_m, cornea_radius_m, L):
    """:func:`conic_flux` of the sphere: Coddington's vergences in closed form (module
    docstring); rays ``d`` (k, 3) from the camera, lights ``L`` (k, 3)."""
    r = float(cornea_radius_m)
    C = camera_position_m
    oc = C - np.asarray(cornea_center_m, dtype=np.float64).reshape(3)
    b = d @ oc
    disc = b * b - (oc @ oc - r * r)
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)  # the near intersection: NaN where the ray misses
    d_c = t
    cos_i = np.clip(-(b + t) / r, 1e-6, 1.0)  # n · (-d) with n = (C + t d - c) / r
    to_l = L - (C + t[:, None] * d)
    d_l = np.sqrt(np.einsum("ij,ij->i", to_l, to_l))
    a = 1.0 + d_c / d_l
    return 1.0 / (d_l * d_l * (a + 2.0 * d_c / (r * cos_i)) * (a + 2.0 * d_c * cos_i / r)), cos_i


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _across(n, v):
    """(k, 3) unit vectors perpendicular to the unit normals ``n`` and to ``v``; where v is
    along n (normal incidence, the apex) any perpendicular of n: every direction is then
    equivalent for the flux."""
    c = np.cross(n, v)
    size = np.linalg.norm(c, axis=-1)
    spare = np.where((np.abs(n[:, 0]) < 0.9)[:, None], [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    c = np.where((size > 1e-12)[:, None], c, np.cross(n, spare))
    return _unit(c)


def conic_flux(camera_position_m, ray_dirs, cornea_center_m, eye_center_m, cornea_radius_m,
               asphericity, lights_world_m) -> tuple[np.ndarray, np.ndarray]:
    """Irradiance per unit intensity at the camera of glints on a conic cornea, and the
    incidence cosines (module docstring: the generalised Coddington equation).

    Parameters
    ----------
    camera_position_m : (3,) float
    ray_dirs : (k, 3) float
        Unit directions of the glints' pixel rays (world).
    cornea_center_m, eye_center_m : (3,) float
        The apex's centre of curvature and the eye centre: the axis points from the second
        through the first, the apex R beyond the centre.
    cornea_radius_m, asphericity : float
        Apex radius R and conic constant Q.
    lights_world_m : (k, 3) float

    Returns
    -------
    irradiance : (k,) float
        E / I_i without Fresnel; NaN where the ray misses the conic.
    cos_i : (k,) float
    """
    R, Q = float(cornea_radius_m), float(asphericity)
    O = np.asarray(camera_position_m, dtype=np.float64).reshape(3)
    d = np.asarray(ray_dirs, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(cornea_center_m, dtype=np.float64).reshape(3)
    u = _unit(c - np.asarray(eye_center_m, dtype=np.float64).reshape(3))
    w = O - (c + R * u)  # from the apex
    # Depth z behind the apex along the ray, z = z0 + t dz; the conic r² + (1 + Q) z² - 2Rz = 0
    # with r² = |w + t d|² - z² is a quadratic in t.
    z0, dz = -(w @ u), -(d @ u)
    a = 1.0 + Q * dz * dz
    b = 2.0 * (d @ w + Q * z0 * dz - R * dz)
    cc = w @ w + Q * z0 * z0 - 2.0 * R * z0
    disc = b * b - 4.0 * a * cc
    with np.errstate(invalid="ignore", divide="ignore"):
        root = -0.5 * (b + np.copysign(np.sqrt(disc), b))  # the stable pair of roots
        t1, t2 = root / a, cc / root
        t = np.where((t1 > 0) & ((t1 <= t2) | ~(t2 > 0)), t1, t2)  # NaN where disc < 0
    P = O + t[:, None] * d
    z = z0 + t * dz
    rel = P - (c + R * u)
    m = rel + z[:, None] * u - (((1.0 + Q) * z - R)[:, None] * u)  # outward normal, |m| = R_s
    r_s = np.linalg.norm(m, axis=-1)
    n = m / r_s[:, None]
    r_t = r_s ** 3 / (R * R)
    cos_i = np.clip(-np.einsum("ij,ij->i", d, n), 1e-6, 1.0)
    t_s = _across(n, np.broadcast_to(u, n.shape))  # across the meridional plane
    t_m = np.cross(n, t_s)
    e_across = _across(n, -d)  # across the plane of incidence
    e_in = np.cross(e_across, n)
    k_m, k_s = 1.0 / r_t, 1.0 / r_s

    def curv(x, y):  # x^T K y in the tangent plane
        return (k_m * np.einsum("ij,ij->i", x, t_m) * np.einsum("ij,ij->i", y, t_m)
                + k_s * np.einsum("ij,ij->i", x, t_s) * np.einsum("ij,ij->i", y, t_s))

    to_l = np.asarray(lights_world_m, dtype=np.float64).reshape(-1, 3) - P
    d_l = np.linalg.norm(to_l, axis=-1)
    d_c = t
    q11 = 1.0 / d_l + 2.0 * curv(e_in, e_in) / cos_i
    q12 = 2.0 * curv(e_in, e_across)
    q22 = 1.0 / d_l + 2.0 * cos_i * curv(e_across, e_across)
    det = (1.0 + d_c * q11) * (1.0 + d_c * q22) - (d_c * q12) ** 2
    return 1.0 / (d_l * d_l * det), cos_i


@dataclass(frozen=True, slots=True)
class GlintFlux:
    """Each light's calibrated power, for the expected flux of its glints.

    Attributes
    ----------
    log_power : (n,) float
        log I_i (DN per model unit; NaN for a light seen in fewer than
        :data:`MIN_FRAMES_PER_LIGHT` calibration frames).
    fresnel : {"dielectric", "constant"}
    log_sd : float
        Robust SD (1.4826 MAD) of log(measured / expected) over the calibration glints.
    noise_px : float
        The calibration's RMS glint residual (px): the scale of a glint's displacement from
        the fitted pose that counts as a cut's (NaN: unknown, not used).
    """

    log_power: np.ndarray
    fresnel: str = "dielectric"
    log_sd: float = float("nan")
    noise_px: float = float("nan")

    def __post_init__(self):
        p = np.asarray(self.log_power, dtype=np.float64).reshape(-1).copy()
        p.setflags(write=False)
        object.__setattr__(self, "log_power", p)
        if self.fresnel not in FRESNEL_MODELS:
            raise ValueError(f"GlintFlux.fresnel must be one of {FRESNEL_MODELS}, "
                             f"got {self.fresnel!r}")
        object.__setattr__(self, "log_sd", float(self.log_sd))
        object.__setattr__(self, "noise_px", float(self.noise_px))

    def expected(self, camera, cornea_center_m, cornea_radius_m, lights_world_m, light_index,
                 glints_px, *, asphericity: float = 0.0, eye_center_m=None) -> np.ndarray:
        """(k,) expected flux (DN) of glints of lights ``light_index`` (into the (n, 3)
        ``lights_world_m``); NaN for lights without a calibrated power. A conic cornea:
        ``asphericity`` and ``eye_center_m`` (:func:`model_flux`)."""
        li = np.asarray(light_index, dtype=np.int64)
        m = model_flux(camera, cornea_center_m, cornea_radius_m, lights_world_m[li], glints_px,
                       self.fresnel, asphericity=asphericity, eye_center_m=eye_center_m)
        return m * np.exp(self.log_power[li])

    def to_dict(self) -> dict:
        return {"fresnel": self.fresnel,
                "log_power": [float(v) if np.isfinite(v) else None for v in self.log_power],
                "log_sd": float(self.log_sd) if np.isfinite(self.log_sd) else None,
                "noise_px": float(self.noise_px) if np.isfinite(self.noise_px) else None}

    @classmethod
    def from_dict(cls, doc: Doc, n_lights: int | None = None) -> "GlintFlux":
        """From the ``glint_flux`` object of a calibration file (``doc``: its :class:`Doc`)."""
        fresnel = doc.string("fresnel", choices=FRESNEL_MODELS)
        items = doc.items("log_power")
        if not items or (n_lights is not None and len(items) != n_lights):
            raise doc.error("log_power", f"expected a list of {n_lights or 'one or more'} "
                                         f"numbers or nulls, got {len(items)} items")
        out = np.full(len(items), np.nan)
        for i, v in enumerate(items):
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) \
                    or abs(v) > LOG_POWER_LIMIT:
                raise doc.error(f"log_power[{i}]", f"expected a finite number within "
                                                   f"±{LOG_POWER_LIMIT:g} or null, got {v!r}")
            out[i] = float(v)
        sd = doc.raw("log_sd", required=False)
        if sd is not None and (isinstance(sd, bool) or not isinstance(sd, (int, float))
                               or not 0 <= sd < 10):
            raise doc.error("log_sd", f"expected a number in [0, 10) or null, got {sd!r}")
        noise = doc.raw("noise_px", required=False)
        if noise is not None and (isinstance(noise, bool) or not isinstance(noise, (int, float))
                                  or not 0 <= noise < 100):
            raise doc.error("noise_px", f"expected a number of pixels in [0, 100) or null, "
                                        f"got {noise!r}")
        return cls(out, fresnel, float("nan") if sd is None else float(sd),
                   float("nan") if noise is None else float(noise))


def fit_glint_flux(camera, cornea_radius_m: float, lights_world_m, centers_m, glints_px,
                   flux, noise_px: float = float("nan"), *, asphericity: float = 0.0,
                   eye_center_m=None) -> GlintFlux:
    """Each light's power from calibration frames: the median over frames of
    log(measured / model), for the Fresnel model whose log ratios spread less.

    Parameters
    ----------
    camera : Camera
    cornea_radius_m : float
    lights_world_m : (n, 3) float
    centers_m : (m, 3) float
        Fitted cornea centre of each frame.
    glints_px : (m, n, 2) float
        Identified glints (NaN: none).
    flux : (m, n) float
        Their measured flux (DN).
    noise_px : float
        The calibration's RMS glint residual, recorded (:attr:`GlintFlux.noise_px`).
    asphericity, eye_center_m
        A conic cornea's Q and eye centre (:func:`model_flux`).
    """
    lights = np.asarray(lights_world_m, dtype=np.float64)
    g = np.asarray(glints_px, dtype=np.float64)
    flux = np.asarray(flux, dtype=np.float64)
    n = lights.shape[0]
    if g.ndim != 3 or g.shape[1:] != (n, 2) or flux.shape != g.shape[:2]:
        raise ValueError(f"glints_px must be (m, {n}, 2) and flux (m, {n}), "
                         f"got {g.shape} and {flux.shape}")
    best = None
    for fresnel in FRESNEL_MODELS:
        logr = np.full(flux.shape, np.nan)
        for k, c in enumerate(np.asarray(centers_m, dtype=np.float64)):
            ok = np.isfinite(g[k, :, 0]) & (flux[k] > 0) & np.isfinite(c).all()
            if ok.any():
                with np.errstate(invalid="ignore", divide="ignore"):
                    logr[k, ok] = np.log(flux[k, ok] / model_flux(
                        camera, c, cornea_radius_m, lights[ok], g[k, ok], fresnel,
                        asphericity=asphericity, eye_center_m=eye_center_m))
        seen = np.isfinite(logr).sum(axis=0)
        with warnings.catch_warnings():  # all-NaN columns: lights never seen
            warnings.simplefilter("ignore", RuntimeWarning)
            power = np.nanmedian(logr, axis=0)
        power[seen < MIN_FRAMES_PER_LIGHT] = np.nan
        res = (logr - power)[np.isfinite(logr - power)]
        sd = 1.4826 * float(np.median(np.abs(res - np.median(res)))) if res.size else np.inf
        if best is None or sd < best.log_sd:
            best = GlintFlux(power, fresnel, sd, noise_px)
    return best
