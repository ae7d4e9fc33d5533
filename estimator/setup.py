"""The immutable description of one SCET system: camera, sensor, eye, lights, strobe, screen.

A scene file (``scenes/*.toml``, read by :mod:`estimator.scene`) loads into one :class:`Setup`;
the feature-level simulator, the renderer and the estimator all take it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .eye import Eye
from .geometry import Camera, RigidPose, as_points


@dataclass(frozen=True, slots=True)
class Sensor:
    """Rolling-shutter timing of the image sensor (Fig. 2 and Eqs. (2)-(3) of the paper).

    ``total_lines`` is S (visible plus invisible lines), ``visible_lines`` is N (the image
    height), ``frame_period_s`` is Δt and ``exposure_s`` is Δe.
    """

    total_lines: int
    visible_lines: int
    frame_period_s: float
    exposure_s: float
    bit_depth: int = 10
    black_level_dn: float = 16.0

    @property
    def line_time_s(self) -> float:
        """Time between the readouts of two consecutive lines, Δt / S."""
        return self.frame_period_s / self.total_lines


@dataclass(frozen=True, slots=True)
class Strobe:
    """Stroboscopic lighting: ``pulses_per_frame`` pulses of width Δs at period Δ_clk.

    ``phase_s`` is s^(0) - t0 of the first frame: the delay from the readout of the first row
    of frame 0 to the first pulse (Eq. (4)). Pulses run freely: pulse j starts at
    ``phase_s + j * period_s`` for every integer j, across frame boundaries.
    """

    pulses_per_frame: int
    pulse_s: float
    period_s: float
    phase_s: float = 0.0


@dataclass(frozen=True, slots=True)
class Screen:
    """The stimulus screen: an axis-aligned rectangle in the plane z = ``z_m``."""

    x_range_m: tuple[float, float]
    y_range_m: tuple[float, float]
    z_m: float

    @property
    def size_m(self) -> tuple[float, float]:
        return (self.x_range_m[1] - self.x_range_m[0], self.y_range_m[1] - self.y_range_m[0])

    def grid(self, cols: int, rows: int, margin: float = 0.5) -> np.ndarray:
        """(rows * cols, 3) target points on a regular grid, row-major from the top left.

        With ``margin = 0.5`` each point sits at the centre of its cell (the paper's 24 x 15
        grid of 360 points covers the screen this way); ``margin = 0`` puts the outer points on
        the screen edges.
        """
        if cols < 1 or rows < 1:
            raise ValueError(f"grid needs at least 1x1 points, got {cols}x{rows}")
        (x0, x1), (y0, y1) = self.x_range_m, self.y_range_m

        def axis(lo, hi, n):
            if n == 1:
                return np.array([(lo + hi) / 2.0])
            if margin > 0:
                return lo + (np.arange(n) + margin) * (hi - lo) / (n - 1 + 2 * margin)
            return np.linspace(lo, hi, n)

        xs = axis(x0, x1, cols)
        ys = axis(y1, y0, rows)  # top row first
        X, Y = np.meshgrid(xs, ys)
        return np.stack([X.ravel(), Y.ravel(), np.full(X.size, self.z_m)], axis=-1)


@dataclass(frozen=True, slots=True)
class DistanceSensor:
    """Infrared distance sensor of Sec. 3.3.1: d_a = gain * t + v, v uniform with SD ``noise_sd``."""

    gain_per_m: float = 1e3
    noise_sd: float = 8e-3


@dataclass(frozen=True, slots=True)
class LightGroup:
    """A rigid group of point lights: ``points_local_m`` placed in the world by ``pose``."""

    name: str
    kind: str
    points_local_m: np.ndarray
    pose: RigidPose = field(default_factory=RigidPose)
    source_radius_m: float = 0.2e-3
    #: The physical emitter behind the points, in the group's local frame, where the group
    #: models one (``kind = "wire_mirror"``: an :class:`estimator.geometry.wire.WireMirror`
    #: whose turns' axes are ``points_local_m``); None for plain point lights.
    emitter: object = None

    def __post_init__(self):
        p = as_points(self.points_local_m, "points_local_m").reshape(-1, 3).copy()
        p.setflags(write=False)
        object.__setattr__(self, "points_local_m", p)

    @property
    def count(self) -> int:
        return self.points_local_m.shape[0]

    @property
    def positions_world_m(self) -> np.ndarray:
        return self.pose.apply(self.points_local_m)

    def moved(self, pose: RigidPose) -> "LightGroup":
        """The same group with another pose."""
        return LightGroup(self.name, self.kind, self.points_local_m, pose, self.source_radius_m,
                          self.emitter)


@dataclass(frozen=True, slots=True)
class LightRig:
    """All light groups of a setup; lights are numbered group after group."""

    groups: tuple[LightGroup, ...]

    @property
    def count(self) -> int:
        return sum(g.count for g in self.groups)

    @property
    def positions_world_m(self) -> np.ndarray:
        """(n, 3) world positions of every light."""
        return np.concatenate([g.positions_world_m for g in self.groups], axis=0)

    @property
    def group_index(self) -> np.ndarray:
        """(n,) index of the group each light belongs to."""
        return np.concatenate([np.full(g.count, i) for i, g in enumerate(self.groups)])


@dataclass(frozen=True, slots=True)
class Setup:
    """One SCET system, as loaded from a scene file."""

    name: str
    camera: Camera
    sensor: Sensor
    eye: Eye
    lights: LightRig
    strobe: Strobe
    screen: Screen
    distance_sensor: DistanceSensor | None = None
    description: str = ""
    source: str = ""
    source_sha256: str = ""
    #: Lids that follow the eye (:class:`estimator.eyelids.Eyelids`, the scene's ``[eyelids]``
    #: table); None: the renderer's static lids.
    eyelids: Eyelids | None = None
    #: The scene's ``[appearance]`` table as written (sorted (key, value) pairs: numbers,
    #: booleans); None: no table. The estimator carries it unread: its keys belong to the
    #: renderer (:func:`scet_render.render.textures.read_appearance`).
    appearance: tuple | None = None

    @property
    def lights_world_m(self) -> np.ndarray:
        return self.lights.positions_world_m
