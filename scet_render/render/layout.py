"""The rendered eye's options and layout: materials and geometry choices
(:class:`SceneOptions`), the derived sizes of its parts and lid margins (:func:`eye_layout`),
and the scene constants (units, radiances, clearances) with the measurements behind them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimator.setup import Setup

#: Strobe light source radiance and ambient environment radiance (W sr^-1 m^-2, near-IR).
#: With 40 lights of 0.2 mm at ~30 mm, skin and sclera under the strobe read ~1, a dielectric
#: glint ~25, and the ambient adds ~0.07 to them over a 1 ms exposure (see rolling_shutter).
DEFAULT_LIGHT_RADIANCE = 1000.0
DEFAULT_AMBIENT_RADIANCE = 0.01
#: Gap between the corneal apex sphere and the eyelid shell, and between lids and skin (m).
LID_CLEARANCE_M = 0.6e-3
SKIN_OVER_LID_M = 0.4e-3
#: Eyelid margin beyond the cornea at full openness (rad), and the pupil's offset in front of
#: the iris (m: far below a pixel, far above float32 rounding at 1 cm).
LID_MARGIN_RAD = math.radians(5.0)
PUPIL_OFFSET_M = 20e-6
#: The iris disk's radius over the limbus radius: it reaches under the sclera's mask edge.
IRIS_OVERLAP = 1.002
#: The face plane (a 10 cm disk facing -z) lies this far behind the rotation centre (m), past
#: the rim of the skin shell (13 mm radius, out to 100 deg from the gaze: 2.3 mm behind).
FACE_BEHIND_CENTER_M = 3e-3
#: Mitsuba scene units per metre: scenes are built in centimetres. Mitsuba offsets every
#: spawned ray by ~9e-5 (1 + |p|) scene units to avoid self-intersection: 89 µm in metres,
#: which moves glints by 0.4 px at 1300 px focal length, but 2 µm (0.01 px) in centimetres.
#: Centimetres also keep the eye's sizes near 1, where float32 keeps Mitsuba's check of a
#: sphere's uniform scale (1e-6 absolute) quiet.
SCENE_UNITS_PER_M = 100.0
#: Mitsuba film pixel i covers [i, i + 1); OpenCV's pixel i is centred on i (DESIGN.md).
FILM_TO_OPENCV_PX = -0.5
#: Rows of the sclera's opacity mask over the polar angle 0..pi: 0.022 deg, 4 µm on the eyeball.
SCLERA_MASK_TEXELS = 8192
#: ``dielectric``: the physically correct cornea, its glints sampled by
#: :mod:`~scet_render.render.cornea_bsdf` (the default); ``plain_dielectric``: Mitsuba's own
#: ``dielectric`` (same image in the limit, glints noisy at low spp); ``conductor``: a mirror with
#: the dielectric's Fresnel reflectance and no refraction.
CORNEA_MODES = ("dielectric", "plain_dielectric", "conductor")
CORNEA_GEOMETRIES = ("sphere", "mesh")
CHANNEL_MODES = ("split", "grey")
#: How strobe light reaches the iris and pupil through the cornea (``channels="split"``):
#: ``mnee`` by manifold next-event estimation (:mod:`~scet_render.render.mnee`, the default);
#: ``path`` by plain path tracing (the cornea transmits the strobe channel: unbiased, but a
#: 0.2 mm light is hit about once in a thousand paths: the brute-force reference for large
#: lights); ``none`` not at all (the renders before MNEE: iris and pupil lit by the ambient only).
THROUGH_CORNEA_MODES = ("mnee", "path", "none")
#: Scene parameters moved by :meth:`EyeScene.set_pose`.
MOVING_KEYS = ("cornea.to_world", "sclera.to_world", "iris.to_world", "pupil.to_world",
               "cornea.vertex_positions", "cornea.vertex_normals")


@dataclass(frozen=True, slots=True)
class SceneOptions:
    """Materials, lighting and geometry choices of a rendered scene (albedos are near-IR).

    ``eyelid_openness`` sets the static lids; a Setup with ``eyelids`` (the scene's
    ``[eyelids]`` table) gets lids that follow the eye instead, unless it is None (no lids).
    ``pupil_radius_m`` overrides the scene's pupil (``eye.pupil_diameter_mm``, half of it);
    None takes the scene's (:func:`pupil_radius`).
    """

    cornea: str = "dielectric"
    cornea_geometry: str = "sphere"
    eyelid_openness: float | None = 1.0
    light_radiance: float = DEFAULT_LIGHT_RADIANCE
    ambient_radiance: float = DEFAULT_AMBIENT_RADIANCE
    channels: str = "split"
    pupil_radius_m: float | None = None
    sclera_albedo: float = 0.7
    iris_albedo: float = 0.3
    pupil_albedo: float = 0.02
    skin_albedo: float = 0.6
    #: Path depth (Mitsuba's ``max_depth``). Light seen on the iris through the refracting
    #: cornea takes more vertices than light on the skin (in, off the iris, out or totally
    #: reflected back inside): against max_depth 64, 6 rendered the iris's ambient 7.1 % darker
    #: and the skin's 3.6 %, 16 within 0.3 % in every region, at the same cost within the
    #: machine's noise (Russian roulette ends the long paths; benchmarks/bench_depth.py,
    #: paper_sim 640x480, 16 spp: 2.4-2.9 s a frame at every depth from 6 to 64).
    max_depth: int = 16
    cornea_edge_m: float = 0.15e-3
    strobe_through_cornea: str = "mnee"

    def __post_init__(self):
        for name, allowed in (("cornea", CORNEA_MODES), ("cornea_geometry", CORNEA_GEOMETRIES),
                              ("channels", CHANNEL_MODES),
                              ("strobe_through_cornea", THROUGH_CORNEA_MODES)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        o = self.eyelid_openness
        if o is not None and not (math.isfinite(o) and 0.0 <= o <= 1.0):
            raise ValueError(f"eyelid_openness must be None (no eyelids) or in [0, 1], got {o!r}")
        for name in ("light_radiance", "ambient_radiance"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        for name in ("sclera_albedo", "iris_albedo", "pupil_albedo", "skin_albedo"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)!r}")
        r_p = 1.0 if self.pupil_radius_m is None else self.pupil_radius_m
        if not (r_p > 0 and math.isfinite(r_p) and self.cornea_edge_m > 0
                and self.max_depth >= 2):
            raise ValueError("pupil_radius_m and cornea_edge_m must be > 0 and max_depth >= 2")


def pupil_radius(setup: Setup, options: SceneOptions) -> float:
    """The rendered pupil's radius (m): ``options.pupil_radius_m``, else half the scene's
    ``eye.pupil_diameter_m`` (4 mm unless the scene says otherwise: the renders before it was
    a scene key)."""
    if options.pupil_radius_m is not None:
        return float(options.pupil_radius_m)
    return 0.5 * setup.eye.pupil_diameter_m


@dataclass(frozen=True, slots=True)
class EyeLayout:
    """Derived eye dimensions (m, rad), all along the gaze axis from the rotation centre."""

    limbus_plane_m: float
    limbus_radius_m: float
    sclera_radius_m: float
    cap_angle_rad: float
    lid_radius_m: float
    skin_radius_m: float
    lid_upper_rad: float
    lid_lower_rad: float
    skin_hole_rad: float


def eye_layout(setup: Setup, options: SceneOptions = SceneOptions()) -> EyeLayout:
    """Sizes of the scene's eye parts, eyelid margins (elevations) and skin opening."""
    eye = setup.eye
    d_l = eye.cornea_offset_m + eye.cornea_radius_m - eye.limbus_depth_m
    r_l = eye.limbus_radius_m
    if d_l <= 0:
        raise ValueError(f"{setup.name}: the limbus plane lies behind the rotation centre "
                         f"(offset + radius - limbus depth = {d_l:.3g} m); no sclera fits")
    cap = math.atan2(r_l, d_l)  # angular radius of the cornea seen from the rotation centre
    lid_r = eye.cornea_offset_m + eye.cornea_radius_m + LID_CLEARANCE_M
    yaw, pitch = eye.angles_toward(setup.screen.grid(9, 9, margin=0.0))
    gaze_off_axis = np.arccos(np.clip(np.cos(yaw) * np.cos(pitch), -1.0, 1.0)).max()
    up_open = min(float(pitch.max()) + cap + LID_MARGIN_RAD, math.radians(80.0))
    low_open = max(float(pitch.min()) - cap - LID_MARGIN_RAD, math.radians(-80.0))
    o = 1.0 if options.eyelid_openness is None else options.eyelid_openness
    closed = 0.5 * (up_open + low_open)
    return EyeLayout(d_l, r_l, math.hypot(d_l, r_l), cap, lid_r, lid_r + SKIN_OVER_LID_M,
                     closed + o * (up_open - closed), closed + o * (low_open - closed),
                     min(float(gaze_off_axis) + cap + 2 * LID_MARGIN_RAD, math.radians(85.0)))
