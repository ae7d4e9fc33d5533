"""The render that matches a capture: the capture's measured timing, the poses its tracker
found, and the sensor model the frame itself gives.

Timing (:func:`measured_setup`): S, the exposure, the pulse and the strobe period of
:func:`estimator.capture.timing.measure_capture`; the phase of the setup's strobe
(s_j = phase + j Δ_clk, :mod:`estimator.banding`) follows from frame n's measured phase φ_n,
the delay from its first readout (n Δt) to its first band onset modulo Δ_clk:
phase ≡ φ_n + n Δt (mod Δ_clk), averaged over the banded frames on the circle.

Poses (:class:`PoseTrajectory`): each tracked sample's cornea centre c gives the eye's Fick
angles from the direction c - c_e (the scene's rotation centre, Böhme's model); between the
samples' strobe instants the angles are interpolated linearly, so the renderer's
:meth:`~scet_render.render.BandedRenderer.render_frame` takes the eye at every strobe where the
tracker saw it.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from estimator.eye import fick_angles
from estimator.setup import Setup

__all__ = ["measured_setup", "strobe_period_s", "PoseTrajectory", "poses_from_samples",
           "render_radiance"]


def strobe_period_s(timing) -> float:
    """Δ_clk = Δt (1 + δ / S) / M (the drift's), or the pitch's p Δt / S without a drift."""
    dt, S = timing.frame_period_s, timing.total_lines
    if math.isfinite(timing.drift_rows_per_frame):
        return dt * (1.0 + timing.drift_rows_per_frame / S) / timing.periods_per_frame
    return timing.pitch_rows * dt / S


def measured_setup(setup: Setup, timing) -> Setup:
    """``setup`` with the capture's measured timing (module docstring); S is rounded to the
    whole line count a sensor mode has."""
    dt = float(timing.frame_period_s)
    period = strobe_period_s(timing)
    frames = [f.index for f in timing.frames if f.status == "bands"]
    angles = [2 * math.pi * ((ph + n * dt) % period) / period
              for n, ph in zip(frames, timing.phase_s)]
    mean = math.atan2(np.mean(np.sin(angles)), np.mean(np.cos(angles))) if angles else 0.0
    phase = mean / (2 * math.pi) * period  # in (-Δ_clk / 2, Δ_clk / 2]
    sensor = replace(setup.sensor, total_lines=int(round(timing.total_lines)),
                     frame_period_s=dt, exposure_s=float(timing.exposure_s))
    strobe = replace(setup.strobe, pulse_s=float(timing.pulse_s), period_s=float(period),
                     phase_s=float(phase))
    return replace(setup, sensor=sensor, strobe=strobe)


class PoseTrajectory:
    """Eye angles at any instant from poses at strobe instants (linear in between, held
    beyond the ends): the ``angles_at(t)`` the renderer asks a trajectory for.

    Parameters
    ----------
    times_s : (n,) float
    yaw_rad, pitch_rad : (n,) float
    """

    def __init__(self, times_s, yaw_rad, pitch_rad):
        t = np.asarray(times_s, dtype=np.float64)
        yaw, pitch = np.asarray(yaw_rad, np.float64), np.asarray(pitch_rad, np.float64)
        ok = np.isfinite(t) & np.isfinite(yaw) & np.isfinite(pitch)
        if not ok.any():
            raise ValueError("PoseTrajectory needs at least one finite pose")
        order = np.argsort(t[ok])
        self.times_s, self.yaw_rad, self.pitch_rad = t[ok][order], yaw[ok][order], pitch[ok][order]

    def angles_at(self, t_s):
        t = np.asarray(t_s, dtype=np.float64)
        return (np.interp(t, self.times_s, self.yaw_rad),
                np.interp(t, self.times_s, self.pitch_rad))


def poses_from_samples(setup: Setup, samples) -> PoseTrajectory:
    """The trajectory of the samples that were estimated (reason "ok")."""
    ok = [s for s in samples if s.ok and np.all(np.isfinite(s.cornea_center_m))]
    if not ok:
        raise ValueError("no tracked sample to take the eye's pose from")
    c = np.array([s.cornea_center_m for s in ok]) - setup.eye.rotation_center_m
    yaw, pitch = fick_angles(c)
    return PoseTrajectory([s.time_s for s in ok], yaw, pitch)


def render_radiance(setup: Setup, trajectory, frames, *, spp: int, cornea: str, seed: int,
                    variant: str | None = None, progress=None) -> dict:
    """{frame: (H, W) float32 radiance} rendered band by band (Mitsuba imported here)."""
    from ..render import BandedRenderer

    renderer = BandedRenderer(setup, variant=variant, spp=spp, cornea=cornea, seed=seed)
    out = {}
    for k, f in enumerate(frames, start=1):
        out[f] = renderer.render_frame(trajectory, int(f)).radiance
        if progress is not None:
            progress(k, len(frames))
    return out
