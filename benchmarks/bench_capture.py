"""Capture frames through the tracker's reader: raw frames per second on one core, unpacking
(CSI-2 packed and 16-bit unpacked) and glint detection on the unpacked frames (the streaming
detector, as on the Pi), on banded frames of the prototype scene drawn analytically.

    python benchmarks/bench_capture.py
"""

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# The analytic banded frames are the tests' (tests/estimator/test_tracker.draw_frame).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from estimator.capture import decode_raw, encode_raw, min_stride, parse_raw_format  # noqa: E402
from estimator.glints import GlintDetector  # noqa: E402
from estimator.scene import load_scene  # noqa: E402


def draw(setup, f, rng):
    from tests.estimator.test_tracker import draw_frame

    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(1, 1))
    return draw_frame(setup, f, float(yaw[0]) + 0.002 * f, float(pitch[0]), rng)


def rate(fn, items, seconds=2.0):
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for it in items:
            fn(it)
            n += 1
    return n / (time.perf_counter() - t0)


def main():
    cv2.setNumThreads(1)
    setup = load_scene("prototype_ov5647")
    rng = np.random.default_rng(0)
    frames = [draw(setup, f, rng) for f in range(30)]
    print(f"prototype_ov5647, 640x480 banded frames, one core ({len(frames)} frames cycled)")
    for name in ("SGBRG10_CSI2P", "SGBRG10"):
        fmt = parse_raw_format(name)
        raws = [encode_raw(f, fmt, min_stride(fmt, 640)) for f in frames]
        fps = rate(lambda r: decode_raw(r, fmt, 640), raws)
        print(f"  unpack {name:14s} {fps:10.0f} frames/s")
    fmt = parse_raw_format("SGBRG10")
    unpacked = [decode_raw(encode_raw(f, fmt, 1280), fmt, 640) for f in frames]
    det = GlintDetector(setup)
    for f, img in enumerate(unpacked):       # warm-up: noise model, compiled kernels
        det(img, f)
    k = iter(range(10 ** 9))
    fps = rate(lambda img: det(img, next(k) % 30), unpacked, seconds=4.0)
    print(f"  detection on unpacked raw frames (GlintDetector, streaming): {fps:.0f} frames/s")
    fmt = parse_raw_format("SGBRG10_CSI2P")
    packed = [encode_raw(f, fmt, 800) for f in frames]
    fps = rate(lambda r: det(decode_raw(r, fmt, 640), next(k) % 30), packed, seconds=4.0)
    print(f"  unpack SGBRG10_CSI2P + detection: {fps:.0f} frames/s")


if __name__ == "__main__":
    main()
