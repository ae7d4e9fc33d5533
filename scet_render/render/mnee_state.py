"""The eye's pose and the scene's lights as the MNEE kernels read them (:mod:`.mnee`): plain
numpy state per pose, its opaque Dr.Jit form (frozen-kernel inputs that change without
recompiling), and the table of strobe lights, iris and pupil.
"""

from __future__ import annotations

import numpy as np

from .layout import IRIS_OVERLAP, PUPIL_OFFSET_M, SCENE_UNITS_PER_M
from .textures import iris_lookup



def pose_state(setup, layout, cornea_to_scene, yaw_rad, pitch_rad, pupil_radius_m=None):
    """Plain numpy description of the eye at a pose, in scene units (cm).

    Parameters
    ----------
    setup : Setup
    layout : EyeLayout
    cornea_to_scene : (4, 4) float
        The cornea's object-to-scene matrix (unit sphere -> corneal sphere or ellipsoid).
    yaw_rad, pitch_rad, pupil_radius_m : float
        The pose, and the pupil's radius (m; None: the scene's, ``setup.eye``).

    Returns
    -------
    dict of str -> ndarray
        ``minv`` (3, 3) and ``tinv`` (3,): scene -> unit-sphere space of the cornea;
        ``center`` (3,) rotation centre, ``gaze`` (3,) unit gaze; ``limbus`` the limbus plane's
        distance along the gaze from the centre; ``sclera``, ``pupil`` the two radii; ``iris_x``,
        ``iris_y`` (3,) the iris disk's local axes.
    """
    from estimator.eye import eye_rotation_matrix

    M = np.asarray(cornea_to_scene, dtype=np.float64)
    minv = np.linalg.inv(M[:3, :3])
    face = eye_rotation_matrix(yaw_rad, pitch_rad) * np.array([1.0, -1.0, -1.0])  # R @ _GAZE_FRAME
    gaze = face[:, 2]
    return {
        "minv": minv, "tinv": -minv @ M[:3, 3],
        "center": setup.eye.rotation_center_m * SCENE_UNITS_PER_M, "gaze": gaze,
        "iris_x": face[:, 0], "iris_y": face[:, 1],
        "limbus": np.float64(layout.limbus_plane_m * SCENE_UNITS_PER_M),
        "sclera": np.float64(layout.sclera_radius_m * SCENE_UNITS_PER_M),
        "pupil": np.float64(SCENE_UNITS_PER_M * (0.5 * setup.eye.pupil_diameter_m
                                                 if pupil_radius_m is None else pupil_radius_m)),
    }


def to_drjit(state: dict, mi) -> dict:
    """:func:`pose_state` as opaque width-1 float64 Dr.Jit variables (frozen-kernel inputs)."""
    import drjit as dr

    F64, V64 = dr.float64_array_t(mi.Float), dr.float64_array_t(mi.Vector3f)

    def vec(v):
        return V64(*(dr.opaque(F64, float(c)) for c in v))

    out = {"m0": vec(state["minv"][0]), "m1": vec(state["minv"][1]),
           "m2": vec(state["minv"][2]), "t": vec(state["tinv"])}
    out.update({k: vec(state[k]) for k in ("center", "gaze", "iris_x", "iris_y")})
    return out | {k: dr.opaque(F64, float(state[k])) for k in ("limbus", "sclera", "pupil")}


def light_table(setup, options, layout, mi, iris=None) -> dict:
    """The scene's constants for :func:`mnee_radiance`: the strobe lights as float64 Dr.Jit
    arrays (``center`` (K) points, ``radius`` (K), in cm, ``count`` K), the iris and pupil disks
    (``iris_cm``, ``pupil_offset_cm`` in front of the iris, albedos; ``iris``: (mean albedo,
    texture or None); the pupil's radius: :func:`pose_state`)."""
    import drjit as dr

    F64, V64 = dr.float64_array_t(mi.Float), dr.float64_array_t(mi.Vector3f)
    p = np.asarray(setup.lights_world_m, dtype=np.float64) * SCENE_UNITS_PER_M
    r = np.array([g.source_radius_m for g in setup.lights.groups for _ in range(g.count)],
                 dtype=np.float64) * SCENE_UNITS_PER_M
    return {"center": V64(F64(p[:, 0]), F64(p[:, 1]), F64(p[:, 2])), "radius": F64(r),
            "count": int(p.shape[0]),
            "iris_cm": float(layout.limbus_radius_m * IRIS_OVERLAP * SCENE_UNITS_PER_M),
            "pupil_offset_cm": float(PUPIL_OFFSET_M * SCENE_UNITS_PER_M),
            "iris_albedo": float(iris[0]) if iris else float(options.iris_albedo),
            **iris_lookup(mi, iris[1] if iris else None),
            "pupil_albedo": float(options.pupil_albedo)}


__all__ = ["light_table", "pose_state", "to_drjit"]
