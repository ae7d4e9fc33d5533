"""What every band step of a stream shares and never changes: :class:`BandContext` (the setup,
the calibration and its fit problems, the gaze method, the matcher and the cheap path's
follower, the prior's motion model), with the one switch between the gaze methods
(:meth:`BandContext.batched_estimate`, :meth:`BandContext.gaze_point`) and the acceptance
limits of a band's estimate (:data:`MIN_GLINTS`, :data:`MAX_RESIDUAL_PX`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

import estimator.matching.kernels as match_kernels

from ..calibration import Calibration, GazeMapping
from ..gaze import CalibratedProblems, geometric_gaze, polynomial_gaze
from ..geometry import compiled
from ..matching import BandFollower, GlintMatcher
from ..reasons import Reason
from ..setup import Setup
from .kernel import CheapBand
from .prior_kernel import PriorBand
from .samples import BandPrior

__all__ = ["BandContext", "METHODS", "MIN_GLINTS", "MAX_RESIDUAL_PX"]

METHODS = ("polynomial", "geometric")
#: Fewest identified glints a sample is fitted from. Three unknowns (the cornea centre) need
#: two glints, but a band with 3-4 glints among clutter is fitted by a wrong pose too often:
#: measured on 40 quick-mode frames (320x240, 4 spp, ~50 clutter blobs per frame), samples
#: from 3-4 identified glints had a wrong identity 1 time in 3 (2 % of all identities), those
#: from 5 or more none in 1433.
MIN_GLINTS = 5
#: Largest RMS glint residual (px) of an accepted fit. Measured on quick-mode renders: right
#: identities fit to 0.18 px (median), 0.39 px at most over 289 samples; five clutter blobs in
#: a band without glints, taken for glints, fitted to 1.4-1.7 px.
MAX_RESIDUAL_PX = 1.0


@dataclass(frozen=True, slots=True)
class BandContext:
    """The fixed inputs of a stream's band steps.

    Attributes
    ----------
    setup : Setup
    calibration : Calibration
    method : {"polynomial", "geometric"}
    mapping : str
        The calibration's mapping polynomial gaze uses.
    gaze_map : GazeMapping or None
        That mapping (None for geometric gaze).
    problems : CalibratedProblems
        The calibrated fit problems (free centre and orbit) every fit of the stream uses.
    matcher : GlintMatcher
    follower : BandFollower or None
        The cheap path (None: the hypothesis search on every band).
    prior : BandPrior or None
        Motion model of the prior sparse bands borrow (None: no prior assistance).
    kernel : CheapBand or None
        The cheap path's band step as one compiled call (:mod:`estimator.tracking.kernel`;
        None: the Python form), built by :meth:`with_kernel`.
    prior_kernel : PriorBand or None
        A sparse band's step from the prior as one compiled call
        (:mod:`estimator.tracking.prior_kernel`; None: the Python form), built by
        :meth:`with_kernel`.
    """

    setup: Setup
    calibration: Calibration
    method: str
    mapping: str
    gaze_map: GazeMapping | None
    problems: CalibratedProblems
    matcher: GlintMatcher
    follower: BandFollower | None
    prior: BandPrior | None
    kernel: CheapBand | None = None
    prior_kernel: PriorBand | None = None

    def with_kernel(self) -> BandContext:
        """This context with the compiled band steps of its cheap path and its prior, where
        it has them (:meth:`CheapBand.of`, :meth:`PriorBand.of`)."""
        return replace(self, kernel=CheapBand.of(self, MAX_RESIDUAL_PX),
                       prior_kernel=PriorBand.of(self, MAX_RESIDUAL_PX))

    @property
    def fast_fits(self) -> bool:
        """Whether identified glints are fitted by the small fit first
        (:mod:`estimator.tracking.estimates`): the cheap path, a spherical cornea and point
        lights (a ``"wire_mirror"`` calibration's virtual sources take the batched fits), and
        either the matcher's compiled steps (:data:`estimator.matching.kernels.ENABLED`, read
        now) or no Numba at all (:data:`estimator.geometry.compiled.ENABLED` off: the small
        fit's float form, :mod:`estimator.cornea.scalar`, ~0.3 ms where the batched fit of one
        band costs ~2 ms; measured on 60 synthetic frames: 534 -> 592 samples/s polynomial,
        576 -> 635 geometric, the same samples to 3e-11 m on the screen)."""
        return (self.follower is not None and (match_kernels.ENABLED or not compiled.ENABLED)
                and not self.calibration.conic
                and self.calibration.light_model == "points")

    @property
    def orbit(self):
        """The calibrated orbit problem where there is a prior, else None."""
        return self.problems.orbit if self.prior is not None else None

    @property
    def n_lights(self) -> int:
        return self.setup.lights.count

    def gaze_point(self, center_m, angles_rad) -> np.ndarray:
        """The screen point (2,) of one estimate: the mapping of its cornea centre (3,)
        (polynomial), or where its optical axis from the calibrated eye centre at Fick
        ``angles_rad`` (2,) meets the screen (geometric; NaN where it does not).

        The geometric point is :func:`estimator.gaze.screen_intersection` of
        :func:`estimator.eye.gaze_direction` written out in scalar arithmetic, the same
        operations in the same order: numpy's calls on (1, 3) arrays cost ~20x more for one
        point (measured 287 against 13 us a call on a loaded core; equal to the last bit on
        20,000 random rotations, ``tests/estimator/test_tracking_state.py``)."""
        if self.method == "polynomial":
            return np.array(self.gaze_map.predict_one(center_m))
        yaw, pitch = float(angles_rad[0]), float(angles_rad[1])
        cp = math.cos(pitch)
        dx, dy, dz = cp * math.sin(yaw), math.sin(pitch), -cp * math.cos(yaw)
        c = self.calibration.eye_center_m
        lam = (self.setup.screen.z_m - float(c[2])) / dz if dz != 0.0 else math.nan
        if not (math.isfinite(lam) and lam > 0):
            return np.full(2, np.nan)
        return np.array([float(c[0]) + lam * dx, float(c[1]) + lam * dy])

    def band_glints(self, glints_px, lights) -> np.ndarray:
        """(1, n, 2) glints of one band by light (NaN where a light has none) from the
        identified detections ``glints_px`` (k, 2) of ``lights`` (k,)."""
        out = np.full((1, self.n_lights, 2), np.nan)
        out[0, lights] = glints_px
        return out

    def batched_estimate(self, glints, *, start=None, prior_mean_rad=None, prior_cov_rad2=None):
        """The estimate of one band's glints (1, n, 2) by the batched fits of
        :mod:`estimator.gaze`, the gaze method's (:func:`polynomial_gaze` from the free centre
        ``start`` (3,), :func:`geometric_gaze` from the orbit angles ``start`` (2,); None: the
        function's own start), with the Gaussian prior ``prior_mean_rad`` (2,),
        ``prior_cov_rad2`` (2, 2) when given (noise: the :class:`BandPrior`'s)."""
        prior = {} if prior_mean_rad is None else dict(
            prior_mean_rad=prior_mean_rad, prior_cov_rad2=prior_cov_rad2,
            noise_px=self.prior.noise_px)
        if self.method == "polynomial":
            return polynomial_gaze(self.setup, self.calibration, glints, mapping=self.mapping,
                                   start=start, problems=self.problems, **prior)
        return geometric_gaze(self.setup, self.calibration, glints,
                              start=(0.0, 0.0) if start is None else start,
                              problems=self.problems, **prior)

    @staticmethod
    def reason_of(est) -> str:
        """The reason of a batched estimate of one band: its own, or
        :attr:`Reason.RESIDUAL_TOO_LARGE` where its RMS is above :data:`MAX_RESIDUAL_PX`."""
        reason = str(est.reason[0])
        if reason == Reason.OK and not est.rms_px[0] <= MAX_RESIDUAL_PX:
            return Reason.RESIDUAL_TOO_LARGE
        return reason

    def implausible(self, state, time_s: float, angles_rad) -> bool:
        """Whether ``state``'s last sample rules out the rotation ``angles_rad`` (2,) at
        ``time_s`` (:meth:`StreamState.implausible`; never without a prior)."""
        return self.prior is not None and state.implausible(
            time_s, angles_rad, self.prior.eye_speed_max_deg_s)

    def recent(self, state, time_s: float):
        """:meth:`StreamState.recent` with the prior's speed bound; None without a prior."""
        return None if self.prior is None else state.recent(time_s,
                                                            self.prior.eye_speed_max_deg_s)
