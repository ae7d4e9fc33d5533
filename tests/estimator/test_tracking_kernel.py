"""The cheap path's band step as one compiled call (:mod:`estimator.tracking.kernel`, issue 31)
gives the Python form's samples bit for bit: its mapping of the cornea centre is
``GazeMapping.predict_one`` to the last bit (each power as CPython's ``float ** int``), and on
a stream of simulated saccade frames every sample and state is the one the Python band step
makes, with the compiled step taking the cheap bands."""

from dataclasses import replace

import numpy as np
import pytest

import estimator.tracking.kernel as kernel
import estimator.tracking.prior_kernel as prior_kernel
from estimator.calibration import MAPPING_TERMS, fit_gaze_mapping
from estimator.tracker import Tracker
from estimator.tracking import inverse_2x2
from tests.estimator.test_cheap_path import saccade_frames
from tests.estimator.test_tracker import calibration, setup  # noqa: F401 fixtures

needs_numba = pytest.mark.skipif(not kernel.ENABLED, reason="the compiled step needs Numba")


def test_int_power_is_cpythons_float_power():
    """Every power the mappings use (0-3) of signed, tiny, huge, unit and special values."""
    rng = np.random.default_rng(31)
    z = np.concatenate([rng.normal(0.0, 2.0, 20000), [0.0, -0.0, 1.0, -1.0, 1e-160, -1e100,
                                                       np.inf, -np.inf, np.nan]])
    for e in range(4):
        got = np.array([kernel.int_power(float(v), e) for v in z])
        want = np.array([float(v) ** e for v in z])
        assert np.array_equal(got.view(np.int64), want.view(np.int64)), f"power {e}"


@pytest.mark.parametrize("kind", ["eq1", "quadratic"])
def test_the_compiled_mapping_is_predict_one_to_the_last_bit(kind):
    rng = np.random.default_rng(7)
    scale, offset = np.array([2e-3, 2e-3, 1e-3]), np.array([0.0, 0.0, -4e-3])
    features = rng.normal(0.0, 1.0, (2000, 3)) * scale + offset
    mapping = fit_gaze_mapping(features[:60], rng.uniform(-0.2, 0.2, (60, 2)), kind)
    exps = np.array(MAPPING_TERMS[kind], dtype=np.int64)
    out = np.empty(2)
    for f in features:
        kernel.mapped_point(f, mapping.offset_m, mapping.scale_m, exps, mapping.coefficients,
                            out)
        want = np.array(mapping.predict_one(f))
        assert np.array_equal(out.view(np.int64), want.view(np.int64))



def test_the_compiled_covariance_is_the_sample_steps_to_the_last_bit():
    """:func:`kernel.inverse_scaled` is ``noise_px ** 2 * inverse_2x2(JᵀJ)`` (an infinite
    matrix where that is None) bit for bit: well-conditioned JᵀJ of orbit fits' scale (a few
    glints, ~1e6-1e8 px²/rad²), nearly and exactly singular ones, zero, NaN."""
    rng = np.random.default_rng(5)
    mats = []
    for _ in range(3000):
        J = rng.normal(0.0, 10.0 ** rng.uniform(2, 4), (rng.integers(1, 9), 2))
        mats.append(J.T @ J)
    J = rng.normal(0.0, 1e3, (2000, 1, 2))  # rank one: det within rounding of 0
    mats += [j.T @ j for j in J]
    mats += [np.zeros((2, 2)), np.full((2, 2), np.nan), np.array([[1.0, 1.0], [1.0, 1.0]]),
             np.array([[4.0, 2.0], [2.0, 1.0 + 1e-12]]), np.array([[-1.0, 0.0], [0.0, 2.0]])]
    noise = 0.5
    out = np.empty((2, 2))
    singular = 0
    for A in mats:
        kernel.inverse_scaled(A, noise ** 2, out)
        inv = inverse_2x2(A)
        want = np.full((2, 2), np.inf) if inv is None else noise ** 2 * inv
        singular += inv is None
        assert np.array_equal(out.view(np.int64), want.view(np.int64)), A
    assert singular > 5, "the singular cases are exercised"

class _Counted:
    """A context's compiled step, counting the bands it answers with ``outcome``."""

    def __init__(self, step, outcome):
        self.step, self.outcome, self.answered = step, outcome, 0
        self.polynomial = getattr(step, "polynomial", None)

    def __call__(self, *a):
        out = self.step(*a)
        self.answered += out[0] == self.outcome
        return out


def _same_bits(a, b) -> bool:
    a, b = np.atleast_1d(a), np.atleast_1d(b)
    return (a.shape == b.shape and a.dtype == b.dtype
            and np.array_equal(a.view(np.uint8), b.view(np.uint8)))


@needs_numba
@pytest.mark.parametrize("method", ["polynomial", "geometric"])
def test_the_compiled_step_gives_the_python_forms_samples_bit_for_bit(setup, calibration,  # noqa: F811
                                                                      method):
    # Every third frame dropped: the bands after a gap are sparse or far from the prior, and
    # take the prior-assisted step.
    frames = [(f, img) for f, img in enumerate(saccade_frames(setup, n=9)) if f % 3 != 1]
    out, states = {}, {}
    for compiled in (False, True):
        tr = Tracker(setup, calibration, method)
        if compiled:
            cheap = _Counted(tr.context.kernel, kernel.ACCEPTED)
            prior = _Counted(tr.context.prior_kernel, prior_kernel.ESTIMATED)
            tr.context = replace(tr.context, kernel=cheap, prior_kernel=prior)
        else:
            tr.context = replace(tr.context, kernel=None, prior_kernel=None)
        out[compiled] = [s for f, img in frames for s in tr.process(img, f)]
        states[compiled] = tr.state
    assert cheap.answered >= 10, "the compiled step takes the stream's cheap bands"
    assert prior.answered >= 3, "and its prior-assisted ones"
    assert len(out[True]) == len(out[False]) > 0
    for x, y in zip(out[False], out[True]):
        assert (x.reason, x.prior_assisted, x.time_s) == (y.reason, y.prior_assisted, y.time_s)
        for name in ("screen_xy_m", "cornea_center_m", "glints_px", "light_index",
                     "confidence", "flux_flagged"):
            assert _same_bits(getattr(x, name), getattr(y, name)), name
        assert _same_bits(np.float64(x.residual_px), np.float64(y.residual_px))
    a, b = states[False], states[True]
    for name in ("prior_angles_rad", "start", "velocity_rad_s"):
        u, v = getattr(a, name), getattr(b, name)
        assert (u is None and v is None) or _same_bits(u, v), name
    assert _same_bits(a.last.angles_rad, b.last.angles_rad)
    assert _same_bits(a.last.cov_rad2, b.last.cov_rad2)


def test_no_compiled_step_without_a_cheap_path(setup, calibration):  # noqa: F811
    """The search on every band, and a calibration without the orbit's prior, have none."""
    assert Tracker(setup, calibration, cheap=False).context.kernel is None
    off = Tracker(setup, calibration, "polynomial", prior=None).context
    assert off.kernel is None and off.prior_kernel is None
