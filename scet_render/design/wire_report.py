"""The wire mirror's LED designed for the prototype (issue 35, "Design from it"): the study
behind ``scet design-lights --wire-led`` and the "Design" section of reports/wire_mirror.md.

Steps (glints by the two-bounce solver throughout, :mod:`.wire_led`):

1. The LED at the cornea's mirror image through the arc's plane, centred along the normal
   (:func:`~.wire.centred_led`), the prototype scene's LED, and a grid about the centred one
   (+-6 mm across, +-2 mm along the normal): each scored over an 8 x 5 grid of gaze targets
   (glints lost on the 2 mm strip against the point model, the strip width that keeps every
   glint) and at 3 x 3 targets (brightness ratio across turns).
2. The strip widths that keep every glint for the best LED (exact solves, occlusion tested).
3. A second LED: the best partner of the best single LED (a turn's glint counts when either
   LED makes it; both make two glints of the same turn, their separation in px).
4. The brightness: the longest run of neighbouring turns within :data:`~.wire_led.MAX_FLUX_RATIO`,
   and the same mirror slid in its plane, in steps (:data:`SLIDES`), toward the placement
   whose arc is centred over the eye (every turn then as far from the eye), each with the
   rule's LED: the ratio against the glints the cornea shows at all.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from estimator.formats import atomic_write
from estimator.geometry.rigid import RigidPose
from estimator.geometry.wire import eye_wire_glints
from estimator.setup import LightGroup, Setup

from .objective import with_lights
from .wire import centred_led, mirrored_led
from .wire_led import (MAX_FLUX_RATIO, design_poses_wire, pair_score, run_strip, search_leds,
                       trade_offs, wire_group, with_led)

#: Fractions of the way to the eye-centred placement tried (:func:`recentred`).
SLIDES = (0.0, 0.25, 0.5, 0.6, 0.75, 1.0)
#: The designed strip width (m): the narrowest of :data:`WIDTHS_M` that loses no glint with
#: the design rule's LED on the prototype's mirror (reports/wire_mirror.md, "Design").
DESIGN_WIDTH_M = 3.0e-3
#: Strip widths (m) tried for the chosen LED.
WIDTHS_M = (2.0e-3, 2.5e-3, 3.0e-3, 3.5e-3, 4.0e-3)


def _local(pose, p):
    return pose.inverse().apply(np.asarray(p, float))


def lost_at_width(setup: Setup, mirror, pose, led_m, width_m: float, grid=(8, 5), *,
                  paper: bool = False) -> tuple[float, float]:
    """(lost share, worst turn's kept share) of the point model's glints, exact solve at
    ``width_m`` with the LED at ``led_m`` (local frame), over the ``grid`` edge to edge (or,
    ``paper``, its cell centres: the paper's 24 x 15 accuracy grid)."""
    if paper:
        yaw, pitch = setup.eye.angles_toward(setup.screen.grid(*grid))
    else:
        yaw, pitch, _, _ = design_poses_wire(setup, grid)
    real = with_led(mirror, led_m, width_m=width_m).posed(pose)
    vis = eye_wire_glints(setup.eye, setup.camera, real, yaw, pitch).visible
    ref = setup.eye.glints(setup.camera, real.wire_axes_m, yaw, pitch)[1]
    return (float((ref & ~vis).sum() / max(ref.sum(), 1)),
            float(((ref & vis).sum(0) / np.maximum(ref.sum(0), 1)).min()))


def recentred(setup: Setup, mirror_world, fraction: float = 1.0):
    """The mirror (world frame) slid in its own plane by ``fraction`` of the way that puts its
    arc's centre over the eye's rotation centre, its LED placed by the design rule
    (:mod:`.wire`)."""
    n = mirror_world.normal
    c_e = setup.eye.rotation_center_m
    h = float((mirror_world.center_m - c_e) @ n)
    target = c_e + h * n
    m = replace(mirror_world, center_m=mirror_world.center_m + fraction * (target - mirror_world.center_m),
                led_position_m=mirror_world.center_m)
    led = mirrored_led(setup, m.wire_axes_m, n, m.center_m)
    return centred_led(setup, with_led(m, led))


def slid_score(setup: Setup, mirror_world, fraction: float, yaw, pitch, fy, fp) -> dict:
    """The slid mirror (:func:`recentred`) scored: its :class:`~.wire_led.LedScore` and the
    glints lost at each of :data:`WIDTHS_M` (exact solves)."""
    from .region import Region, in_screen_view
    from .wire_led import score_led

    rec = recentred(setup, mirror_world, fraction)
    rs = with_lights(setup, [LightGroup("slid", "wire_mirror", rec.wire_axes_m,
                                        source_radius_m=rec.wire_radius_m, emitter=rec)])
    identity = RigidPose()
    score = score_led(rs, rec, identity, rec.led_position_m, yaw, pitch, fy, fp)
    return {"fraction": fraction, "mirror": rec, "score": score,
            "shift_mm": 1e3 * fraction * float(np.linalg.norm(
                recentred(setup, mirror_world).center_m - mirror_world.center_m)),
            "widths": {w: lost_at_width(rs, rec, identity, rec.led_position_m, w) for w in WIDTHS_M},
            "in_view": int(in_screen_view(setup, Region(), np.vstack([rec.wire_axes_m, rec.led_position_m])).sum()),
            "camera_mm": 1e3 * float(np.linalg.norm(rec.wire_axes_m - setup.camera.position_m, axis=1).min())}


def led_design_study(setup: Setup, *, step_mm: float = 3.0, axial_step_mm: float = 1.0,
                     progress=None) -> dict:
    """The module docstring's steps on ``setup``'s one wire mirror; a dict of the figures."""
    t0 = time.perf_counter()
    gi, m, pose = wire_group(setup)
    world = m.posed(pose)
    rule = centred_led(setup, with_led(world, mirrored_led(setup, world.wire_axes_m, world.normal,
                                                            world.center_m)))
    centre = _local(pose, rule.led_position_m)
    cands = [m.led_position_m, centre]
    k = np.arange(-2, 3)
    for a in k * step_mm * 1e-3:
        for b in k * step_mm * 1e-3:
            for c in k * axial_step_mm * 1e-3:
                if a == b == c == 0:
                    continue
                p = centre + a * m.u + b * m.v + c * m.normal
                try:
                    with_led(m, p)
                except ValueError:
                    continue
                cands.append(p)
    scores = search_leds(setup, np.array(cands), progress=progress)
    t = trade_offs(scores, m.width_m)
    best = t["coverage"]
    widths = {w: lost_at_width(setup, m, pose, scores[best].led_local_m, w) for w in WIDTHS_M}
    # The best partner of the best single LED.
    pairs = [(j, pair_score(scores[best], scores[j], m.width_m)) for j in range(len(scores)) if j != best]
    j, pair = min(pairs, key=lambda x: (x[1]["lost"], -x[1]["separation_px"]))
    run = run_strip(scores[best].flux)
    paper = {w: lost_at_width(setup, m, pose, scores[1].led_local_m, w, (24, 15), paper=True)
             for w in (m.width_m, DESIGN_WIDTH_M)}
    yaw, pitch, fy, fp = design_poses_wire(setup)
    slides = [slid_score(setup, world, f, yaw, pitch, fy, fp) for f in SLIDES]
    return {"scene": setup.name, "mirror": m, "pose": pose, "candidates": len(scores),
            "scores": scores, "trade": t, "best": best, "prototype": 0, "rule": 1,
            "widths": widths, "pair": (best, j), "pair_score": pair, "run": run,
            "slides": slides, "paper": paper,
            "seconds": time.perf_counter() - t0}


def _mm(p) -> str:
    return "[" + ", ".join(f"{1e3 * x:.1f}" for x in p) + "] mm"


def _pct(x) -> str:
    return f"{100 * x:.1f} %"


def write_design_section(report_path, d: dict) -> Path:
    """Replace (or append) the "## Design" section at the end of ``report_path``: the section
    runs from its heading to the next "## " heading or the end."""
    path = Path(report_path)
    text = path.read_text(encoding="utf-8") if path.exists() else ""
    new = design_section(d)
    if "\n## Design\n" in text:
        head, rest = text.split("\n## Design\n", 1)
        nxt = rest.find("\n## ")
        tail = rest[nxt:] if nxt >= 0 else ""
        text = head.rstrip() + "\n\n" + new + tail
    else:
        text = text.rstrip() + "\n\n" + new
    return atomic_write(path, text)


def design_section(d: dict) -> str:
    """The "Design" section (markdown) of reports/wire_mirror.md."""
    sc, m = d["scores"], d["mirror"]
    w0 = m.width_m
    rows = []
    for label, i in (("prototype scene's LED", d["prototype"]), ("design rule (mirror image, centred)", d["rule"]),
                     ("fewest glints lost", d["best"]), ("smallest brightness ratio", d["trade"]["ratio"])):
        s = sc[i]
        rows.append(f"| {label} | {_mm(s.led_local_m)} | {_pct(s.lost(w0))} | {_pct(s.worst_turn(w0))} | "
                    f"{1e3 * s.required_width_m:.2f} | {s.flux_ratio:.1f} |")
    widths = "".join(f"| {1e3 * w:.1f} mm | {_pct(lost)} | {_pct(worst)} |\n" for w, (lost, worst) in d["widths"].items())
    slides = "".join(
        f"| {100 * x['fraction']:.0f} % | {x['shift_mm']:.1f} | {_pct(x['score'].reference.mean())} | "
        f"{_pct(x['widths'][2.0e-3][0])} | {_pct(x['widths'][3.0e-3][0])} | "
        f"{1e3 * x['score'].required_width_m:.2f} | {x['score'].flux_ratio:.1f} | {x['in_view']} | "
        f"{x['camera_mm']:.1f} |\n" for x in d["slides"])
    i, j = d["pair"]
    ps = d["pair_score"]
    a, b = d["run"]
    both = d["trade"]["both"]
    return f"""## Design

Where to put the LED so that no glint is lost over the screen and every turn's brightness stays
within {MAX_FLUX_RATIO:g}x (two stops: with the brightest glint just under the 10-bit full scale the
dimmest still peaks near 250 DN); `scet design-lights prototype_ov5647_wire --wire-led`
(`scet_render/design/wire_report.py`, {d['seconds']:.0f} s). Glints by the two-bounce solver
over an 8 x 5 grid of gaze targets spanning the screen edge to edge, "lost" against the glints
the point-source model shows; brightness = relative flux (`wire_glint_flux`) at 3 x 3 targets
edge to edge, brightest over dimmest turn at the worst target. {d['candidates']} LED positions (group frame, aimed at the middle turn): the
prototype scene's, the design rule's (the turns' mean reflection point on the cornea mirrored
through the arc's plane, then moved along the normal until the highlights' ranges centre on the
strip: along a turn the wire is a plane mirror, the highlight follows the cornea by
D_L / (D_L + D_X) ~ 1/2 of its travel) and a grid about it (+-6 mm across, +-2 mm along the normal).

| LED | position | lost on the {1e3 * w0:g} mm strip | worst turn kept | strip width keeping all, mm | brightness ratio |
|---|---|---:|---:|---:|---:|
{chr(10).join(rows)}

{"No LED position meets both targets on this mirror (its placement, its 2 mm strip)." if both is None else f"LED {_mm(sc[both].led_local_m)} meets both."}

**Lost glints: the strip's width binds.** The cornea's travel over the screen moves each
turn's highlight ~2-3 mm along its wire whatever the LED's position (the LED's axial position
only centres the range; only an LED nearer the wire than the eye shrinks it, and those tried
lose the far turns). With the best LED, exact solves (occlusion tested) over strip widths:

| strip width | lost | worst turn kept |
|---|---:|---:|
{widths}
**A second LED** (best partner of the best single LED, {_mm(sc[j].led_local_m)}): lost
{_pct(ps['lost'])}, worst turn {_pct(ps['worst_turn'])}; but each turn then makes two glints, both
showing in {_pct(ps['both'])} of the kept (pose, turn) pairs, {ps['separation_px']:.1f} px apart
(median): two spots per turn that the matcher must tell apart, or one blended spot. A wider
strip does more for less.

**Brightness: the mirror's placement binds.** With the best LED the ratio is
{sc[d['best']].flux_ratio:.1f}x; the longest run of neighbouring turns within {MAX_FLUX_RATIO:g}x at every
target is turns {a}-{b - 1} ({b - a} of {m.turns}). The eye sits off the arc's axis: seen along the
normal it is ~5 mm from the nearest turns and ~35 mm from the far end, and each glint's flux
falls with the turn's distance from the eye and from the LED (the thin wire's demagnification);
no LED position evens that out (the smallest ratio of all candidates:
{sc[d['trade']['ratio']].flux_ratio:.1f}x). Sliding the same mirror in its plane toward the placement
whose arc is centred over the eye's rotation centre (every turn then as far from the eye), the
LED placed by the same rule each time:

| slid | shift mm | point model shows | lost on 2 mm | lost on 3 mm | strip keeping all, mm | brightness ratio | turns + LED in the screen view | nearest turn to the camera, mm |
|---:|---:|---:|---:|---:|---:|---:|---:|---:|
{slides}
The eye-centred mirror evens the brightness (a glint's flux then falls only with the gaze's
angle across the arc) but the cornea shows far fewer of its glints: the trade-off is between the
ratio and the share of the screen over which a turn shows at all, which the point model's own
coverage (the third column) bounds before any LED is placed.

**The designed part** (`scet hardware mirror --designed`, `hardware/mirror.py` `DESIGNED`):
the prototype's placement, a {1e3 * DESIGN_WIDTH_M:g} mm strip and the design rule's LED. Over the
paper's 24 x 15 grid (exact solves) it loses {_pct(d['paper'][DESIGN_WIDTH_M][0])} of the point model's
glints (worst turn keeps {_pct(d['paper'][DESIGN_WIDTH_M][1])}; the same LED on the {1e3 * w0:g} mm strip:
{_pct(d['paper'][w0][0])}, worst turn {_pct(d['paper'][w0][1])}); brightness {sc[d['rule']].flux_ratio:.1f}x, the
placement's limit above. The STL's notches and the written `wire_mirror` group come from one
`WireMirror` (`hardware.mirror.wire_mirror`; tests/hardware/test_mirror_design.py holds the
turns in the notches to 1e-6 mm). To meet the {MAX_FLUX_RATIO:g}x target too, the mirror must move
~60 % of the way toward the eye-centred placement (table above), giving up the glints the
cornea then no longer shows; a second LED is not the lever (two spots per turn).
"""


__all__ = ["led_design_study", "design_section", "write_design_section", "lost_at_width", "recentred", "slid_score",
           "WIDTHS_M", "SLIDES", "DESIGN_WIDTH_M"]
