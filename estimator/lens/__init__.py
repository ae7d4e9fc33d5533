"""The camera's lens: the calibration board, camera calibration from board views, the camera
file (``camera.json``) it writes, and undistortion of detected points.

Modules: ``board`` (:class:`BoardSpec`, ``board.json``), ``calibrate``
(:func:`calibrate_from_images`: OpenCV's ChArUco detector and ``cv2.calibrateCamera``),
``camera_file`` (:class:`CameraFile`, ``camera.json``).
"""

from .board import (BOARD_FORMAT, BOARD_VERSION, DEFAULT_BOARD, DICTIONARIES, BoardError,
                    BoardSpec, read_board, write_board)

__all__ = ["BOARD_FORMAT", "BOARD_VERSION", "DEFAULT_BOARD", "DICTIONARIES", "BoardError",
           "BoardSpec", "read_board", "write_board"]
