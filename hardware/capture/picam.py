"""The Raspberry Pi capture program: raw 10-bit Bayer VGA frames from the OV5647 at a fixed
frame duration, manual exposure and gain, AE and AWB off, every frame's metadata recorded,
buffered in memory and written after the run (a Pi 3B+ SD card cannot take 23-37 MB/s,
HARDWARE.md Sec. 2).

picamera2 imports libcamera at import time and exists only on a Pi, so it is imported inside
:func:`capture_to_folder`. The recipe follows HARDWARE.md Sec. 2 (picamera2 0.3.x): a video
configuration with a raw stream of the requested format, ``FrameDurationLimits`` with equal
ends, and the first frames after start (mistrusted by libcamera's OV5647 helper, and before the
controls take effect 2 frames later) dropped.
"""

from __future__ import annotations

import platform
import time
from dataclasses import dataclass, field

from estimator.capture import capture_header, min_stride, parse_raw_format, write_capture

__all__ = ["CaptureSettings", "camera_controls", "capture_to_folder", "METADATA_RECORDED"]

#: Metadata keys written to frames.jsonl when picamera2 reports them (the first five are required).
METADATA_RECORDED = ("SensorTimestamp", "ExposureTime", "FrameDuration", "AnalogueGain",
                     "SensorBlackLevels", "DigitalGain", "ColourGains", "Lux", "ScalerCrop",
                     "FrameWallClock")


@dataclass(frozen=True, slots=True)
class CaptureSettings:
    """What to ask the camera for (picamera2 units: us, gain factor)."""

    frames: int
    frame_duration_us: int = 16637
    exposure_us: int = 984
    analogue_gain: float = 1.0
    raw_format: str = "SGBRG10_CSI2P"
    size_px: tuple = (640, 480)
    skip_frames: int = 4
    buffer_count: int = 6
    strobe: dict | None = None
    strobe_model: dict | None = None
    extra: dict = field(default_factory=dict)

    def check(self) -> None:
        parse_raw_format(self.raw_format)
        if self.frames < 1 or self.frame_duration_us <= 0 or self.exposure_us <= 0:
            raise ValueError("frames, frame_duration_us and exposure_us must be positive")
        if self.exposure_us >= self.frame_duration_us:
            raise ValueError(f"exposure {self.exposure_us} us does not fit in a frame of "
                             f"{self.frame_duration_us} us")
        if not self.analogue_gain >= 1.0:
            raise ValueError(f"analogue gain must be >= 1.0, got {self.analogue_gain!r}")


def camera_controls(s: CaptureSettings) -> dict:
    """The libcamera controls of a run: fixed frame duration, manual exposure and gain."""
    return {"FrameDurationLimits": [int(s.frame_duration_us), int(s.frame_duration_us)],
            "ExposureTime": int(s.exposure_us), "AnalogueGain": float(s.analogue_gain),
            "AeEnable": False, "AwbEnable": False}


def capture_to_folder(out_dir, s: CaptureSettings, progress=None):
    """Capture ``s.frames`` raw frames on a Raspberry Pi into a capture folder.

    Raises
    ------
    RuntimeError
        picamera2 is not available (not a Raspberry Pi), or the camera did not give the
        requested raw stream.
    """
    s.check()
    try:
        from picamera2 import Picamera2
    except ImportError as exc:
        raise RuntimeError(f"picamera2 cannot be imported ({exc}): capturing needs a Raspberry "
                           "Pi with python3-picamera2 (sudo apt install python3-picamera2); "
                           "off the Pi, use scet capture --replay DATASET") from None
    import picamera2

    controls = camera_controls(s)
    cam = Picamera2()
    try:
        cfg = cam.create_video_configuration(
            main={"size": tuple(s.size_px), "format": "YUV420"},
            raw={"size": tuple(s.size_px), "format": s.raw_format},
            sensor={"output_size": tuple(s.size_px), "bit_depth": 10},
            buffer_count=s.buffer_count, controls=controls)
        cam.configure(cfg)
        raw_cfg = cam.camera_configuration()["raw"]
        if str(raw_cfg["format"]) != s.raw_format or tuple(raw_cfg["size"]) != tuple(s.size_px):
            raise RuntimeError(f"the camera gave raw {raw_cfg['format']} {raw_cfg['size']}, "
                               f"asked for {s.raw_format} {tuple(s.size_px)}")
        stride = int(raw_cfg["stride"])
        model = cam.camera_properties.get("Model", "unknown")
        cam.start()
        buffered = []
        for n in range(s.skip_frames + s.frames):
            req = cam.capture_request()
            try:
                if n >= s.skip_frames:
                    # A copy: the request's buffer goes back to libcamera on release.
                    rows = req.make_array("raw").copy()
                    md = req.get_metadata()
                    buffered.append((rows, {k: md[k] for k in METADATA_RECORDED if k in md}))
            finally:
                req.release()
            if progress is not None:
                progress(n + 1, s.skip_frames + s.frames)
        cam.stop()
    finally:
        cam.close()
    fmt = parse_raw_format(s.raw_format)
    header = capture_header(
        raw_format=s.raw_format, size_px=s.size_px, stride=stride,
        camera={"model": model, "sensor_mode": {"size": list(s.size_px), "bit_depth": 10,
                                               "unicam_stride": min_stride(fmt, s.size_px[0])}},
        controls=controls, strobe=s.strobe, source="picamera2",
        software={"picamera2": getattr(picamera2, "__version__", "unknown"),
                  "python": platform.python_version(), "captured_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")},
    )
    if s.strobe_model is not None:
        header["strobe_model"] = s.strobe_model
    exposures = sorted(md["ExposureTime"] for _, md in buffered if "ExposureTime" in md)
    if exposures:
        header["exposure_s"] = exposures[len(exposures) // 2] * 1e-6    # applied, not requested
    header.update(s.extra)
    return write_capture(out_dir, header, buffered)
