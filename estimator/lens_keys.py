"""The lens keys of a scene's ``[camera]`` table (see :class:`~estimator.geometry.Camera`).

``distortion = [k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tauX, tauY]]]]]`` is OpenCV's
distortion model in OpenCV's order; ``f_number``, ``focus_distance_<length unit>`` and
``pixel_pitch_um`` make a thin lens (defocus). Without any of them the camera is the pinhole it
always was. ``t`` is the scene loader's table reader (:mod:`estimator.scene`); every problem
raises its :class:`~estimator.errors.SceneError` naming the key.
"""

from __future__ import annotations

import numpy as np

#: Thin-lens ranges: f-numbers of real lenses (F0.95 ... F64, with margin) and pixel pitches of
#: real sensors (binned modes included); focus from 5 mm (macro at an eye tracker's reach) to 1 km.
_F_NUMBER_RANGE = (0.5, 64.0)
_FOCUS_RANGE_M = (5e-3, 1e3)
_PIXEL_PITCH_RANGE_UM = (0.1, 100.0)


def read_lens(t, focal_px: float):
    """The ``[camera]`` lens keys: (distortion, f_number, focus_distance_m, pixel_pitch_m) or None.

    ``distortion = [k1, k2, p1, p2, ...]`` in OpenCV's order (4, 5, 8, 12 or 14 values);
    ``f_number`` with ``focus_distance_<unit>`` and ``pixel_pitch_um`` make a thin lens.
    """
    keys = ("distortion", "f_number", "pixel_pitch_um")
    if not any(t.has(k) for k in keys) and not any(k.startswith("focus_distance") for k in t.data):
        return None
    dist = ()
    if t.has("distortion"):
        raw = t.raw("distortion")
        if not isinstance(raw, (list, tuple)) or len(raw) not in (4, 5, 8, 12, 14):
            raise t.error("distortion", "expected OpenCV's 4, 5, 8, 12 or 14 coefficients (k1, k2, p1, "
                                        "p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tauX, tauY]]]]), got "
                                        f"{raw!r}")
        dist = t.vector("distortion", len(raw))
        if np.abs(dist).max() > 1e3:
            raise t.error("distortion", f"expected coefficients of magnitude below 1000, got "
                                        f"{dist.tolist()}")
    n = (t.number("f_number", lo=_F_NUMBER_RANGE[0], hi=_F_NUMBER_RANGE[1])
         if t.has("f_number") else None)
    focus = t.quantity("focus_distance", "length", required=False, lo=_FOCUS_RANGE_M[0],
                       hi=_FOCUS_RANGE_M[1])
    pitch = (t.number("pixel_pitch_um", lo=_PIXEL_PITCH_RANGE_UM[0], hi=_PIXEL_PITCH_RANGE_UM[1])
             if t.has("pixel_pitch_um") else None)
    if (n is None) != (focus is None):
        missing = "focus_distance_mm" if focus is None else "f_number"
        raise t.error(missing, "a thin lens needs both f_number and focus_distance_mm (or neither: a "
                               "pinhole)")
    if n is not None and pitch is None:
        raise t.error("pixel_pitch_um", "a thin lens (f_number) needs the pixel pitch to size its "
                                        "aperture (the OV5647's VGA mode: 5.6 um, 1.4 um binned 4x)")
    pitch_m = None if pitch is None else pitch * 1e-6
    if n is not None and focus <= focal_px * pitch_m:
        raise t.error("focus_distance_mm", f"the focus distance ({focus * 1e3:g} mm) must lie beyond "
                                           f"the lens-to-sensor distance focal_px * pixel_pitch_um "
                                           f"({focal_px * pitch_m * 1e3:g} mm)")
    return dist, n, focus, pitch_m
