"""Physically based renders with Mitsuba 3: the variant (``backend``), the eye scene
(``scene``, ``meshes``, ``export``), lids that follow the eye and their occlusion of glints
(``lids``, ``occlusion``), the rolling-shutter strobe renderer (``rolling_shutter``), the
camera's lens (``lens``: distortion and thin-lens rays), calibration-board frames (``board``),
which part of the eye each pixel sees (``regions``)
and the OV5647 sensor model (``sensor``). Mitsuba is imported lazily.
"""

from .backend import (
    DEFAULT_LLVM_GLOBS,
    LLVM_ENV,
    LLVM_MIN_VERSION,
    SUPPORTED_VARIANTS,
    VARIANT_ENV,
    BackendUnavailableError,
    VariantChoice,
    activate,
    choose_variant,
    find_libllvm,
    gpu_available,
    is_jit_variant,
    llvm_version,
)
from .board import CharucoSpec, board_poses, render_board, render_board_frames
from .export import export_mitsuba
from .layout import (
    CHANNEL_MODES,
    CORNEA_GEOMETRIES,
    CORNEA_MODES,
    DEFAULT_AMBIENT_RADIANCE,
    DEFAULT_LIGHT_RADIANCE,
    FACE_BEHIND_CENTER_M,
    FILM_TO_OPENCV_PX,
    LID_CLEARANCE_M,
    LID_MARGIN_RAD,
    MOVING_KEYS,
    PUPIL_OFFSET_M,
    SCENE_UNITS_PER_M,
    SCLERA_MASK_TEXELS,
    SKIN_OVER_LID_M,
    EyeLayout,
    SceneOptions,
    eye_layout,
)
from .lens import NEWTON_STEPS, LensRays, band_rays
from .lids import (
    CLOSED_OVERLAP_RAD,
    LASH_ALBEDO,
    LID_MOVING_KEYS,
    UPPER_LID_GAP_M,
    lash_mesh,
    lid_rotations_rad,
    lid_transforms,
    lid_transforms_m,
    moving_lid_meshes,
)
from .meshes import cornea_mesh, cornea_opacity, eye_part_transforms, eyelid_meshes, sclera_opacity, skin_mesh
from .occlusion import OCCLUDER_NAMES, SPOT_SAMPLES, GlintOcclusion, LidOccluder, occluder_names
from .regions import REGIONS, region_labels
from .rolling_shutter import (
    SPEED_SAMPLES_PER_PERIOD,
    BandedRenderer,
    FramePlan,
    FrameRender,
    motion_instants,
    plan_frame,
)
from .scene import EyeScene, SceneDescription, describe_scene, mitsuba_mesh, sensor_dict
from .sensor import (
    CORNEA_FRESNEL_REFLECTANCE,
    DEFAULT_ELECTRONS_PER_RADIANCE,
    GLINT_SATURATION_FRACTION,
    OV5647_ADC_BIT_DEPTH,
    OV5647_BLACK_LEVEL_DN,
    OV5647_CONVERSION_GAIN_E_PER_DN,
    OV5647_DARK_CURRENT_E_PER_S,
    OV5647_FULL_WELL_E,
    OV5647_READ_NOISE_E,
    OV5647_SATURATION_E,
    REFERENCE_EMITTER_RADIANCE,
    SensorModel,
)

__all__ = [
    "REGIONS", "region_labels",
    "LLVM_MIN_VERSION", "SUPPORTED_VARIANTS", "VARIANT_ENV", "LLVM_ENV", "DEFAULT_LLVM_GLOBS",
    "VariantChoice", "BackendUnavailableError", "llvm_version", "find_libllvm", "gpu_available", "choose_variant",
    "activate", "is_jit_variant", "export_mitsuba", "DEFAULT_LIGHT_RADIANCE",
    "DEFAULT_AMBIENT_RADIANCE", "LID_CLEARANCE_M", "SKIN_OVER_LID_M", "LID_MARGIN_RAD",
    "PUPIL_OFFSET_M", "FACE_BEHIND_CENTER_M", "SCENE_UNITS_PER_M", "FILM_TO_OPENCV_PX",
    "SCLERA_MASK_TEXELS", "CORNEA_MODES", "CORNEA_GEOMETRIES", "CHANNEL_MODES", "MOVING_KEYS",
    "SceneOptions", "EyeLayout", "eye_layout", "cornea_mesh", "eyelid_meshes", "skin_mesh",
    "sclera_opacity", "cornea_opacity", "eye_part_transforms", "SPEED_SAMPLES_PER_PERIOD", "FrameRender",
    "FramePlan", "motion_instants", "plan_frame", "BandedRenderer", "sensor_dict",
    "SceneDescription", "describe_scene", "EyeScene", "CORNEA_FRESNEL_REFLECTANCE",
    "REFERENCE_EMITTER_RADIANCE", "GLINT_SATURATION_FRACTION", "OV5647_FULL_WELL_E",
    "OV5647_READ_NOISE_E", "OV5647_DARK_CURRENT_E_PER_S", "OV5647_CONVERSION_GAIN_E_PER_DN",
    "OV5647_BLACK_LEVEL_DN", "OV5647_ADC_BIT_DEPTH", "OV5647_SATURATION_E",
    "DEFAULT_ELECTRONS_PER_RADIANCE", "SensorModel", "UPPER_LID_GAP_M", "CLOSED_OVERLAP_RAD",
    "LASH_ALBEDO", "LID_MOVING_KEYS", "moving_lid_meshes", "lash_mesh", "lid_rotations_rad",
    "lid_transforms", "lid_transforms_m", "OCCLUDER_NAMES", "SPOT_SAMPLES", "GlintOcclusion",
    "LidOccluder", "occluder_names", "mitsuba_mesh", "LensRays", "band_rays", "NEWTON_STEPS",
    "CharucoSpec", "board_poses", "render_board", "render_board_frames",
]
