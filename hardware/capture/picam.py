"""The Raspberry Pi camera as the capture loop's source: raw 10-bit Bayer VGA frames from the
OV5647 at a fixed frame duration, manual exposure and gain, AE and AWB off, every frame's
metadata recorded; the loop (:mod:`.stream`) writes them as they arrive.

picamera2 imports libcamera at import time and exists only on a Pi, so it is imported inside
:meth:`PicameraSource.open`. The recipe follows HARDWARE.md Sec. 2: a video configuration with
a raw stream of the requested format, ``FrameDurationLimits`` with equal ends, and the first
frames after start dropped (mistrusted by libcamera's OV5647 helper, and before the controls
take effect 2 frames later).

Versions: ``sensor=`` of ``create_video_configuration`` (which fixes the 640x480 10-bit
sensor mode) appeared in picamera2 0.3.13 (2023-08); Raspberry Pi OS Bookworm ships
python3-picamera2 0.3.1x and later (and libcamera with the 58.333 MHz VGA pixel rate of the
ov5647_mode6 profile); Bullseye's 0.3.12 and older are refused with that reason. The version
recorded is the installed distribution's (``importlib.metadata``; Debian's
python3-picamera2 installs its metadata).

Every camera call has a timeout: ``capture_request`` is dispatched as a job
(``wait=False``) whose result is awaited for ``timeout_s``; start, stop and close run on a
helper thread awaited the same way, so a stalled camera ends the run with a message instead
of hanging it.
"""

from __future__ import annotations

import platform
import threading
import time
from dataclasses import dataclass, field

from estimator.capture import min_stride, parse_raw_format

from .stream import CameraError, CameraStall

__all__ = ["CaptureSettings", "camera_controls", "PicameraSource", "METADATA_RECORDED",
           "MIN_PICAMERA2", "picamera2_version"]

#: Oldest picamera2 with ``sensor=`` in its configurations.
MIN_PICAMERA2 = (0, 3, 13)

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


def picamera2_version() -> str:
    """The installed picamera2 distribution's version, or "unknown" (a source checkout)."""
    try:
        from importlib.metadata import PackageNotFoundError, version
    except ImportError:    # pragma: no cover - Python >= 3.8 has it
        return "unknown"
    try:
        return version("picamera2")
    except PackageNotFoundError:
        return "unknown"


def _version_tuple(text: str) -> tuple:
    parts = []
    for p in text.split(".")[:3]:
        digits = "".join(ch for ch in p if ch.isdigit())
        parts.append(int(digits) if digits else 0)
    return tuple(parts)


