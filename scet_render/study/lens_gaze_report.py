"""The gaze-level section of ``reports/lens.md`` (:mod:`scet_render.study.lens_gaze`): the table
of valid share and gaze error per lens condition and tracker model, the board calibration's
scores, and sentences computed from the numbers (so that a rerun rewrites them), ending in a
recommendation for the prototype's focus and aperture."""

from __future__ import annotations

import math

from ..validate import ValidationConfig

#: A condition "keeps" the in-focus result when its valid share is at least this share of it.
KEEP_VALID = 0.9
#: In-focus stock-lens results within this many valid-share points (a share) and this ratio of
#: the median error count as alike (a judgement, not a measured spread: the default run has
#: 264 bands of two fixations, so one fixation's bands move the share by points).
ALIKE_VALID, ALIKE_MEDIAN = 0.02, 1.1

_HEAD = ("| condition | tracker | focal (px) | lens | blur at the glints (px) | bands | "
         "geometric valid | median (deg) | p95 (deg) | polynomial valid | median (deg) | "
         "p95 (deg) | identities | calibration RMS (px) |\n"
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
_TRACKER_NAMES = {"lens": "(a) right model", "pinhole": "(b) pinhole",
                  "board": "(c) board calibration"}


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %" if math.isfinite(x) else "-"


def _deg(x: float) -> str:
    return f"{x:.3f}" if math.isfinite(x) else "-"


def _row(r) -> str:
    cam = r.camera
    lens = (f"F{cam.f_number:g}, focus {cam.focus_distance_m * 1e3:.1f} mm"
            if cam.is_thin_lens else "pinhole")
    g, p = r.stats.get("geometric"), r.stats.get("polynomial")
    cells = [r.condition.label, _TRACKER_NAMES[r.tracker], f"{cam.fx_px:g}", lens,
             f"{r.blur_px:.2f}", str(g.n if g else 0)]
    for s in (g, p):
        cells += ([_pct(s.valid), _deg(s.median_deg), _deg(s.p95_deg)] if s is not None
                  else ["-"] * 3)
    cells += [_pct(r.identity_rate), f"{r.calibration_rms_px:.3f}"]
    return "| " + " | ".join(cells) + " |"


def gaze_table(results: list) -> str:
    """The markdown table: one row per (condition, tracker)."""
    return _HEAD + "\n" + "\n".join(_row(r) for r in results)


def _valid(r) -> float:
    g = r.stats.get("geometric")
    return g.valid if g is not None else math.nan


def _median(r) -> float:
    g = r.stats.get("geometric")
    return g.median_deg if g is not None else math.nan


def _summary(r) -> str:
    return f"{_pct(_valid(r))} valid, median {_deg(_median(r))} deg"


def reading(results: list, glints: list | None = None) -> str:
    """Sentences from the gaze table (and the glint-level optics table ``glints``, a list of
    :class:`~scet_render.study.lens.LensResult`), with the recommendation."""
    lines = []
    lens = [r for r in results if r.tracker == "lens"]
    base = lens[0] if lens else None
    trackers = {r.tracker: r for r in results if base is not None and r.condition == base.condition}
    if base is not None and len(trackers) > 1:
        parts = [f"{_TRACKER_NAMES[k]} {_summary(v)}" for k, v in trackers.items()]
        lines.append(f"* Tracker models on the same renders ({base.condition.label}, geometric "
                     f"gaze): " + "; ".join(parts) + ".")
    board = trackers.get("board")
    if board is not None and board.board:
        b = board.board
        lines.append(f"* The board calibration ({b['views']} views) recovered the focal length "
                     f"{b['focal_error_pct']:+.2f} % off, the distortion within "
                     f"{b['distortion_diff_px']:.2f} px over the frame (after the best "
                     f"homography), reprojection RMS {b['rms_px']:.3f} px, through the "
                     f"lens's depth of field at F{board.camera.f_number:g}.")
    focus = [r for r in lens if r.condition.focal_px == base.condition.focal_px
             and r.condition.working_distance_m is None
             and r.condition.f_number == base.condition.f_number] if base else []
    if len(focus) > 1 and math.isfinite(_valid(base)):
        kept = [r.condition.focus_offset_m * 1e3 for r in focus
                if _valid(r) >= KEEP_VALID * _valid(base)]
        lines.append("* Focus: " + "; ".join(
            f"{r.condition.focus_offset_m * 1e3:+g} mm ({r.blur_px:.1f} px blur) {_summary(r)}"
            for r in focus) + f". Within {KEEP_VALID:.0%} of the in-focus valid share up to "
            f"{max(kept):g} mm of those measured.")
    apert = [r for r in lens if r.condition.focus_offset_m == 0.0
             and r.condition.working_distance_m is None]
    if len(apert) > 1:
        lines.append("* Focal length and aperture (in focus, strobe power compensated): " +
                     "; ".join(f"{r.condition.label} {_summary(r)}" for r in apert) + ".")
    far = [r for r in lens if r.condition.working_distance_m is not None]
    for r in far:
        lines.append(f"* Farther out: {r.condition.label} {_summary(r)}.")
    lines.append(_recommendation(lens, glints or []))
    return "\n".join(lines)


def _recommendation(lens: list, glints: list) -> str:
    stock = [r for r in lens if r.condition.focal_px == 643.0
             and r.condition.working_distance_m is None and r.condition.focus_offset_m == 0.0
             and math.isfinite(_valid(r))]
    if not stock:
        return "* Recommendation: no stock-lens condition was measured."
    best = max(stock, key=lambda r: (round(_valid(r), 3), -_median(r)))
    # In-focus results this close are alike at these sample sizes: take the larger f-number of
    # them, for its depth of field (a focus error's blur scales as 1 / N).
    alike = [r for r in stock if _valid(r) >= _valid(best) - ALIKE_VALID
             and _median(r) <= ALIKE_MEDIAN * _median(best)] or [best]
    best = max(alike, key=lambda r: r.condition.f_number)
    n = best.condition.f_number
    light = ("at the stock strobe power" if n == 2.9 else
             "with the strobe power raised to keep the 1 ms exposure's signal")
    text = (f"* Recommendation (from these numbers): focus the stock lens on the glints' virtual "
            f"images ({best.camera.focus_distance_m * 1e3:.1f} mm from the camera, ~3.5 mm "
            f"behind the corneal apex) at F{n:g} ({_summary(best)} {light}")
    if len(alike) > 1:
        text += ("; in focus " + " and ".join(f"F{r.condition.f_number:g}" for r in alike) +
                 f" are alike (within {100 * ALIKE_VALID:g} points valid and "
                 f"{ALIKE_MEDIAN:g}x the median), so the larger f-number, for its depth of field")
    text += ")"
    off = [r for r in lens if r.condition.focal_px == 643.0 and r.condition.focus_offset_m > 0
           and r.condition.working_distance_m is None]
    if off:
        r = min(off, key=lambda r: r.condition.focus_offset_m)
        n0 = r.condition.f_number
        text += (f"; a focus error's blur scales as 1 / N: the "
                 f"{r.condition.focus_offset_m * 1e3:+g} mm condition's {r.blur_px:.2f} px at "
                 f"F{n0:g} is {r.blur_px * n0 / 5.6:.2f} px at F5.6")
    g_ok = [g for g in glints if g.condition.focal_px == 643.0
            and g.condition.working_distance_m is None and g.condition.focus_offset_m == 0.0]
    same = [g for g in g_ok if g.condition.f_number == n]
    if same:
        g = same[0]
        text += (f"; at the stock strobe power, i.e. (2.9 / {n:g})^2 = "
                 f"{(2.9 / n) ** 2:.2f} of the light, the glint detector still finds "
                 f"{100 * g.found:.0f} % of the lit glints (glint table above)")
    longer = [r for r in lens if r.condition.focal_px > 643.0 and r.condition.focus_offset_m == 0.0
              and r.condition.working_distance_m is None and math.isfinite(_valid(r))]
    if longer:
        top = max(longer, key=lambda r: (round(_valid(r), 3), -_median(r)))
        text += (f". A longer lens helps more than any aperture or focus setting: "
                 f"{top.condition.label} (focal {top.condition.focal_px:g} px) gives "
                 f"{_summary(top)} against {_summary(best)}")
    return text + (". The sensor model assumes the exposure's electrons scale with the light "
                   "collected, (2.9 / N)^2, at a fixed 1 ms exposure; the strobe's real power "
                   "and the LEDs' limits are not modelled.")


def gaze_section(results: list, config: ValidationConfig, wall_s: float,
                 glints: list | None = None) -> str:
    """The whole section: what was run, the table, the reading."""
    cfg = config
    render_s = sum(r.render_s for r in results)
    return f"""## Gaze error and valid share (calibrated and tracked per lens)

Each render condition runs the validation's pipeline (`scet_render.validate.validate_setup`):
single-pulse calibration frames of a {cfg.calib_grid[0]}x{cfg.calib_grid[1]} calibration grid,
{cfg.frames} banded test frames at {', '.join(map(str, cfg.pulses_per_frame))} pulses per frame
(fixations of the 24 x 15 grid, seed as above), {cfg.spp} spp, {cfg.cornea} cornea, scale 1/{cfg.scale}, rendered
through the condition's lens; calibrated and tracked by the estimator with (a) the rendered
lens model, (b) the same intrinsics as a pinhole, (c) intrinsics and distortion from a camera
calibration of ChArUco board frames rendered through the same lens (`scet render --board
charuco` + `scet camera calibrate`). Valid: bands with a gaze estimate; errors in degrees
against the true gaze; identities: identified glints whose light is right. The aperture here
changes the defocus only: the sensor collects the same light at every f-number (the strobe
power raised by (N / 2.9)^2); the glint tables above keep the strobe power. Gaze level run
time: {wall_s / 60:.1f} min on this machine, of which rendering {render_s / 60:.1f} min
(renders already in the work folder are reused).

{gaze_table(results)}

### Reading (gaze level)

{reading(results, glints)}
"""
