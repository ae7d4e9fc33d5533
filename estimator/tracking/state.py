"""The stream's state between bands: :class:`StreamState`, immutable; every band step takes one
and returns the next.

What one band hands the next:

- ``prior_angles_rad``: the eye rotation of the previous band's accepted sample, the prior of
  the next dense band's identification (the cheap path's prediction, the search's window);
  None after a band that failed, so the next dense band is identified cold;
- ``start``: where the next fit starts (the free centre (3,) of polynomial gaze, the orbit
  angles (2,) of geometric gaze); None with ``prior_angles_rad``;
- ``last``: the last accepted sample's time, rotation and covariance (:class:`LastEstimate`),
  kept across failed bands: the Gaussian prior of sparse bands (grown with its age by the
  :class:`~estimator.tracking.BandPrior`), the plausibility check of a band's identification
  (:meth:`StreamState.recent`);
- ``velocity_rad_s``: the eye's angular velocity from the last two accepted samples when they
  are at most :data:`VELOCITY_AGE_S` apart, which carries the prior across the bands between
  two frames' glints.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["StreamState", "LastEstimate", "JUMP_AGE_S", "JUMP_SLACK_DEG", "VELOCITY_AGE_S"]

#: A band identified on its own is checked against the previous sample when that sample is at
#: most this old (s): a little over one frame period, so the first band of a frame is checked
#: against the last of the one before. Older samples do not gate (a wrong one would otherwise
#: hold back the right ones for long).
JUMP_AGE_S = 0.02
#: Slack of that check beyond the turn the eye can make, v_max √2 Δt (v_max per axis, the
#: :class:`BandPrior`'s): the two samples' estimation error. In the full validation, three
#: 5-glint bands of clutter with no glint at all (top rows, dielectric renders) were matched
#: to a chain 19-28 deg away from the previous sample 1 ms before; right samples differ from
#: the previous one by well under a degree.
JUMP_SLACK_DEG = 2.0
#: The eye's velocity is measured from two samples at most this far apart (s): neighbouring
#: bands (1.04 ms at 16 pulses per frame, 2.08 ms at 8), where 0.05° of estimation error
#: makes 25-50°/s, against saccades at hundreds.
VELOCITY_AGE_S = 2.5e-3


@dataclass(frozen=True, slots=True)
class LastEstimate:
    """The last accepted sample as a prior.

    Attributes
    ----------
    time_s : float
    angles_rad : (2,) float
        Fick (yaw, pitch).
    cov_rad2 : (2, 2) float
        Its covariance: the fit's σ² (JᵀJ)⁻¹, or a prior-assisted fit's posterior.
    """

    time_s: float
    angles_rad: np.ndarray
    cov_rad2: np.ndarray


@dataclass(frozen=True, slots=True)
class StreamState:
    """What the tracker knows between two bands (see the module docstring); the default is a
    stream that has no sample yet."""

    prior_angles_rad: np.ndarray | None = None
    start: np.ndarray | None = None
    last: LastEstimate | None = None
    velocity_rad_s: np.ndarray | None = None

    def lost(self) -> StreamState:
        """After a failed band: the next dense band is matched cold (the prior of sparse bands,
        ``last``, is kept; it grows with its age)."""
        if self.prior_angles_rad is None and self.start is None:
            return self
        return StreamState(None, None, self.last, self.velocity_rad_s)

    def estimated(self, time_s: float, angles_rad, cov_rad2, *, prior_angles_rad,
                  start) -> StreamState:
        """The state after an accepted sample at ``time_s`` of rotation ``angles_rad`` (2,)
        and covariance ``cov_rad2`` (2, 2); the velocity where the sample before it is at most
        :data:`VELOCITY_AGE_S` older."""
        angles = np.array(angles_rad, dtype=np.float64)
        velocity = None
        last = self.last
        if last is not None and 0 < time_s - last.time_s <= VELOCITY_AGE_S:
            velocity = (angles - last.angles_rad) / (time_s - last.time_s)
        return StreamState(prior_angles_rad, start, LastEstimate(time_s, angles, cov_rad2),
                           velocity)

    def fresh_prior(self) -> bool:
        """Whether the previous band gave an accepted sample (its rotation is the prior)."""
        return self.prior_angles_rad is not None

    def carried_prior(self, time_s: float):
        """The rotation (2,) the last sample predicts at ``time_s`` when it is at most
        :data:`JUMP_AGE_S` old: its own, carried on at the eye's last measured velocity; else
        None."""
        last = self.last
        if last is None or not 0 <= time_s - last.time_s <= JUMP_AGE_S:
            return None
        prior = last.angles_rad
        if self.velocity_rad_s is not None:
            prior = prior + self.velocity_rad_s * (time_s - last.time_s)
        return prior

    def recent(self, time_s: float, eye_speed_max_deg_s: float):
        """(mean (2,), covariance (2, 2), age s, reach rad) of the last sample where it is at
        most :data:`JUMP_AGE_S` old, else None. Reach: the furthest the eye turns since at
        ``eye_speed_max_deg_s`` per axis, v_max √2 Δt, plus :data:`JUMP_SLACK_DEG`."""
        last = self.last
        if last is None:
            return None
        dt = time_s - last.time_s
        if not 0 <= dt <= JUMP_AGE_S:
            return None
        reach = math.radians(eye_speed_max_deg_s * math.sqrt(2.0) * dt + JUMP_SLACK_DEG)
        return last.angles_rad, last.cov_rad2, dt, reach

    def implausible(self, time_s: float, angles_rad, eye_speed_max_deg_s: float) -> bool:
        """Whether the eye rotation ``angles_rad`` is further from the last sample's than the
        eye turns in the time between them (:meth:`recent`)."""
        recent = self.recent(time_s, eye_speed_max_deg_s)
        return recent is not None and math.hypot(float(angles_rad[0] - recent[0][0]),
                                                 float(angles_rad[1] - recent[0][1])) > recent[3]
