"""Is a calibration plausible? Checks of a fitted calibration against what eyes and the
apparatus can be, so that a calibration made from the wrong frames says so instead of being
used silently.

Each check compares one fitted quantity with a population or a tolerance and, when it fails,
gives one sentence naming the quantity, its value, the range and what to check. The checks and
their thresholds:

- corneal radius r_c: outside the central 95 % of Read et al. (2006), 7.77 +/- 2 x 0.2 mm
  (:data:`~estimator.calibration.lighting.CORNEA_RADIUS_INIT_M`), or at the solver's bound
  (+/- 5 SD: the fit was stopped there, so the glints did not fit any normal cornea);
- lighting pose: corrected by more than half the bounds the calibration allows (2.5 mm,
  2.5 deg, :data:`~estimator.calibration.lighting.POSE_BOUND_M`), or by the bound itself;
- RMS glint residual above :data:`MAX_RMS_PX` (a well-identified calibration frame fits to the
  detector's noise, 0.05-0.6 px in the validations);
- orbit radius r_co at its bound;
- fewer than :data:`MIN_FRAMES_SHARE` of the calibration frames usable.
"""

from __future__ import annotations

import math

import numpy as np

from .lighting import (
    CORNEA_RADIUS_BOUNDS_M,
    CORNEA_RADIUS_INIT_M,
    CORNEA_RADIUS_SD_M,
    POSE_BOUND_M,
    POSE_BOUND_RAD,
    LightingFit,
)
from .orbit import ORBIT_RADIUS_BOUNDS_M, OrbitFit

#: Population range of r_c: Read et al.'s mean +/- this many SD (95 % of normal corneas).
RADIUS_SD_RANGE = 2.0
#: A pose correction beyond this share of its bound is "far from the nominal pose".
POSE_SHARE = 0.5
#: RMS glint residual (px) above which the calibration frames did not fit the model.
MAX_RMS_PX = 1.0
#: Share of the calibration frames that must be usable.
MIN_FRAMES_SHARE = 0.8
#: Relative distance to a bound that counts as "at the bound".
AT_BOUND_RTOL = 1e-3


def _at(value: float, bound: float) -> bool:
    return abs(value - bound) <= AT_BOUND_RTOL * max(abs(bound), 1e-12)


def calibration_warnings(lighting: LightingFit, orbit: OrbitFit | None = None, *,
                         frames_used: int | None = None, frames_total: int | None = None
                         ) -> list[str]:
    """The failed checks of a calibration's fits (module docstring), one sentence each; an
    empty list for a plausible calibration."""
    out = []
    r_c = float(lighting.cornea_radius_m)
    lo = CORNEA_RADIUS_INIT_M - RADIUS_SD_RANGE * CORNEA_RADIUS_SD_M
    hi = CORNEA_RADIUS_INIT_M + RADIUS_SD_RANGE * CORNEA_RADIUS_SD_M
    if not math.isfinite(r_c):
        out.append("r_c is not finite: the lighting fit failed")
    elif _at(r_c, CORNEA_RADIUS_BOUNDS_M[0]) or _at(r_c, CORNEA_RADIUS_BOUNDS_M[1]):
        out.append(f"r_c = {r_c * 1e3:.3f} mm stopped at the solver's bound "
                   f"({CORNEA_RADIUS_BOUNDS_M[0] * 1e3:.2f}-{CORNEA_RADIUS_BOUNDS_M[1] * 1e3:.2f} mm):"
                   " the glints fit no normal cornea; check the frames and the scene")
    elif not lo <= r_c <= hi:
        out.append(f"r_c = {r_c * 1e3:.3f} mm lies outside the central 95 % of corneas "
                   f"({lo * 1e3:.2f}-{hi * 1e3:.2f} mm, Read et al. 2006): check the calibration "
                   "frames (single-pulse, eye fixating the labelled targets)")
    shift = float(np.linalg.norm(lighting.translation_m))
    turn = float(np.linalg.norm(lighting.rotvec_rad))
    if shift >= POSE_SHARE * POSE_BOUND_M or turn >= POSE_SHARE * POSE_BOUND_RAD:
        where = ("at the bound" if shift >= POSE_BOUND_M * (1 - AT_BOUND_RTOL)
                 or turn >= POSE_BOUND_RAD * (1 - AT_BOUND_RTOL) else "far from the nominal pose")
        out.append(f"the lighting moved {shift * 1e3:.2f} mm and turned {math.degrees(turn):.2f} deg "
                   f"from the scene's pose ({where}; allowed {POSE_BOUND_M * 1e3:.0f} mm, "
                   f"{math.degrees(POSE_BOUND_RAD):.0f} deg): check the lights in the scene file")
    if not lighting.rms_px <= MAX_RMS_PX:
        out.append(f"the glints fit with {lighting.rms_px:.2f} px RMS (> {MAX_RMS_PX:g} px): "
                   "frames with glints of several instants (banded frames), wrong identities or "
                   "a wrong scene")
    if not lighting.converged:
        out.append("the lighting fit stopped at its evaluation limit")
    if orbit is not None:
        r_co = float(orbit.orbit_radius_m)
        if not math.isfinite(r_co) or any(_at(r_co, b) for b in ORBIT_RADIUS_BOUNDS_M):
            out.append(f"r_co = {r_co * 1e3:.3f} mm stopped at its bound "
                       f"({ORBIT_RADIUS_BOUNDS_M[0] * 1e3:.0f}-{ORBIT_RADIUS_BOUNDS_M[1] * 1e3:.0f}"
                       " mm): the eye centre is not determined by these frames")
    if frames_used is not None and frames_total:
        if frames_used < MIN_FRAMES_SHARE * frames_total:
            out.append(f"only {frames_used} of {frames_total} calibration frames were usable "
                       "(the others are logged): check exposure and focus")
    return out
