"""Where to put the wire mirror's LED (issue 35, "Design from it"): every turn's glint kept on
its turn over the screen, and every turn's brightness within a stated ratio.

The glints are the two-bounce solver's (:mod:`estimator.geometry.wire`). Along a turn's axis
the wire is a plane mirror, so the highlight sits where the unfolded path LED -> wire -> cornea
crosses the axis (Eq. (A) there): s = (l_a D_X + x_a D_L) / (D_L + D_X), with l_a, x_a the LED's
and the cornea's reflection point's axial coordinates and D_L, D_X their distances from the
wire across the axis. The cornea's travel over the screen moves x_a by a few mm, and the
highlight follows it by the share D_L / (D_L + D_X): the LED's axial offset only centres that
travel on the strip, the strip's width must hold its extent, and only an LED nearer the wire
than the eye shrinks it. So for each candidate LED one solve with a wide strip gives, for every
strip width w at once, which glints stay on (|s| <= w / 2), and the width that keeps all
(``required_width_m``: 2 max |s|).

Brightness: each turn's relative flux on the sensor, :func:`~estimator.geometry.wire.wire_glint_flux`
(the LED's beam toward the turn x enamelled copper's reflectance x the cornea's Fresnel x the
two mirrors' demagnification of the LED), at a few poses; the ratio is the brightest turn's
over the dimmest's at each pose, the worst pose's stated. :data:`MAX_FLUX_RATIO` is the target.

Candidates sit in the group's local frame (radius from the arc's axis, angle from the first
turn, offset along the arc's normal), each aimed at the middle turn (the scene format's default
``led_aim``), the mirror's pose kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from estimator.geometry.wire import eye_wire_glints, setup_wire_mirrors, wire_glint_flux
from estimator.geometry.wire_model import WireMirror
from estimator.setup import Setup

#: The brightness target: the dimmest turn's glint at least a quarter of the brightest's (two
#: stops). With the brightest glint exposed just under the 10-bit full scale (1023 DN) the
#: dimmest still peaks near 250 DN, far above the 16 DN black level and the shot noise of the
#: iris around it; a wider span forces either clipped bright glints or faint dim ones.
MAX_FLUX_RATIO = 4.0
#: The strip width (m) of the solve that measures every width at once: wide enough that no
#: highlight of a glint the cornea can show leaves it (the prototype's highlights stay within
#: +-2 mm of mid-width, reports/wire_mirror.md).
WIDE_STRIP_M = 12e-3


@dataclass(frozen=True, slots=True)
class LedScore:
    """One LED position scored over the poses.

    Attributes
    ----------
    led_local_m : (3,) float
        In the group's local frame.
    kept : (P, T) bool
        Glint visible with the wide strip, no occlusion test (lids, cap, image: everything but
        the strip's width).
    axial_m : (P, T) float
        The highlight's offset from mid-width (NaN where not ``kept``).
    reference : (P, T) bool
        Where the point-source model sees the turn (what "no glint lost" is measured against).
    flux : (F, T) float
        Relative flux at the flux poses: 0 where the wire loses a glint the point model shows,
        NaN where the point model shows none either (off the cap or the image: no LED helps).
    exact : (P, T) bool
        Visible on the mirror's own strip (``width_m``), occlusion tested.
    width_m : float
    glints_px : (P, T, 2) float
        The exact solve's glints.
    """

    led_local_m: np.ndarray
    kept: np.ndarray
    axial_m: np.ndarray
    reference: np.ndarray
    flux: np.ndarray
    exact: np.ndarray
    width_m: float
    glints_px: np.ndarray

    def visible(self, width_m: float) -> np.ndarray:
        """(P, T) visible on a strip ``width_m`` wide: the exact solve at the mirror's width,
        else the wide solve's highlights within the width (no occlusion test: an estimate)."""
        if abs(width_m - self.width_m) < 1e-12:
            return self.exact
        return self.kept & (np.abs(np.nan_to_num(self.axial_m, nan=np.inf)) <= 0.5 * width_m)

    def lost(self, width_m: float) -> float:
        """Share of the point model's glints (pose, turn) that the wire loses."""
        ref = self.reference
        return float((ref & ~self.visible(width_m)).sum() / max(ref.sum(), 1))

    def worst_turn(self, width_m: float) -> float:
        """The least covered turn's share of the point model's poses kept."""
        ref = self.reference
        got = (ref & self.visible(width_m)).sum(0) / np.maximum(ref.sum(0), 1)
        return float(got.min())

    @property
    def required_width_m(self) -> float:
        """The strip width that keeps every glint the point model sees and the wide strip keeps."""
        a = np.abs(self.axial_m[self.kept & self.reference])
        return float(2 * a.max()) if a.size else math.nan

    @property
    def flux_ratio(self) -> float:
        """The worst flux pose's brightest over dimmest glint, over the turns whose glint shows
        there (a glint lost is counted by :meth:`lost`, not here); NaN if none shows."""
        out = math.nan
        for f in self.flux:
            f = f[np.isfinite(f) & (f > 0)]
            if f.size:
                r = float(f.max() / f.min())
                out = r if math.isnan(out) else max(out, r)
        return out


def wire_group(setup: Setup):
    """(group index, its local :class:`WireMirror`, its pose) of the setup's one wire mirror."""
    found = setup_wire_mirrors(setup)
    if len(found) != 1:
        raise ValueError(f"{setup.name}: expected one wire_mirror light group, found {len(found)}")
    gi = found[0][0]
    group = setup.lights.groups[gi]
    return gi, group.emitter, group.pose


def led_position(mirror: WireMirror, radius_m: float, angle_rad: float, axial_m: float) -> np.ndarray:
    """(3,) a point in the mirror's frame: ``radius_m`` from the arc's axis at ``angle_rad``
    from the first turn, ``axial_m`` along the normal."""
    return (mirror.center_m + radius_m * (math.cos(angle_rad) * mirror.u + math.sin(angle_rad) * mirror.v)
            + axial_m * mirror.normal)


def with_led(mirror: WireMirror, led_m, *, width_m: float | None = None) -> WireMirror:
    """The mirror with its LED at ``led_m`` aimed at the middle turn (and another strip width)."""
    led = np.asarray(led_m, dtype=np.float64)
    mid = mirror.wire_axes_m[mirror.turns // 2]
    aim = (mid - led) / np.linalg.norm(mid - led)
    return replace(mirror, led_position_m=led, led_aim=aim,
                   width_m=mirror.width_m if width_m is None else float(width_m))


def score_led(setup: Setup, mirror: WireMirror, pose, led_m, yaw, pitch, flux_yaw, flux_pitch,
              reference=None) -> LedScore:
    """Score one LED (module docstring): the exact solve at the mirror's width, the wide-strip
    solve over (P,) poses and the flux at (F,) poses. ``mirror`` in the group's frame, ``pose``
    the group's."""
    real = with_led(mirror, led_m).posed(pose)
    wide = with_led(mirror, led_m, width_m=max(WIDE_STRIP_M, mirror.width_m)).posed(pose)
    exact = eye_wire_glints(setup.eye, setup.camera, real, yaw, pitch)
    # A wider strip and longer turns would block rays that the real ones let pass: the wide
    # solve skips the occlusion test (the exact solve holds it).
    w = eye_wire_glints(setup.eye, setup.camera, wide, yaw, pitch, occlusion=False)
    if reference is None:
        reference = setup.eye.glints(setup.camera, real.wire_axes_m, yaw, pitch)[1]
    eye = setup.eye
    center = eye.cornea_center(flux_yaw, flux_pitch)
    axis = eye.apex(flux_yaw, flux_pitch) - center
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    _, flux = wire_glint_flux(setup.camera, wide, center, eye.cornea_radius_m, cornea_axis=axis,
                              cap_cos_min=eye.cap_cos_min, refractive_index=eye.refractive_index,
                              occlusion=False)
    shown = eye.glints(setup.camera, real.wire_axes_m, flux_yaw, flux_pitch)[1]
    flux = np.where(shown, flux, np.nan)
    return LedScore(np.asarray(led_m, float), w.visible, np.where(w.visible, w.axial_m, np.nan),
                    np.asarray(reference, bool), flux, exact.visible, float(real.width_m),
                    exact.glints_px)


def design_poses_wire(setup: Setup, grid=(8, 5), flux_grid=(3, 3)):
    """(yaw, pitch) over the ``grid`` of screen targets and over the ``flux_grid``, edge to
    edge (``margin = 0``: the cornea's travel's extremes, beyond the 24 x 15 grid's cell
    centres)."""
    yaw, pitch = setup.eye.angles_toward(setup.screen.grid(*grid, margin=0.0))
    fy, fp = setup.eye.angles_toward(setup.screen.grid(*flux_grid, margin=0.0))
    return yaw, pitch, fy, fp


def candidate_leds(mirror: WireMirror, radii_mm, angles_deg, axial_mm) -> np.ndarray:
    """(C, 3) candidate LED positions (local frame) that the mirror accepts (inside the arc,
    clear of the wire)."""
    out = []
    for r in radii_mm:
        for a in angles_deg:
            for z in axial_mm:
                p = led_position(mirror, 1e-3 * r, math.radians(a), 1e-3 * z)
                try:
                    with_led(mirror, p)
                except ValueError:
                    continue
                out.append(p)
    return np.array(out).reshape(-1, 3)


def search_leds(setup: Setup, candidates_m, *, grid=(8, 5), flux_grid=(3, 3), progress=None) -> list:
    """Score every candidate (:func:`score_led`); the list of :class:`LedScore`."""
    _, mirror, pose = wire_group(setup)
    yaw, pitch, fy, fp = design_poses_wire(setup, grid, flux_grid)
    ref = setup.eye.glints(setup.camera, mirror.posed(pose).wire_axes_m, yaw, pitch)[1]
    out = []
    for i, p in enumerate(np.asarray(candidates_m, float)):
        out.append(score_led(setup, mirror, pose, p, yaw, pitch, fy, fp, ref))
        if progress is not None:
            progress(i + 1, len(candidates_m))
    return out


def trade_offs(scores: list, width_m: float, max_ratio: float = MAX_FLUX_RATIO) -> dict:
    """The choices a designer weighs, each an index into ``scores``: ``both`` (no glint lost at
    ``width_m`` and the ratio met: the smallest ratio; None if none), ``coverage`` (fewest lost,
    then the smallest ratio), ``ratio`` (the smallest ratio), ``width`` (the narrowest strip that
    loses nothing, among those meeting the ratio; None if none)."""
    lost = np.array([s.lost(width_m) for s in scores])
    ratio = np.array([s.flux_ratio for s in scores])
    ratio = np.where(np.isfinite(ratio), ratio, np.inf)
    need = np.array([s.required_width_m for s in scores])
    ok_ratio = ratio <= max_ratio
    both = np.flatnonzero((lost == 0) & ok_ratio)
    order = np.lexsort((ratio, lost))
    meets = np.flatnonzero(ok_ratio & np.isfinite(need))
    return {"both": int(both[np.argmin(ratio[both])]) if both.size else None,
            "coverage": int(order[0]), "ratio": int(np.argmin(ratio)),
            "width": int(meets[np.argmin(need[meets])]) if meets.size else None,
            "lost": lost, "ratios": ratio, "required_width_m": need}


def run_strip(flux_row, max_ratio: float = MAX_FLUX_RATIO) -> tuple[int, int]:
    """(first, stop) of the longest run of neighbouring turns whose brightness (``flux_row``
    (T,) or (F, T): every row; NaN and zero entries, glints not showing, ignored) stays within
    ``max_ratio``."""
    f = np.atleast_2d(np.asarray(flux_row, float))
    T = f.shape[1]
    best = (0, 0)
    for a in range(T):
        for b in range(a + 1, T + 1):
            seg = f[:, a:b]
            lit = [row[np.isfinite(row) & (row > 0)] for row in seg]
            if any(x.size and x.max() / x.min() > max_ratio for x in lit):
                break
            if b - a > best[1] - best[0]:
                best = (a, b)
    return best


def pair_score(a: LedScore, b: LedScore, width_m: float) -> dict:
    """Two LEDs on one mirror: each turn then makes two glints. ``lost`` (share of the point
    model's glints that neither keeps), ``both`` (share of kept (pose, turn) pairs where both
    glints show) and ``separation_px`` (median distance between the two glints of a turn
    where both show: closer than ~4 px they blend into one spot)."""
    va, vb = a.visible(width_m), b.visible(width_m)
    ref = a.reference
    either = va | vb
    both = va & vb
    sep = np.linalg.norm(a.glints_px - b.glints_px, axis=-1)[both]
    return {"lost": float((ref & ~either).sum() / max(ref.sum(), 1)),
            "worst_turn": float(((ref & either).sum(0) / np.maximum(ref.sum(0), 1)).min()),
            "both": float(both.sum() / max(either.sum(), 1)),
            "separation_px": float(np.median(sep)) if sep.size else math.nan}


__all__ = ["run_strip", "pair_score", "MAX_FLUX_RATIO", "WIDE_STRIP_M", "LedScore", "wire_group", "led_position", "with_led",
           "score_led", "design_poses_wire", "candidate_leds", "search_leds", "trade_offs"]
