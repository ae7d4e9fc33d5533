"""Parametric light layouts: circular arcs of evenly spaced lights around the eye.

An arc is a small circle on the sphere of radius ρ about the eye's rotation centre: the lights
that sit at angular radius β about an axis direction (azimuth, elevation, seen from the eye),
from the angle φ0 over a span, evenly spaced. One arc about -z is a ring in a glasses rim;
tilting its axis tilts the ring; a short span is an arc like the paper's (Sec. 3) and like the
prototype's wire-wound mirror (Sec. 4.1), whose turns are evenly spaced point sources along a
circular strip. Every arc is a planar circle, so it is written to a scene file exactly as
``kind = "arc"`` (:meth:`Arc.scene_table`).

The family's parameter vector (for :func:`scipy.optimize.differential_evolution`) holds, per
arc, azimuth and elevation of the axis (deg), β (deg), φ0 (deg), span (deg), ρ (m) and a weight,
then the total light count (an integer); the count is shared out by the weights
(:func:`share_counts`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Per-arc parameters of the family vector, in order, with their bounds (distance bounds come
#: from the region).
ARC_PARAMS = ("azimuth_deg", "elevation_deg", "beta_deg", "phi0_deg", "span_deg", "rho_m",
              "weight")
ARC_BOUNDS = {"azimuth_deg": (-180.0, 180.0), "elevation_deg": (-80.0, 80.0),
              "beta_deg": (5.0, 75.0), "phi0_deg": (0.0, 360.0), "span_deg": (20.0, 360.0),
              "weight": (0.05, 1.0)}


def axis_direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit direction seen from the eye: azimuth about -z toward +x, elevation toward +y."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(e) * math.sin(a), math.sin(e), -math.cos(e) * math.cos(a)])


def _basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``axis`` to a right-handed frame (e1 x e2 = axis)."""
    ref = np.array([0.0, 1.0, 0.0]) if abs(axis[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(ref, axis)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


@dataclass(frozen=True, slots=True)
class Arc:
    """One arc of ``count`` evenly spaced lights (see the module docstring; angles in deg)."""

    azimuth_deg: float
    elevation_deg: float
    beta_deg: float
    phi0_deg: float
    span_deg: float
    rho_m: float
    count: int

    def __post_init__(self):
        if self.count < 1:
            raise ValueError(f"an arc needs count >= 1, got {self.count}")
        if not (0 < self.beta_deg < 90 and 0 < self.span_deg <= 360 and self.rho_m > 0):
            raise ValueError(f"arc needs 0 < beta_deg < 90, 0 < span_deg <= 360 and rho_m > 0, "
                             f"got {self.beta_deg}, {self.span_deg}, {self.rho_m}")

    @property
    def closed(self) -> bool:
        return self.span_deg >= 360.0 - 1e-9

    @property
    def circle(self):
        """(centre (3,), radius, axis (3,), e1, e2) of the arc's circle about the eye at 0."""
        axis = axis_direction(self.azimuth_deg, self.elevation_deg)
        b = math.radians(self.beta_deg)
        e1, e2 = _basis(axis)
        return self.rho_m * math.cos(b) * axis, self.rho_m * math.sin(b), axis, e1, e2

    def angles_rad(self) -> np.ndarray:
        """Angles of the lights about the axis from e1: a closed ring spaces its lights over
        the whole turn without doubling the first."""
        step = self.span_deg / (self.count if self.closed else max(self.count - 1, 1))
        return np.radians(self.phi0_deg + step * np.arange(self.count))

    def positions(self, eye_center_m) -> np.ndarray:
        """(count, 3) light positions in the world."""
        c, r, _, e1, e2 = self.circle
        a = self.angles_rad()
        return (np.asarray(eye_center_m, float) + c
                + r * (np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2))

    @property
    def spacing_m(self) -> float:
        """Chord between neighbouring lights."""
        if self.count < 2:
            return math.inf
        _, r, _, _, _ = self.circle
        step = math.radians(self.span_deg) / (self.count if self.closed else self.count - 1)
        return 2 * r * math.sin(step / 2)

    def scene_table(self, eye_center_m, name: str, source_diameter_mm: float) -> str:
        """The arc as a ``[[lights]]`` table of ``kind = "arc"`` (docs/formats/scene.md)."""
        c, r, axis, e1, e2 = self.circle
        a0 = math.radians(self.phi0_deg)
        first = np.asarray(eye_center_m, float) + c + r * (math.cos(a0) * e1 + math.sin(a0) * e2)
        to_center = -(math.cos(a0) * e1 + math.sin(a0) * e2)
        # The loader spaces ``count`` lights over ``span`` end to end; a closed ring leaves the
        # last gap open so that no light doubles the first.
        span = self.span_deg * (self.count - 1) / self.count if self.closed else self.span_deg
        vec = lambda v: "[" + ", ".join(f"{x:.9f}" for x in v) + "]"  # noqa: E731
        return (f"[[lights]]\nname = \"{name}\"\nkind = \"arc\"\ncount = {self.count}\n"
                f"radius_mm = {r * 1e3:.6f}\nspan_deg = {span:.6f}\n"
                f"first_m = {vec(first)}\ncenter_direction = {vec(to_center)}\n"
                f"normal = {vec(axis)}\nsource_diameter_mm = {source_diameter_mm:g}\n")

    def describe(self) -> str:
        return (f"{self.count} lights, axis azimuth {self.azimuth_deg:.1f} deg / elevation "
                f"{self.elevation_deg:.1f} deg, beta {self.beta_deg:.1f} deg, from "
                f"{self.phi0_deg:.1f} deg over {self.span_deg:.1f} deg, "
                f"{self.rho_m * 1e3:.1f} mm from the eye (spacing {self.spacing_m * 1e3:.2f} mm)")


def share_counts(total: int, weights, minimum: int) -> np.ndarray:
    """``total`` lights shared over arcs by ``weights`` (largest remainders), each at least
    ``minimum``."""
    w = np.asarray(weights, dtype=np.float64)
    k = w.size
    if total < k * minimum:
        raise ValueError(f"total {total} lights cannot give {k} arcs {minimum} lights each")
    spare = total - k * minimum
    raw = spare * w / w.sum()
    base = np.floor(raw).astype(int)
    rest = spare - base.sum()
    base[np.argsort(-(raw - base), kind="stable")[:rest]] += 1
    return base + minimum


@dataclass(frozen=True, slots=True)
class ArcFamily:
    """``arcs`` arcs with ``min_total``..``max_total`` lights, each arc at least
    ``min_per_arc``, at distances ``rho_range_m`` from the eye."""

    arcs: int
    min_total: int
    max_total: int
    min_per_arc: int
    rho_range_m: tuple

    def __post_init__(self):
        if self.arcs < 1:
            raise ValueError(f"arcs must be >= 1, got {self.arcs}")
        if self.min_per_arc < 1:
            raise ValueError(f"min_per_arc must be >= 1, got {self.min_per_arc}")
        if self.max_total < self.arcs * self.min_per_arc:
            raise ValueError(f"lights: {self.max_total} cannot fill {self.arcs} arcs of at least "
                             f"{self.min_per_arc} lights each")
        if not self.min_total <= self.max_total:
            raise ValueError(f"min_total {self.min_total} exceeds max_total {self.max_total}")

    @property
    def dimension(self) -> int:
        return self.arcs * len(ARC_PARAMS) + 1

    def bounds(self) -> list[tuple[float, float]]:
        per = [self.rho_range_m if p == "rho_m" else ARC_BOUNDS[p] for p in ARC_PARAMS]
        lo = max(self.min_total, self.arcs * self.min_per_arc)
        return per * self.arcs + [(float(lo), float(self.max_total))]

    def integrality(self) -> np.ndarray:
        out = np.zeros(self.dimension, dtype=bool)
        out[-1] = True
        return out

    def decode(self, x) -> tuple[Arc, ...]:
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.dimension,):
            raise ValueError(f"parameter vector must have shape ({self.dimension},), got {x.shape}")
        n = len(ARC_PARAMS)
        per = x[:-1].reshape(self.arcs, n)
        counts = share_counts(int(round(x[-1])), per[:, n - 1], self.min_per_arc)
        return tuple(Arc(*row[: n - 1], count=int(c)) for row, c in zip(per, counts))

    def positions(self, x, eye_center_m) -> np.ndarray:
        return np.concatenate([a.positions(eye_center_m) for a in self.decode(x)])
