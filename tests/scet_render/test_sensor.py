"""The sensor model: photon transfer, black level, clipping, quantisation, determinism."""

import math

import numpy as np
import pytest

from estimator.scene import load_scene
from scet_render.render import (
    CORNEA_FRESNEL_REFLECTANCE,
    GLINT_SATURATION_FRACTION,
    REFERENCE_EMITTER_RADIANCE,
    SensorModel,
)

#: Pixels per flat field: 2^16 samples put the standard error of a variance at
#: sqrt(2 / n) = 0.55 % of it.
FLAT_SHAPE = (256, 256)
#: Statistical tolerance, in standard errors: a false failure has odds of about 1 in 1.7 million
#: per comparison.
N_SE = 5.0


def flat(model: SensorModel, electrons: float, shape=FLAT_SHAPE) -> np.ndarray:
    """Radiance image whose pixels collect ``electrons`` photo-electrons on average."""
    return np.full(shape, electrons / model.electrons_per_radiance, dtype=np.float32)


def ptc_variance(model: SensorModel, mean_e: float) -> float:
    """Photon-transfer variance in output DN^2: shot + read noise over K^2, plus quantisation."""
    K = model.electrons_per_dn
    return mean_e / K**2 + (model.read_noise_e / K) ** 2 + 1.0 / 12.0


@pytest.fixture(scope="module")
def ov5647():
    return SensorModel()


# --------------------------------------------------------------------------- photon transfer


@pytest.mark.parametrize("gain", [1.0, 2.0])
@pytest.mark.parametrize("signal_e", [30.0, 300.0, 1500.0])
def test_flat_field_mean_and_variance_follow_the_photon_transfer_curve(signal_e, gain):
    model = SensorModel(analog_gain=gain, dark_current_e_per_s=0.0)
    dn = model.apply(flat(model, signal_e), rng=11).astype(np.float64)
    K, n = model.electrons_per_dn, dn.size
    want_var = ptc_variance(model, signal_e)
    assert abs(dn.mean() - (model.black_level_dn + signal_e / K)) < N_SE * math.sqrt(want_var / n)
    assert abs(dn.var(ddof=1) - want_var) < N_SE * want_var * math.sqrt(2.0 / (n - 1))


def test_photon_transfer_slope_is_one_over_the_conversion_gain():
    """Fit var = mean / K + c over a sweep of flat fields (the way sensors are characterised)."""
    model = SensorModel(dark_current_e_per_s=0.0)
    levels = np.linspace(100.0, 3000.0, 8)
    means, variances = [], []
    for i, e in enumerate(levels):
        dn = model.apply(flat(model, e, (128, 128)), rng=100 + i).astype(np.float64)
        means.append(dn.mean() - model.black_level_dn)
        variances.append(dn.var(ddof=1))
    # Each variance has a 1.1 % standard error, so the slope is known to about 1 %; the
    # intercept (read noise + quantisation, 0.6 DN^2) is lost in that scatter and is checked on
    # dark frames instead.
    slope, _ = np.polyfit(means, variances, 1)
    assert slope == pytest.approx(1.0 / model.electrons_per_dn, rel=0.03)


def test_dark_frame_sits_on_the_black_level(ov5647):
    no_dark = SensorModel(dark_current_e_per_s=0.0)
    dn = no_dark.apply(np.zeros(FLAT_SHAPE), rng=5).astype(np.float64)
    want_var = ptc_variance(no_dark, 0.0)
    assert abs(dn.mean() - 16.0) < N_SE * math.sqrt(want_var / dn.size)
    assert dn.var(ddof=1) == pytest.approx(want_var, rel=N_SE * math.sqrt(2 / dn.size))
    # The datasheet's worst-case dark current adds 0.125 e- in 1 ms: 0.035 DN.
    dark = ov5647.apply(np.zeros(FLAT_SHAPE), rng=5).astype(np.float64)
    mean_e = ov5647.dark_current_e_per_s * ov5647.exposure_s
    assert abs(dark.mean() - (16.0 + mean_e / ov5647.electrons_per_dn)) < N_SE * math.sqrt(
        ptc_variance(ov5647, mean_e) / dark.size)


def test_black_level_at_8_bit_is_a_quarter():
    m8 = SensorModel(bit_depth=8, dark_current_e_per_s=0.0, read_noise_e=0.0)
    assert m8.black_level_output_dn == 4.0
    assert np.all(m8.apply(np.zeros((4, 4)), rng=0) == 4)


# --------------------------------------------------------------------------- clipping


def test_ov5647_saturates_in_the_adc_before_the_full_well(ov5647):
    assert ov5647.saturation_e == pytest.approx((1023 - 16) * 3.54)
    assert ov5647.saturation_e < ov5647.full_well_e
    dn = ov5647.apply(flat(ov5647, 2.0 * ov5647.full_well_e, (64, 64)), rng=1)
    assert np.all(dn == 1023)


def test_full_well_clips_the_charge_when_the_adc_has_headroom():
    # 5 e-/DN: the ADC spans (1023 - 16) * 5 = 5035 e-, more than the 4300 e- well.
    model = SensorModel(conversion_gain_e_per_dn=5.0, read_noise_e=0.0, dark_current_e_per_s=0.0)
    plateau = round(16 + 4300 / 5.0)  # 876 DN
    for electrons in (1.2 * 4300, 10 * 4300, 1e12):
        dn = model.apply(flat(model, electrons, (32, 32)), rng=2)
        assert np.all(dn == plateau)
    # With read noise the plateau keeps only the read noise (the shot noise is gone).
    noisy = SensorModel(conversion_gain_e_per_dn=5.0, dark_current_e_per_s=0.0)
    dn = noisy.apply(flat(noisy, 3 * 4300), rng=3).astype(np.float64)
    assert abs(dn.mean() - (16 + 4300 / 5.0)) < 0.05
    assert dn.var(ddof=1) == pytest.approx((2.5 / 5.0) ** 2 + 1 / 12, rel=0.05)


