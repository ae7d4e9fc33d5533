"""Eyelids that follow the eye: the ``[eyelids]`` table of a scene file.

The lid margins are described by their elevation (radians, up positive) seen from the eyeball
rotation centre on the vertical meridian, as a linear function of the eye's pitch p (lid-eye
coupling):

    upper(p) = upper_margin_rad + upper_gain * p,    lower(p) = lower_margin_rad + lower_gain * p.

The upper lid follows vertical gaze almost one to one, the lower lid much less (Becker & Fuchs
1988: the upper lid's position tracks vertical eye position with a gain near 1 over the
oculomotor range, and its saccades match the eye's; the lower lid moves about a third as much,
mostly in down-gaze: Becker & Fuchs 1988, Evinger et al. 1991). A blink (see
:mod:`scet_render.motion.blinks`) brings the upper margin down onto the lower one.

Without an ``[eyelids]`` table a scene has no moving lids (``Setup.eyelids`` is None) and the
renderer draws its static lids, as before this table existed.

References
----------
Becker, W., Fuchs, A. F. (1988). Lid-eye coordination during vertical gaze changes in man and
monkey. *Journal of Neurophysiology* 60, 1227-1252.
Evinger, C., Manning, K. A., Sibony, P. A. (1991). Eyelid movements. Mechanisms and normal data.
*Investigative Ophthalmology & Visual Science* 32, 387-400.
Bentivoglio, A. R., Bressman, S. B., Cassetta, E., Carretta, D., Tonali, P., Albanese, A. (1997).
Analysis of blink rate patterns in normal subjects. *Movement Disorders* 12, 1028-1034.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .eye import Eye
from .setup import Screen

#: Upper and lower lid gains on vertical gaze (lid rotation per eye pitch). Becker & Fuchs
#: (1988) found the upper lid following eye position with a gain of about 0.9-1.0; the lower lid
#: moves roughly a third as much (brief of issue 14: ~0.3).
DEFAULT_UPPER_GAIN = 0.9
DEFAULT_LOWER_GAIN = 0.3
#: Gains outside [0, 1.5] are not lid-eye coupling (a lid moving against the eye, or far more
#: than it).
GAIN_RANGE = (0.0, 1.5)
#: Lid margin clearance beyond the cornea's edge used for the default margins (rad): the
#: renderer's static lids keep the same 5 degrees (scet_render.render.LID_MARGIN_RAD).
DEFAULT_CLEARANCE_RAD = math.radians(5.0)
#: Highest accepted spontaneous blink rate (per minute). Bentivoglio et al. (1997) measured
#: 17 +- 8 blinks/min at rest and 26 in conversation in 150 normal subjects, the highest
#: individual rates near 50/min; one blink a second is beyond any normal subject.
MAX_BLINK_RATE_PER_MIN = 60.0
#: Upper-lid eyelashes: count and length. Real upper lids carry 90-160 lashes of 8-12 mm;
#: the renderer draws fewer, thicker ones (a few dozen, 0.1 mm wide ribbons): what matters to
#: the glints is whether a lash crosses a light's path, not the exact count.
DEFAULT_LASH_LENGTH_M = 9e-3
MAX_LASHES = 200
LASH_LENGTH_RANGE_M = (2e-3, 15e-3)


@dataclass(frozen=True, slots=True)
class Eyelids:
    """Lids that follow the eye (module docstring); angles in radians, lengths in metres.

    Attributes
    ----------
    upper_margin_rad, lower_margin_rad : float
        Margin elevations at primary gaze (pitch 0), seen from the rotation centre.
    upper_gain, lower_gain : float
        Margin elevation per radian of eye pitch.
    blink_rate_per_min : float
        Mean spontaneous blink rate (0: no blinks).
    lash_count : int
        Opaque lashes on the upper lid margin (0: none).
    lash_length_m : float
    lash_seed : int
        Seed of the lashes' random placement, length and curl.
    """

    upper_margin_rad: float
    lower_margin_rad: float
    upper_gain: float = DEFAULT_UPPER_GAIN
    lower_gain: float = DEFAULT_LOWER_GAIN
    blink_rate_per_min: float = 0.0
    lash_count: int = 0
    lash_length_m: float = DEFAULT_LASH_LENGTH_M
    lash_seed: int = 0

    def __post_init__(self):
        for name in ("upper_margin_rad", "lower_margin_rad", "upper_gain", "lower_gain",
                     "blink_rate_per_min", "lash_length_m"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)!r}")
        if not -math.pi / 2 < self.lower_margin_rad < self.upper_margin_rad < math.pi / 2:
            raise ValueError("need -pi/2 < lower_margin_rad < upper_margin_rad < pi/2, got "
                             f"{self.lower_margin_rad}, {self.upper_margin_rad}")
        for name in ("upper_gain", "lower_gain"):
            if not GAIN_RANGE[0] <= getattr(self, name) <= GAIN_RANGE[1]:
                raise ValueError(f"{name} must lie in {list(GAIN_RANGE)}, got {getattr(self, name)}")
        if not 0.0 <= self.blink_rate_per_min <= MAX_BLINK_RATE_PER_MIN:
            raise ValueError(f"blink_rate_per_min must lie in [0, {MAX_BLINK_RATE_PER_MIN:g}], "
                             f"got {self.blink_rate_per_min}")
        if not 0 <= self.lash_count <= MAX_LASHES:
            raise ValueError(f"lash_count must lie in [0, {MAX_LASHES}], got {self.lash_count}")
        if not LASH_LENGTH_RANGE_M[0] <= self.lash_length_m <= LASH_LENGTH_RANGE_M[1]:
            raise ValueError(f"lash_length_m must lie in {list(LASH_LENGTH_RANGE_M)}, got "
                             f"{self.lash_length_m}")

    def margins_rad(self, pitch_rad, closure=0.0) -> tuple[np.ndarray, np.ndarray]:
        """(upper, lower) margin elevations at eye pitches, with the upper lid ``closure``
        (0 open .. 1 shut: the upper margin on the lower one) of a blink; shaped like the
        broadcast of ``pitch_rad`` and ``closure``."""
        p = np.asarray(pitch_rad, dtype=np.float64)
        c = np.asarray(closure, dtype=np.float64)
        upper = self.upper_margin_rad + self.upper_gain * p
        lower = self.lower_margin_rad + self.lower_gain * p
        upper, lower, c = np.broadcast_arrays(upper, lower, c)
        return upper - c * (upper - lower), lower.copy()


def cornea_angular_radius(eye: Eye) -> float:
    """Half angle (rad) of the corneal cap seen from the rotation centre (limbus circle)."""
    d_l = eye.cornea_offset_m + eye.cornea_radius_m - eye.limbus_depth_m
    return math.atan2(eye.limbus_radius_m, d_l)


def screen_pitch_range(eye: Eye, screen: Screen) -> tuple[float, float]:
    """(lowest, highest) eye pitch (rad) of gazes at the screen's edges and corners."""
    _, pitch = eye.angles_toward(screen.grid(9, 9, margin=0.0))
    return float(pitch.min()), float(pitch.max())


