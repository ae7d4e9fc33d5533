"""Planning strobe and exposure settings: a pulse count and period whose bands tile
the frame (:func:`plan_strobe`), the single-pulse calibration timing and the scaled timing
used by validation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from ..setup import Sensor, Setup, Strobe
from .equations import _check_pulse_s, _check_sensor

# --------------------------------------------------------------------------- planning


@dataclass(frozen=True, slots=True)
class StrobePlan:
    """A strobe and exposure setting whose bands tile the frame (see :func:`plan_strobe`).

    Attributes
    ----------
    pulses_per_frame : int
        P; P * period_s == Δt, so the bands stay on the same rows frame after frame.
    period_s, pulse_s, exposure_s : float
        Δ_clk, Δs and the camera exposure Δe to set.
    bands_visible : float
        Expected visible bands per frame, P N / S.
    """

    pulses_per_frame: int
    period_s: float
    pulse_s: float
    exposure_s: float
    bands_visible: float

    def apply(self, sensor: Sensor, phase_s: float = 0.0) -> tuple[Sensor, Strobe]:
        """The sensor with this plan's exposure and the planned :class:`Strobe` at ``phase_s``."""
        planned = Sensor(
            sensor.total_lines,
            sensor.visible_lines,
            sensor.frame_period_s,
            self.exposure_s,
            sensor.bit_depth,
            sensor.black_level_dn,
        )
        return planned, Strobe(self.pulses_per_frame, self.pulse_s, self.period_s, phase_s)


def plan_strobe(
    sensor: Sensor,
    bands_visible: float,
    pulse_s: float | None = None,
    duty: float = 0.1,
    overlap: bool = False,
) -> StrobePlan:
    """Plan pulses, period, pulse width and exposure for at least ``bands_visible`` visible bands.

    P = ceil(bands_visible S / N) pulses per frame (only N of the S lines are transferred, so a
    frame shows about P N / S bands). The period is locked to the frame, Δ_clk = Δt / P: pulse
    j + P then falls on the same rows one frame later as pulse j did, and the bands do not drift
    (:func:`band_drift_rows` is 0). The pulse is ``pulse_s`` or ``duty`` Δ_clk.

    The exposure follows Eq. (8), Δe = Δ_clk - Δs: band j ends exactly where band j + 1 begins
    (k'''_j = k_{j+1}, :func:`band_gap_rows` = 0), so no row is dark over a positive height and
    no row mixes two pulses; the price is a V-shaped dip in brightness 2 S Δs / Δt rows wide at
    each boundary (the ramps of Eq. (5)). With ``overlap=True`` the paper's variant
    k_{j+1} = k''_j is used instead, Δe = Δ_clk (Δs drops out of Eqs. (7) and (8)): every row then
    collects exactly one pulse's worth of light, with no dip, but the S Δs / Δt rows at each
    boundary mix two pulses, i.e. two instants Δ_clk apart.

    Parameters
    ----------
    sensor : Sensor
        Its S, N and Δt are used; its exposure is an output of the plan, not an input.
    bands_visible : float
        Wanted visible bands per frame, > 0.
    pulse_s : float, optional
        Δs; default ``duty`` * Δ_clk.
    duty : float
        Δs / Δ_clk when ``pulse_s`` is not given, in (0, 1).
    overlap : bool
        Use the k_{j+1} = k''_j variant.

    Returns
    -------
    StrobePlan
    """
    _check_sensor(sensor)
    bands_visible = float(bands_visible)
    if not (math.isfinite(bands_visible) and bands_visible > 0):
        raise ValueError(f"bands_visible must be positive, got {bands_visible!r}")
    S, N, dt = sensor.total_lines, sensor.visible_lines, sensor.frame_period_s
    # The small tolerance keeps e.g. 16 N / S requested bands at 16 pulses despite rounding.
    P = max(1, math.ceil(bands_visible * S / N - 1e-9))
    period = dt / P
    if pulse_s is None:
        duty = float(duty)
        if not (math.isfinite(duty) and 0 < duty < 1):
            raise ValueError(f"duty must be in (0, 1), got {duty!r}")
        pulse_s = duty * period
    else:
        pulse_s = _check_pulse_s(pulse_s)
        if pulse_s >= period:
            raise ValueError(
                f"pulse_s = {pulse_s!r} s does not fit in the period Δt / P = {period!r} s "
                f"needed for {bands_visible} visible bands"
            )
    exposure = period if overlap else period - pulse_s
    return StrobePlan(P, period, pulse_s, exposure, P * N / S)


