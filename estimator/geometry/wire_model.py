"""The wire-wound mirror as built, its LED and its materials: the geometry the two-bounce glint
solver (:mod:`estimator.geometry.wire`) and the renderer share.

Each turn's stretch on the strip's inner face is a straight cylinder of radius d/2 along the
arc plane's normal, at radius R - d/2 from the arc's axis (the wire lies on the face); the LED
is a point with a datasheet radiant-intensity pattern (:class:`LedBeam`); the wire is enamelled
copper (:func:`enamelled_copper_reflectance`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from .rigid import RigidPose, as_points

__all__ = ["LedBeam", "WireMirror", "WireGeometryError", "enamelled_copper_reflectance",
           "fresnel_unpolarized", "COPPER_INDEX_850NM", "ENAMEL_INDEX"]

#: Copper's complex refractive index at 850 nm, n + ik: Mitsuba 3's data/ior/Cu.eta.spd and
#: Cu.k.spd (the luxpop tables) interpolated linearly between 826.6 and 855.1 nm
#: (0.26 + 5.26i, 0.28 + 5.49i). Johnson & Christy (1972, Phys. Rev. B 6, 4370) give
#: n ~ 0.2-0.3, k ~ 5.3-5.5 in this band; normal-incidence reflectance 0.965.
COPPER_INDEX_850NM = complex(0.2769, 5.449)
#: Refractive index of the wire's enamel (polyurethane / polyester-imide magnet-wire
#: varnish): ~1.5-1.6 for such polymers in the near IR; 1.55 assumed [G]. The film is
#: 20-40 µm thick, tens of wavelengths and not uniform, so its interference averages out
#: (incoherent sum in :func:`enamelled_copper_reflectance`).
ENAMEL_INDEX = 1.55
class WireGeometryError(ValueError):
    """A wire mirror that cannot be built; ``key`` names the scene key at fault."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


@dataclass(frozen=True, slots=True)
class LedBeam:
    """The LED's radiant-intensity pattern I(θ) / I_max against the angle θ from its aim.

    Attributes
    ----------
    angles_rad : (k,) float
        Increasing angles from 0 to at most π/2.
    relative : (k,) float
        I(θ) / I_max at those angles, in [0, 1]; linear in between, 0 beyond the last angle.
    exponent : float
        m of the cos^m θ lobe that stands for the pattern where one lobe is needed (the
        renderer): exact for :meth:`cos_power`, a least-squares fit in log space otherwise.
    """

    angles_rad: np.ndarray
    relative: np.ndarray
    exponent: float

    @classmethod
    def cos_power(cls, half_angle_rad: float) -> "LedBeam":
        """The cos^m θ lobe with I(θ½) = I(0) / 2: m = ln 2 / -ln cos θ½ (m = 1, Lambertian, at
        θ½ = 60 deg, e.g. Vishay VSMY1850, 850 nm 0805 SMD, datasheet 83397: ±60 deg)."""
        h = float(half_angle_rad)
        if not (math.isfinite(h) and 0.0 < h < math.pi / 2):
            raise WireGeometryError("led_half_angle_deg", f"expected a half-intensity angle in "
                                    f"(0, 90) deg, got {math.degrees(h):g} deg")
        m = math.log(2.0) / -math.log(math.cos(h))
        a = np.linspace(0.0, math.pi / 2, 181)
        return cls(a, np.cos(a) ** m, m)

    @classmethod
    def table(cls, angles_rad, relative) -> "LedBeam":
        """A datasheet's "relative radiant intensity vs angular displacement" curve, normalised
        to its peak; the cos^m exponent is fitted to the points above 5 % of the peak."""
        a = np.asarray(angles_rad, dtype=np.float64).reshape(-1)
        r = np.asarray(relative, dtype=np.float64).reshape(-1)
        key = "led_pattern"
        if a.size < 2 or a.size != r.size:
            raise WireGeometryError(key, "expected at least two [angle_deg, relative] rows")
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(r))):
            raise WireGeometryError(key, "expected finite angles and intensities")
        if a[0] != 0.0 or np.any(np.diff(a) <= 0) or a[-1] > math.pi / 2 + 1e-12:
            raise WireGeometryError(key, "expected angles rising strictly from 0 to at most 90 deg")
        if np.any(r < 0) or r.max() <= 0:
            raise WireGeometryError(key, "expected intensities >= 0, not all zero (a radiant-"
                                         "intensity pattern is a non-negative distribution)")
        r = r / r.max()
        use = (r > 0.05) & (a > 0) & (a < math.pi / 2)
        if use.any():
            x, y = np.log(np.cos(a[use])), np.log(r[use] / max(r[0], 1e-12))
            m = float((x @ y) / (x @ x))
        else:
            m = 1.0
        return cls(a, r, max(m, 1e-3))

    def __call__(self, cos_theta) -> np.ndarray:
        """I(θ) / I_max for (...,) cos θ (0 behind the LED and beyond the pattern)."""
        c = np.clip(np.asarray(cos_theta, dtype=np.float64), -1.0, 1.0)
        theta = np.arccos(c)
        out = np.interp(theta, self.angles_rad, self.relative, right=0.0)
        return np.where(theta <= self.angles_rad[-1], out, 0.0)


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


