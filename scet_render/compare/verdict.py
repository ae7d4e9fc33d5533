"""The verdict table of a comparison: one row per quantity, its tolerance and the reason for
it, pass or flag, and for a flagged row the likely cause.

Tolerances (:data:`TOL`) are in one place, each with the measurement that set it: the
test captures (tests/scet_render/foreign.py: paper_sim at 320x240, conductor cornea, 4 spp,
4 frames; the seven of them, each perturbed in one respect, measured alike in every other)
against their renders, whose differences are sampling noise, pose error of the tracker and
the timing measurement's own error. Other resolutions, spp and corneas may need others: the
rows print what they measured.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

__all__ = ["CAUSES", "Tolerance", "TOL", "VerdictRow", "row"]

#: The likely causes a flagged row names.
CAUSES = ("geometry", "timing", "sensor", "material", "optics")


@dataclass(frozen=True, slots=True)
class Tolerance:
    value: float
    unit: str
    reason: str


TOL = {
    "total_lines": Tolerance(0.5, "lines", "S is a whole line count; measured -0.15 to +0.09 "
                             "line from the truth on rendered 320x240 captures (4 frames)"),
    "exposure": Tolerance(0.5, "lines", "libcamera sets the exposure in whole lines; measured "
                          "+0.03 to +0.17 line from the truth on rendered captures"),
    "pulse": Tolerance(0.5, "lines", "the pulse is ~2.4 lines at 320x240; measured -0.08 to "
                       "+0.11 line from the truth"),
    "phase": Tolerance(0.25, "lines", "measured -0.10 to +0.03 line from the truth; a "
                       "capture's phase against the scene's is only meaningful for replays or "
                       "a phase-locked strobe"),
    "clock": Tolerance(100.0, "ppm", "a replay has none, yet 4 rendered frames give -56 to "
                       "+64 ppm; the render follows the measured period whatever it is"),
    "black": Tolerance(0.5, "DN", "the darkest patches: -0.06 to -0.10 DN from the truth"),
    "gain": Tolerance(0.05, "ratio - 1", "signal of the capture over the render's (scene's "
                      "sensor model) on lit, glint-free pixels: 0.997-1.002 on unperturbed "
                      "captures; the measured timing's errors move it by ~0.5 %"),
    "band_first_row": Tolerance(0.3, "rows", "band fits of a frame and its render agree to "
                                "-0.05 to +0.04 row; a line of phase moves them by 1"),
    "band_height": Tolerance(0.5, "rows", "Eq. (7): (Δe + Δs) S / Δt, one exposure line is 1 "
                             "row; -0.19 to 0.00 row measured"),
    "profile": Tolerance(0.10, "relative RMS", "row profiles of a frame and its render differ "
                         "by 4.1-5.3 % at 4 spp (Monte Carlo noise, pose error), 8.2 % with "
                         "the cornea 0.2 mm off"),
    "glint_position": Tolerance(0.5, "px", "same-light glints of a capture and its render: "
                                "0.22-0.25 px (pose error, 4-spp centroids)"),
    "blur": Tolerance(0.7, "px", "the blur that gives the render the capture's glint spot "
                      "sizes pair by pair (second moments): +0.12 px on the unperturbed 320x240 "
                      "capture (25 spot pairs; their quadrature +0.07), 1.21 px where its frames "
                      "were blurred by 1.2 px (1.22 px at 640x480). It read +0.36-0.40 px "
                      "unperturbed while the fit compared median sizes over different spots and "
                      "blurred with a sampled Gaussian, whose variance falls short of σ² below "
                      "0.6 px (scet_render/compare/optics.py); blurs add in quadrature, so "
                      "0.7 px widens a 1 px spot by 22 %"),
    "glint_peak": Tolerance(0.12, "ratio - 1", "medians of single-pixel peaks: -0.01 to +0.04 "
                            "measured"),
    "glint_energy": Tolerance(0.08, "ratio - 1", "medians of spot sums: -0.01 to +0.03 "
                              "measured; the render has the estimated gain, a light level or "
                              "corneal reflectance error shows here"),
    "glint_area": Tolerance(0.25, "ratio - 1", "areas count pixels above the threshold: one "
                            "pixel of ~5; 0 measured, -0.17 with the cornea 0.2 mm off"),
    "glints_matched": Tolerance(0.2, "share unmatched", "glints at band edges come and go "
                                "with the pose: 4-9 % measured"),
    "background": Tolerance(0.06, "ratio - 1", "lit skin and sclera: -0.03 to +0.01 "
                            "measured"),
    "noise": Tolerance(0.10, "ratio - 1", "noise SD from neighbour differences of lit skin: "
                       "-0.03 to 0.00 measured"),
    "clutter": Tolerance(4.0, "per frame", "detections of 3 px or more that no light "
                         "explains: 1-4 a frame at 4 spp, differing by up to 2.7 between a "
                         "capture and its render"),
    "cornea_radius": Tolerance(0.1, "mm", "orbit fits of 4-spp glints: -0.003 to -0.014 mm "
                               "from the truth (SE ~0.01); lights 0.3 mm off bias it by -0.06"),
    "light_offsets": Tolerance(0.15, "px", "per-light mean residual of the free-radius fits "
                               "above what per-glint noise leaves (RMS / sqrt(count)); a light "
                               "0.3 mm off moves its glint ~0.5-0.8 px at 320x240"),
    "gaze": Tolerance(0.3, "deg", "the render is made at the capture's tracked poses: the "
                      "tracker on the render returns them to 0.035-0.073 deg (4 spp)"),
    "drift": Tolerance(0.0, "frames", "at least 3 banded frames give the drift and so S "
                       "without the strobe clock"),
}


@dataclass
class VerdictRow:
    """One quantity compared: ``difference`` (capture - render, or capture - scene) against
    ``tolerance``; ``cause`` is one of :data:`CAUSES` for a flagged row, "" otherwise."""

    group: str
    quantity: str
    capture: float
    render: float
    difference: float
    tolerance: float
    unit: str
    reason: str
    passed: bool
    cause: str
    note: str = ""

    def to_dict(self) -> dict:
        d = asdict(self)
        for k in ("capture", "render", "difference", "tolerance"):
            v = d[k]
            d[k] = None if v is None or not math.isfinite(v) else float(v)
        return d


def row(group: str, quantity: str, key: str, capture: float, render: float, difference: float,
        cause: str, note: str = "", tolerance: float | None = None) -> VerdictRow:
    """A row against :data:`TOL` [key]; a NaN difference is flagged (nothing to compare)."""
    tol = TOL[key]
    t = tol.value if tolerance is None else float(tolerance)
    ok = math.isfinite(difference) and abs(difference) <= t
    if not math.isfinite(difference) and not note:
        note = "could not be measured"
    return VerdictRow(group, quantity, capture, render, difference, t, tol.unit, tol.reason, ok,
                      "" if ok else cause, note)
