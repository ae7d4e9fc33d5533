"""Geometry: rigid poses and rotations, the pinhole camera, the closed-form glint
projection of a spherical cornea (:func:`project_glints`), its root finders and Jacobians,
and the packed rows the cornea fits sum.

Modules: ``rigid`` (poses, rotations, point checks), ``camera`` (:class:`Camera`),
``reflection`` (:func:`project_glints`, in ideal (undistorted) pixels, :func:`reflection_points`, :func:`reflect_pixel_rays`),
``conic`` (:func:`project_glints_conic`: exact reflections on an aspheric, conic cornea),
``roots`` (the reflection equation's solvers), ``jacobians`` (:func:`glint_jacobians`),
``fit_rows`` (the centre and orbit fits' packed rows), ``compiled`` (:func:`glints_one_pose`,
:func:`glints_and_rows_one_pose`: the projection of one pose, and its d glint / d centre,
compiled with Numba where it is).
"""

from .camera import Camera, full_coefficients, lens_jacobian, lens_map, tilt_matrix
from .conic import conic_reflection_points, conic_sag, project_glints_conic
from .compiled import camera_arrays, glints_and_rows_one_pose, glints_one_pose
from .jacobians import glint_jacobians, jacobian_terms, radius_rows
from .reflection import project_glints, reflect_pixel_rays, reflection_points
from .rigid import (
    RigidPose,
    as_points,
    look_at_rotation,
    normalize,
    rotation_from_vector,
    rotation_matrix,
    rotation_to_vector,
    rotations_from_vectors,
)

__all__ = [
    "Camera", "glint_jacobians", "radius_rows", "jacobian_terms", "reflection_points",
    "project_glints", "reflect_pixel_rays", "as_points", "normalize", "rotation_matrix",
    "rotation_from_vector", "rotation_to_vector", "look_at_rotation", "RigidPose",
    "rotations_from_vectors", "glints_one_pose", "glints_and_rows_one_pose", "camera_arrays",
    "project_glints_conic", "conic_reflection_points", "conic_sag", "lens_map", "lens_jacobian",
    "tilt_matrix", "full_coefficients",
]
