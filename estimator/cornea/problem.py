"""A cornea fit's inputs and outputs: :class:`FitProblem` (camera, lights, eye:
what a calibration fixes), :class:`CorneaFit` (per-sample results) and the reason codes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import Camera, rotations_from_vectors
from ..reasons import Reason

MODELS = {"center": 3, "center_radius": 4, "orbit": 2, "full": 10}
#: Reason codes of a fit, per sample (:class:`estimator.reasons.Reason`; the values, plain
#: strings, fill the fits' arrays of reasons).
OK, TOO_FEW_GLINTS, NOT_CONVERGED, NON_FINITE = (
    Reason.OK.value, Reason.TOO_FEW_GLINTS.value, Reason.NOT_CONVERGED.value,
    Reason.NON_FINITE.value)


@dataclass(frozen=True, slots=True)
class CorneaFit:
    """Per-sample results of a cornea fit (B samples).

    Attributes
    ----------
    center_m : (B, 3) float
        Cornea centre; NaN where the fit failed.
    radius_m : (B,) float
        Corneal radius (fitted by ``"full"``, given otherwise).
    angles_rad : (B, 2) float
        Fick (yaw, pitch) of the centre about the eye centre (``"orbit"`` only, else NaN).
    light_pose_rotvec : (B, 3) float
        Rotation vector of the lighting relative to its nominal pose about its centroid
        (``"full"`` only, else NaN).
    light_pose_translation_m : (B, 3) float
        Translation of the lighting relative to its nominal pose (``"full"`` only, else NaN).
    rms_px : (B,) float
        Root mean square glint residual.
    glints_used : (B,) int
    iterations : (B,) int
    reason : (B,) str
        ``"ok"``, ``"too_few_glints"``, ``"not_converged"`` or ``"non_finite"``.
    """

    center_m: np.ndarray
    radius_m: np.ndarray
    angles_rad: np.ndarray
    light_pose_rotvec: np.ndarray
    light_pose_translation_m: np.ndarray
    rms_px: np.ndarray
    glints_used: np.ndarray
    iterations: np.ndarray
    reason: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        return self.reason == OK


@dataclass(frozen=True, slots=True)
class FitProblem:
    """What a cornea fit knows: camera, lights, and the model's fixed quantities."""

    camera: Camera
    lights_world_m: np.ndarray  # (n, 3) nominal light positions
    cornea_radius_m: float
    eye_center_m: np.ndarray | None = None  # "orbit"
    orbit_radius_m: float | None = None  # "orbit"
    # Glints and Jacobian at a shared starting point, per (model, start): what every batch
    # started there reuses (the arrays above are read-only copies, so this cannot go stale).
    _start_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        lights = np.array(self.lights_world_m, dtype=np.float64)
        if lights.ndim != 2 or lights.shape[1] != 3:
            raise ValueError(f"lights_world_m must have shape (n, 3), got {lights.shape}")
        lights.setflags(write=False)
        object.__setattr__(self, "lights_world_m", lights)
        object.__setattr__(self, "cornea_radius_m", float(self.cornea_radius_m))
        if self.eye_center_m is not None:
            c = np.array(self.eye_center_m, dtype=np.float64).reshape(3)
            c.setflags(write=False)
            object.__setattr__(self, "eye_center_m", c)

    def lights_posed(self, rotvec, translation_m) -> np.ndarray:
        """(B, n, 3) lights moved rigidly about their centroid."""
        L = self.lights_world_m
        pivot = L.mean(axis=0)
        R = rotations_from_vectors(np.atleast_2d(rotvec))
        return np.einsum("bij,nj->bni", R, L - pivot) + pivot + np.atleast_2d(translation_m)[:, None]