def default_margins_rad(eye: Eye, screen: Screen, upper_gain: float,
                        lower_gain: float) -> tuple[float, float]:
    """Margins at primary gaze that clear the cornea by :data:`DEFAULT_CLEARANCE_RAD` at every
    gaze at the screen: upper(p) >= p + cap + clearance and lower(p) <= p - cap - clearance."""
    cap = cornea_angular_radius(eye)
    pitches = np.array(screen_pitch_range(eye, screen))
    upper = float(np.max((1.0 - upper_gain) * pitches)) + cap + DEFAULT_CLEARANCE_RAD
    lower = float(np.min((1.0 - lower_gain) * pitches)) - cap - DEFAULT_CLEARANCE_RAD
    return min(upper, math.radians(80.0)), max(lower, math.radians(-80.0))


def always_closed(lids: Eyelids, eye: Eye, screen: Screen) -> bool:
    """True when the lid opening leaves no part of the cornea uncovered at any gaze at the
    screen (open lids, no blink): the upper margin below the cornea's lower edge, the lower
    margin above its upper edge, or the upper margin below the lower, at every pitch."""
    cap = cornea_angular_radius(eye)
    lo, hi = screen_pitch_range(eye, screen)
    p = np.linspace(lo, hi, 64)
    upper, lower = lids.margins_rad(p)
    shut = (upper <= p - cap) | (lower >= p + cap) | (upper <= lower)
    return bool(np.all(shut))


