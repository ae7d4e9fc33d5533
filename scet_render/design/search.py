"""The layout search: differential evolution over arc families, then free lights where they pay.

1. **Arcs** (:class:`~scet_render.design.families.ArcFamily`): scipy's
   :func:`~scipy.optimize.differential_evolution` (seeded, ``workers=1``, integer light count)
   maximises the share of (pose, design band) pairs with at least ``need`` usable glints
   (:func:`~scet_render.design.objective.band_counts`, on every ``search_step``-th design
   pose), plus a tie-breaker that rewards glints up to ``need`` in the pairs still short
   (a smooth signal while few bands reach the bar). Lights outside the region, and, in the
   wire style, neighbours closer than the wire allows, are penalised (one whole share per
   offending light: the best layout has none). In the wire style every arc is a wire-wound
   mirror lit by one LED (:mod:`~scet_render.design.wire`) and the objective counts its
   two-bounce glints; an LED outside the region or a mirror that cannot be built is penalised
   like an offending light.
2. **Free lights** (``free`` > 0): from admissible positions drawn over the region, lights
   are added one at a time, each the one that brings most short (pose, band) pairs closer to
   ``need``, as long as one adds anything (a light that blends with existing glints at a pose
   counts against it there).
3. The layout before (the scene's own lights) and after are scored with the tracker's matcher
   on all design poses (:func:`~scet_render.design.objective.evaluate_layout`).

Bad budgets and regions raise ``ValueError`` naming the parameter.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import differential_evolution

from estimator.setup import LightGroup, Setup
from estimator.tracker import MIN_GLINTS

from .families import Arc, ArcFamily
from .objective import (BandModel, DesignPoses, LayoutScore, band_counts, band_model,
                        counted_share, design_poses, evaluate_layout, glint_bands, layout_glints,
                        setup_layout_glints, with_lights)
from .region import Region, admissible, on_frame, sample_region, scene_shells

STYLES = ("free", "wire")
#: The prototype's wire: 0.8 mm turns (scenes/prototype_ov5647.toml); neighbouring turns
#: need at least one wire diameter of gap to be wound and to image as separate glints.
WIRE_DIAMETER_M = 0.8e-3


@dataclass(frozen=True, slots=True)
class Budget:
    """What the search may spend.

    Attributes
    ----------
    lights : int
        Most lights in all.
    arcs : int
        Arcs of the family.
    free : int
        Lights (of ``lights``) kept for the free stage; 0 in the wire style.
    style : {"free", "wire"}
        ``"wire"``: arcs only, neighbours at least two wire diameters apart (centre to
        centre), each arc a ``wire_mirror`` (0.8 mm turns on a ``strip_width_m`` strip, one
        LED: :mod:`~scet_render.design.wire`), as the prototype's mirror is built.
    min_per_arc : int
    """

    lights: int = 80
    arcs: int = 3
    free: int = 16
    style: str = "free"
    min_per_arc: int = 4
    #: The wire style's strip width (m): 2 mm, the prototype's.
    strip_width_m: float = 2.0e-3

    def __post_init__(self):
        if not (np.isfinite(self.strip_width_m) and WIRE_DIAMETER_M <= self.strip_width_m <= 0.05):
            raise ValueError(f"strip_width_m must lie in [{WIRE_DIAMETER_M}, 0.05] m (no narrower "
                             f"than the wire), got {self.strip_width_m!r}")
        if self.style not in STYLES:
            raise ValueError(f"style must be one of {STYLES}, got {self.style!r}")
        if self.lights < MIN_GLINTS:
            raise ValueError(f"lights = {self.lights}: a band needs at least {MIN_GLINTS} glints "
                             f"(estimator.tracker.MIN_GLINTS), so no budget below {MIN_GLINTS} "
                             f"lights can make a valid band")
        if self.arcs < 1:
            raise ValueError(f"arcs must be >= 1, got {self.arcs}")
        if not 0 <= self.free < self.lights:
            raise ValueError(f"free = {self.free} must lie in [0, lights = {self.lights})")
        if self.style == "wire" and self.free:
            raise ValueError("free must be 0 in the wire style (a wound mirror holds arcs only)")
        if self.lights - self.free < self.arcs * self.min_per_arc:
            raise ValueError(f"lights = {self.lights} (free {self.free}) cannot fill arcs = "
                             f"{self.arcs} arcs of at least min_per_arc = {self.min_per_arc}")

    @property
    def source_diameter_mm(self) -> float:
        return WIRE_DIAMETER_M * 1e3 if self.style == "wire" else 0.4


@dataclass(frozen=True, slots=True)
class SearchSettings:
    """Sizes of the search (defaults: the committed designs)."""

    seed: int = 0
    maxiter: int = 40
    popsize: int = 8
    need: int = MIN_GLINTS + 1
    grid: tuple = (24, 15)
    motion: int = 96
    search_step: int = 3
    candidates: int = 1500
    noise_px: float = 0.5
    evaluate: bool = True

    def __post_init__(self):
        if self.need < MIN_GLINTS:
            raise ValueError(f"need must be >= {MIN_GLINTS} (estimator.tracker.MIN_GLINTS), "
                             f"got {self.need}")
        for name in ("maxiter", "popsize", "search_step", "candidates"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


@dataclass(frozen=True, slots=True)
class DesignResult:
    """The designed layout and its scores (``before``/``after`` are None when not evaluated)."""

    setup: Setup
    arcs: tuple
    free_m: np.ndarray
    budget: Budget
    region: Region
    settings: SearchSettings
    counted_before: float
    counted_after: float
    counted_arcs: float
    counts_before: np.ndarray
    counts_after: np.ndarray
    model: BandModel
    bound: float
    before: LayoutScore | None
    after: LayoutScore | None
    de_message: str
    de_evaluations: int
    history: list = field(default_factory=list)

    @property
    def lights(self) -> int:
        return self.setup.lights.count


def _objective_parts(model: BandModel, counts: np.ndarray, need: int) -> float:
    """Counted share plus the tie-breaker (at most 0.01)."""
    design = counts[:, model.design]
    short = np.minimum(design, need).mean() / need
    return counted_share(model, counts, need) + 0.01 * short


def coverage_bound(setup: Setup, model: BandModel, poses: DesignPoses, candidates_m,
                   need: int, shells) -> tuple[float, np.ndarray]:
    """Share of (pose, design band) pairs that any layout drawn from ``candidates_m`` could
    reach: the candidates' glints, thinned to :data:`~.objective.MIN_SEPARATION_PX` greedily,
    hold at least ``need`` in the band. Also returns the (P, B) counts of that thinned set."""
    from .objective import MIN_SEPARATION_PX
    from estimator.geometry import project_glints
    from estimator.eye import gaze_direction
    from .region import glint_unblocked

    eye = setup.eye
    center = eye.cornea_center(poses.yaw_rad, poses.pitch_rad)
    axis = gaze_direction(poses.yaw_rad, poses.pitch_rad)
    g, vis, pts = project_glints(setup.camera, center, eye.cornea_radius_m, candidates_m,
                                 cornea_axis=axis, cap_cos_min=eye.cap_cos_min, return_points=True)
    vis = vis & glint_unblocked(setup, shells, pts, candidates_m)
    bands = glint_bands(model, g, vis)
    counts = np.zeros((poses.count, model.count), dtype=np.int64)
    for p in range(poses.count):
        for b in range(model.count):
            pts_b = g[p, bands[p] == b]
            kept = []
            for q in pts_b:  # greedy thinning: a maximal well-separated subset
                if all(np.hypot(*(q - k)) >= MIN_SEPARATION_PX for k in kept):
                    kept.append(q)
                    if len(kept) >= need:
                        break
            counts[p, b] = len(kept)
    return counted_share(model, counts, need), counts


def _wire_layout(setup: Setup, region: Region, arcs, budget: Budget):
    """(the arcs' ``wire_mirror`` groups, penalty): one per mirror that cannot be built and per
    LED that is not admissible; groups None when a mirror cannot be built."""
    from .wire import led_positions, wire_groups

    try:
        groups = wire_groups(setup, arcs, WIRE_DIAMETER_M, width_m=budget.strip_width_m)
    except ValueError:
        return None, float(len(arcs))
    return groups, float((~admissible(setup, region, led_positions(groups))).sum())


def _arc_penalty(arcs: tuple[Arc, ...], budget: Budget) -> float:
    if budget.style != "wire":
        return 0.0
    return float(sum(a.count for a in arcs if a.spacing_m < 2 * WIRE_DIAMETER_M))


def _greedy_free(setup, model, poses, counts, current_m, candidates_m, free, need, shells):
    """Add up to ``free`` candidates one at a time (module docstring, step 2)."""
    from .objective import MIN_SEPARATION_PX

    chosen = []
    if free == 0 or candidates_m.shape[0] == 0:
        return np.zeros((0, 3)), counts
    g_c, u_c = layout_glints(setup, candidates_m, poses, shells)
    b_c = glint_bands(model, g_c, u_c)  # (P, C)
    design = model.design
    lights = np.asarray(current_m, float)
    g_l, u_l = layout_glints(setup, lights, poses, shells)
    gl = np.where(u_l[..., None], g_l, np.nan)
    # Distance of every candidate's glint to the layout's nearest glint, per pose (P, C),
    # over blocks of candidates, then kept up to date light by light.
    near = np.full(b_c.shape, np.inf)
    for c0 in range(0, candidates_m.shape[0], 64):
        d = np.linalg.norm(g_c[:, c0:c0 + 64, None, :] - gl[:, None, :, :], axis=-1)
        near[:, c0:c0 + 64] = np.nanmin(np.where(np.isnan(d), np.inf, d), axis=2)
    P = counts.shape[0]
    rows = np.arange(P)[:, None]
    band = np.clip(b_c, 0, model.count - 1)
    for _ in range(free):
        ok = (b_c >= 0) & (near >= MIN_SEPARATION_PX)
        cb = counts[rows, band]
        gain = ok & design[band] & (cb < need)
        # Reaching the bar is worth more than a step toward it; blending costs.
        score = (gain * (1.0 + 4.0 * (cb == need - 1))).sum(axis=0)
        score = score - ((b_c >= 0) & (near < MIN_SEPARATION_PX)).sum(axis=0) * 0.5
        best = int(np.argmax(score))
        if score[best] <= 0:
            break
        chosen.append(candidates_m[best])
        lights = np.concatenate([lights, candidates_m[best][None]])
        new = np.where(u_c[:, best, None], g_c[:, best], np.nan)  # (P, 2)
        d = np.linalg.norm(g_c - new[:, None, :], axis=-1)
        near = np.minimum(near, np.where(np.isnan(d), np.inf, d))
        g_l, u_l = layout_glints(setup, lights, poses, shells)
        counts = band_counts(model, g_l, u_l)
    return np.array(chosen).reshape(-1, 3), counts


def design_lights(setup: Setup, budget: Budget = Budget(), region: Region = Region(),
                  settings: SearchSettings = SearchSettings(), progress=None) -> DesignResult:
    """Search a layout for ``setup``'s camera, eye, screen and strobe (module docstring).

    Parameters
    ----------
    progress : callable, optional
        ``progress(stage, done, total)``; stages "arcs" (DE generations), "free" and
        "evaluate before" / "evaluate after" (poses).
    """
    check_budget_region(setup, budget, region)
    rng = np.random.default_rng(np.random.SeedSequence([settings.seed, 1]))
    shells = scene_shells(setup)
    model = band_model(setup)
    if not model.design.any():
        raise ValueError(f"setup {setup.name!r}: no band has {100 * 0.5:.0f} % of its light on "
                         "visible rows (sensor/strobe leave nothing to design for)")
    poses = design_poses(setup, settings.grid, settings.motion, settings.seed)
    search = poses.subset(settings.search_step)
    candidates = sample_region(setup, region, settings.candidates, rng)
    bound, _ = (0.0, None) if candidates.shape[0] == 0 else coverage_bound(
        setup, model, search, candidates, settings.need, shells)
    if candidates.shape[0] == 0 or bound == 0.0:
        raise ValueError(f"region: no admissible light position sees the cornea within the "
                         f"design bands ({region.describe()}; min_eye_distance_m, "
                         f"max_eye_distance_m, max_z_m, screen_margin_deg, frame_z_m)")
    c_e = setup.eye.rotation_center_m
    family = ArcFamily(budget.arcs, max(budget.arcs * budget.min_per_arc, MIN_GLINTS),
                       budget.lights - budget.free, budget.min_per_arc,
                       (region.min_eye_distance_m, region.max_eye_distance_m))
    history = []

    def layout(x):
        arcs = family.decode(x)
        pos = on_frame(setup, region, np.concatenate([a.positions(c_e) for a in arcs]))
        return arcs, pos

    def cost(x):
        arcs, pos = layout(x)
        bad = (~admissible(setup, region, pos)).sum() + _arc_penalty(arcs, budget)
        if budget.style == "wire":
            groups, bad_wire = _wire_layout(setup, region, arcs, budget)
            if groups is None:
                return bad + bad_wire
            g, u = setup_layout_glints(with_lights(setup, groups), search, shells)
            return -_objective_parts(model, band_counts(model, g, u), settings.need) + bad + bad_wire
        g, u = layout_glints(setup, pos, search, shells)
        return -_objective_parts(model, band_counts(model, g, u), settings.need) + bad

    def callback(intermediate_result):
        history.append(float(-intermediate_result.fun))
        if progress is not None:
            progress("arcs", len(history), settings.maxiter)

    de = differential_evolution(cost, family.bounds(), integrality=family.integrality(),
                                seed=settings.seed, maxiter=settings.maxiter,
                                popsize=settings.popsize, workers=1, polish=False, tol=1e-6,
                                callback=callback)
    arcs, arc_pos = layout(de.x)
    groups, bad_wire = (_wire_layout(setup, region, arcs, budget) if budget.style == "wire"
                        else (None, 0))
    if not admissible(setup, region, arc_pos).all() or _arc_penalty(arcs, budget) or bad_wire:
        raise ValueError("region: the search found no arc layout inside the region that keeps "
                         "every light" + (" and LED" if budget.style == "wire" else "")
                         + " admissible; widen the region (min_eye_distance_m, "
                         "max_eye_distance_m, screen_margin_deg) or raise maxiter")
    if groups is not None:  # the wire style: no free lights, the arcs are the layout
        g, u = setup_layout_glints(with_lights(setup, groups), poses, shells)
        counts_arcs = counts_after = band_counts(model, g, u)
        free_m = np.zeros((0, 3))
    else:
        g, u = layout_glints(setup, arc_pos, poses, shells)
        counts_arcs = band_counts(model, g, u)
        g, u = layout_glints(setup, arc_pos, search, shells)
        free_m, _ = _greedy_free(setup, model, search, band_counts(model, g, u), arc_pos,
                                 candidates, budget.free, settings.need, shells)
        g, u = layout_glints(setup, np.concatenate([arc_pos, free_m]), poses, shells)
        counts_after = band_counts(model, g, u)
    if progress is not None:
        progress("free", 1, 1)
    if groups is not None:
        groups = list(groups)
    else:
        groups = [LightGroup(f"arc{i}", "arc", a.positions(c_e), source_radius_m=0.5e-3
                             * budget.source_diameter_mm) for i, a in enumerate(arcs)]
    if free_m.shape[0]:
        groups.append(LightGroup("free", "list", free_m, source_radius_m=0.2e-3))
    designed = with_lights(setup, groups)
    g0, u0 = setup_layout_glints(setup, poses, shells)
    counts_before = band_counts(model, g0, u0)
    before = after = None
    if settings.evaluate:
        stage = (lambda name: (lambda d, t: progress(name, d, t))) if progress else (lambda n: None)
        before = evaluate_layout(setup, poses, noise_px=settings.noise_px, seed=settings.seed,
                                 progress=stage("evaluate before"))
        after = evaluate_layout(designed, poses, noise_px=settings.noise_px, seed=settings.seed,
                                progress=stage("evaluate after"))
    return DesignResult(designed, arcs, free_m, budget, region, settings,
                        counted_share(model, counts_before, settings.need),
                        counted_share(model, counts_after, settings.need),
                        counted_share(model, counts_arcs, settings.need),
                        counts_before, counts_after, model, bound, before, after,
                        str(de.message), int(de.nfev), history)


def check_budget_region(setup: Setup, budget: Budget, region: Region) -> None:
    """Raise early (before any search) when the region is outside the eye's reach."""
    if region.max_eye_distance_m <= setup.eye.cornea_offset_m + setup.eye.cornea_radius_m:
        raise ValueError(f"region max_eye_distance_m = {region.max_eye_distance_m * 1e3:g} mm "
                         f"lies inside the eye (corneal apex "
                         f"{(setup.eye.cornea_offset_m + setup.eye.cornea_radius_m) * 1e3:.2f} mm)")
    del budget  # validated by its own constructor


__all__ = ["Budget", "SearchSettings", "DesignResult", "design_lights", "coverage_bound",
           "check_budget_region", "STYLES", "WIRE_DIAMETER_M"]
