"""Image sensor model: linear radiance -> electrons -> noisy, clipped, quantised digital numbers.

The renderer (:class:`scet_render.render.rolling_shutter.FrameRender`) returns, for each pixel, the
radiance integrated over the row's exposure window divided by the pulse width Δs: each strobe's
radiance weighted by the fraction of the pulse the row collected
(:func:`estimator.banding.row_pulse_weights`), plus the ambient light. So a pixel that collects
one whole pulse reads the scene radiance under the strobe, and the exposure scale below is per
pulse. :meth:`SensorModel.apply` turns that into the raw frame the OV5647 would read out, in the
order a CMOS pixel does it:

1. **Exposure.** Mean collected electrons mu = ``electrons_per_radiance`` * L +
   ``dark_current_e_per_s`` * ``exposure_s``. ``electrons_per_radiance`` lumps pixel area, lens
   étendue, pulse length, quantum efficiency and photon energy into one scale. Physically it is
   pi A Δs QE λ / (4 F^2 h c), about 12 e- per W sr^-1 m^-2 for 1.4 µm pixels behind the
   stock f/2.9 lens with a 100 µs pulse, QE 0.15 at 850 nm; but the renderer's emitter
   radiance is itself a free choice, so the default (:data:`DEFAULT_ELECTRONS_PER_RADIANCE`)
   is set the way a prototype is tuned: the *expected* radiance of a glint of the default scene
   (emitter radiance times the cornea's Fresnel reflectance) lands at 70 % of the saturation
   level. Mitsuba's own dielectric (``plain_dielectric``) rendered at low spp reflects each
   camera sample with probability ~2.5 %, so its glint pixels are 0 or at least L_e / spp:
   single pixels then clip until the spp reaches a few hundred. The default cornea samples
   reflection with probability 0.75 (weight F / 0.75) and the conductor renders F directly,
   so their glint pixels are near the expected value.
2. **Photon shot noise and dark current shot noise.** n ~ Poisson(mu).
3. **Full well.** n = min(n, ``full_well_e``): the photodiode holds no more charge.
4. **Read noise.** v = n + N(0, ``read_noise_e``^2), input referred, in electrons.
5. **Conversion and offset.** x = v * ``analog_gain`` / ``conversion_gain_e_per_dn`` +
   ``black_level_dn``, in ADC digital numbers.
6. **ADC.** DN = clip(round(x), 0, 2^``adc_bit_depth`` - 1).
7. **Output word.** With ``bit_depth`` < ``adc_bit_depth`` (the OV5647's RAW8 output) the low
   bits are dropped: DN_out = floor(DN / 2^(adc_bit_depth - bit_depth)).

Photon transfer: for a flat field well below saturation the DN mean and variance obey
var = (mean - black) / K + (read / K)^2 + 1/12, with K = ``conversion_gain_e_per_dn`` /
``analog_gain`` (e-/DN) and the 1/12 DN^2 of uniform quantisation (Janesick, *Photon Transfer*,
SPIE 2007). The tests check exactly this.

Bad input (NaN, infinite or negative radiance) raises :class:`ValueError`: no renderer of
physical light produces it, so it signals a bug upstream that a silent clip would hide.

OV5647 parameters and their sources
-----------------------------------
[DS] OmniVision OV5647 datasheet, preliminary specification v1.0 (2009), "key specifications"
and Sec. 3.4; [PI] Raspberry Pi Camera Module v1.x hardware specification (TechSpecs.pdf);
[LC] libcamera's Raspberry Pi tuning file for the OV5647 (``src/ipa/rpi/vc4/data/ov5647.json``)
and its camera tuning tool, ``ctt_noise.py`` (noise std = a + b sqrt(mean), 16-bit scale).

===========================  ===========  ======================================================
parameter                    value        source
===========================  ===========  ======================================================
pixel pitch                  1.4 µm       [DS], [PI]
full well                    4,300 e-     [DS] "well capacity 4.3 ke-", [PI]; consistent with the
                                          36 dB maximum SNR of [DS]: 20 log10 sqrt(4300) = 36.3 dB
ADC                          10 bit       [DS] Sec. 3.4 "10-bit A/D converters"
black level                  16 DN        [LC] ``rpi.black_level`` 1024 on the 16-bit scale = 16 DN
                                          at 10 bit; also the scene files' ``black_level_dn``
conversion gain              3.54 e-/DN   [LC] ``rpi.noise`` slope 4.25 on the 16-bit scale at unit
                                          analogue gain: var16 = 4.25^2 mean16, so 1/K16 = 18.06
                                          DN16/e- and K10 = 64 / 18.06 = 3.54 e-/DN10. The ADC
                                          therefore clips at (1023 - 16) * 3.54 = 3,565 e-, before
                                          the well fills (common at base gain)
read noise                   2.5 e-       assumption. [DS] gives a 68 dB dynamic range, [PI] 67 dB
                                          "@ 8x gain": 4300 e- / 10^(68/20) = 1.7 e- at high gain.
                                          Input-referred read noise is higher at unit gain (about
                                          2x for small-pixel CMOS, e.g. the Pi HQ camera's IMX477
                                          measures 3 e- at gain 1 and 1.5 e- at gain 16), hence
                                          2.5 e-. It is of the order of the 1.0 e- rms quantisation
                                          noise of a 3.54 e- step, so its exact value matters little
dark current                 125 e-/s     [DS] "16 mV/s at 60 °C", converted with an assumed pixel
                                          conversion gain of 128 µV/e- (not published; a 0.55 V
                                          swing over 4.3 ke-, typical of 1.4 µm 4T pixels). The
                                          60 °C worst case (it about halves every 6-7 °C cooler);
                                          over the 1 ms exposure it adds 0.13 e-, negligible
exposure                     1 ms         the paper's prototype (Sec. 4.2); only the dark current
                                          uses it (the light is in the strobes)
===========================  ===========  ======================================================
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from estimator.eye import CORNEA_REFRACTIVE_INDEX
from estimator.setup import Sensor

from .layout import DEFAULT_LIGHT_RADIANCE

#: Normal-incidence Fresnel reflectance of the cornea, ((n - 1) / (n + 1))^2 = 0.0250 for
#: n = 1.376: the share of an emitter's radiance that a glint shows to the camera.
CORNEA_FRESNEL_REFLECTANCE = (
    (CORNEA_REFRACTIVE_INDEX - 1.0) / (CORNEA_REFRACTIVE_INDEX + 1.0)) ** 2

#: Emitter radiance (W sr^-1 m^-2) the default exposure scale is built for: the renderer's
#: default strobe light radiance, :data:`scet_render.render.scene.DEFAULT_LIGHT_RADIANCE`.
REFERENCE_EMITTER_RADIANCE = DEFAULT_LIGHT_RADIANCE

#: Fraction of the saturation level that the peak of a glint reaches at the default exposure:
#: near, but with room for Monte Carlo noise and grazing Fresnel gain, below clipping.
GLINT_SATURATION_FRACTION = 0.7

#: OV5647 values (sources in the module docstring).
OV5647_FULL_WELL_E = 4300.0
OV5647_READ_NOISE_E = 2.5
OV5647_DARK_CURRENT_E_PER_S = 125.0
OV5647_CONVERSION_GAIN_E_PER_DN = 3.54
OV5647_BLACK_LEVEL_DN = 16.0
OV5647_ADC_BIT_DEPTH = 10
OV5647_SATURATION_E = min(
    OV5647_FULL_WELL_E,
    ((1 << OV5647_ADC_BIT_DEPTH) - 1 - OV5647_BLACK_LEVEL_DN) * OV5647_CONVERSION_GAIN_E_PER_DN)

#: Default exposure scale, electrons per unit of (pulse-weighted) radiance, 99.6 e- per
#: W sr^-1 m^-2: a fully lit row's glint pixel sees CORNEA_FRESNEL_REFLECTANCE *
#: REFERENCE_EMITTER_RADIANCE = 25.0 and collects GLINT_SATURATION_FRACTION of the 3,565 e-
#: saturation level (ADC-limited, see the table above); skin and sclera under the strobe
#: (~1.3, see scet_render.render.scene) read ~37 DN above black.
DEFAULT_ELECTRONS_PER_RADIANCE = (GLINT_SATURATION_FRACTION * OV5647_SATURATION_E
                                  / (CORNEA_FRESNEL_REFLECTANCE * REFERENCE_EMITTER_RADIANCE))

#: Poisson means above this multiple of the full well are capped before sampling: every sample
#: then exceeds the full well anyway (P(n < FW | mu = 2 FW) < 1e-130 for FW >= 1000), and
#: numpy's Poisson sampler rejects means near 1e19.
_POISSON_CAP_FULL_WELLS = 2.0


@dataclass(frozen=True, slots=True)
class SensorModel:
    """Photon-to-DN model of a CMOS image sensor; the defaults are the OV5647 (see the module).

    Attributes
    ----------
    electrons_per_radiance : float
        Exposure scale: mean photo-electrons per unit of pulse-weighted radiance, e-.
    full_well_e : float
        Charge at which the photodiode saturates, e-.
    read_noise_e : float
        Input-referred read noise (standard deviation), e-.
    dark_current_e_per_s : float
        Mean dark current, e-/s; 0 turns it off.
    exposure_s : float
        Exposure window Δe over which the dark current accumulates, s.
    conversion_gain_e_per_dn : float
        Electrons per ADC digital number at unit analogue gain.
    analog_gain : float
        Analogue gain; the effective conversion gain is ``conversion_gain_e_per_dn / analog_gain``.
    black_level_dn : float
        Offset added before the ADC, in ADC DN (``adc_bit_depth`` bits).
    adc_bit_depth : int
        Resolution of the ADC.
    bit_depth : int
        Bits of the output word, 1 <= bit_depth <= adc_bit_depth (10: RAW10, 8: RAW8).
    """

    electrons_per_radiance: float = DEFAULT_ELECTRONS_PER_RADIANCE
    full_well_e: float = OV5647_FULL_WELL_E
    read_noise_e: float = OV5647_READ_NOISE_E
    dark_current_e_per_s: float = OV5647_DARK_CURRENT_E_PER_S
    exposure_s: float = 1e-3
    conversion_gain_e_per_dn: float = OV5647_CONVERSION_GAIN_E_PER_DN
    analog_gain: float = 1.0
    black_level_dn: float = OV5647_BLACK_LEVEL_DN
    adc_bit_depth: int = OV5647_ADC_BIT_DEPTH
    bit_depth: int = OV5647_ADC_BIT_DEPTH

    def __post_init__(self):
        for name in ("adc_bit_depth", "bit_depth"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 1 <= v <= 16:
                raise ValueError(f"SensorModel.{name} must be an integer in [1, 16], got {v!r}")
            object.__setattr__(self, name, int(v))
        if self.bit_depth > self.adc_bit_depth:
            raise ValueError(f"SensorModel.bit_depth ({self.bit_depth}) cannot exceed "
                             f"adc_bit_depth ({self.adc_bit_depth})")
        positive = ("electrons_per_radiance", "full_well_e", "exposure_s",
                    "conversion_gain_e_per_dn", "analog_gain")
        non_negative = ("read_noise_e", "dark_current_e_per_s", "black_level_dn")
        for name in positive + non_negative:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                raise ValueError(f"SensorModel.{name} must be a finite number, got {v!r}")
            if (name in positive and v <= 0) or v < 0:
                bound = "> 0" if name in positive else ">= 0"
                raise ValueError(f"SensorModel.{name} must be {bound}, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.black_level_dn > self.adc_max_dn:
            raise ValueError(f"SensorModel.black_level_dn ({self.black_level_dn}) exceeds the "
                             f"ADC range [0, {self.adc_max_dn}]")

    # -- construction ------------------------------------------------------------------------

    @classmethod
    def from_sensor(cls, sensor: Sensor, **overrides) -> "SensorModel":
        """The OV5647 model with a scene's output bit depth, black level and exposure.

        ``sensor.black_level_dn`` is read at ``sensor.bit_depth`` bits (16 DN at 10 bit) and
        stored at the ADC's 10 bits. Keyword arguments override any field.
        """
        adc_bits = int(overrides.get("adc_bit_depth", OV5647_ADC_BIT_DEPTH))
        bits = int(sensor.bit_depth)
        values = {
            "bit_depth": bits,
            "black_level_dn": float(sensor.black_level_dn) * 2.0 ** (adc_bits - bits),
            "exposure_s": float(sensor.exposure_s),
        }
        values.update(overrides)
        return cls(**values)

    def with_glint_level(self, glint_radiance: float,
                         fraction: float = GLINT_SATURATION_FRACTION) -> "SensorModel":
        """A copy whose exposure puts a pixel of ``glint_radiance`` at ``fraction`` of saturation.

        Parameters
        ----------
        glint_radiance : float
            Pulse-weighted radiance of the glint's peak pixel (e.g. the emitter radiance times
            :data:`CORNEA_FRESNEL_REFLECTANCE`), > 0.
        fraction : float
            Target share of :attr:`saturation_e`, in (0, 1].
        """
        glint_radiance, fraction = float(glint_radiance), float(fraction)
        if not (math.isfinite(glint_radiance) and glint_radiance > 0):
            raise ValueError(f"glint_radiance must be finite and > 0, got {glint_radiance!r}")
        if not 0 < fraction <= 1:
            raise ValueError(f"fraction must lie in (0, 1], got {fraction!r}")
        return replace(self, electrons_per_radiance=fraction * self.saturation_e / glint_radiance)

    # -- derived quantities ------------------------------------------------------------------

    @property
    def adc_max_dn(self) -> int:
        """Largest ADC code, 2^adc_bit_depth - 1."""
        return (1 << self.adc_bit_depth) - 1

    @property
    def max_dn(self) -> int:
        """Largest output code, 2^bit_depth - 1."""
        return (1 << self.bit_depth) - 1

    @property
    def output_shift(self) -> int:
        """Low ADC bits dropped from the output word."""
        return self.adc_bit_depth - self.bit_depth

    @property
    def electrons_per_dn(self) -> float:
        """K, electrons per *output* DN at the current analogue gain (the photon-transfer slope
        is 1 / K)."""
        return self.conversion_gain_e_per_dn / self.analog_gain * (1 << self.output_shift)

    @property
    def black_level_output_dn(self) -> float:
        """Black level in output DN (16 at 10 bit, 4 at 8 bit for the OV5647)."""
        return self.black_level_dn / (1 << self.output_shift)

    @property
    def saturation_e(self) -> float:
        """Electrons at which the output stops rising: the full well, or the ADC's top code if
        it comes first (it does for the OV5647 at unit gain)."""
        adc_e = (self.adc_max_dn - self.black_level_dn) * self.conversion_gain_e_per_dn
        return min(self.full_well_e, adc_e / self.analog_gain)

    def mean_electrons(self, radiance) -> np.ndarray:
        """(...) mean collected electrons (before noise and clipping) for (...) radiance."""
        L = _check_radiance(radiance)
        return L * self.electrons_per_radiance + self.dark_current_e_per_s * self.exposure_s

    # -- the model ---------------------------------------------------------------------------

    def apply(self, radiance, rng) -> np.ndarray:
        """Simulate one raw readout of a radiance image.

        Parameters
        ----------
        radiance : (...) float
            Pulse-weighted linear radiance per pixel (usually (H, W) float32), finite, >= 0.
        rng : numpy.random.Generator or int or numpy.random.SeedSequence
            Source of the noise; an int or SeedSequence seeds a fresh generator. The same seed
            gives byte-identical output. A Generator is advanced (Poisson draws first, then the
            Gaussian read noise, both over the whole array in C order).

        Returns
        -------
        (...) uint16
            Raw digital numbers in [0, 2^bit_depth - 1], black level included.

        Raises
        ------
        ValueError
            If any radiance is NaN, infinite or negative, or ``rng`` is missing.
        """
        mu = self.mean_electrons(radiance)
        gen = _generator(rng)
        mu = np.minimum(mu, _POISSON_CAP_FULL_WELLS * self.full_well_e)
        electrons = np.minimum(gen.poisson(mu).astype(np.float64), self.full_well_e)
        electrons += self.read_noise_e * gen.standard_normal(size=electrons.shape)
        x = electrons * (self.analog_gain / self.conversion_gain_e_per_dn) + self.black_level_dn
        dn = np.clip(np.floor(x + 0.5), 0, self.adc_max_dn).astype(np.uint16)
        return dn >> np.uint16(self.output_shift) if self.output_shift else dn

    # -- files -------------------------------------------------------------------------------

    def to_dict(self) -> dict:
        """Plain-JSON parameters (field name -> value; units are in the names)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> "SensorModel":
        """Inverse of :meth:`to_dict`; unknown or missing keys raise ValueError."""
        if not isinstance(data, dict):
            raise ValueError(f"sensor parameters must be a JSON object, got {type(data).__name__}")
        names = {f.name for f in fields(cls)}
        unknown, missing = sorted(set(data) - names), sorted(names - set(data))
        if unknown or missing:
            raise ValueError(f"sensor parameters: unknown keys {unknown}, missing keys {missing}")
        return cls(**data)


def _check_radiance(radiance) -> np.ndarray:
    L = np.asarray(radiance, dtype=np.float64)
    bad = ~np.isfinite(L)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0]) if L.ndim else ()
        raise ValueError(f"radiance has {int(bad.sum())} non-finite value(s) (first at index "
                         f"{where}); the renderer must return finite radiance")
    neg = L < 0
    if neg.any():
        where = tuple(int(i) for i in np.argwhere(neg)[0]) if L.ndim else ()
        raise ValueError(f"radiance has {int(neg.sum())} negative value(s) (first at index "
                         f"{where}, {L[where]!r}); radiance is >= 0")
    return L


def _generator(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, np.random.SeedSequence):
        return np.random.default_rng(rng)
    if isinstance(rng, numbers.Integral) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise ValueError("rng must be a numpy.random.Generator, a SeedSequence or an int seed "
                     f"(sensor noise must be reproducible), got {rng!r}")
