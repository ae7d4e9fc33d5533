"""Capturing on the Raspberry Pi (picamera2, imported only when a camera is opened) and
replaying rendered datasets as a camera, both through one streaming loop into capture folders
(``scet-capture`` version 2; the reader is :mod:`estimator.capture`)."""

from .picam import CaptureSettings, PicameraSource, camera_controls, picamera2_version
from .replay import ReplayCamera, replay_dataset
from .stream import (CameraError, CameraStall, CaptureReport, TimingMismatch, Worker,
                     check_timing, stream_capture)

__all__ = ["CaptureSettings", "PicameraSource", "camera_controls", "picamera2_version",
           "ReplayCamera", "replay_dataset", "CameraError", "CameraStall", "CaptureReport",
           "TimingMismatch", "Worker", "check_timing", "stream_capture"]