def test_huge_radiance_does_not_overflow_the_poisson_sampler(ov5647):
    dn = ov5647.apply(np.array([[1e30, 0.0], [3e38, 1e-30]]), rng=0)
    assert dn[0, 0] == 1023 and dn[1, 0] == 1023


# --------------------------------------------------------------------------- quantisation


@pytest.mark.parametrize("bits, top", [(10, 1023), (8, 255)])
def test_output_codes_span_exactly_the_bit_depth(bits, top):
    model = SensorModel(bit_depth=bits)
    rng = np.random.default_rng(0)
    electrons = np.concatenate([np.zeros(500), rng.uniform(0, 6000, 5000), np.full(500, 1e6)])
    dn = model.apply(electrons / model.electrons_per_radiance, rng=4)
    assert dn.dtype == np.uint16
    assert dn.min() >= 0 and dn.max() == top
    assert np.array_equal(dn, np.floor(dn))


def test_8_bit_output_is_the_10_bit_code_without_its_two_low_bits():
    radiance = np.random.default_rng(1).uniform(0, 0.05, (64, 64))
    dn10 = SensorModel(bit_depth=10).apply(radiance, rng=9)
    dn8 = SensorModel(bit_depth=8).apply(radiance, rng=9)
    assert np.array_equal(dn8, dn10 >> 2)


# --------------------------------------------------------------------------- exposure scale


def test_default_glint_lands_near_but_below_saturation(ov5647):
    glint = CORNEA_FRESNEL_REFLECTANCE * REFERENCE_EMITTER_RADIANCE
    assert ov5647.mean_electrons(glint) == pytest.approx(
        GLINT_SATURATION_FRACTION * ov5647.saturation_e, rel=1e-3)
    dn = ov5647.apply(np.full((64, 64), glint), rng=7)
    assert np.all(dn < 1023)  # 0.7 of saturation is 18 shot-noise SDs below it
    assert dn.mean() == pytest.approx(16 + 0.7 * (1023 - 16), abs=1.0)


def test_with_glint_level_rescales_the_exposure(ov5647):
    m = ov5647.with_glint_level(2.0, fraction=0.5)
    assert m.mean_electrons(2.0) == pytest.approx(0.5 * m.saturation_e + 0.125)
    with pytest.raises(ValueError, match="fraction"):
        ov5647.with_glint_level(1.0, fraction=1.5)
    with pytest.raises(ValueError, match="glint_radiance"):
        ov5647.with_glint_level(0.0)


def test_cornea_reflects_2_5_percent():
    assert CORNEA_FRESNEL_REFLECTANCE == pytest.approx(0.02504, abs=1e-5)


# --------------------------------------------------------------------------- determinism


def test_same_seed_gives_byte_identical_output(ov5647):
    radiance = np.random.default_rng(2).uniform(0, 0.03, (48, 64)).astype(np.float32)
    a = ov5647.apply(radiance, rng=123)
    assert a.tobytes() == ov5647.apply(radiance, rng=123).tobytes()
    assert a.tobytes() == ov5647.apply(radiance, np.random.default_rng(123)).tobytes()
    assert a.tobytes() == ov5647.apply(radiance, np.random.SeedSequence(123)).tobytes()
    assert a.tobytes() != ov5647.apply(radiance, rng=124).tobytes()
    assert a.shape == radiance.shape


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("bad, match", [(np.nan, "non-finite"), (np.inf, "non-finite"),
                                        (-1e-6, "negative")])
def test_bad_radiance_is_refused(ov5647, bad, match):
    radiance = np.zeros((4, 5))
    radiance[2, 3] = bad
    with pytest.raises(ValueError, match=match) as err:
        ov5647.apply(radiance, rng=0)
    assert "(2, 3)" in str(err.value)


@pytest.mark.parametrize("rng", [None, 1.5, True, "seed"])
def test_rng_is_required(ov5647, rng):
    with pytest.raises(ValueError, match="rng"):
        ov5647.apply(np.zeros((2, 2)), rng=rng)


@pytest.mark.parametrize("kwargs, match", [
    ({"bit_depth": 12}, "cannot exceed"),
    ({"bit_depth": 0}, "bit_depth"),
    ({"full_well_e": -1.0}, "full_well_e"),
    ({"read_noise_e": float("nan")}, "read_noise_e"),
    ({"conversion_gain_e_per_dn": 0.0}, "conversion_gain_e_per_dn"),
    ({"black_level_dn": 2000.0}, "black_level_dn"),
])
def test_bad_parameters_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SensorModel(**kwargs)


# --------------------------------------------------------------------------- construction


def test_from_sensor_takes_the_scene_timing_and_output_format():
    sensor = load_scene("prototype_ov5647").sensor
    model = SensorModel.from_sensor(sensor)
    assert model == SensorModel(exposure_s=sensor.exposure_s)
    from dataclasses import replace
    m8 = SensorModel.from_sensor(replace(sensor, bit_depth=8, black_level_dn=4.0))
    assert (m8.bit_depth, m8.black_level_dn, m8.black_level_output_dn) == (8, 16.0, 4.0)


def test_parameters_round_trip_through_a_dict(ov5647):
    assert SensorModel.from_dict(ov5647.to_dict()) == ov5647
    with pytest.raises(ValueError, match="unknown keys"):
        SensorModel.from_dict({**ov5647.to_dict(), "gamma": 2.2})