#: Calibration frames: share of the slack between exposure and readout span given to the pulse.
CALIB_PULSE_SHARE = 0.5


def scaled_setup(setup: Setup, factor: int) -> Setup:
    """The setup imaged at 1/``factor`` of the resolution: same field of view, same strobe
    timing (S scaled with N, so the line time fraction and the bands keep their timing)."""
    if factor == 1:
        return setup
    cam = setup.camera
    camera = cam.with_intrinsics(cam.fx_px / factor, cam.fy_px / factor,
                                 (cam.cx_px + 0.5) / factor - 0.5, (cam.cy_px + 0.5) / factor - 0.5,
                                 cam.width_px // factor, cam.height_px // factor)
    if setup.sensor.total_lines % factor or cam.height_px % factor:
        raise ValueError(f"cannot scale setup {setup.name!r} by 1/{factor}: total_lines "
                         f"{setup.sensor.total_lines} and height {cam.height_px} must divide")
    sensor = replace(setup.sensor, total_lines=setup.sensor.total_lines // factor,
                     visible_lines=cam.height_px // factor)
    return replace(setup, camera=camera, sensor=sensor)


def calibration_setup(setup: Setup, exposure_share: float = 0.9) -> Setup:
    """The setup with single-pulse calibration timing: one pulse per frame that every visible
    row collects whole, so the whole frame shows one instant.

    Row y is exposed over [R(y) - Δe, R(y)] with R(y) = t0 + (y / S) Δt (Eqs. (2)-(3)); all
    visible rows share [R(N - 1) - Δe, R(0)], which is non-empty when Δe exceeds the readout
    span (N - 1) Δt / S. The exposure is set to ``exposure_share`` Δt and the pulse, centred in
    the shared window, takes :data:`CALIB_PULSE_SHARE` of it. (A pulse as wide as the exposure
    cannot be collected whole by every row of a rolling shutter; this one can.)
    """
    sensor = setup.sensor
    dt = sensor.frame_period_s
    span = (sensor.visible_lines - 1) * dt / sensor.total_lines
    exposure = exposure_share * dt
    slack = exposure - span
    if slack <= 0:
        raise ValueError(f"setup {setup.name!r}: an exposure of {exposure:.4g} s does not cover "
                         f"the readout span {span:.4g} s")
    pulse = CALIB_PULSE_SHARE * slack
    phase = -0.5 * slack - 0.5 * pulse  # centre of [span - Δe, 0] relative to t0_f
    strobe = replace(setup.strobe, pulses_per_frame=1, pulse_s=pulse, period_s=dt, phase_s=phase)
    return replace(setup, sensor=replace(sensor, exposure_s=exposure), strobe=strobe)


def strobe_setup(setup: Setup, pulses_per_frame: int) -> Setup:
    """The setup strobed ``pulses_per_frame`` times a frame: the period locked to the frame
    (Δ_clk = Δt / P), the setup's pulse width kept and the exposure of Eq. (8), Δe = Δ_clk - Δs,
    so the bands tile the frame (:func:`estimator.banding.plan_strobe`). The setup's own pulse
    count returns the setup unchanged (its exposure as configured)."""
    if pulses_per_frame == setup.strobe.pulses_per_frame:
        return setup
    if pulses_per_frame < 1:
        raise ValueError(f"pulses_per_frame must be >= 1, got {pulses_per_frame}")
    sensor = setup.sensor
    # plan_strobe asks for visible bands: ceil(b S / N) = P for b just under P N / S.
    plan = plan_strobe(sensor, pulses_per_frame * sensor.visible_lines / sensor.total_lines
                       * (1 - 1e-9), pulse_s=setup.strobe.pulse_s)
    if plan.pulses_per_frame != pulses_per_frame:  # pragma: no cover - rounding guard
        raise RuntimeError(f"planned {plan.pulses_per_frame} pulses, wanted {pulses_per_frame}")
    strobe = replace(setup.strobe, pulses_per_frame=plan.pulses_per_frame,
                     pulse_s=plan.pulse_s, period_s=plan.period_s)
    return replace(setup, sensor=replace(sensor, exposure_s=plan.exposure_s), strobe=strobe)
