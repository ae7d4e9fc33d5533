"""Gaze from glints: geometric (Sec. 2.2.1) and polynomial (Sec. 2.2.2) estimation.

Geometric: fit the cornea centre on its orbit (Fick angles about the calibrated eye centre c_e,
radius r_co) to the sample's glints, then intersect the optical axis, the ray from c_e through
the cornea centre, with the screen plane. Polynomial: fit the cornea centre alone (known r_c and
lighting) and map it to the screen with a calibrated :class:`~estimator.calibration.GazeMapping`.

Both are batched: a batch of samples is fitted at once by :func:`estimator.cornea.fit_cornea`
(``solver="lm"``, ours) from a shared start, or one sample after another from the previous
sample's estimate (``chain=True``: the paper's warm start, Sec. 2.2.1; with ``solver="trf"``
this is the paper's reference). A stream passes :attr:`GazeEstimates.resume_from` of one
batch as the ``start`` of the next. A sample that cannot be estimated is NaN with a reason
code (:data:`REASONS`); the batch always completes.

Both take an optional Gaussian prior on the eye rotation (Fick angles about c_e, with a
covariance in rad²), the tracker's estimate carried over from the previous band: the cornea is
then fitted on its calibrated orbit with the prior (:func:`estimator.cornea.fit_cornea`,
``prior_mean`` / ``prior_information``), which makes one glint enough. Polynomial gaze maps
that orbit fit's cornea centre: its own model, the free centre (3 unknowns), is not determined
by one glint, and a prior on the centre would have to take its shape (a thin disc tangent to
the orbit, spread by the eye's rotation) from the same c_e and r_co.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from .calibration import Calibration, GazeMapping
from .cornea import (
    NON_FINITE,
    NOT_CONVERGED,
    OK,
    TOO_FEW_GLINTS,
    CorneaFit,
    FitProblem,
    fit_cornea,
    fit_cornea_conic,
    fit_covariance,
    refit_on_wire,
)
from .eye import gaze_direction
from .geometry.wire_fast import WireLights
from .reasons import Reason

#: The optical axis does not reach the screen plane (it points away from it).
MISSES_SCREEN = Reason.MISSES_SCREEN.value
REASONS = (OK, TOO_FEW_GLINTS, NOT_CONVERGED, NON_FINITE, MISSES_SCREEN)
#: Bounds on the orbit fit's Fick angles (rad). The human oculomotor range is about +/-50 deg;
#: the bound only keeps the solver on the front half of the orbit, where the optical axis can
#: reach the screen (TRF needs finite bounds to be the paper's bounded solver).
ANGLE_BOUND_RAD = np.deg2rad(80.0)


@dataclass(frozen=True, slots=True)
class GazeEstimates:
    """Gaze of B samples.

    Attributes
    ----------
    point_m : (B, 3) float
        Estimated gaze point on the screen plane (NaN where the sample failed).
    cornea_center_m : (B, 3) float
        Fitted cornea centre.
    angles_rad : (B, 2) float
        Fick (yaw, pitch) about c_e of orbit fits: geometric gaze, and polynomial gaze's
        samples with a prior; NaN otherwise.
    rms_px : (B,) float
        RMS glint residual of the cornea fit.
    reason : (B,) str
        One of :data:`REASONS`.
    method : str
    """

    point_m: np.ndarray
    cornea_center_m: np.ndarray
    angles_rad: np.ndarray
    rms_px: np.ndarray
    reason: np.ndarray
    method: str

    @property
    def ok(self) -> np.ndarray:
        return self.reason == OK

    @property
    def screen_xy_m(self) -> np.ndarray:
        """(B, 2) screen coordinates."""
        return self.point_m[:, :2]

    @property
    def resume_from(self):
        """Start for the next batch of a stream: the last successful fit's parameters (Fick
        angles for geometric gaze, cornea centre for polynomial gaze), or None."""
        idx = np.flatnonzero(self.ok)
        if idx.size == 0:
            return None
        return (self.angles_rad if self.method == "geometric" else self.cornea_center_m)[idx[-1]].copy()


@dataclass(frozen=True, slots=True)
class CalibratedProblems:
    """The fit problems of one calibration on one setup: built once (:func:`calibrated_problems`)
    and reused by every band of a stream, by the tracker, its matcher and the gaze functions.

    Attributes
    ----------
    center : FitProblem
        The ``"center"`` problem of polynomial gaze: corrected lights and r_c.
    orbit : FitProblem or None
        The ``"orbit"`` problem of geometric gaze (:func:`orbit_problem`); None without the
        calibration's eye centre and orbit radius.
    """

    center: FitProblem
    orbit: FitProblem | None
    wire: WireLights | None = None


def calibrated_problems(setup, calibration: Calibration) -> CalibratedProblems:
    """The :class:`CalibratedProblems` of ``calibration`` on ``setup``."""
    wire = wire_lights(setup, calibration)
    lights = calibrated_lights(setup, calibration, wire)
    center = FitProblem(setup.camera, lights, calibration.cornea_radius_m)
    orbit = orbit_problem(setup, calibration, lights) if calibration.has_orbit else None
    return CalibratedProblems(center, orbit, wire)


def wire_lights(setup, calibration: Calibration) -> WireLights | None:
    """The calibrated wire mirror's virtual sources when ``calibration.light_model`` is
    ``"wire_mirror"`` (the fits then refine the point-source answer on them:
    :func:`estimator.cornea.refit_on_wire`), else None."""
    if calibration.light_model != "wire_mirror":
        return None
    return WireLights.from_setup(setup, calibration.lighting_correction)


def calibrated_lights(setup, calibration: Calibration, wire: WireLights | None = None) -> np.ndarray:
    """(n, 3) the point lights of the point-source fits and of the matcher: the calibrated
    lights; for a ``"wire_mirror"`` calibration each turn's virtual source at the calibrated
    eye's primary gaze (the highlights' fixed part, so that identification and the point fit
    that starts the wire fit see only the part that moves with the eye: 0.5-1.2 px RMS on
    prototype_ov5647_wire, against 1.5-2.2 px of fixed offset at the turns' axes)."""
    if calibration.light_model != "wire_mirror":
        return calibration.lights_world_m(setup.lights_world_m)
    wire = wire_lights(setup, calibration) if wire is None else wire
    if calibration.has_orbit:
        c = calibration.eye_center_m + calibration.orbit_radius_m * gaze_direction(0.0, 0.0)
    else:
        c = calibration.lighting_correction.apply(setup.eye.cornea_center(0.0, 0.0))
    W, ok = wire.sources(np.reshape(c, (1, 3)), calibration.cornea_radius_m)
    return np.where(ok[0][:, None] & np.isfinite(W[0]), W[0], wire.points_m)


