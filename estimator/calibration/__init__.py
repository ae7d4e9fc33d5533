"""Calibration (Sec. 2.4-2.5): lighting pose and corneal radius, eye centre and orbit
radius, the gaze mappings, and the calibration file.

Modules: ``lighting``, ``conic`` (the joint fit with the conic constant Q, and identification
on the calibrated conic), ``orbit``, ``mapping`` (Eq. (1) and the second-order polynomials),
``result`` (:class:`Calibration`, versioned JSON), ``checks`` (is a calibration plausible),
``wire`` (the joint fit on a wire mirror's moving virtual sources).
"""

from .checks import (
    AT_BOUND_RTOL,
    MAX_RMS_PX,
    MIN_FRAMES_SHARE,
    POSE_SHARE,
    RADIUS_SD_RANGE,
    calibration_warnings,
)
from .conic import (CROWDED_RMS, IDENTIFY_ROUNDS, Q_BOUNDS, calibrate_joint_conic,
                    identify_on_conic, prediction_sd_px, reidentify_on_conic)
from .lighting import (
    CORNEA_RADIUS_BOUNDS_M,
    CORNEA_RADIUS_INIT_M,
    CORNEA_RADIUS_SD_M,
    POSE_BOUND_M,
    POSE_BOUND_RAD,
    LightingFit,
    calibrate_joint,
    calibrate_lighting_joint,
    calibrate_lighting_per_frame,
    corrected_lights,
    pose_correction,
)
from .flux import FRESNEL_MODELS, GlintFlux, fit_glint_flux, model_flux
from .mapping import MAPPING_TERMS, RANK_RTOL, GazeMapping, distance_reading, fit_gaze_mapping
from .orbit import ORBIT_RADIUS_BOUNDS_M, OrbitFit, orbit_law_of_sines, orbit_sphere_fit
from .result import LIGHT_MODELS, Calibration
from .wire import calibrate_joint_wire, calibrate_wire

__all__ = [
    "RADIUS_SD_RANGE", "POSE_SHARE", "MAX_RMS_PX", "MIN_FRAMES_SHARE", "AT_BOUND_RTOL",
    "calibration_warnings", "CORNEA_RADIUS_INIT_M", "CORNEA_RADIUS_SD_M",
    "CORNEA_RADIUS_BOUNDS_M", "POSE_BOUND_M", "POSE_BOUND_RAD", "pose_correction",
    "corrected_lights", "LightingFit", "calibrate_lighting_per_frame",
    "calibrate_lighting_joint", "calibrate_joint", "MAPPING_TERMS", "RANK_RTOL", "GazeMapping",
    "fit_gaze_mapping", "distance_reading", "ORBIT_RADIUS_BOUNDS_M", "OrbitFit",
    "orbit_law_of_sines", "orbit_sphere_fit", "Calibration", "Q_BOUNDS", "calibrate_joint_conic",
    "IDENTIFY_ROUNDS", "CROWDED_RMS", "identify_on_conic", "prediction_sd_px",
    "reidentify_on_conic", "FRESNEL_MODELS", "GlintFlux", "fit_glint_flux",
    "model_flux", "LIGHT_MODELS", "calibrate_joint_wire", "calibrate_wire",
]
