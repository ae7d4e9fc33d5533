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
   and the same mirror slid in its plane until its arc is centred over the eye (every turn
   then as far from the eye), which is what the ratio needs.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace

import numpy as np

from estimator.geometry.wire import eye_wire_glints
from estimator.setup import LightGroup, Setup

from .objective import with_lights
from .wire import centred_led, mirrored_led
from .wire_led import (MAX_FLUX_RATIO, design_poses_wire, pair_score, run_strip, search_leds,
                       trade_offs, wire_group, with_led)

#: Strip widths (m) tried for the chosen LED.
WIDTHS_M = (2.0e-3, 2.5e-3, 3.0e-3, 3.5e-3, 4.0e-3)


def _local(pose, p):
    return pose.inverse().apply(np.asarray(p, float))


def lost_at_width(setup: Setup, mirror, pose, led_m, width_m: float, grid=(8, 5)) -> tuple[float, float]:
    """(lost share, worst turn's kept share) of the point model's glints, exact solve at
    ``width_m`` with the LED at ``led_m`` (local frame)."""
    yaw, pitch, _, _ = design_poses_wire(setup, grid)
    real = with_led(mirror, led_m, width_m=width_m).posed(pose)
    vis = eye_wire_glints(setup.eye, setup.camera, real, yaw, pitch).visible
    ref = setup.eye.glints(setup.camera, real.wire_axes_m, yaw, pitch)[1]
    return (float((ref & ~vis).sum() / max(ref.sum(), 1)),
            float(((ref & vis).sum(0) / np.maximum(ref.sum(0), 1)).min()))


def recentred(setup: Setup, mirror_world):
    """The mirror (world frame) slid in its own plane so that its arc's centre sits over the
    eye's rotation centre, its LED placed by the design rule (:mod:`.wire`)."""
    n = mirror_world.normal
    c_e = setup.eye.rotation_center_m
    h = float((mirror_world.center_m - c_e) @ n)
    m = replace(mirror_world, center_m=c_e + h * n)
    led = mirrored_led(setup, m.wire_axes_m, n, m.center_m)
    return centred_led(setup, with_led(m, led))


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
    rec = recentred(setup, world)
    rec_setup = with_lights(setup, [LightGroup("recentred", "wire_mirror", rec.wire_axes_m,
                                               source_radius_m=rec.wire_radius_m, emitter=rec)])
    yaw, pitch, fy, fp = design_poses_wire(setup)
    from .wire_led import score_led

    identity = type(pose)()
    rec_score = score_led(rec_setup, rec, identity, rec.led_position_m, yaw, pitch, fy, fp)
    rec_widths = {w: lost_at_width(rec_setup, rec, identity, rec.led_position_m, w) for w in WIDTHS_M}
    from .region import Region, in_screen_view

    rec_view = int(in_screen_view(setup, Region(), np.vstack([rec.wire_axes_m, rec.led_position_m])).sum())
    rec_cam_mm = 1e3 * float(np.linalg.norm(rec.wire_axes_m - setup.camera.position_m, axis=1).min())
    return {"recentred_in_view": rec_view, "recentred_camera_mm": rec_cam_mm,
            "scene": setup.name, "mirror": m, "pose": pose, "candidates": len(scores),
            "scores": scores, "trade": t, "best": best, "prototype": 0, "rule": 1,
            "widths": widths, "pair": (best, j), "pair_score": pair, "run": run,
            "recentred": rec, "recentred_shift_mm": 1e3 * float(np.linalg.norm(rec.center_m - world.center_m)),
            "recentred_score": rec_score, "recentred_widths": rec_widths,
            "seconds": time.perf_counter() - t0}


def _mm(p) -> str:
    return "[" + ", ".join(f"{1e3 * x:.1f}" for x in p) + "] mm"


def _pct(x) -> str:
    return f"{100 * x:.1f} %"


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
    rwidths = "".join(f"| {1e3 * w:.1f} mm | {_pct(lost)} | {_pct(worst)} |\n" for w, (lost, worst) in d["recentred_widths"].items())
    i, j = d["pair"]
    ps = d["pair_score"]
    a, b = d["run"]
    rs = d["recentred_score"]
    both = d["trade"]["both"]
    return f"""## Design

Where to put the LED so that no glint is lost over the screen and every turn's brightness stays
within {MAX_FLUX_RATIO:g}x (two stops: with the brightest glint just under the 10-bit full scale the
dimmest still peaks near 250 DN); `scet design-lights prototype_ov5647_wire --wire-led`
(`scet_render/design/wire_report.py`, {d['seconds']:.0f} s). Glints by the two-bounce solver
over an 8 x 5 grid of gaze targets, "lost" against the glints the point-source model shows;
brightness = relative flux (`wire_glint_flux`) at 3 x 3 targets, brightest over dimmest turn at
the worst target. {d['candidates']} LED positions (group frame, aimed at the middle turn): the
prototype scene's, the design rule's (the turns' mean reflection point on the cornea mirrored
through the arc's plane, then moved along the normal until the highlights' ranges centre on the
strip: along a turn the wire is a plane mirror, the highlight follows the cornea by
D_L / (D_L + D_X) ~ 1/2 of its travel) and a grid about it (+-6 mm across, +-2 mm along the normal).

| LED | position | lost on the {1e3 * w0:g} mm strip | worst turn kept | strip width keeping all, mm | brightness ratio |
|---|---|---:|---:|---:|---:|
{chr(10).join(rows)}

{"No LED position meets both targets on this mirror." if both is None else f"LED {_mm(sc[both].led_local_m)} meets both."}

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
{sc[d['trade']['ratio']].flux_ratio:.1f}x). Sliding the same mirror {d['recentred_shift_mm']:.1f} mm in its plane until
the arc's centre sits over the eye's rotation centre (every turn then as far from the eye; LED by
the same rule at {_mm(d['recentred'].led_position_m)} world) gives a ratio of {rs.flux_ratio:.1f}x
(the point model shows {_pct(rs.reference.mean())} of its (pose, turn) glints, the prototype's
placement {_pct(sc[0].reference.mean())}),
{_pct(rs.lost(w0))} lost on the 2 mm strip (worst turn {_pct(rs.worst_turn(w0))}), strip width
keeping all ~{1e3 * rs.required_width_m:.2f} mm (no occlusion); exact solves:

| strip width | lost | worst turn kept |
|---|---:|---:|
{rwidths}
The re-centred mirror puts {d['recentred_in_view']} of its {m.turns} turns and LED in the eye's view of the
screen (2 deg margin, `design.region.in_screen_view`); its nearest turn is
{d['recentred_camera_mm']:.1f} mm from the camera's centre (whether the strip hides the camera's view of
the eye is not checked here).
"""


__all__ = ["led_design_study", "design_section", "lost_at_width", "recentred", "WIDTHS_M"]
