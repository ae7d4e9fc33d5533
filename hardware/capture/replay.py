"""A rendered dataset replayed as the Pi would have captured it: each 10-bit frame as the
sensor reads it out (the Bayer mosaic of the per-channel responses, packed or unpacked rows of
the Unicam stride), picamera2's metadata with ``SensorTimestamp`` from the dataset's frame
times, and the labels copied, so the whole capture path runs without a Pi.

The dataset is read directly (``manifest.json``, optional ``timing.json``, ``frames/*.png``,
``labels.jsonl``; scet_render/dataset.py's format), without importing the renderer.
"""

from __future__ import annotations

import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from estimator.capture import (CaptureWriter, capture_header, encode_raw, min_stride, mosaic_from_grey,
                               parse_raw_format)
from estimator.formats import (LABELS_NAME, MANIFEST_NAME, TIMING_FORMAT, TIMING_NAME, check_format,
                               frame_name, read_json)
from estimator.scene import load_scene, resolve_scene

from ..firmware import F_CPU_HZ

__all__ = ["ReplayCamera", "replay_dataset", "BOOT_TIMESTAMP_NS"]

#: SensorTimestamp of the first replayed frame: CLOCK_MONOTONIC is time since boot.
BOOT_TIMESTAMP_NS = 1_000_000_000


def _setup_of(folder: Path, manifest: dict, scene):
    """The replayed frames' setup and its scene TOML text (``--scene``, else the manifest's)."""
    if scene is not None:
        return load_scene(scene), resolve_scene(scene).read_text(encoding="utf-8")
    text = manifest.get("scene", {}).get("toml") if isinstance(manifest.get("scene"), dict) else None
    if not isinstance(text, str):
        raise ValueError(f"{folder / MANIFEST_NAME}: key 'scene.toml' missing; pass --scene")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.toml"
        path.write_text(text, encoding="utf-8")
        return load_scene(path), text


