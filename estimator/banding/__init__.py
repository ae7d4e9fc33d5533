"""Rolling-shutter banding under stroboscopic light (Sec. 2.3 of the SCET paper).

Modules: ``equations`` (Eqs. (2)-(8)), ``layout`` (the exact fraction of every pulse each row
collects, the strobe and time stamp of every row, the bands of a frame, also as arrays), ``plan`` (strobe
and exposure settings: bands that tile the frame, calibration timing).
"""

from .equations import (
    TIME_EPS_S,
    band_drift_rows,
    band_gap_rows,
    band_height,
    band_spacing_rows,
    exposure_start,
    first_lit_row,
    partial_lines,
    readout_time,
    tiling_period,
    usable_lines,
)
from .layout import (
    NO_PULSE,
    Band,
    band_layout,
    band_rows,
    pulse_times,
    row_pulse_weights,
    row_strobe,
    strobe_instant,
)
from .plan import (
    CALIB_PULSE_SHARE,
    StrobePlan,
    calibration_setup,
    plan_strobe,
    scaled_setup,
    strobe_setup,
)

__all__ = [
    "TIME_EPS_S", "readout_time", "exposure_start", "first_lit_row", "partial_lines",
    "usable_lines", "band_height", "tiling_period", "band_spacing_rows", "band_gap_rows",
    "band_drift_rows", "NO_PULSE", "strobe_instant", "pulse_times", "row_pulse_weights",
    "row_strobe", "Band", "band_layout", "band_rows", "StrobePlan", "plan_strobe", "CALIB_PULSE_SHARE",
    "scaled_setup", "calibration_setup", "strobe_setup"
]