def orbit_problem(setup, calibration: Calibration, lights=None) -> FitProblem:
    """The calibrated ``"orbit"`` fit problem: corrected lights (:func:`calibrated_lights`, or
    ``lights`` (n, 3) when the caller has them), r_c, c_e and r_co."""
    if not calibration.has_orbit:
        raise ValueError("the orbit model needs a calibration with the eye centre and orbit radius")
    return FitProblem(setup.camera, calibrated_lights(setup, calibration) if lights is None else lights,
                      calibration.cornea_radius_m, calibration.eye_center_m,
                      calibration.orbit_radius_m)


def prior_information(prior_cov_rad2, noise_px: float) -> np.ndarray:
    """(B, 2, 2) prior information σ² Σ⁻¹ (px² / rad²) of prior covariances Σ (B, 2, 2) rad²
    for glint noise σ = ``noise_px``; NaN where Σ is not finite or not positive definite."""
    cov = np.asarray(prior_cov_rad2, dtype=np.float64).reshape(-1, 2, 2)
    out = np.full(cov.shape, np.nan)
    fin = np.isfinite(cov).all(axis=(1, 2))
    if fin.any():
        w, V = np.linalg.eigh(cov[fin])
        pd = w.min(axis=1) > 0
        info = noise_px ** 2 * (V / np.where(w > 0, w, 1.0)[:, None, :]) @ np.swapaxes(V, 1, 2)
        sub = np.full((fin.sum(), 2, 2), np.nan)
        sub[pd] = info[pd]
        out[fin] = sub
    return out


