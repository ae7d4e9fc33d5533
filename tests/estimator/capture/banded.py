"""Banded capture folders whose true timing the measurement is not told.

Each frame is one static scene image (a smooth eye-like blob with glints, the per-strobe
image) composed with the production row weighting (``estimator.banding.row_pulse_weights``)
of a Sensor and a Strobe whose period carries a clock mismatch, plus Gaussian read noise,
written as a ``scet-capture`` folder with the firmware's nominal tick settings only.
"""

from __future__ import annotations

import numpy as np

from estimator.banding import row_pulse_weights
from estimator.capture import capture_header, min_stride, mosaic_from_grey, parse_raw_format
from estimator.capture import write_capture
from estimator.setup import Sensor, Strobe

F_HZ = 16e6
BOOT_NS = 5_000_000_000


def scene_image(w=640, h=480, seed=0):
    """A per-strobe image in DN above black: a lit face, a dark pupil, a few glints."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    img = 180 * np.exp(-(((x - w / 2) / (0.45 * w)) ** 2 + ((y - h / 2) / (0.5 * h)) ** 2))
    img *= 1 - 0.8 * np.exp(-(((x - 0.52 * w) ** 2 + (y - 0.47 * h) ** 2) / (0.08 * w) ** 2))
    for _ in range(12):
        gx, gy = rng.uniform(0.35 * w, 0.65 * w), rng.uniform(0.3 * h, 0.7 * h)
        img += 500 * np.exp(-((x - gx) ** 2 + (y - gy) ** 2) / 4.0)
    return img + 20.0


def make_capture(folder, *, S=524, N=480, w=640, frames=60, ppm=0.0, phase_s=0.0,
                 exposure_s=None, pulse_ticks=560, pulses=16, frame_s=1 / 60, noise_dn=1.0,
                 seed=1, image=None, single=False, level=1.0):
    """Write a banded capture; returns the true (Sensor, Strobe)."""
    period_nom = frame_s / pulses
    ticks = period_nom * F_HZ
    pt, trim = int(ticks), int(round((ticks % 1) * 256))
    nominal = (pt + trim / 256) / F_HZ
    line = frame_s / S
    if exposure_s is None:
        exposure_s = nominal - pulse_ticks / F_HZ + 3 * line
    sensor = Sensor(S, N, frame_s, exposure_s)
    strobe = Strobe(1 if single else pulses, pulse_ticks / F_HZ,
                    frame_s if single else nominal * (1 + ppm * 1e-6), phase_s)
    img = (scene_image(w, N, seed) if image is None else image) * level
    rng = np.random.default_rng(seed)
    fmt = parse_raw_format("SGBRG10_CSI2P")

    def gen():
        for n in range(frames):
            _, _, wts = row_pulse_weights(sensor, strobe, n)
            grey = 16 + img * wts.sum(axis=1)[:, None] + rng.normal(0, noise_dn, img.shape)
            mosaic = mosaic_from_grey(np.clip(grey, 0, 1023), fmt.bayer_order, [16] * 4,
                                      [1] * 4, 16)
            yield mosaic, {"SensorTimestamp": BOOT_NS + int(round(n * frame_s * 1e9)),
                           "ExposureTime": int(round(exposure_s * 1e6)),
                           "FrameDuration": int(round(frame_s * 1e6)), "AnalogueGain": 1.0,
                           "SensorBlackLevels": [1024] * 4}

    firmware = {"pulses": strobe.pulses_per_frame, "width_ticks": pulse_ticks,
                "period_ticks": pt, "trim_256th": trim,
                "mode": "single" if single else "banded"}
    fus = int(round(frame_s * 1e6))
    header = capture_header(raw_format=fmt.name, size_px=(w, N), stride=min_stride(fmt, w),
                            camera={"model": "test"}, controls={
                                "FrameDurationLimits": [fus, fus],
                                "ExposureTime": int(round(exposure_s * 1e6)),
                                "AnalogueGain": 1.0, "AeEnable": False, "AwbEnable": False},
                            strobe=firmware, software={"test": "banded"}, source="test")
    write_capture(folder, header, gen())
    return sensor, strobe