def read_eyelids(t, eye: Eye, screen: Screen) -> Eyelids:
    """The ``[eyelids]`` table (``t``: the scene reader's table) -> :class:`Eyelids`.

    Keys (all optional): ``upper_gain``, ``lower_gain``, ``upper_margin_deg``/``_rad``,
    ``lower_margin_deg``/``_rad`` (margin elevations at primary gaze; default: clear of the
    cornea by 5 degrees at every gaze at the screen), ``blink_rate_per_min``, ``lash_count``,
    ``lash_length_mm``/``_m``, ``lash_seed``. Errors name the key (``SceneError``).
    """
    g_up = t.number("upper_gain", DEFAULT_UPPER_GAIN, required=False, lo=GAIN_RANGE[0],
                    hi=GAIN_RANGE[1])
    g_low = t.number("lower_gain", DEFAULT_LOWER_GAIN, required=False, lo=GAIN_RANGE[0],
                     hi=GAIN_RANGE[1])
    up0, low0 = default_margins_rad(eye, screen, g_up, g_low)
    limit = math.radians(85.0)
    up = t.quantity("upper_margin", "angle", default=up0, required=False, lo=-limit, hi=limit)
    low = t.quantity("lower_margin", "angle", default=low0, required=False, lo=-limit, hi=limit)
    if not low < up:
        key = next((k for k in ("upper_margin_deg", "upper_margin_rad") if t.has(k)),
                   "lower_margin_deg" if t.has("lower_margin_deg") else "lower_margin_rad")
        raise t.error(key, f"the upper margin ({math.degrees(up):.2f} deg) must lie "
                      f"above the lower ({math.degrees(low):.2f} deg)")
    rate = t.number("blink_rate_per_min", 0.0, required=False)
    if not 0.0 <= rate <= MAX_BLINK_RATE_PER_MIN:
        raise t.error("blink_rate_per_min", f"expected a rate in [0, {MAX_BLINK_RATE_PER_MIN:g}] "
                      "per minute (physiological spontaneous rates are 4-50/min, Bentivoglio et "
                      f"al. 1997), got {rate:g}")
    count = t.integer("lash_count", 0, required=False, minimum=0, maximum=MAX_LASHES)
    length = t.quantity("lash_length", "length", default=DEFAULT_LASH_LENGTH_M, required=False,
                        lo=LASH_LENGTH_RANGE_M[0], hi=LASH_LENGTH_RANGE_M[1])
    seed = t.integer("lash_seed", 0, required=False, minimum=0, maximum=2**32 - 1)
    t.finish()
    lids = Eyelids(up, low, g_up, g_low, rate, count, length, seed)
    if always_closed(lids, eye, screen):
        given = [k for k in ("upper_margin_deg", "upper_margin_rad", "lower_margin_deg",
                             "lower_margin_rad", "upper_gain", "lower_gain") if t.has(k)]
        raise t.error(given[0] if given else "upper_margin_deg", "these lids cover the whole cornea at every gaze at the screen "
                      f"(upper margin {math.degrees(up):.2f} deg, lower {math.degrees(low):.2f} "
                      f"deg at primary gaze, gains {g_up:g} / {g_low:g}): the eye is closed in "
                      "every frame")
    return lids
