"""A camera that sees the simulated strobe board: the closed phase lock off the Pi.

The strobe firmware runs in simavr (:class:`scet_hardware.firmware.SimulatedBoard` with
``edges=True``, which logs the simulated cycle of every rising edge of the strobe pin); this
camera renders each frame's rows from those pulses by the rolling-shutter equations: row y
of frame k is read at R(y) = t_k + y Δt / S (Eq. (2)) and collects the part of each pulse
[s_j, s_j + Δs] that overlaps its exposure [R(y) - Δe, R(y)] (Eqs. (3)-(6)), times a smooth
scene and plus read noise, as a packed GBRG raw frame of an OV5647. Only the camera is
simulated: the pulse train is the firmware's own, moved by the host's real serial commands.

Clocks: the board's cycles become the camera's (Pi's) seconds as
t = cycles / (16 MHz (1 + ppm 1e-6)): a board ``ppm`` fast (a resonator runs up to a few
thousand ppm off) makes its strobe period short on the Pi's clock, and the bands drift
(``estimator.capture.timing``). simavr is paced to the wall clock; the camera waits for the
board to have run past each frame's end, so a slow machine slows both alike.

Like :class:`ReplayCamera` it behaves as picamera2 does: a sensor thread completes frames
whether or not anyone takes them, the newest is kept and older ones recycled.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from estimator.capture import capture_header, encode_raw, min_stride, parse_raw_format

from ..firmware import F_CPU_HZ

__all__ = ["StrobeRigCamera"]


class StrobeRigCamera:
    """Frames of the simulated board's strobe (module docstring).

    Parameters
    ----------
    board : SimulatedBoard
        Started with ``edges=True``.
    total_lines, frame_period_s, exposure_s, pulse_s
        S, Δt, Δe and Δs of the simulated sensor and the firmware's pulse width.
    ppm : float
        The board's clock error against the camera's.
    signal_dn : float
        Brightness of a row lit for a whole pulse (DN above black).
    """

    def __init__(self, board, *, total_lines: int = 524, frame_period_s: float = 16636.35e-6,
                 exposure_s: float = 984.2e-6, pulse_s: float = 100e-6, ppm: float = 0.0,
                 size_px=(640, 480), signal_dn: float = 400.0, noise_dn: float = 1.0,
                 black_dn: float = 16.0, seed: int = 0, raw_format: str = "SGBRG10_CSI2P"):
        self.board = board
        self.S, self.dt, self.exposure_s, self.pulse_s = int(total_lines), float(frame_period_s), \
            float(exposure_s), float(pulse_s)
        self.tick_s = 1.0 / (F_CPU_HZ * (1.0 + ppm * 1e-6))
        self.size = tuple(size_px)
        self.fmt = parse_raw_format(raw_format)
        self.stride = min_stride(self.fmt, self.size[0])
        self.signal_dn, self.noise_dn, self.black_dn = float(signal_dn), float(noise_dn), float(black_dn)
        self.rng = np.random.default_rng(seed)
        w, h = self.size
        x = np.arange(w)
        self.texture = 0.75 + 0.25 * np.cos(2 * np.pi * x / 157.0)   # a smooth scene across
        # Read noise: a few planes drawn once, cycled (drawing one a frame costs more than the
        # rest of the frame).
        self._noise = self.rng.normal(0.0, self.noise_dn, (4, self.size[1], self.size[0]))
        self.name = f"rig:{board.port}"
        self.truth: dict[int, float] = {}   # frame -> first band onset after t_k (rows)
        self.skipped = 0                     # frames not rendered in time (never delivered)
        self._slot = None
        self._cond = threading.Condition()
        self._running = False
        self._thread = None
        self.t0_s = None

    def header(self) -> dict:
        us = int(round(self.dt * 1e6))
        return capture_header(
            raw_format=self.fmt.name, size_px=self.size, stride=self.stride,
            camera={"model": "ov5647 (simulated rig)", "sensor_mode": {
                "size": list(self.size), "bit_depth": 10, "total_lines": self.S,
                "line_time_us": self.dt / self.S * 1e6}},
            controls={"FrameDurationLimits": [us, us], "ExposureTime": int(round(self.exposure_s * 1e6)),
                      "AnalogueGain": 1.0, "AeEnable": False, "AwbEnable": False},
            strobe=None, software={"simulated": "scet_hardware.capture.rig"}, source=self.name)

    def _row_weights(self, t_k: float, pulses_s: np.ndarray) -> np.ndarray:
        h = self.size[1]
        R = t_k + np.arange(h) * self.dt / self.S
        lo = np.maximum(R[:, None] - self.exposure_s, pulses_s[None, :])
        hi = np.minimum(R[:, None], pulses_s[None, :] + self.pulse_s)
        return np.clip(hi - lo, 0.0, None).sum(axis=1) / self.pulse_s

    def render(self, k: int, pulses_s: np.ndarray) -> np.ndarray:
        """(H, stride) uint8 packed rows of frame k from the pulse starts (camera s)."""
        t_k = self.t0_s + k * self.dt
        w = self._row_weights(t_k, pulses_s)
        after = pulses_s[pulses_s >= t_k]
        if after.size:
            self.truth[k] = float((after[0] - t_k) / (self.dt / self.S))
        img = self.black_dn + self.signal_dn * w[:, None] * self.texture[None, :]
        img = img + self._noise[k % len(self._noise)]
        return encode_raw(np.clip(np.rint(img), 0, 1023).astype(np.uint16), self.fmt, self.stride)

    def start(self) -> None:
        self._running = True
        self._thread = threading.Thread(target=self._sensor, name="rig-sensor", daemon=True)
        self._thread.start()

    def _sensor(self) -> None:
        edges_s = np.zeros(0)
        read = 0
        k = 0
        while self._running:
            cyc = self.board.edge_cycles()
            if cyc.size > read:
                edges_s = np.concatenate([edges_s, cyc[read:].astype(np.float64) * self.tick_s])
                read = cyc.size
            if self.t0_s is None:
                if edges_s.size < 2:
                    time.sleep(0.005)
                    continue
                self.t0_s = float(edges_s[0]) + 0.37 * self.dt   # an arbitrary start phase
            # A sensor never falls behind: when rendering did, the frames it missed were never
            # delivered (drops, as when the taker is late), and the newest complete one is next.
            newest = int((edges_s[-1] - self.t0_s) / self.dt) - 2
            if newest > k:
                self.skipped += newest - k
                k = newest
            t_k = self.t0_s + k * self.dt
            # Frame k is complete when the board has run past its last row's readout.
            if edges_s[-1] < t_k + self.dt:
                time.sleep(0.002)
                continue
            near = edges_s[(edges_s > t_k - self.exposure_s - self.pulse_s) & (edges_s < t_k + self.dt)]
            rows = self.render(k, near)
            md = {"SensorTimestamp": int(round((1.0 + t_k) * 1e9)),
                  "ExposureTime": int(round(self.exposure_s * 1e6)),
                  "FrameDuration": int(round(self.dt * 1e6)), "AnalogueGain": 1.0,
                  "SensorBlackLevels": [int(self.black_dn * 64)] * 4}
            with self._cond:
                self._slot = (rows, md)
                self._cond.notify_all()
            k += 1
            edges_s = edges_s[edges_s > t_k - 0.1]

    def next_frame(self, timeout_s: float):
        from .stream import CameraStall

        with self._cond:
            if not self._cond.wait_for(lambda: self._slot is not None, timeout=timeout_s):
                raise CameraStall(f"{self.name}: no frame within {timeout_s:g} s")
            item, self._slot = self._slot, None
        return item

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None

    def close(self) -> None:
        self.stop()