class ReplayCamera:
    """A rendered dataset as the camera: the capture loop's source off the Pi.

    ``realtime=False``: frames in the dataset's order as fast as they are asked for, time
    stamps from the dataset's frame times (deterministic: :func:`replay_dataset`).

    ``realtime=True`` behaves as picamera2 does on the Pi: from :meth:`start` a sensor thread
    completes one frame every frame period of the wall clock whether or not anyone takes it,
    ``SensorTimestamp`` is its start on CLOCK_MONOTONIC (ns, the clock picamera2 reports), the
    newest completed frame is kept and older ones recycled (dropped: the taker sees the gap in
    the time stamps). The dataset's frames repeat when the run is longer (``loop``).
    Faults, for the fault tests: ``stall_after`` frames then no frame for ``stall_s``
    seconds (a stalled camera); ``drop``, frame numbers the sensor never delivers;
    ``report_frame_us``, a FrameDuration reported other than the dataset's (a sensor running
    another mode than the plan).
    """

    def __init__(self, dataset, *, scene=None, raw_format: str = "SGBRG10_CSI2P",
                 channel_response=(1.0, 1.0, 1.0, 1.0), black_level_16bit: int = 1024,
                 realtime: bool = False, loop: bool = False, stall_after: int | None = None,
                 stall_s: float = 0.0, drop=(), report_frame_us: int | None = None):
        folder = Path(dataset)
        manifest_path = folder / MANIFEST_NAME
        manifest = read_json(manifest_path)
        check_format(manifest, manifest_path, "scet-dataset", 1)
        setup, self.scene_toml = _setup_of(folder, manifest, scene)
        sensor, strobe = setup.sensor, setup.strobe
        timing_path = folder / TIMING_NAME
        exposure_s, strobe_model = sensor.exposure_s, None
        if timing_path.is_file():
            timing = read_json(timing_path)
            check_format(timing, timing_path, TIMING_FORMAT, 1)
            starts = {int(k): float(v) for k, v in timing["frames"].items()}
            exposure_s = float(timing.get("exposure_s", exposure_s))
            strobe_model = timing.get("strobe")
        else:
            try:
                n = int(manifest["frames"])
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"{manifest_path}: key 'frames' missing or not an integer") from None
            starts = {f: f * sensor.frame_period_s for f in range(n)}
        fmt = parse_raw_format(raw_format)
        w, h = setup.camera.width_px, setup.camera.height_px
        response = np.asarray(channel_response, dtype=np.float64)
        if response.shape != (4,) or not np.all(response > 0):
            raise ValueError(f"channel_response must be 4 positive numbers, got {channel_response!r}")
        self.name = f"replay:{folder}"
        self.folder, self.fmt, self.size = folder, fmt, (w, h)
        self.stride = min_stride(fmt, w)
        self.gains = 1.0 / response
        self._black_dn = [black_level_16bit / 2 ** (16 - fmt.bit_depth)] * 4
        self._black_16 = int(black_level_16bit)
        self._scene_black = sensor.black_level_dn
        self.starts = starts
        self.order = sorted(starts)
        self.frame_period_s = sensor.frame_period_s
        self.exposure_s = exposure_s
        st = strobe_model or {"pulses_per_frame": strobe.pulses_per_frame, "pulse_s": strobe.pulse_s,
                              "period_s": strobe.period_s, "phase_s": strobe.phase_s}
        period_ticks = st["period_s"] * F_CPU_HZ
        self.firmware = {"pulses": int(st["pulses_per_frame"]),
                         "width_ticks": int(round(st["pulse_s"] * F_CPU_HZ)),
                         "period_ticks": int(period_ticks),
                         "trim_256th": int(round((period_ticks % 1) * 256)),
                         "mode": "single" if int(st["pulses_per_frame"]) == 1 else "banded"}
        self.strobe_model = {k: float(st[k]) if k != "pulses_per_frame" else int(st[k])
                             for k in ("pulses_per_frame", "pulse_s", "period_s", "phase_s")}
        self.frame_us = int(round(sensor.frame_period_s * 1e6))
        self.report_frame_us = report_frame_us
        self.sensor = sensor
        self.manifest = manifest
        labels = folder / LABELS_NAME
        self.labels_text = labels.read_text(encoding="utf-8") if labels.is_file() else None
        self.realtime, self.loop = bool(realtime), bool(loop)
        self.stall_after, self.stall_s = stall_after, float(stall_s)
        self.drop = set(int(v) for v in drop)
        self._cache: dict[int, np.ndarray] = {}
        self._next = 0
        self._slot = None
        self._cond = threading.Condition()
        self._halt = threading.Event()
        self._running = False
        self._thread = None
        self.produced = 0
        self.t0_ns = None

    # ------------------------------------------------------------------ the header
    def header(self) -> dict:
        """``capture.json`` of a capture from this camera."""
        s = self.sensor
        header = capture_header(
            raw_format=self.fmt.name, size_px=self.size, stride=self.stride,
            camera={"model": "ov5647 (replayed render)", "sensor_mode": {
                "size": list(self.size), "bit_depth": self.fmt.bit_depth,
                "total_lines": s.total_lines, "line_time_us": s.line_time_s * 1e6}},
            controls={"FrameDurationLimits": [self.frame_us, self.frame_us],
                      "ExposureTime": int(round(self.exposure_s * 1e6)), "AnalogueGain": 1.0,
                      "AeEnable": False, "AwbEnable": False},
            strobe=self.firmware, software={"replayed_from": str(self.folder),
                                            "dataset_software": self.manifest.get("software")},
            source=self.name, channel_gains=self.gains.tolist())
        header["strobe_model"] = dict(self.strobe_model)
        header["exposure_s"] = float(self.exposure_s)
        # The scene the frames were rendered with: scet calibrate / track / compare read it
        # when --scene is not given (scet_render.cli_scene).
        header["scene"] = {"toml": self.scene_toml}
        return header

    # ------------------------------------------------------------------ frames
    def _rows(self, f: int) -> np.ndarray:
        rows = self._cache.get(f)
        if rows is None:
            png = self.folder / "frames" / frame_name(f, "png")
            grey = cv2.imdecode(np.frombuffer(png.read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
            w, h = self.size
            if grey is None or grey.shape != (h, w):
                raise ValueError(f"{png}: not a {w}x{h} grey PNG")
            mosaic = mosaic_from_grey(grey, self.fmt.bayer_order, self._black_dn, self.gains,
                                      self._scene_black)
            rows = encode_raw(mosaic, self.fmt, self.stride)
            rows.setflags(write=False)
            if self.realtime:
                self._cache[f] = rows     # repeats: decode each dataset frame once
        return rows

    def _meta(self, timestamp_ns: int) -> dict:
        return {"SensorTimestamp": int(timestamp_ns),
                "ExposureTime": int(round(self.exposure_s * 1e6)),
                "FrameDuration": int(self.report_frame_us or self.frame_us),
                "AnalogueGain": 1.0, "DigitalGain": 1.0,
                "SensorBlackLevels": [self._black_16] * 4}

    def __len__(self) -> int:
        return len(self.order)

    def start(self) -> None:
        if not self.realtime:
            return
        for f in self.order:
            self._rows(f)
        self._running = True
        self._halt.clear()
        self._thread = threading.Thread(target=self._sensor, name="replay-sensor", daemon=True)
        self._thread.start()

    def _sensor(self) -> None:
        dt = self.frame_period_s
        t0 = time.monotonic_ns() + int(0.01e9)
        self.t0_ns = t0          # SensorTimestamp of the sensor's frame 0
        k = 0
        stalled = False
        while self._running:
            if not self.loop and k >= len(self.order):
                return
            t_start = t0 + int(round(k * dt * 1e9))
            done = t_start + int(round(dt * 1e9))   # the readout ends one frame later
            wait = (done - time.monotonic_ns()) * 1e-9
            if wait > 0:
                time.sleep(wait)
            if (not stalled and self.stall_after is not None and self.produced >= self.stall_after):
                stalled = True
                self._halt.wait(self.stall_s)
                # The sensor runs on; frames of the stall were never delivered.
                k = int((time.monotonic_ns() - t0) / (dt * 1e9))
                continue
            if k not in self.drop:
                rows = self._rows(self.order[k % len(self.order)])
                with self._cond:
                    self._slot = (rows, self._meta(t_start))   # older frame recycled
                    self.produced += 1
                    self._cond.notify_all()
            k += 1

    def next_frame(self, timeout_s: float):
        """The next frame ((H, stride) uint8 rows, metadata); :class:`CameraStall` when none
        comes within ``timeout_s``."""
        from .stream import CameraStall

        if not self.realtime:
            if self._next >= len(self.order):
                raise CameraStall(f"{self.name}: the dataset has no frame {self._next}")
            f = self.order[self._next]
            self._next += 1
            return self._rows(f), self._meta(BOOT_TIMESTAMP_NS + int(round(self.starts[f] * 1e9)))
        with self._cond:
            if not self._cond.wait_for(lambda: self._slot is not None, timeout=timeout_s):
                raise CameraStall(f"{self.name}: no frame within {timeout_s:g} s (the camera "
                                  "stalled)")
            item, self._slot = self._slot, None
        return item

    def stop(self) -> None:
        self._running = False
        self._halt.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None

    def close(self) -> None:
        self.stop()


def replay_dataset(dataset, out_dir, *, scene=None, raw_format: str = "SGBRG10_CSI2P",
                   channel_response=(1.0, 1.0, 1.0, 1.0), black_level_16bit: int = 1024,
                   progress=None) -> Path:
    """Write the capture folder of a rendered dataset, frame for frame (not paced: the time
    stamps are the dataset's frame times).

    Parameters
    ----------
    dataset : path
        A rendered dataset folder (``manifest.json``, ``frames/NNNNNN.png``).
    scene : str or path, optional
        The scene; default the one the manifest embeds.
    raw_format : str
        ``S<order>10_CSI2P`` (packed, as the sensor sends it) or ``S<order>10``.
    channel_response : 4 floats
        Relative response of R, Gr, Gb, B (a NoIR sensor under NIR: about 1 each); the
        capture's ``channel_gains`` are their inverses.
    black_level_16bit : int
        ``SensorBlackLevels`` of every channel (libcamera's 1024 = 16 DN at 10 bit).
    """
    from .stream import stream_capture

    cam = ReplayCamera(dataset, scene=scene, raw_format=raw_format,
                       channel_response=channel_response, black_level_16bit=black_level_16bit)
    writer = CaptureWriter(out_dir, cam.header())
    n = len(cam)

    def on_frame(index, rows, md):
        if progress is not None:
            progress(index + 1, n)

    report = stream_capture(cam, writer, frames=n, skip_frames=0, on_frame=on_frame,
                            labels_text=cam.labels_text, queue_frames=4)
    if report.state != "complete":
        raise OSError(f"{out_dir}: the replay stopped: {report.stopped}")
    return Path(out_dir)
