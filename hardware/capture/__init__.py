"""Capturing on the Raspberry Pi (picamera2, imported only when a camera is opened) and
replaying rendered datasets into the same capture folders (``scet-capture``, version 1; the
reader is :mod:`estimator.capture`)."""

from .picam import CaptureSettings, capture_to_folder, camera_controls
from .replay import replay_dataset

__all__ = ["CaptureSettings", "capture_to_folder", "camera_controls", "replay_dataset"]
