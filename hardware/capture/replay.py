"""A rendered dataset replayed as the Pi would have captured it: each 10-bit frame as the
sensor reads it out (the Bayer mosaic of the per-channel responses, packed or unpacked rows of
the Unicam stride), picamera2's metadata with ``SensorTimestamp`` from the dataset's frame
times, and the labels copied, so the whole capture path runs without a Pi.

The dataset is read directly (``manifest.json``, optional ``timing.json``, ``frames/*.png``,
``labels.jsonl``; scet_render/dataset.py's format), without importing the renderer.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import cv2
import numpy as np

from estimator.capture import capture_header, min_stride, mosaic_from_grey, parse_raw_format, write_capture
from estimator.formats import (LABELS_NAME, MANIFEST_NAME, TIMING_FORMAT, TIMING_NAME, check_format,
                               frame_name, read_json)
from estimator.scene import load_scene

from ..firmware import F_CPU_HZ

__all__ = ["replay_dataset", "BOOT_TIMESTAMP_NS"]

#: SensorTimestamp of the first replayed frame: CLOCK_MONOTONIC is time since boot.
BOOT_TIMESTAMP_NS = 1_000_000_000


def _setup_of(folder: Path, manifest: dict, scene):
    if scene is not None:
        return load_scene(scene)
    text = manifest.get("scene", {}).get("toml") if isinstance(manifest.get("scene"), dict) else None
    if not isinstance(text, str):
        raise ValueError(f"{folder / MANIFEST_NAME}: key 'scene.toml' missing; pass --scene")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.toml"
        path.write_text(text, encoding="utf-8")
        return load_scene(path)


def replay_dataset(dataset, out_dir, *, scene=None, raw_format: str = "SGBRG10_CSI2P",
                   channel_response=(1.0, 1.0, 1.0, 1.0), black_level_16bit: int = 1024,
                   progress=None) -> Path:
    """Write the capture folder of a rendered dataset.

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
    folder = Path(dataset)
    manifest_path = folder / MANIFEST_NAME
    manifest = read_json(manifest_path)
    check_format(manifest, manifest_path, "scet-dataset", 1)
    setup = _setup_of(folder, manifest, scene)
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
    stride = min_stride(fmt, w)
    response = np.asarray(channel_response, dtype=np.float64)
    if response.shape != (4,) or not np.all(response > 0):
        raise ValueError(f"channel_response must be 4 positive numbers, got {channel_response!r}")
    gains = 1.0 / response
    black_dn = [black_level_16bit / 2 ** (16 - fmt.bit_depth)] * 4
    st = strobe_model or {"pulses_per_frame": strobe.pulses_per_frame, "pulse_s": strobe.pulse_s,
                          "period_s": strobe.period_s, "phase_s": strobe.phase_s}
    period_ticks = st["period_s"] * F_CPU_HZ
    firmware = {"pulses": int(st["pulses_per_frame"]), "width_ticks": int(round(st["pulse_s"] * F_CPU_HZ)),
                "period_ticks": int(period_ticks), "trim_256th": int(round((period_ticks % 1) * 256)),
                "mode": "single" if int(st["pulses_per_frame"]) == 1 else "banded"}
    frame_us = int(round(sensor.frame_period_s * 1e6))

    def frames():
        for done, f in enumerate(sorted(starts), start=1):
            png = folder / "frames" / frame_name(f, "png")
            grey = cv2.imdecode(np.frombuffer(png.read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
            if grey is None or grey.shape != (h, w):
                raise ValueError(f"{png}: not a {w}x{h} grey PNG")
            mosaic = mosaic_from_grey(grey, fmt.bayer_order, black_dn, gains, sensor.black_level_dn)
            meta = {"SensorTimestamp": BOOT_TIMESTAMP_NS + int(round(starts[f] * 1e9)),
                    "ExposureTime": int(round(exposure_s * 1e6)), "FrameDuration": frame_us,
                    "AnalogueGain": 1.0, "DigitalGain": 1.0,
                    "SensorBlackLevels": [int(black_level_16bit)] * 4}
            if progress is not None:
                progress(done, len(starts))
            yield mosaic, meta

    header = capture_header(
        raw_format=fmt.name, size_px=(w, h), stride=stride,
        camera={"model": "ov5647 (replayed render)", "sensor_mode": {
            "size": [w, h], "bit_depth": fmt.bit_depth, "total_lines": sensor.total_lines,
            "line_time_us": sensor.line_time_s * 1e6}},
        controls={"FrameDurationLimits": [frame_us, frame_us],
                  "ExposureTime": int(round(exposure_s * 1e6)), "AnalogueGain": 1.0,
                  "AeEnable": False, "AwbEnable": False},
        strobe=firmware, software={"replayed_from": str(folder), "dataset_software": manifest.get("software")},
        source=f"replay:{folder}", channel_gains=gains.tolist())
    header["strobe_model"] = {k: float(st[k]) if k != "pulses_per_frame" else int(st[k])
                              for k in ("pulses_per_frame", "pulse_s", "period_s", "phase_s")}
    header["exposure_s"] = float(exposure_s)
    labels = folder / LABELS_NAME
    return write_capture(out_dir, header, frames(),
                         labels.read_text(encoding="utf-8") if labels.is_file() else None)
