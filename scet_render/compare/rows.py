"""The verdict rows of a comparison and the quantified findings (see :mod:`.verdict`)."""

from __future__ import annotations

import math

import numpy as np

from .measure import match_identified
from .verdict import row

__all__ = ["verdict_rows", "blur_row", "extra_blur_px"]


def _circ(d, period):
    return (d + period / 2) % period - period / 2


def _ratio(a, b):
    return a / b - 1.0 if (math.isfinite(a) and math.isfinite(b) and b != 0) else math.nan


def _med(values):
    v = np.asarray([x for x in values if math.isfinite(x)], dtype=np.float64)
    return float(np.median(v)) if v.size else math.nan


def _timing_rows(setup, msetup, timing):
    sensor, strobe = setup.sensor, setup.strobe
    line_s = timing.frame_period_s / timing.total_lines
    S, S_sd = timing.total_lines, timing.total_lines_sd
    out = [row("timing", "S, total lines", "total_lines", S, sensor.total_lines,
               S - sensor.total_lines, "timing", f"SD {S_sd:.2f} line",
               tolerance=max(0.5, 3 * S_sd))]
    e_l = (timing.exposure_s - sensor.exposure_s) / line_s
    out.append(row("timing", "exposure (us)", "exposure", 1e6 * timing.exposure_s,
                   1e6 * sensor.exposure_s, e_l, "timing",
                   f"{1e6 * (timing.exposure_s - sensor.exposure_s):+.1f} us; SD "
                   f"{timing.exposure_s_sd / line_s:.2f} line",
                   tolerance=max(0.5, 3 * timing.exposure_s_sd / line_s)))
    p_l = (timing.pulse_s - strobe.pulse_s) / line_s
    out.append(row("timing", "pulse (us)", "pulse", 1e6 * timing.pulse_s, 1e6 * strobe.pulse_s,
                   p_l, "timing", tolerance=max(0.5, 3 * timing.pulse_s_sd / line_s)))
    ph = _circ(msetup.strobe.phase_s - strobe.phase_s, msetup.strobe.period_s)
    ph_sd = float(np.median(timing.phase_s_sd)) / line_s if timing.phase_s_sd else math.nan
    out.append(row("timing", "strobe phase (us)", "phase", 1e6 * msetup.strobe.phase_s,
                   1e6 * strobe.phase_s, ph / line_s, "timing",
                   f"{1e6 * ph:+.1f} us", tolerance=max(0.25, 3 * ph_sd)
                   if math.isfinite(ph_sd) else None))
    ppm = timing.clock_ppm
    out.append(row("timing", "strobe clock (ppm)", "clock", ppm, 0.0, ppm, "timing",
                   tolerance=max(100.0, 3 * timing.clock_ppm_sd)
                   if math.isfinite(timing.clock_ppm_sd) else None))
    n_b = sum(f.status == "bands" for f in timing.frames)
    out.append(row("timing", "banded frames for the drift", "drift", n_b, 3,
                   0.0 if n_b >= 3 else math.nan, "timing",
                   "" if n_b >= 3 else f"{n_b} banded frame(s): S from the nominal strobe clock"))
    return out, {"total_lines": S, "total_lines_diff": S - sensor.total_lines,
                 "exposure_diff_lines": e_l, "exposure_diff_s": timing.exposure_s - sensor.exposure_s,
                 "pulse_diff_lines": p_l, "phase_diff_s": ph, "phase_diff_lines": ph / line_s,
                 "clock_ppm": ppm}


def _band_rows(cm, rm):
    d_first, d_h, prof = [], [], []
    for f in cm:
        a, b = cm[f].bands, rm[f].bands
        if a.status == "bands" and b.status == "bands":
            d = (a.phase_rows - b.phase_rows + a.pitch_rows / 2) % a.pitch_rows - a.pitch_rows / 2
            d_first.append(d)
            d_h.append((a.rise_rows + a.width_rows) - (b.rise_rows + b.width_rows))
        pa, pb = cm[f].profile_dn, rm[f].profile_dn
        prof.append(float(np.sqrt(np.mean((pa - pb) ** 2)) / max(np.mean(np.abs(pb)), 1e-9)))
    return [row("bands", "first lit row, capture - render (rows)", "band_first_row",
                math.nan, math.nan, _med(d_first), "timing"),
            row("bands", "band height, capture - render (rows)", "band_height", math.nan,
                math.nan, _med(d_h), "timing"),
            row("bands", "row profile, RMS difference / mean", "profile", math.nan, math.nan,
                _med(prof), "material")]


def extra_blur_px(sigma_capture, sigma_render) -> float:
    """The Gaussian blur σ (px) the capture's glint spots have beyond the render's: the square
    root of the median over same-light pairs of σ_capture² - σ_render² (second moments of a
    convolution add), negative when the render's spots are the larger; NaN without a pair."""
    a, b = np.asarray(sigma_capture, dtype=np.float64), np.asarray(sigma_render, dtype=np.float64)
    ok = np.isfinite(a) & np.isfinite(b)
    if not ok.any():
        return math.nan
    d2 = float(np.median(a[ok] ** 2 - b[ok] ** 2))
    return math.copysign(math.sqrt(abs(d2)), d2)


def blur_row(sigma_capture, sigma_render):
    """The verdict row of the glint spots' size: the capture's extra blur, cause the optics
    (focus, aperture: :func:`~estimator.geometry.Camera.blur_diameter_px`)."""
    a = _med(sigma_capture)
    b = _med(sigma_render)
    n = int(np.sum(np.isfinite(sigma_capture) & np.isfinite(sigma_render)))
    return row("glints", "glint spot size, extra blur of the capture (px)", "blur", a, b,
               extra_blur_px(sigma_capture, sigma_render), "optics",
               f"RMS spot width along the rows, capture / render medians; {n} pairs")