def _with_timeout(fn, timeout_s: float, what: str):
    """``fn()`` on a helper thread, awaited ``timeout_s``: a libcamera call that hangs
    leaves the thread behind (daemon) and raises :class:`CameraStall`."""
    out: dict = {}

    def run():
        try:
            out["value"] = fn()
        except BaseException as exc:
            out["error"] = exc

    t = threading.Thread(target=run, name=f"camera-{what}", daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        raise CameraStall(f"camera: {what} did not return within {timeout_s:g} s")
    if "error" in out:
        raise out["error"]
    return out.get("value")


class PicameraSource:
    """The OV5647 through picamera2 (module docstring); :meth:`open` checks the camera.

    Raises (from :meth:`open`)
    ------
    CameraError
        picamera2 missing or too old, no camera, a camera that is not an OV5647, a raw stream
        of another Bayer order, format or size than asked.
    """

    def __init__(self, s: CaptureSettings, *, timeout_s: float = 2.0):
        s.check()
        self.settings = s
        self.timeout_s = float(timeout_s)
        self.name = "camera"
        self._cam = None
        self.stride = None
        self.model = None
        self.version = None

    def open(self) -> "PicameraSource":
        s = self.settings
        try:
            from picamera2 import Picamera2
        except ImportError as exc:
            raise CameraError(f"picamera2 cannot be imported ({exc}): capturing needs a Raspberry "
                              "Pi with python3-picamera2 (sudo apt install python3-picamera2, "
                              "Raspberry Pi OS Bookworm); off the Pi, use --replay DATASET") from None
        self.version = picamera2_version()
        if self.version != "unknown" and _version_tuple(self.version) < MIN_PICAMERA2:
            raise CameraError(f"picamera2 {self.version} is too old: the capture needs "
                              f"{'.'.join(map(str, MIN_PICAMERA2))} or later (sensor= in "
                              "create_video_configuration; Raspberry Pi OS Bookworm)")
        try:
            cams = Picamera2.global_camera_info()
        except Exception as exc:   # libcamera's own errors: no common base class
            raise CameraError(f"camera: libcamera cannot list the cameras ({exc})") from None
        if not cams:
            raise CameraError("camera: libcamera finds no camera (ribbon seated? camera enabled?)")
        model = str(cams[0].get("Model", "unknown"))
        if model.lower() != "ov5647":
            raise CameraError(f"camera: the first camera is {model!r}, not the OV5647 this "
                              "capture is planned for")
        self.model = model
        try:
            self._cam = _with_timeout(Picamera2, self.timeout_s, "open")
            cam = self._cam
            cfg = cam.create_video_configuration(
                main={"size": tuple(s.size_px), "format": "YUV420"},
                raw={"size": tuple(s.size_px), "format": s.raw_format},
                sensor={"output_size": tuple(s.size_px), "bit_depth": 10},
                buffer_count=s.buffer_count, controls=camera_controls(s))
            _with_timeout(lambda: cam.configure(cfg), self.timeout_s, "configure")
            raw_cfg = cam.camera_configuration()["raw"]
        except CameraError:
            self.close()
            raise
        except Exception as exc:
            self.close()
            raise CameraError(f"camera {model}: cannot configure the raw stream ({exc})") from None
        got = str(raw_cfg["format"])
        want = parse_raw_format(s.raw_format)
        try:
            got_fmt = parse_raw_format(got)
        except ValueError:
            got_fmt = None
        if got_fmt is None or got_fmt.bayer_order != want.bayer_order:
            self.close()
            raise CameraError(f"camera {model}: raw stream {got}, not the Bayer order "
                              f"{want.bayer_order} of {s.raw_format} (flipped sensor?)")
        if got != s.raw_format or tuple(raw_cfg["size"]) != tuple(s.size_px):
            self.close()
            raise CameraError(f"camera {model}: raw {got} {tuple(raw_cfg['size'])}, asked for "
                              f"{s.raw_format} {tuple(s.size_px)}")
        self.stride = int(raw_cfg["stride"])
        self.name = f"camera {model}"
        return self

    def header(self, *, strobe=None, strobe_model=None, extra=None) -> dict:
        from estimator.capture import capture_header

        s = self.settings
        fmt = parse_raw_format(s.raw_format)
        header = capture_header(
            raw_format=s.raw_format, size_px=s.size_px, stride=self.stride,
            camera={"model": self.model, "sensor_mode": {"size": list(s.size_px), "bit_depth": 10,
                                                         "unicam_stride": min_stride(fmt, s.size_px[0])}},
            controls=camera_controls(s), strobe=strobe, source="picamera2",
            software={"picamera2": self.version, "python": platform.python_version(),
                      "captured_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
        if strobe_model is not None:
            header["strobe_model"] = strobe_model
        header["exposure_s"] = s.exposure_us * 1e-6
        header.update(extra or {})
        return header

    def start(self) -> None:
        _with_timeout(self._cam.start, self.timeout_s, "start")

    def next_frame(self, timeout_s: float):
        cam = self._cam
        job = cam.capture_request(wait=False)
        try:
            req = job.get_result(timeout=timeout_s)
        except TimeoutError:
            raise CameraStall(f"{self.name}: no frame within {timeout_s:g} s (the camera "
                              "stalled)") from None
        try:
            # A copy: the request's buffer goes back to libcamera on release.
            rows = req.make_array("raw").copy()
            md = req.get_metadata()
        finally:
            req.release()
        return rows, {k: md[k] for k in METADATA_RECORDED if k in md}

    def stop(self) -> None:
        if self._cam is not None:
            try:
                _with_timeout(self._cam.stop, self.timeout_s, "stop")
            except CameraStall as exc:
                import logging

                logging.getLogger(__name__).error("%s", exc)

    def close(self) -> None:
        if self._cam is not None:
            cam, self._cam = self._cam, None
            try:
                _with_timeout(cam.close, self.timeout_s, "close")
            except Exception as exc:   # closing is best effort; the frames are written
                import logging

                logging.getLogger(__name__).error("camera: close failed (%s)", exc)
