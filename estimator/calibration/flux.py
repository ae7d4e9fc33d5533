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

F is the unpolarised Fresnel reflectance of the tear film (n = 1.376) for a real cornea and the
renderer's ``dielectric`` and ``conductor`` corneas (README, "The cornea"); ``fresnel="constant"``
models a mirror of one reflectance (the renderer's conductor before issue 14 was scaled by F(0)
only). The calibration fits both and keeps the one whose log ratios spread less (it is
recorded in the file).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..checks import Doc
from ..errors import InputError
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
               fresnel: str = "dielectric") -> np.ndarray:
    """Expected flux of glints per unit light intensity (module docstring).

    Parameters
    ----------
    camera : Camera
    cornea_center_m : (3,) float
        Fitted cornea centre (world).
    cornea_radius_m : float
    lights_world_m : (k, 3) float
        The light of each glint.
    glints_px : (k, 2) float
        Detected glint centroids: the glint point is where the pixel ray meets the sphere.
    fresnel : {"dielectric", "constant"}

    Returns
    -------
    (k,) float
        NaN where the ray misses the sphere.
    """
    g = np.asarray(glints_px, dtype=np.float64).reshape(-1, 2)
    L = np.asarray(lights_world_m, dtype=np.float64).reshape(-1, 3)
    if L.shape[0] != g.shape[0]:
        raise ValueError(f"lights_world_m must have shape ({g.shape[0]}, 3), got {L.shape}")
    if fresnel not in FRESNEL_MODELS:
        raise ValueError(f"fresnel must be one of {FRESNEL_MODELS}, got {fresnel!r}")
    r = float(cornea_radius_m)
    C = camera.position_m
    xn = (g[:, 0] - camera.cx_px) / camera.fx_px
    yn = (g[:, 1] - camera.cy_px) / camera.fy_px
    q = 1.0 + xn * xn + yn * yn  # 1 / cos² φ
    d = (xn[:, None] * camera.rotation[0] + yn[:, None] * camera.rotation[1]
         + camera.rotation[2]) / np.sqrt(q)[:, None]
    oc = C - np.asarray(cornea_center_m, dtype=np.float64).reshape(3)
    b = d @ oc
    disc = b * b - (oc @ oc - r * r)
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)  # the near intersection: NaN where the ray misses
    d_c = t
    cos_i = -(b + t) / r  # n · (-d) with n = (C + t d - c) / r
    to_l = L - (C + t[:, None] * d)
    d_l = np.sqrt(np.einsum("ij,ij->i", to_l, to_l))
    cos_i = np.clip(cos_i, 1e-6, 1.0)
    a = 1.0 + d_c / d_l
    e = 1.0 / (d_l * d_l * (a + 2.0 * d_c / (r * cos_i)) * (a + 2.0 * d_c * cos_i / r))
    f = fresnel_reflectance(cos_i) if fresnel == "dielectric" else 1.0
    return f * e * q * np.sqrt(q)


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
                 glints_px) -> np.ndarray:
        """(k,) expected flux (DN) of glints of lights ``light_index`` (into the (n, 3)
        ``lights_world_m``); NaN for lights without a calibrated power."""
        li = np.asarray(light_index, dtype=np.int64)
        m = model_flux(camera, cornea_center_m, cornea_radius_m, lights_world_m[li], glints_px,
                       self.fresnel)
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
                   flux, noise_px: float = float("nan")) -> GlintFlux:
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
                        camera, c, cornea_radius_m, lights[ok], g[k, ok], fresnel))
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
