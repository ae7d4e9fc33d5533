"""Prototype captures: raw Bayer frames from the Raspberry Pi camera (picamera2's formats) and
the ``scet-capture`` folders that hold them. numpy only (no picamera2 here: the capture
program lives in ``hardware/capture``); the tracker reads captures through
:mod:`estimator.folders`."""

from .folder import (CAPTURE_FORMAT, CAPTURE_NAME, CAPTURE_VERSION, CAPTURE_VERSIONS,
                     FRAMES_LIST_NAME, METADATA_KEYS, CaptureError, CaptureFolder, CaptureFrame,
                     capture_header, is_capture_folder, unicam_stride, write_capture)
from .follow import CaptureFollower, follow_capture
from .raw import (BAYER_ORDERS, CHANNELS, RawFormat, cfa_channel_map, decode_raw, encode_raw,
                  min_stride, mosaic_from_grey, pack_csi2p10, parse_raw_format, row_bytes,
                  to_tracker_frame, unpack_csi2p10)
from .writer import CaptureWriter

__all__ = ["CAPTURE_FORMAT", "CAPTURE_NAME", "CAPTURE_VERSION", "CAPTURE_VERSIONS",
           "CaptureFollower", "follow_capture", "CaptureWriter", "FRAMES_LIST_NAME",
           "METADATA_KEYS", "CaptureError", "CaptureFolder", "CaptureFrame", "capture_header",
           "is_capture_folder", "unicam_stride", "write_capture", "BAYER_ORDERS", "CHANNELS",
           "RawFormat", "cfa_channel_map", "decode_raw", "encode_raw", "min_stride",
           "mosaic_from_grey", "pack_csi2p10", "parse_raw_format", "row_bytes",
           "to_tracker_frame", "unpack_csi2p10"]
