"""OV5647 sensor profiles for the prototype and a strobe planner whose settings both the
firmware (whole 16 MHz ticks) and libcamera (whole lines) can realise.

The paper's 16.636 ms VGA frame fits two sensor modes (HARDWARE.md Sec. 1):

* ``ov5647_mode6``: today's kernel driver (pixel rate 58.333 MHz, HTS 1852) and the legacy
  firmware's mode 6: line 31.749 us (raspiraw ``line_time_ns`` 31749; 1852 / 58.333 MHz =
  31.74875 us), S = 524 at 16.636 ms.
* ``ov5647_mode7``: legacy mode 7 (87.5 MHz; raspberrypi/linux PR #7582 would bring it back):
  line 21.1657 us (1852 / 87.5 MHz), S = 786.

libcamera truncates: frame length = floor(FrameDurationLimits / line), exposure lines =
floor(ExposureTime / line) (``CamHelper::getBlanking``, HARDWARE.md Sec. 2), exposure at least
4 lines and at most frame length - 4 (kernel driver ``OV5647_EXPOSURE_MIN``, ``VTS - 4``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from estimator.banding import plan_strobe
from estimator.setup import Sensor

from .firmware import F_CPU_HZ

__all__ = ["SensorProfile", "PROFILES", "profile", "RealisedPlan", "plan_prototype_strobe"]


@dataclass(frozen=True, slots=True)
class SensorProfile:
    """One reading of the OV5647 VGA mode."""

    name: str
    line_s: float
    visible_lines: int = 480
    min_vblank_lines: int = 24          # kernel driver OV5647_VBLANK_MIN
    exposure_min_lines: int = 4         # OV5647_EXPOSURE_MIN
    exposure_margin_lines: int = 4      # exposure <= VTS - 4
    black_level_dn: float = 16.0        # libcamera ov5647(_noir).json: 1024 on a 16-bit scale
    bayer_order: str = "GBRG"           # no user flips on a Pi camera v1 (driver codes[])
    source: str = ""

    def frame_lines(self, frame_duration_us: float) -> int:
        """The frame length libcamera programs for a FrameDurationLimits of ``frame_duration_us``."""
        lines = math.floor(frame_duration_us * 1e-6 / self.line_s + 1e-9)
        return max(lines, self.visible_lines + self.min_vblank_lines)

    def exposure_lines(self, exposure_us: float, frame_lines: int) -> int:
        lines = math.floor(exposure_us * 1e-6 / self.line_s + 1e-9)
        return min(max(lines, self.exposure_min_lines), frame_lines - self.exposure_margin_lines)

    def request_frame_us(self, lines: int) -> int:
        """The smallest whole-us FrameDurationLimits that gives ``lines`` (16,637 us, not
        16,636, for 524 lines of 31.74875 us: HARDWARE.md Sec. 2)."""
        us = math.ceil(lines * self.line_s * 1e6 - 1e-9)
        while self.frame_lines(us) < lines:
            us += 1
        return us

    def request_exposure_us(self, lines: int) -> int:
        us = math.ceil(lines * self.line_s * 1e6 - 1e-9)
        while math.floor(us * 1e-6 / self.line_s + 1e-9) < lines:
            us += 1
        return us

    def sensor(self, frame_lines: int, exposure_lines: int) -> Sensor:
        """The :class:`estimator.setup.Sensor` of these settings (S = frame length)."""
        return Sensor(total_lines=frame_lines, visible_lines=self.visible_lines,
                      frame_period_s=frame_lines * self.line_s,
                      exposure_s=exposure_lines * self.line_s, bit_depth=10,
                      black_level_dn=self.black_level_dn)


PROFILES = {
    "ov5647_mode6": SensorProfile("ov5647_mode6", 1852 / 58.333e6,
                                  source="kernel driver ov5647.c VGA (pixel_rate 58333000, hts 1852); "
                                         "raspiraw mode 6 line_time_ns 31749"),
    "ov5647_mode7": SensorProfile("ov5647_mode7", 1852 / 87.5e6,
                                  source="raspiraw ov5647_modes.h mode 7 (line_time_ns 21165, PLL 0x69)"),
}


def profile(name: str) -> SensorProfile:
    try:
        return PROFILES[name]
    except KeyError:
        raise ValueError(f"unknown sensor profile {name!r}, expected one of {sorted(PROFILES)}") from None


@dataclass(frozen=True, slots=True)
class RealisedPlan:
    """Settings for libcamera and for the firmware, and what they give.

    Attributes
    ----------
    controls : dict
        picamera2 controls: ``FrameDurationLimits`` (us, equal ends), ``ExposureTime`` (us),
        ``AnalogueGain``, ``AeEnable``/``AwbEnable`` False.
    firmware : dict
        ``pulses``, ``width_ticks``, ``period_ticks``, ``trim_256th``, ``mode``.
    sensor : Sensor
        The realised frame (S = frame length lines, Δt, Δe in whole lines).
    period_s, pulse_s : float
        Realised mean strobe period (trim included) and pulse width.
    drift_rows_per_frame : float
        How far the bands move per frame from the remaining clock mismatch (Sec. 6 of
        HARDWARE.md: δ = S (P Δclk - Δt) / Δt), with ideal clocks.
    """

    profile: str
    controls: dict
    firmware: dict
    sensor: Sensor
    period_s: float
    pulse_s: float
    drift_rows_per_frame: float


def plan_prototype_strobe(prof: SensorProfile, *, frame_duration_us: float = 16636.0,
                          bands_visible: float | None = None, pulses: int | None = None,
                          pulse_us: float = 100.0, exposure_us: float | None = None,
                          overlap: bool = False, analogue_gain: float = 1.0,
                          single_pulse: bool = False) -> RealisedPlan:
    """Plan a prototype run: frame length and exposure in whole lines, strobe in whole ticks.

    The frame length is the whole number of lines nearest ``frame_duration_us``; the pulses per
    frame come from ``pulses`` or ``bands_visible`` (:func:`estimator.banding.plan_strobe`,
    default 16 as in the paper); the period is the realised frame over the pulses, rounded to
    ticks with the fraction in 1/256 tick as the firmware's TRIM; the exposure is
    ``exposure_us`` or Eq. (8)'s Δclk - Δs, truncated to lines as libcamera does.
    """
    lines = max(round(frame_duration_us * 1e-6 / prof.line_s), prof.visible_lines + prof.min_vblank_lines)
    frame_us = prof.request_frame_us(lines)
    frame_lines = prof.frame_lines(frame_us)
    base = prof.sensor(frame_lines, prof.exposure_min_lines)
    if pulses is None:
        pulses = 16 if bands_visible is None else plan_strobe(base, bands_visible,
                                                              pulse_s=pulse_us * 1e-6).pulses_per_frame
    pulses = int(pulses)
    if not 1 <= pulses <= 255:
        raise ValueError(f"pulses must be 1..255 (the firmware's PULSES), got {pulses}")
    period_ticks_exact = base.frame_period_s * F_CPU_HZ / pulses
    period_ticks = int(math.floor(period_ticks_exact))
    trim = int(round((period_ticks_exact - period_ticks) * 256))
    if trim == 256:
        period_ticks, trim = period_ticks + 1, 0
    width_ticks = int(round(pulse_us * 1e-6 * F_CPU_HZ))
    if not 64 <= width_ticks <= period_ticks - 128 or not 1024 <= period_ticks <= 65000:
        raise ValueError(f"a {pulse_us:g} us pulse every {period_ticks} ticks is outside the "
                         f"firmware's limits (WIDTH 64..PERIOD-128, PERIOD 1024..65000)")
    period_s = (period_ticks + trim / 256) / F_CPU_HZ
    pulse_s = width_ticks / F_CPU_HZ
    if exposure_us is None:
        exposure_us = (period_s if overlap else period_s - pulse_s) * 1e6
    exp_lines = prof.exposure_lines(exposure_us, frame_lines)
    sensor = prof.sensor(frame_lines, exp_lines)
    controls = {"FrameDurationLimits": [frame_us, frame_us],
                "ExposureTime": prof.request_exposure_us(exp_lines),
                "AnalogueGain": float(analogue_gain), "AeEnable": False, "AwbEnable": False}
    firmware = {"pulses": pulses, "width_ticks": width_ticks, "period_ticks": period_ticks,
                "trim_256th": trim, "mode": "single" if single_pulse else "banded"}
    dt = sensor.frame_period_s
    drift = frame_lines * (pulses * period_s - dt) / dt
    return RealisedPlan(prof.name, controls, firmware, sensor, period_s, pulse_s, drift)
