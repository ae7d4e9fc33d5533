"""What a light layout is worth: glints per band over the gaze a tracker meets.

Two measures, one cheap and one real:

* :func:`band_counts` (the search's objective): for each design pose and each visible band,
  the glints that land on the rows the band's pulse dominates with at least
  :data:`ROW_WEIGHT_MIN` of its light (dimmer ramp rows lose glints in the detector), on the
  corneal cap, past the lids and the skin, and at least :data:`MIN_SEPARATION_PX` from every
  other glint (closer ones blend into one detection). A band "counts" with at least ``need``
  of them.
* :func:`evaluate_layout` (what the report states): the same glints with the feature noise
  e_f, identified by the tracker's own :class:`estimator.matching.GlintMatcher` cold (no
  prior from the band before, the harder case), band by band; a band is valid when it holds
  at least :data:`estimator.tracker.MIN_GLINTS` glints, the match is ``ok`` (unambiguous
  under the matcher's gate and margin) with that many identities, and its orbit fit's RMS
  residual is under :data:`estimator.tracker.MAX_RESIDUAL_PX`. Accuracy is the angle between
  the fitted and the true optical axis.

Design poses: the paper's 24 x 15 accuracy grid and poses drawn from the "saccades" dataset
trajectory (:func:`scet_render.dataset.dataset_trajectory`: main-sequence saccades between
random screen points, fixational drift and tremor), every pose tested against every band.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from estimator.banding import NO_PULSE, band_layout, row_strobe
from estimator.eye import gaze_direction
from estimator.matching import GlintMatcher, MatchParams
from estimator.geometry import project_glints
from estimator.geometry.wire import eye_wire_glints, setup_wire_mirrors
from estimator.setup import Setup
from estimator.tracker import MAX_RESIDUAL_PX, MIN_GLINTS

from .region import Shells, glint_unblocked, scene_shells

#: A glint counts for the band whose pulse dominates its row only where that pulse gives the
#: row at least half its light: the ramp rows at band edges (Eq. (5), 4.7 rows at 100 us in
#: paper_sim) render glints dim and cut, which the detector flags or misses.
ROW_WEIGHT_MIN = 0.5
#: Glints closer than this (px, at the camera's resolution) blend into one detection: a
#: rendered glint spot is 2-3 px across at 1300 px focal length.
MIN_SEPARATION_PX = 4.0
#: A band is a design band when at least this share of its pulse's light lands on visible
#: rows. paper_sim at 16 pulses has a 3-row sliver at the top (2.5 % of a pulse, rows 0-2)
#: that no layout can fill with 5 glints; it is reported, not optimised.
VISIBLE_SHARE_MIN = 0.5


@dataclass(frozen=True, slots=True)
class DesignPoses:
    """Eye rotations a layout is scored on: (m,) Fick yaw and pitch (rad), and where each
    came from (``"grid"`` or ``"motion"``)."""

    yaw_rad: np.ndarray
    pitch_rad: np.ndarray
    source: tuple

    @property
    def count(self) -> int:
        return int(self.yaw_rad.shape[0])

    def subset(self, step: int) -> "DesignPoses":
        """Every ``step``-th pose."""
        sel = slice(None, None, max(int(step), 1))
        return DesignPoses(self.yaw_rad[sel], self.pitch_rad[sel], self.source[sel])


def design_poses(setup: Setup, grid=(24, 15), motion: int = 96, seed: int = 0) -> DesignPoses:
    """The accuracy grid (cell centres) and ``motion`` poses of the "saccades" trajectory at
    seeded random instants."""
    from scet_render.dataset import dataset_trajectory

    if motion < 0 or grid[0] < 1 or grid[1] < 1:
        raise ValueError(f"design poses need a grid of at least 1x1 and motion >= 0, got "
                         f"grid {grid} and motion {motion}")
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(int(grid[0]), int(grid[1])))
    src = ["grid"] * yaw.size
    if motion:
        frames = max(60, motion // 4)
        traj = dataset_trajectory(setup, "saccades", frames, seed)
        t = np.random.default_rng(np.random.SeedSequence([seed, 7])).uniform(
            0.0, traj.duration_s, motion)
        my, mp = traj.angles_at(np.sort(t))
        yaw, pitch = np.concatenate([yaw, my]), np.concatenate([pitch, mp])
        src += ["motion"] * motion
    return DesignPoses(np.asarray(yaw, float), np.asarray(pitch, float), tuple(src))


@dataclass(frozen=True, slots=True)
class BandModel:
    """The visible bands of frame 0 and which band each visible row's glints belong to.

    Attributes
    ----------
    first_row, last_row : (B,) int
        Rows each band lights (:class:`estimator.banding.Band`).
    pulse_index : (B,) int
    fraction_visible : (B,) float
    row_band : (N,) int
        Band (0..B-1) whose pulse dominates the row with weight >= :data:`ROW_WEIGHT_MIN`;
        -1 for dark or dim rows.
    """

    first_row: np.ndarray
    last_row: np.ndarray
    pulse_index: np.ndarray
    fraction_visible: np.ndarray
    row_band: np.ndarray

    @property
    def count(self) -> int:
        return int(self.first_row.shape[0])

    @property
    def design(self) -> np.ndarray:
        """(B,) bool: bands with at least :data:`VISIBLE_SHARE_MIN` of their light visible."""
        return self.fraction_visible >= VISIBLE_SHARE_MIN


def band_model(setup: Setup) -> BandModel:
    """The band layout of frame 0 (the strobe is locked to the frame in every built-in scene;
    a drifting strobe shifts the bands from frame to frame and frame 0 stands for them)."""
    bands = [b for b in band_layout(setup.sensor, setup.strobe, 0) if b.visible]
    pulse, _, weight = row_strobe(setup.sensor, setup.strobe, 0)
    index = {b.pulse_index: i for i, b in enumerate(bands)}
    row_band = np.array([index.get(int(p), -1) if p != NO_PULSE and w >= ROW_WEIGHT_MIN else -1
                         for p, w in zip(pulse, weight)], dtype=np.int64)
    return BandModel(np.array([b.first_row for b in bands]), np.array([b.last_row for b in bands]),
                     np.array([b.pulse_index for b in bands]),
                     np.array([b.fraction_visible for b in bands]), row_band)


def layout_glints(setup: Setup, lights_m, poses: DesignPoses, shells: Shells | None = None):
    """Noise-free glints (P, n, 2) and whether each is usable (P, n): on the cap, inside the
    image, past lids and skin, and clear of every other usable glint by
    :data:`MIN_SEPARATION_PX`. Every light is a point source."""
    lights = np.asarray(lights_m, dtype=np.float64).reshape(-1, 3)
    g, vis, pts = _point_glints(setup, lights, poses)
    return usable_glints(setup, g, vis, pts, lights, shells)


def _point_glints(setup: Setup, lights, poses: DesignPoses):
    """(glints (P, n, 2), visible (P, n), reflection points (P, n, 3)) of point lights."""
    eye = setup.eye
    center = eye.cornea_center(poses.yaw_rad, poses.pitch_rad)
    axis = gaze_direction(poses.yaw_rad, poses.pitch_rad)
    return project_glints(setup.camera, center, eye.cornea_radius_m, lights,
                          cornea_axis=axis, cap_cos_min=eye.cap_cos_min, return_points=True)


def setup_layout_glints(setup: Setup, poses: DesignPoses, shells: Shells | None = None):
    """:func:`layout_glints` of the setup's own lights, where a ``wire_mirror`` group's turns
    are the LED seen in each wire turn (two bounces, :func:`estimator.geometry.wire.eye_wire_glints`;
    the light toward the cornea leaves the wire's highlight) and other groups are points."""
    lights = setup.lights_world_m
    wires = setup_wire_mirrors(setup)
    if not wires:
        return layout_glints(setup, lights, poses, shells)
    eye = setup.eye
    g, vis, pts = (np.array(a) for a in _point_glints(setup, lights, poses))
    sources = np.array(np.broadcast_to(lights, pts.shape))
    for _, first, mirror in wires:
        w = eye_wire_glints(eye, setup.camera, mirror, poses.yaw_rad, poses.pitch_rad)
        sl = slice(first, first + mirror.turns)
        g[:, sl], vis[:, sl] = w.glints_px, w.visible
        pts[:, sl], sources[:, sl] = w.cornea_point_m, w.highlight_m
    return usable_glints(setup, g, vis, pts, sources, shells)


def usable_glints(setup: Setup, glints_px, visible, points_m, sources_m, shells: Shells | None = None):
    """(glints (P, n, 2), usable (P, n)): ``visible`` glints whose rays pass the lids and the
    skin (``sources_m`` (n, 3) or (P, n, 3): where the light toward the cornea comes from),
    clear of every other usable glint by :data:`MIN_SEPARATION_PX`."""
    shells = scene_shells(setup) if shells is None else shells
    g = glints_px
    vis = visible & glint_unblocked(setup, shells, points_m, sources_m)
    gz = np.where(vis[..., None], g, np.nan)
    d = np.linalg.norm(gz[:, :, None, :] - gz[:, None, :, :], axis=-1)
    idx = np.arange(g.shape[1])
    d[:, idx, idx] = np.inf
    crowded = np.nanmin(np.where(np.isnan(d), np.inf, d), axis=2) < MIN_SEPARATION_PX
    return g, vis & ~crowded


def glint_bands(model: BandModel, glints_px, usable) -> np.ndarray:
    """(P, n) band index of each usable glint (-1: none)."""
    v = np.round(np.where(usable, glints_px[..., 1], -1.0)).astype(np.int64)
    inside = usable & (v >= 0) & (v < model.row_band.shape[0])
    return np.where(inside, model.row_band[np.clip(v, 0, model.row_band.shape[0] - 1)], -1)


def band_counts(model: BandModel, glints_px, usable) -> np.ndarray:
    """(P, B) usable glints per pose and band."""
    b = glint_bands(model, glints_px, usable)
    P = b.shape[0]
    counts = np.zeros((P, model.count), dtype=np.int64)
    rows, cols = np.nonzero(b >= 0)
    np.add.at(counts, (rows, b[rows, cols]), 1)
    return counts


def counted_share(model: BandModel, counts, need: int) -> float:
    """Share of (pose, design band) pairs with at least ``need`` glints."""
    sel = model.design
    if not sel.any():
        return 0.0
    return float((counts[:, sel] >= need).mean())


@dataclass(frozen=True, slots=True)
class LayoutScore:
    """What :func:`evaluate_layout` measured for one layout.

    Attributes
    ----------
    valid : (P, B) bool
        Band valid at the pose (see the module docstring).
    counts : (P, B) int
        Usable glints in the band (before noise).
    error_deg : (P, B) float
        Angle between fitted and true optical axis (NaN where not valid).
    reasons : dict
        Why bands failed, with counts ("few_glints" below MIN_GLINTS, "match_<reason>",
        "too_few_identified", "residual_too_large").
    model : BandModel
    lights : int
    """

    valid: np.ndarray
    counts: np.ndarray
    error_deg: np.ndarray
    reasons: dict
    model: BandModel
    lights: int
    noise_px: float = 0.5
    extra: dict = field(default_factory=dict)

    @property
    def share_design(self) -> float:
        """Share of valid (pose, design band) pairs."""
        return float(self.valid[:, self.model.design].mean())

    @property
    def share_all(self) -> float:
        """Share of valid (pose, band) pairs over every band that touches visible rows (what
        the tracker emits and ``scet validate`` counts)."""
        return float(self.valid.mean())

    def per_band(self) -> np.ndarray:
        """(B,) share of poses at which each band is valid."""
        return self.valid.mean(axis=0)

    def accuracy(self) -> tuple[float, float, float]:
        """Mean, median and 95th percentile of the error of valid bands (deg)."""
        e = self.error_deg[np.isfinite(self.error_deg)]
        if not e.size:
            return (math.nan, math.nan, math.nan)
        return float(e.mean()), float(np.median(e)), float(np.percentile(e, 95))


def evaluate_layout(setup: Setup, poses: DesignPoses, *, noise_px: float = 0.5, seed: int = 0,
                    params: MatchParams = MatchParams(), progress=None) -> LayoutScore:
    """Identify and fit every band at every pose with the tracker's matcher (module docstring).

    Parameters
    ----------
    setup : Setup
        The scene with the layout under test as its lights.
    poses : DesignPoses
    noise_px : float
        Feature noise e_f, uniform in [-e_f, e_f] per axis (Böhme et al.; the paper's 0.5 px).
    seed : int
    params : MatchParams
    progress : callable, optional
        ``progress(done, total)`` after each pose.
    """
    from scet_render.simulate import feature_noise

    model = band_model(setup)
    lights = setup.lights_world_m
    g, usable = setup_layout_glints(setup, poses)
    bands = glint_bands(model, g, usable)
    counts = band_counts(model, g, usable)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 11]))
    noisy = g + feature_noise(g.shape, noise_px, "uniform", rng)
    matcher = GlintMatcher(setup, params)
    P, B = counts.shape
    valid = np.zeros((P, B), dtype=bool)
    err = np.full((P, B), np.nan)
    reasons: dict = {}
    truth = gaze_direction(poses.yaw_rad, poses.pitch_rad)
    for p in range(P):
        for b in range(B):
            sel = bands[p] == b
            if sel.sum() < MIN_GLINTS:
                reason = "few_glints"
            else:
                m = matcher.match(noisy[p, sel], rows=(model.first_row[b], model.last_row[b]))
                if not m.ok:
                    reason = f"match_{m.reason}"
                elif m.matched.sum() < MIN_GLINTS:
                    reason = "too_few_identified"
                elif not m.rms_px <= MAX_RESIDUAL_PX:
                    reason = "residual_too_large"
                else:
                    reason = "ok"
                    valid[p, b] = True
                    est = gaze_direction(*m.angles_rad)
                    err[p, b] = math.degrees(math.acos(min(1.0, float(est @ truth[p]))))
            reasons[reason] = reasons.get(reason, 0) + 1
        if progress is not None:
            progress(p + 1, P)
    return LayoutScore(valid, counts, err, dict(sorted(reasons.items())), model,
                       int(lights.shape[0]), float(noise_px))


def with_lights(setup: Setup, groups) -> Setup:
    """The setup with another light rig (a tuple of :class:`estimator.setup.LightGroup`)."""
    from estimator.setup import LightRig

    return replace(setup, lights=LightRig(tuple(groups)))
