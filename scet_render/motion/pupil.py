"""Pupil size over time: the pupillary light reflex and hippus (pupillary unrest), seeded.

The pupil diameter of a :class:`PupilTrace` at time t is

    D(t) = D0 + sum_k dD_k r_k(t - t_k - latency) + h(t),   clipped to [D_min, D_max],

* **light response**: a change of the light reaching the eye at t_k (a brighter screen, a
  lamp) moves the pupil by dD_k (negative: constriction) after the reflex latency, along the
  critically damped step response r(s) = 1 - (1 + s / tau) exp(-s / tau) (zero for s < 0; no
  jump in size or speed at the onset). Constriction is faster than redilation (tau 0.15 s:
  90 % of the change 0.58 s after the latency; redilation tau 0.6 s: 90 % after 2.3 s), as
  measured by Ellis (1981); the latency, 0.22 s, is inside the 0.2-0.25 s of Ellis (1981)
  and Bergamin & Kardon (2003) for bright steps;
* **hippus**: the pupil's slow unrest with steady light (Stark, Campbell & Atwood 1958), a sum
  of ``hippus_components`` sinusoids with seeded frequencies in ``hippus_band_hz``
  (0.05-0.3 Hz) and phases, scaled to an RMS of ``hippus_rms_mm`` (0.1 mm: peaks of about
  0.3 mm, inside the 0.1-0.5 mm usually quoted);
* the result stays inside [``min_diameter_mm``, ``max_diameter_mm``] (2-8 mm, the range from
  bright to dark adaptation, Watson & Yellott 2012) and below the iris (the renderer checks).

Nothing here runs unless asked for: a :class:`~scet_render.motion.Trajectory` without a
``pupil`` trace keeps the scene's ``eye.pupil_diameter_mm`` at every instant, so datasets
rendered without one are what they were before this module existed.

References
----------
Ellis, C. J. K. (1981). The pupillary light reflex in normal subjects. *British Journal of
Ophthalmology* 65, 754-759.
Bergamin, O., Kardon, R. H. (2003). Latency of the pupil light reflex: sample rate, stimulus
intensity, and variation in normal subjects. *Investigative Ophthalmology & Visual Science* 44,
1546-1554.
Stark, L., Campbell, F. W., Atwood, J. (1958). Pupil unrest: an example of noise in a
biological servomechanism. *Nature* 182, 857-858.
Watson, A. B., Yellott, J. I. (2012). A unified formula for light-adapted pupil size.
*Journal of Vision* 12(10):12.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class PupilModel:
    """Dynamics and statistics of the pupil (module docstring); sizes in mm, times in s.

    ``light_steps_per_min`` is the mean rate of random light changes :func:`pupil_schedule`
    draws (0: none, hippus only), each moving the pupil by a size uniform in
    ``light_step_range_mm``.
    """

    latency_s: float = 0.22
    constriction_tau_s: float = 0.15
    dilation_tau_s: float = 0.6
    hippus_rms_mm: float = 0.1
    hippus_band_hz: tuple[float, float] = (0.05, 0.3)
    hippus_components: int = 6
    light_steps_per_min: float = 0.0
    light_step_range_mm: tuple[float, float] = (-1.5, 1.5)
    min_diameter_mm: float = 2.0
    max_diameter_mm: float = 8.0

    def __post_init__(self):
        for name in ("latency_s", "hippus_rms_mm", "light_steps_per_min"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")
        for name in ("constriction_tau_s", "dilation_tau_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be finite and > 0, got {v!r}")
        lo, hi = self.hippus_band_hz
        if not (0 < lo <= hi and math.isfinite(hi)):
            raise ValueError(f"hippus_band_hz must be (low, high) with 0 < low <= high, got "
                             f"{self.hippus_band_hz!r}")
        if isinstance(self.hippus_components, bool) or not (
                isinstance(self.hippus_components, int) and self.hippus_components >= 1):
            raise ValueError(f"hippus_components must be an integer >= 1, got "
                             f"{self.hippus_components!r}")
        a, b = self.light_step_range_mm
        if not (math.isfinite(a) and math.isfinite(b) and a <= b):
            raise ValueError(f"light_step_range_mm must be (low, high), got "
                             f"{self.light_step_range_mm!r}")
        if not (0 < self.min_diameter_mm < self.max_diameter_mm
                and math.isfinite(self.max_diameter_mm)):
            raise ValueError("need 0 < min_diameter_mm < max_diameter_mm")


def _step_response(s, tau):
    """Critically damped unit step response 1 - (1 + s/tau) exp(-s/tau), 0 for s <= 0."""
    x = np.maximum(np.asarray(s, dtype=np.float64), 0.0) / tau
    return 1.0 - (1.0 + x) * np.exp(-x)


@dataclass(frozen=True, slots=True, eq=False)
class PupilTrace:
    """The pupil diameter over a trajectory's time axis.

    Attributes
    ----------
    base_diameter_m : float
        D0, the diameter before any light change (the scene's, usually).
    step_s : (k,) float
        Instants of the light changes.
    step_m : (k,) float
        The size change each causes once settled (negative: constriction).
    hippus_amplitude_m, hippus_frequency_hz, hippus_phase_rad : (c,) float
        The hippus sinusoids.
    model : PupilModel
    """

    base_diameter_m: float
    step_s: np.ndarray
    step_m: np.ndarray
    hippus_amplitude_m: np.ndarray
    hippus_frequency_hz: np.ndarray
    hippus_phase_rad: np.ndarray
    model: PupilModel = PupilModel()

    def __post_init__(self):
        d0 = float(self.base_diameter_m)
        if not (math.isfinite(d0) and d0 > 0):
            raise ValueError(f"base_diameter_m must be finite and > 0, got {d0!r}")
        object.__setattr__(self, "base_diameter_m", d0)
        pairs = (("step_s", "step_m"),
                 ("hippus_amplitude_m", "hippus_frequency_hz", "hippus_phase_rad"))
        for names in pairs:
            arrays = [np.array(getattr(self, n), dtype=np.float64).reshape(-1) for n in names]
            if len({a.shape for a in arrays}) != 1 or not all(np.all(np.isfinite(a))
                                                               for a in arrays):
                raise ValueError(f"{', '.join(names)} must be finite arrays of one length")
            for n, a in zip(names, arrays):
                a.setflags(write=False)
                object.__setattr__(self, n, a)

    def diameter_at(self, t_s) -> np.ndarray:
        """(...) pupil diameter (m) at times ``t_s`` (any shape), seconds."""
        t = np.asarray(t_s, dtype=np.float64)
        m = self.model
        d = np.full(t.shape, self.base_diameter_m)
        for when, size in zip(self.step_s, self.step_m):
            tau = m.constriction_tau_s if size < 0 else m.dilation_tau_s
            d = d + size * _step_response(t - when - m.latency_s, tau)
        arg = (2.0 * np.pi * self.hippus_frequency_hz * t[..., None] + self.hippus_phase_rad)
        d = d + np.sum(self.hippus_amplitude_m * np.sin(arg), axis=-1)
        return np.clip(d, m.min_diameter_mm * 1e-3, m.max_diameter_mm * 1e-3)


def pupil_schedule(duration_s: float, base_diameter_m: float, rng,
                   model: PupilModel = PupilModel()) -> PupilTrace:
    """A seeded :class:`PupilTrace` over [0, duration_s]: hippus, and light changes at the
    model's mean rate (a Poisson process) with uniform sizes.

    Raises
    ------
    ValueError
        A negative or non-finite duration or base diameter.
    """
    if not (math.isfinite(duration_s) and duration_s >= 0):
        raise ValueError(f"duration_s must be finite and >= 0, got {duration_s!r}")
    gen = np.random.default_rng(rng)
    c = model.hippus_components
    lo, hi = model.hippus_band_hz
    freq = np.exp(gen.uniform(math.log(lo), math.log(hi), c))
    phase = gen.uniform(0.0, 2.0 * np.pi, c)
    # A sum of c sinusoids of amplitude a has RMS a sqrt(c / 2).
    amp = np.full(c, model.hippus_rms_mm * 1e-3 / math.sqrt(0.5 * c))
    steps, sizes = [], []
    if model.light_steps_per_min > 0:
        mean_gap = 60.0 / model.light_steps_per_min
        t = float(gen.exponential(mean_gap))
        while t < duration_s:
            steps.append(t)
            sizes.append(float(gen.uniform(*model.light_step_range_mm)) * 1e-3)
            t += float(gen.exponential(mean_gap))
    return PupilTrace(base_diameter_m, np.array(steps), np.array(sizes), amp, freq, phase, model)


def pupil_diameters(trajectory, times_s, default_m: float) -> np.ndarray:
    """(M,) pupil diameters (m) of ``trajectory`` at ``times_s``: its
    ``pupil_diameter_at(t, default_m)`` where it has one (:class:`~scet_render.motion.Trajectory`
    does), else ``default_m`` (the scene's) throughout."""
    at = getattr(trajectory, "pupil_diameter_at", None)
    times = np.atleast_1d(np.asarray(times_s, dtype=np.float64))
    if at is None:
        return np.full(times.shape, float(default_m))
    return np.atleast_1d(np.asarray(at(times, default_m), dtype=np.float64))