@dataclass(frozen=True, slots=True)
class WireMirror:
    """The wire-wound mirror and its LED, in SI units, in one frame (a scene group's local frame
    or the world: :meth:`posed`).

    Attributes
    ----------
    center_m : (3,) float
        The arc's centre.
    u, v, normal : (3,) float
        Orthonormal frame: ``u`` from the centre toward the first turn, ``v`` the direction the
        arc runs, ``normal`` the arc plane's normal (the wire stretches' axis).
    radius_m : float
        R, the strip's inner face (the wire's axes lie at R - d/2).
    span_rad : float
        Angle from the first turn to the last (``end_to_end`` winding) or the strip's arc
        split into ``turns`` equal cells with a turn at each middle (``mid_cell``).
    width_m, thickness_m : float
        The strip across the arc plane (along ``normal``) and radially.
    turns : int
    wire_diameter_m : float
    led_position_m, led_aim : (3,) float
        The LED's emitting point and unit aim.
    beam : LedBeam
    led_diameter_m : float
        The emitter's size for rendering.
    winding : str
        ``"end_to_end"`` or ``"mid_cell"``.
    """

    center_m: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    radius_m: float
    span_rad: float
    width_m: float
    thickness_m: float
    turns: int
    wire_diameter_m: float
    led_position_m: np.ndarray
    led_aim: np.ndarray
    beam: LedBeam = field(default_factory=lambda: LedBeam.cos_power(math.radians(60.0)))
    led_diameter_m: float = 0.5e-3
    winding: str = "end_to_end"

    def __post_init__(self):
        for name in ("center_m", "u", "v", "normal", "led_position_m", "led_aim"):
            a = as_points(getattr(self, name), name).reshape(3).copy()
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        self.check()

    # -- geometry ---------------------------------------------------------------------------
    @property
    def wire_radius_m(self) -> float:
        return 0.5 * self.wire_diameter_m

    @property
    def turn_angles_rad(self) -> np.ndarray:
        """(turns,) angle of each turn from ``u`` toward ``v``."""
        k = np.arange(self.turns)
        if self.winding == "mid_cell":
            return self.span_rad * (k + 0.5) / self.turns
        return self.span_rad * k / max(self.turns - 1, 1)

    @property
    def radial(self) -> np.ndarray:
        """(turns, 3) unit vectors from the arc's centre toward each turn."""
        a = self.turn_angles_rad
        return np.cos(a)[:, None] * self.u + np.sin(a)[:, None] * self.v

    @property
    def wire_axes_m(self) -> np.ndarray:
        """(turns, 3) each turn's stretch on the inner face: its axis at mid-width, R - d/2 from
        the centre. This is also the point-source model's light (``hardware/mirror.py``)."""
        return self.center_m + (self.radius_m - self.wire_radius_m) * self.radial

    @property
    def strip_angles_rad(self) -> tuple[float, float]:
        """The strip's angular extent: half a pitch beyond the end turns, at least the wire's
        radius plus 0.5 mm (``hardware/mirror.py``'s clearance)."""
        a = self.turn_angles_rad
        pitch = self.span_rad / max(self.turns - 1, 1) if self.winding == "end_to_end" else self.span_rad / self.turns
        extra = max(0.5 * pitch, (self.wire_radius_m + 0.5e-3) / self.radius_m)
        return float(a[0] - extra), float(a[-1] + extra)

    def pitch_m(self) -> float:
        """Centre-to-centre distance of neighbouring turns' axes (m)."""
        if self.turns < 2:
            return math.inf
        step = float(self.turn_angles_rad[1] - self.turn_angles_rad[0])
        return 2.0 * (self.radius_m - self.wire_radius_m) * math.sin(0.5 * step)

    def check(self) -> None:
        """Raise :class:`WireGeometryError` naming the scene key for a mirror that cannot be
        built or lit."""
        if not (self.radius_m > 0 and self.width_m > 0 and self.thickness_m > 0):
            raise WireGeometryError("radius_mm", "radius, strip width and thickness must be > 0")
        if self.turns < 1:
            raise WireGeometryError("turns", f"expected at least one turn, got {self.turns}")
        if self.winding not in ("end_to_end", "mid_cell"):
            raise WireGeometryError("winding", f"expected 'end_to_end' or 'mid_cell', got {self.winding!r}")
        if not (0 < self.span_rad < 2 * math.pi):
            raise WireGeometryError("span_deg", "expected a span in (0, 360) deg")
        if not self.wire_diameter_m > 0:
            raise WireGeometryError("wire_diameter_mm", "expected a positive wire diameter")
        if self.wire_diameter_m > self.width_m:
            raise WireGeometryError("wire_diameter_mm", f"the wire ({self.wire_diameter_m * 1e3:g} mm) "
                                    f"is wider than the strip it is wound on ({self.width_m * 1e3:g} mm)")
        if self.wire_diameter_m >= self.radius_m:
            raise WireGeometryError("wire_diameter_mm", "the wire is thicker than the arc's radius")
        if self.pitch_m() < self.wire_diameter_m:
            raise WireGeometryError("turns", f"{self.turns} turns of {self.wire_diameter_m * 1e3:g} mm "
                                    f"wire overlap: the pitch on the inner face is "
                                    f"{self.pitch_m() * 1e3:.3f} mm, below the wire's diameter")
        lo, hi = self.strip_angles_rad
        if hi - lo >= 2 * math.pi:
            raise WireGeometryError("span_deg", "the strip would close on itself")
        # The LED must light the inner face: inside the arc, clear of the wire turns.
        rel = self.led_position_m - self.center_m
        z = float(rel @ self.normal)
        rho = float(np.hypot(rel @ self.u, rel @ self.v))
        inner = self.radius_m - self.wire_diameter_m
        if rho >= inner:
            where = ("inside the strip" if rho <= self.radius_m + self.thickness_m and abs(z) <= 0.5 * self.width_m
                     else "behind the strip's inner face")
            raise WireGeometryError("led_position_m", f"the LED lies {where}: {rho * 1e3:.3f} mm from "
                                    f"the arc's axis, where it must be under R - d = {inner * 1e3:.3f} mm "
                                    "to light the wire on the inner face")
        if not np.isclose(np.linalg.norm(self.led_aim), 1.0, atol=1e-9):
            raise WireGeometryError("led_aim", "expected a unit aim direction")

    def posed(self, pose: RigidPose) -> "WireMirror":
        """The mirror moved rigidly by ``pose`` (a scene group's pose)."""
        R = pose.rotation
        return replace(self, center_m=pose.apply(self.center_m), u=R @ self.u, v=R @ self.v,
                       normal=R @ self.normal, led_position_m=pose.apply(self.led_position_m),
                       led_aim=R @ self.led_aim)


