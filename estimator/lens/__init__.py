"""The camera's lens: the calibration board, camera calibration from board views, the camera
file (``camera.json``) it writes, and the ideal (pinhole) image undistorted points lie in.

Modules: ``board`` (:class:`BoardSpec`, ``board.json``), ``calibrate``
(:func:`calibrate_from_folder`: OpenCV's ChArUco detector and ``cv2.calibrateCamera``),
``camera_file`` (:class:`CameraFile`, ``camera.json``; :func:`ideal_setup`,
:func:`camera_from_file`). The undistortion of detections itself is
:meth:`estimator.glints.GlintDetections.undistorted` (:meth:`estimator.geometry.Camera.undistort_px`).
"""

from .board import (BOARD_FORMAT, BOARD_VERSION, DEFAULT_BOARD, DICTIONARIES, BoardError,
                    BoardSpec, board_for_setup, read_board, working_distance_m, write_board)
from .calibrate import CalibrationError, calibrate_from_folder, calibrate_views, detect_board
from .camera_file import (CAMERA_FORMAT, CAMERA_VERSION, CameraFile, CameraFileError,
                          camera_file_record, camera_from_file,
                          check_camera_record, distortion_difference_px, distortion_effect_px,
                          ideal_setup, pinhole_of, read_camera_file, write_camera_file)

__all__ = ["BOARD_FORMAT", "BOARD_VERSION", "DEFAULT_BOARD", "DICTIONARIES", "BoardError",
           "BoardSpec", "board_for_setup", "read_board", "working_distance_m", "write_board",
           "CalibrationError", "calibrate_from_folder", "calibrate_views", "detect_board",
           "CAMERA_FORMAT", "CAMERA_VERSION", "CameraFile", "CameraFileError",
           "camera_file_record", "camera_from_file", "check_camera_record",
           "distortion_difference_px", "distortion_effect_px", "ideal_setup", "pinhole_of",
           "read_camera_file", "write_camera_file"]