def posterior_covariance(problem: FitProblem, angles_rad, mask, prior_cov_rad2,
                         noise_px: float) -> np.ndarray:
    """(B, 2, 2) covariance of orbit fits at ``angles_rad`` (B, 2) from the glints in ``mask``
    (B, n) and a Gaussian prior of covariance ``prior_cov_rad2`` (B, 2, 2; NaN = none):
    (Σ_glints⁻¹ + Σ_prior⁻¹)⁻¹, Σ_glints = σ² (JᵀJ)⁻¹ (:func:`estimator.cornea.fit_covariance`).
    Glints that leave an angle undetermined add nothing; NaN where neither term is finite."""
    angles = np.asarray(angles_rad, dtype=np.float64).reshape(-1, 2)
    cg = fit_covariance(problem, angles, mask, model="orbit", noise_px=noise_px)
    cp = np.broadcast_to(np.asarray(prior_cov_rad2, dtype=np.float64), cg.shape)
    info = np.zeros(cg.shape)
    known = np.zeros(cg.shape[0], dtype=bool)
    for c in (cg, cp):
        fin = np.isfinite(c).all(axis=(1, 2))
        if fin.any():
            info[fin] += np.linalg.inv(c[fin])
            known |= fin
    out = np.full(cg.shape, np.nan)
    if known.any():
        out[known] = np.linalg.inv(info[known])
    return out


def conic_of(calibration: Calibration):
    """``(Q, c_e)`` of a calibration whose cornea model is the conic, else None (the sphere)."""
    return (calibration.cornea_asphericity, calibration.eye_center_m) if calibration.conic else None


def _fit(problem, glints_px, mask, start, model, solver, chain, lower, upper, max_iter,
         prior_mean=None, prior_information=None, conic=None, wire=None):
    """fit_cornea over a batch, from a shared start or chained sample to sample; with
    ``conic`` = (Q, c_e), :func:`estimator.cornea.fit_cornea_conic` instead; with ``wire``
    (:class:`WireLights`), refined on the virtual sources."""
    if wire is not None:
        point = _fit(problem, glints_px, mask, start, model, solver, chain, lower, upper,
                     max_iter, prior_mean, prior_information, conic)
        glints = np.asarray(glints_px, dtype=np.float64).reshape(-1, wire.count, 2)
        m = np.isfinite(glints).all(axis=-1) if mask is None else np.asarray(mask, bool).reshape(glints.shape[:2])
        return refit_on_wire(problem, wire, glints, m, point, model, start, lower=lower,
                             upper=upper, prior_mean=prior_mean, prior_information=prior_information)
    fit = fit_cornea if conic is None else partial(
        fit_cornea_conic, asphericity=conic[0], eye_center_m=conic[1],
        conic_start=conic[2] if len(conic) > 2 else None)
    glints = np.asarray(glints_px, dtype=np.float64)
    if glints.ndim == 2:
        glints = glints[None]
    if mask is None:
        mask = np.isfinite(glints).all(axis=-1)
    mask = np.asarray(mask, dtype=bool).reshape(glints.shape[:2])
    if prior_mean is not None:
        if chain:
            raise ValueError("a prior per sample and chain=True exclude each other")
        return fit(problem, glints, mask, start, model=model, solver=solver, lower=lower,
                   upper=upper, max_iter=max_iter, prior_mean=prior_mean,
                   prior_information=prior_information)
    if not chain:
        return fit(problem, glints, mask, start, model=model, solver=solver, lower=lower,
                   upper=upper, max_iter=max_iter)
    x = np.asarray(start, dtype=np.float64)
    fits = []
    for b in range(glints.shape[0]):
        f = fit(problem, glints[b:b + 1], mask[b:b + 1], x, model=model, solver=solver,
                lower=lower, upper=upper, max_iter=max_iter)
        fits.append(f)
        if f.ok[0]:
            x = f.angles_rad[0] if model == "orbit" else f.center_m[0]
    return CorneaFit(*(np.concatenate([getattr(f, name) for f in fits]) for name in CorneaFit.__slots__))