def _glint_rows(cm, rm):
    dist, peak, energy, area, unmatched, total = [], [], [], [], 0, 0
    s_cap, s_ren = [], []
    for f in cm:
        a, b = match_identified(cm[f], rm[f])
        total += len(cm[f].identified)
        unmatched += len(cm[f].identified) - a.shape[0]
        dist.extend(np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1]))
        peak.extend(a[:, 2] / np.maximum(b[:, 2], 1e-9))
        energy.extend(a[:, 3] / np.maximum(b[:, 3], 1e-9))
        area.extend(a[:, 4] / np.maximum(b[:, 4], 1e-9))
        s_cap.extend(a[:, 5])
        s_ren.extend(b[:, 5])
    bg = _ratio(_med([m.background_dn for m in cm.values()]),
                _med([m.background_dn for m in rm.values()]))
    ns = _ratio(_med([m.noise_dn for m in cm.values()]), _med([m.noise_dn for m in rm.values()]))
    cl_c = float(np.mean([m.clutter for m in cm.values()]))
    cl_r = float(np.mean([m.clutter for m in rm.values()]))
    share = unmatched / total if total else math.nan
    return [row("glints", "same-light glint distance, median (px)", "glint_position", math.nan,
                math.nan, _med(dist), "geometry", f"{len(dist)} pairs"),
            row("glints", "identified glints the render lacks (share)", "glints_matched",
                unmatched, total, share, "geometry"),
            blur_row(s_cap, s_ren),
            row("glints", "glint peak, capture / render - 1", "glint_peak", math.nan, math.nan,
                _med(peak) - 1.0, "sensor"),
            row("glints", "glint energy, capture / render - 1", "glint_energy", math.nan,
                math.nan, _med(energy) - 1.0, "material"),
            row("glints", "glint area, capture / render - 1", "glint_area", math.nan, math.nan,
                _med(area) - 1.0, "material"),
            row("background", "background level, capture / render - 1", "background",
                _med([m.background_dn for m in cm.values()]),
                _med([m.background_dn for m in rm.values()]), bg, "material"),
            row("background", "noise SD, capture / render - 1", "noise",
                _med([m.noise_dn for m in cm.values()]), _med([m.noise_dn for m in rm.values()]),
                ns, "sensor"),
            row("background", "clutter per frame, capture - render", "clutter", cl_c, cl_r,
                cl_c - cl_r, "material")], {"glint_distance_px": _med(dist)}


def verdict_rows(setup, msetup, timing, sensor, geometry, gc, gr, cm, rm, gaze, cap_samples,
                 ren_samples):
    """(rows, findings): every :class:`~.verdict.VerdictRow` and the quantified differences."""
    rows, findings = _timing_rows(setup, msetup, timing)
    g = sensor["response_ratio"]
    rows.append(row("sensor", "black level (DN)", "black", sensor["black_level_dn"],
                    sensor["scene_black_level_dn"],
                    sensor["black_level_dn"] - sensor["scene_black_level_dn"], "sensor"))
    rows.append(row("sensor", "response vs the scene's sensor model - 1", "gain", g, 1.0,
                    g - 1.0, "sensor",
                    f"photon-transfer K {sensor['ptc_gain_e_per_dn_capture']:.2f} e-/DN "
                    f"(its render {sensor['ptc_gain_e_per_dn_render']:.2f}, the model "
                    f"{sensor['scene_gain_e_per_dn']:.2f})"))
    findings.update({"response_ratio": g, "black_level_dn": sensor["black_level_dn"]})
    rows.extend(_band_rows(cm, rm))
    grows, gf = _glint_rows(cm, rm)
    rows.extend(grows)
    findings.update(gf)
    r_c, r_r = geometry["cornea_radius_mm_capture"], geometry["scene_cornea_radius_mm"]
    se = geometry["cornea_radius_se_mm"]
    rows.append(row("geometry", "corneal radius, orbit fit (mm)", "cornea_radius", r_c, r_r,
                    r_c - r_r, "geometry", f"SE {se:.3f} mm; its render "
                    f"{geometry['cornea_radius_mm_render']:.3f} mm",
                    tolerance=max(0.1, 3 * se) if math.isfinite(se) else None))
    excess = gc.systematic_rms_px - max(gr.systematic_rms_px, gc.systematic_floor_px) \
        if math.isfinite(gr.systematic_rms_px) else math.nan
    rows.append(row("geometry", "per-light glint offsets, RMS (px)", "light_offsets",
                    gc.systematic_rms_px, gr.systematic_rms_px, excess, "geometry",
                    "difference: capture RMS above the larger of its render's and its noise "
                    f"floor ({gc.systematic_floor_px:.3f} px)"))
    findings.update({"cornea_radius_mm": r_c, "cornea_radius_diff_mm": r_c - r_r,
                     "light_offset_rms_px": gc.systematic_rms_px,
                     "light_offset_excess_px": excess})
    all_d = [d for v in gaze.values() for d in v]
    n_ok_c = sum(s.ok for s in cap_samples)
    n_ok_r = sum(s.ok for s in ren_samples)
    rows.append(row("tracker", "gaze difference, capture vs render, median (deg)", "gaze",
                    n_ok_c, n_ok_r, _med(all_d), "geometry",
                    "capture / render columns: samples estimated; per band in the report"))
    findings["gaze_difference_deg"] = _med(all_d)
    return rows, findings