# -- Fresnel ---------------------------------------------------------------------------------
def fresnel_unpolarized(cos_i, n1, n2) -> np.ndarray:
    """Unpolarized Fresnel reflectance from a medium of index ``n1`` (real) into ``n2`` (real
    or complex n + ik) at incidence cosine ``cos_i`` (..., in [0, 1])."""
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    n2 = np.asarray(n2, dtype=np.complex128)
    s2 = (n1 / n2) ** 2 * (1.0 - c * c)
    ct = np.sqrt(1.0 - s2 + 0j)
    rs = (n1 * c - n2 * ct) / (n1 * c + n2 * ct)
    rp = (n2 * c - n1 * ct) / (n2 * c + n1 * ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def enamelled_copper_reflectance(cos_i, *, enamel_index: float = ENAMEL_INDEX,
                                 copper_index: complex = COPPER_INDEX_850NM) -> np.ndarray:
    """Specular reflectance of enamelled copper wire at incidence cosine ``cos_i`` (...,).

    A clear film of index n_e on copper, summed incoherently (the film is many wavelengths
    thick): per polarization R = F + (1 - F)² R_c / (1 - F R_c), with F the air-enamel Fresnel
    reflectance at the incidence angle (equal from inside at the refracted angle) and R_c the
    enamel-copper reflectance at the refracted angle; the two polarizations averaged. At
    normal incidence: 0.948 for n_e = 1.55 (bare copper: 0.965)."""
    c = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    s2 = (1.0 - c * c) / enamel_index ** 2
    ct = np.sqrt(1.0 - s2)
    out = 0.0
    for pol in ("s", "p"):
        F = _fresnel_pol(c, 1.0, enamel_index, pol)
        Rc = _fresnel_pol(ct, enamel_index, copper_index, pol)
        out = out + 0.5 * (F + (1 - F) ** 2 * Rc / (1 - F * Rc))
    return out


def _fresnel_pol(c, n1, n2, pol):
    n2 = np.asarray(n2, dtype=np.complex128)
    ct = np.sqrt(1.0 - (n1 / n2) ** 2 * (1.0 - c * c) + 0j)
    if pol == "s":
        r = (n1 * c - n2 * ct) / (n1 * c + n2 * ct)
    else:
        r = (n2 * c - n1 * ct) / (n2 * c + n1 * ct)
    return np.abs(r) ** 2