def screen_intersection(eye_center_m, directions, screen_z_m: float):
    """Points where rays from ``eye_center_m`` along (B, 3) ``directions`` meet the plane
    z = ``screen_z_m``; NaN (and False) where a ray points away from it."""
    c = np.asarray(eye_center_m, dtype=np.float64).reshape(3)
    d = np.asarray(directions, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (screen_z_m - c[2]) / d[:, 2]
    hits = np.isfinite(lam) & (lam > 0)
    lam = np.where(hits, lam, np.nan)
    return c + lam[:, None] * d, hits


def _estimates(fit, points, hits, method, angles, miss_reason=MISSES_SCREEN):
    """Gaze estimates from a cornea fit; fitted samples whose point is not ``hits`` fail with
    ``miss_reason``."""
    reason = fit.reason.astype(object)
    reason[(reason == OK) & ~hits] = miss_reason
    bad = reason != OK
    points = np.where(bad[:, None], np.nan, points)
    return GazeEstimates(points, fit.center_m, angles, fit.rms_px, reason.astype(str), method)


def _prior_args(prior_mean_rad, prior_cov_rad2, noise_px, B: int):
    """(mean (B, 2), information (B, 2, 2), present (B,)) of an angle prior, or None."""
    if prior_mean_rad is None and prior_cov_rad2 is None:
        return None
    if prior_mean_rad is None or prior_cov_rad2 is None or noise_px is None:
        raise ValueError("prior_mean_rad, prior_cov_rad2 and noise_px must be given together")
    if not noise_px > 0:
        raise ValueError(f"noise_px must be positive, got {noise_px!r}")
    mean = np.asarray(prior_mean_rad, dtype=np.float64)
    cov = np.asarray(prior_cov_rad2, dtype=np.float64)
    if mean.shape not in ((2,), (B, 2)) or cov.shape not in ((2, 2), (B, 2, 2)):
        raise ValueError(f"prior_mean_rad must have shape ({B}, 2) and prior_cov_rad2 "
                         f"({B}, 2, 2), got {mean.shape} and {cov.shape}")
    mean = np.broadcast_to(mean, (B, 2))
    info = prior_information(np.broadcast_to(cov, (B, 2, 2)), noise_px)
    present = np.isfinite(mean).all(axis=1) & np.isfinite(info).all(axis=(1, 2))
    return mean, info, present


def _batch(glints_px) -> int:
    return 1 if np.ndim(glints_px) == 2 else int(np.shape(glints_px)[0])


def _orbit_fit(problem, glints_px, mask, start, chain, solver, max_iter, prior, conic=None,
               wire=None):
    lim = np.full(2, ANGLE_BOUND_RAD)
    if prior is None:
        return _fit(problem, glints_px, mask, start, "orbit", solver, chain, -lim, lim, max_iter,
                    conic=conic, wire=wire)
    mean, info, present = prior
    x0 = np.where(present[:, None], mean, np.broadcast_to(np.asarray(start, np.float64), mean.shape))
    return _fit(problem, glints_px, mask, x0, "orbit", solver, False, -lim, lim, max_iter,
                prior_mean=mean, prior_information=info, conic=conic, wire=wire)


def geometric_gaze(setup, calibration: Calibration, glints_px, mask=None, *, start=(0.0, 0.0),
                   chain: bool = False, solver: str = "lm", max_iter: int = 50,
                   prior_mean_rad=None, prior_cov_rad2=None, noise_px: float | None = None,
                   problems: CalibratedProblems | None = None) -> GazeEstimates:
    """Geometric gaze estimation (Sec. 2.2.1): cornea on its orbit, optical axis to the screen.

    Parameters
    ----------
    setup : Setup
        Camera, nominal lights and screen.
    calibration : Calibration
        Lighting correction, r_c, c_e and r_co.
    glints_px : (B, n, 2) float
        Detected glints (NaN = missing), lights in the setup's order.
    mask : (B, n) bool, optional
    start : (2,) float
        Fick (yaw, pitch) to start from: the primary position (0, 0) for the first sample, as in
        the paper; the previous batch's :attr:`GazeEstimates.resume_from` in a stream.
    chain : bool
        Start each sample from the previous sample's estimate (the paper's warm start) instead of
        fitting the batch at once from ``start``.
    solver : {"lm", "trf"}
    prior_mean_rad : (B, 2) or (2,) float, optional
        Gaussian prior on the Fick angles (mean); a sample whose mean or covariance is not
        finite has none. Samples with a prior start from its mean.
    prior_cov_rad2 : (B, 2, 2) or (2, 2) float, optional
        Its covariance Σ (rad²).
    noise_px : float, optional
        Glint noise σ (px per axis) that weighs the prior against the glints (information
        σ² Σ⁻¹); required with a prior.
    problems : CalibratedProblems, optional
        The calibration's problems, built once by the caller (:func:`calibrated_problems`);
        default: built for this call.
    """
    if not calibration.has_orbit:
        raise ValueError("geometric gaze needs a calibration with the eye centre and orbit radius")
    problem = orbit_problem(setup, calibration) if problems is None else problems.orbit
    prior = _prior_args(prior_mean_rad, prior_cov_rad2, noise_px, _batch(glints_px))
    wire = wire_lights(setup, calibration) if problems is None else problems.wire
    fit = _orbit_fit(problem, glints_px, mask, start, chain, solver, max_iter, prior,
                     conic_of(calibration), wire)
    points, hits = screen_intersection(calibration.eye_center_m,
                                       gaze_direction(fit.angles_rad[:, 0], fit.angles_rad[:, 1]),
                                       setup.screen.z_m)
    return _estimates(fit, points, hits, "geometric", fit.angles_rad)


def fit_cornea_centers(setup, calibration: Calibration, glints_px, mask=None, *, start=None,
                       chain: bool = False, solver: str = "lm", max_iter: int = 50,
                       problems: CalibratedProblems | None = None) -> CorneaFit:
    """Cornea centres (the ``"center"`` model: known r_c and calibrated lighting) of a batch of
    samples: the features of polynomial gaze, for calibrating a mapping and for using it. With
    a conic calibration (``cornea_model = "conic"``) the feature is the conic orbit fit's
    centre (the calibrated c_e and r_co constrain it; comment below), unless ``chain``.

    ``start`` is the initial centre, by default the nominal eye's at primary position (the
    paper's, Sec. 2.2.1); ``chain`` and ``solver`` as in :func:`geometric_gaze`.
    """
    problems = calibrated_problems(setup, calibration) if problems is None else problems
    x0 = setup.eye.cornea_center(0.0, 0.0) if start is None else start
    conic = conic_of(calibration)
    if conic is not None and problems.orbit is not None and not chain:
        # A conic's feature is the centre on the calibrated orbit (the conic orbit fit), not
        # the free centre: a band's glints determine the free centre's 3 unknowns less well on
        # a conic than on a sphere (lateral scatter 1.3-1.7x at 0.3 px of noise), and Eq. (1)
        # amplifies it (quick renders, Q = -0.25: 0.93 deg against 0.64 at Q = 0 with the
        # free centre). The conic calibration has c_e and r_co in any case.
        lim = np.full(2, ANGLE_BOUND_RAD)
        return _fit(problems.orbit, glints_px, mask, (0.0, 0.0), "orbit", solver, False, -lim,
                    lim, max_iter, conic=conic)
    return _fit(problems.center, glints_px, mask, x0, "center", solver, chain, None, None,
                max_iter, conic=conic, wire=problems.wire)


def polynomial_gaze(setup, calibration: Calibration, glints_px, mask=None, *, mapping="eq1_25",
                    distance=None, start=None, chain: bool = False, solver: str = "lm",
                    max_iter: int = 50, prior_mean_rad=None, prior_cov_rad2=None,
                    noise_px: float | None = None,
                    problems: CalibratedProblems | None = None) -> GazeEstimates:
    """Polynomial gaze estimation (Sec. 2.2.2): cornea centre, then a calibrated mapping.

    Parameters
    ----------
    setup, calibration, glints_px, mask, chain, solver
        As :func:`geometric_gaze` (only the lighting correction and r_c of the calibration are
        used, besides the mapping).
    mapping : str or GazeMapping
        A mapping, or the name of one in ``calibration.mappings``.
    distance : (B,) float, optional
        Distance-sensor readings d_a, required by ``quadratic_da`` mappings (Sec. 3.3.1).
    start : (3,) float, optional
        Initial cornea centre; default the nominal eye's at primary position (the paper's).
    prior_mean_rad, prior_cov_rad2, noise_px
        As :func:`geometric_gaze`. A sample with a prior gets its cornea centre from the orbit
        fit with the prior (the calibration's c_e and r_co; module docstring), the others
        from the free-centre fit.
    """
    if isinstance(mapping, str):
        if mapping not in calibration.mappings:
            raise ValueError(f"no gaze mapping {mapping!r} in the calibration "
                             f"(has {sorted(calibration.mappings)})")
        mapping = calibration.mappings[mapping]
    if not isinstance(mapping, GazeMapping):
        raise ValueError(f"mapping must be a GazeMapping or its name, got {type(mapping).__name__}")
    prior = _prior_args(prior_mean_rad, prior_cov_rad2, noise_px, _batch(glints_px))
    if prior is not None and prior[2].any():
        if not calibration.has_orbit:
            raise ValueError("a prior on the eye rotation needs a calibration with the eye "
                             "centre and orbit radius")
        orbit = orbit_problem(setup, calibration) if problems is None else problems.orbit
        fit = _merge(prior[2],
                     _orbit_fit(orbit, glints_px, mask, (0.0, 0.0), False, solver, max_iter,
                                prior, conic_of(calibration),
                                wire_lights(setup, calibration) if problems is None else problems.wire),
                     fit_cornea_centers(setup, calibration, glints_px, mask, start=start,
                                        chain=chain, solver=solver, max_iter=max_iter,
                                        problems=problems))
    else:
        fit = fit_cornea_centers(setup, calibration, glints_px, mask, start=start, chain=chain,
                                 solver=solver, max_iter=max_iter, problems=problems)
    features = fit.center_m
    if mapping.n_features == 4:
        if distance is None:
            raise ValueError(f"the {mapping.kind!r} mapping needs the distance readings d_a")
        d = np.asarray(distance, dtype=np.float64).reshape(-1)
        if d.shape != (features.shape[0],):
            raise ValueError(f"distance must have shape ({features.shape[0]},), got {d.shape}")
        features = np.column_stack([features, d])
    xy = mapping.predict(features)
    points = np.column_stack([xy, np.full(len(xy), setup.screen.z_m)])
    return _estimates(fit, points, np.isfinite(xy).all(axis=1), "polynomial", fit.angles_rad,
                      miss_reason=NON_FINITE)


def _merge(take_first, first: CorneaFit, second: CorneaFit) -> CorneaFit:
    """Per sample, ``first``'s result where ``take_first`` (B,) else ``second``'s."""
    def pick(a, b):
        m = np.asarray(take_first).reshape((-1,) + (1,) * (np.ndim(a) - 1))
        return np.where(m, a, b)
    return CorneaFit(*(pick(getattr(first, n), getattr(second, n)) for n in CorneaFit.__slots__))
