"""``scet compare``: prototype captures against renders of the same frames (issue 13)."""

from .measure import FrameMeasure, GeometryFit, fit_geometry, match_identified, measure_image
from .render import PoseTrajectory, measured_setup, poses_from_samples, render_radiance
from .run import CompareError, CompareResult, compare_capture, nominal_calibration
from .sensor_fit import SensorFit, fit_sensor
from .verdict import CAUSES, TOL, VerdictRow

__all__ = ["FrameMeasure", "GeometryFit", "fit_geometry", "match_identified", "measure_image",
           "PoseTrajectory", "measured_setup", "poses_from_samples", "render_radiance",
           "CompareError", "CompareResult", "compare_capture", "nominal_calibration",
           "SensorFit", "fit_sensor", "CAUSES", "TOL", "VerdictRow"]
