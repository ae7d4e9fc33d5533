"""System calibration (Sec. 2.4 and 3.1 of the SCET paper) and gaze mappings (Sec. 2.2.2, 3.3.1).

Four steps, each in two flavours: the paper's as described, and ours.

1. **Lighting pose and corneal radius** from frames of the eye fixating calibration targets,
   lit by a rigid light group of known shape (the 6x6 grid of Sec. 3.1). Unknowns: cornea
   centre c_c, radius r_c and the group's rigid pose (rotation vector about the nominal
   centroid plus translation). The paper fits all ten per frame
   (:func:`calibrate_lighting_per_frame`); that problem is badly conditioned (pose and centre
   trade off), so ours fits all frames at once with one r_c and one pose shared and a centre per
   frame (:func:`calibrate_lighting_joint`). The result is a world-frame :class:`RigidPose`
   correction; since every light group is mounted on the same frame, the same correction moves
   any of them (:func:`corrected_lights`): the grid's calibrates the arc's.
2. **Eye centre c_e and orbit radius r_co** from the cornea centres of the calibration frames:
   the paper's law of sines (:func:`orbit_law_of_sines`) and its baseline, the least-squares
   sphere (:func:`orbit_sphere_fit`, Ahn et al. 2001).
3. **Ours, all at once**: :func:`calibrate_joint` fits r_c, the lighting pose, c_e and r_co to
   the glints of every calibration frame, the cornea centre of frame i being
   c_e + r_co d_i with d_i the direction from c_e to the known target (or free Fick angles).
4. **Gaze mappings** from cornea centre (and the distance reading d_a) to screen point:
   :func:`fit_gaze_mapping` -> :class:`GazeMapping`.

Everything ends up in a :class:`Calibration`, written as versioned JSON.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

import numpy as np

from ..checks import Doc, parse_json
from ..cornea import ASPHERICITY_RANGE, CORNEA_MODELS, check_conic
from ..errors import InputError
from ..formats import CALIBRATION_FORMAT, CALIBRATION_VERSION, check_format
from ..geometry import RigidPose
from .flux import GlintFlux
from .lighting import CORNEA_RADIUS_INIT_M, LightingFit, corrected_lights
from .mapping import GazeMapping
from .orbit import OrbitFit

# --------------------------------------------------------------------------------------------
# Everything together

#: Physical ranges of a calibration file's fields (m): a corneal radius of 1-50 mm (humans
#: 6.7-9.4 mm, Read et al.; a value in millimetres under the ``_m`` key is refused), an orbit
#: radius under 50 mm, an eye centre within 10 m of the world origin and a lighting correction
#: of under a metre.
#: How the estimators model the lights (:attr:`Calibration.light_model`).
LIGHT_MODELS = ("points", "wire_mirror")
FILE_RANGES = {"cornea_radius_m": (1e-3, 0.05), "orbit_radius_m": (0.0, 0.05),
               "eye_center_m": 10.0, "translation_m": 1.0}


@dataclass(frozen=True, slots=True)
class Calibration:
    """Everything the gaze estimators need beyond the nominal setup.

    Attributes
    ----------
    lighting_correction : RigidPose
        World-frame correction of the whole light rig (identity = nominal).
    cornea_radius_m : float
    eye_center_m : (3,) float
        c_e; NaN when not calibrated (polynomial gaze does not need it).
    orbit_radius_m : float
        r_co; NaN when not calibrated.
    mappings : dict[str, GazeMapping]
        Named gaze mappings, e.g. ``{"eq1_9": ..., "eq1_25": ..., "quadratic_25": ...}``.
    methods : dict[str, str]
        How each part was obtained (free text, e.g. ``{"lighting": "joint"}``).
    quality : dict
        How well it fitted, JSON-ready: ``rms_px`` (glint residual), ``frames_used``,
        ``frames_total`` and ``warnings`` (the failed plausibility checks of
        :func:`estimator.calibration.checks.calibration_warnings`; empty when plausible).
    cornea_model : {"sphere", "conic"}
        The cornea the estimators model: the paper's sphere of radius r_c, or a conic of
        revolution about the optical axis (c_e through the cornea centre) with apex radius r_c
        and conic constant ``cornea_asphericity`` (:mod:`estimator.cornea.conic`). Written to
        the file only when ``"conic"`` (a spherical calibration's file is as before).
    cornea_asphericity : float
        Q in (-1, 1]; 0 for the sphere.
    glint_flux : GlintFlux or None
        Each light's power for the glints' expected flux (:mod:`estimator.calibration.flux`),
        the tracker's check for glints cut by a lash; None (old files) turns it off.
    light_model : {"points", "wire_mirror"}
        How the estimators model a ``wire_mirror`` light group's turns: fixed point lights (the
        paper's), or the LED's highlights on the turns, which move with the cornea
        (:mod:`estimator.cornea.wire`; the lighting pose then moves the mirror and its LED).
        Written to the file only when ``"wire_mirror"``.
    camera_file : dict or None
        The camera file (``scet calibrate --camera``) the glints were undistorted through:
        ``{"path": str, "sha256": str}`` (:func:`estimator.lens.camera_file_record`); None:
        the scene's own camera. ``scet track`` refuses another camera file
        (:func:`estimator.lens.check_camera_record`).
    """

    lighting_correction: RigidPose = field(default_factory=RigidPose)
    cornea_radius_m: float = CORNEA_RADIUS_INIT_M
    eye_center_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    orbit_radius_m: float = float("nan")
    mappings: dict = field(default_factory=dict)
    methods: dict = field(default_factory=dict)
    quality: dict = field(default_factory=dict)
    cornea_model: str = "sphere"
    cornea_asphericity: float = 0.0
    glint_flux: GlintFlux | None = None
    light_model: str = "points"
    camera_file: dict | None = None

    def __post_init__(self):
        if self.light_model not in LIGHT_MODELS:
            raise ValueError(f"light_model must be one of {LIGHT_MODELS}, got {self.light_model!r}")
        if self.light_model == "wire_mirror" and self.cornea_model != "sphere":
            raise ValueError("light_model 'wire_mirror' models the sphere's reflections; "
                             f"cornea_model {self.cornea_model!r} is not supported with it")
        model, q = check_conic(self.cornea_model, self.cornea_asphericity)
        object.__setattr__(self, "cornea_model", model)
        object.__setattr__(self, "cornea_asphericity", q)
        if model == "conic" and not np.isfinite(np.asarray(self.eye_center_m, dtype=float)).all():
            raise ValueError("a conic cornea needs the eye centre (its optical axis)")
        ce = np.asarray(self.eye_center_m, dtype=np.float64).reshape(3).copy()
        ce.setflags(write=False)
        object.__setattr__(self, "eye_center_m", ce)
        object.__setattr__(self, "cornea_radius_m", float(self.cornea_radius_m))
        object.__setattr__(self, "orbit_radius_m", float(self.orbit_radius_m))
        object.__setattr__(self, "mappings", dict(self.mappings))
        object.__setattr__(self, "methods", {str(k): str(v) for k, v in self.methods.items()})
        if not isinstance(self.quality, dict):
            raise ValueError(f"Calibration.quality must be a dict, got {type(self.quality).__name__}")
        object.__setattr__(self, "quality", dict(self.quality))
        if self.glint_flux is not None and not isinstance(self.glint_flux, GlintFlux):
            raise ValueError(f"Calibration.glint_flux must be a GlintFlux or None, "
                             f"got {type(self.glint_flux).__name__}")
        for name, m in self.mappings.items():
            if not isinstance(m, GazeMapping):
                raise ValueError(f"Calibration.mappings[{name!r}] must be a GazeMapping, got {type(m).__name__}")

    @classmethod
    def ground_truth(cls, setup, **kwargs) -> "Calibration":
        """The calibration a perfect procedure would give for ``setup`` (nominal lighting)."""
        return cls(RigidPose(), setup.eye.cornea_radius_m, setup.eye.rotation_center_m,
                   setup.eye.cornea_offset_m, methods={"all": "ground_truth"}, **kwargs)

    @classmethod
    def from_fits(cls, lighting: LightingFit, orbit: OrbitFit | None = None,
                  mappings: dict | None = None) -> "Calibration":
        """A calibration from the results of the fits above (``orbit`` only for geometric gaze)."""
        methods = {"lighting": lighting.method}
        if orbit is not None:
            methods["orbit"] = orbit.method
        return cls(lighting.correction, lighting.cornea_radius_m,
                   np.full(3, np.nan) if orbit is None else orbit.eye_center_m,
                   float("nan") if orbit is None else orbit.orbit_radius_m, mappings or {}, methods)

    @property
    def conic(self) -> bool:
        """Whether the estimators model the cornea as a conic (``cornea_model == "conic"``)."""
        return self.cornea_model == "conic"

    @property
    def has_orbit(self) -> bool:
        return bool(np.isfinite(self.eye_center_m).all() and np.isfinite(self.orbit_radius_m))

    def flags_cut_glints(self, n_lights: int | None = None) -> bool:
        """Whether it holds the glint flux the tracker's cut-glint flag needs: a
        :class:`GlintFlux` for ``n_lights`` lights (any count when None)."""
        return self.glint_flux is not None and (
            n_lights is None or self.glint_flux.log_power.size == n_lights)

    def lights_world_m(self, nominal_lights_m) -> np.ndarray:
        """(n, 3) calibrated positions of the nominal lights."""
        return corrected_lights(self.lighting_correction, nominal_lights_m)

    @property
    def warnings(self) -> list[str]:
        """The failed plausibility checks recorded at calibration (empty: plausible)."""
        return list(self.quality.get("warnings", []))

    def with_mappings(self, **mappings: GazeMapping) -> "Calibration":
        return replace(self, mappings={**self.mappings, **mappings})

    def with_quality(self, **quality) -> "Calibration":
        return replace(self, quality={**self.quality, **quality})

    def to_dict(self) -> dict:
        finite = self.has_orbit
        cornea = ({"cornea_model": self.cornea_model, "cornea_asphericity": self.cornea_asphericity}
                  if self.conic else {})
        return {
            "format": CALIBRATION_FORMAT, "version": CALIBRATION_VERSION,
            "lighting_correction": {"rotation": self.lighting_correction.rotation.tolist(),
                                    "translation_m": self.lighting_correction.translation_m.tolist()},
            "cornea_radius_m": self.cornea_radius_m,
            **cornea,
            "eye_center_m": self.eye_center_m.tolist() if finite else None,
            "orbit_radius_m": self.orbit_radius_m if finite else None,
            "mappings": {k: v.to_dict() for k, v in self.mappings.items()},
            "methods": dict(self.methods),
            "quality": dict(self.quality),
            **({} if self.glint_flux is None else {"glint_flux": self.glint_flux.to_dict()}),
            **({} if self.light_model == "points" else {"light_model": self.light_model}),
            **({} if self.camera_file is None else {"camera_file": dict(self.camera_file)}),
        }

    @classmethod
    def from_dict(cls, data: dict, *, path="calibration",
                  error: type[InputError] = InputError) -> "Calibration":
        """A calibration from its JSON document, every field typed and physically ranged
        (:data:`FILE_RANGES`); errors of type ``error`` name ``path`` and the dotted key."""
        check_format(data, path, CALIBRATION_FORMAT, CALIBRATION_VERSION, error)
        doc = Doc(data, path, error=error)
        lc = doc.obj("lighting_correction")
        rotation = lc.array("rotation", (3, 3), lo=-1.0 - 1e-9, hi=1.0 + 1e-9)
        translation = lc.array("translation_m", (3,), lo=-FILE_RANGES["translation_m"],
                               hi=FILE_RANGES["translation_m"])
        try:
            pose = RigidPose(rotation, translation)
        except ValueError as exc:
            raise lc.error("rotation", str(exc)) from None
        lo, hi = FILE_RANGES["cornea_radius_m"]
        radius = doc.number("cornea_radius_m", lo=lo, hi=hi)
        model = doc.string("cornea_model", choices=CORNEA_MODELS, required=False, default="sphere")
        q = doc.number("cornea_asphericity", lo=ASPHERICITY_RANGE[0], hi=ASPHERICITY_RANGE[1],
                       required=False, default=0.0)
        if q == ASPHERICITY_RANGE[0]:
            raise doc.error("cornea_asphericity", "expected a value in (-1, 1] (Q = -1 is a "
                                                  "paraboloid, no closed cornea), got -1")
        if model == "sphere" and q != 0.0:
            raise doc.error("cornea_asphericity", f"a 'sphere' cornea_model has no asphericity, "
                                                  f"got {q!r} (set cornea_model to 'conic')")
        center = doc.array("eye_center_m", (3,), lo=-FILE_RANGES["eye_center_m"],
                           hi=FILE_RANGES["eye_center_m"], required=False,
                           default=np.full(3, np.nan))
        lo, hi = FILE_RANGES["orbit_radius_m"]
        r_co = doc.number("orbit_radius_m", lo=lo, hi=hi, required=False, default=float("nan"))
        maps = doc.obj("mappings")
        mappings = {name: GazeMapping.from_dict(maps.data[name], path=path,
                                                key=maps.full(name), error=error)
                    for name in maps.keys()}
        methods = doc.obj("methods", required=False)
        for name in methods.keys() if methods else ():
            methods.string(name)
        quality = doc.obj("quality", required=False)
        if quality is not None:
            for name in ("warnings",):
                for i, w in enumerate(quality.items(name, required=False)):
                    if not isinstance(w, str):
                        raise quality.error(f"{name}[{i}]", "expected a string")
            skipped = quality.obj("mappings_skipped", required=False)
            for name in skipped.keys() if skipped else ():
                skipped.string(name)
        if model == "conic" and not np.isfinite(center).all():
            raise doc.error("eye_center_m", "a 'conic' cornea_model needs the eye centre")
        flux = doc.obj("glint_flux", required=False)
        flux = GlintFlux.from_dict(flux) if flux is not None else None
        lights = doc.string("light_model", choices=LIGHT_MODELS, required=False, default="points")
        cam = doc.obj("camera_file", required=False)
        if cam is not None:
            digest = cam.string("sha256")
            if len(digest) != 64 or any(c not in "0123456789abcdef" for c in digest):
                raise cam.error("sha256", "expected 64 lower-case hex digits (SHA-256)")
            cam = {"path": cam.string("path"), "sha256": digest}
        return cls(pose, radius, center, r_co, mappings, methods.data if methods else {},
                   quality.data if quality else {}, model, q, flux, lights, cam)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_json(cls, text: str, *, path="calibration",
                  error: type[InputError] = InputError) -> "Calibration":
        return cls.from_dict(parse_json(text, path, error), path=path, error=error)
