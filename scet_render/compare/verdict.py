"""The verdict table of a comparison: one row per quantity, its tolerance and the reason for
it, pass or flag, and for a flagged row the likely cause.

Tolerances (:data:`TOL`) are in one place, each with the measurement that set it: the
unperturbed test captures (paper_sim at 320x240, conductor cornea, 4 spp, 4 frames) against
their renders, whose differences are sampling noise, pose error of the tracker and the timing
measurement's own error.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

__all__ = ["CAUSES", "Tolerance", "TOL", "VerdictRow", "row"]

#: The likely causes a flagged row names.
CAUSES = ("geometry", "timing", "sensor", "material")


@dataclass(frozen=True, slots=True)
class Tolerance:
    value: float
    unit: str
    reason: str


TOL = {
    "total_lines": Tolerance(0.5, "lines", "S is a whole line count; part 1 measures it to "
                             "0.1-0.3 line on rendered 320x240 captures (4 frames)"),
    "exposure": Tolerance(0.5, "lines", "libcamera sets the exposure in whole lines; measured "
                          "to 0.1 line on rendered captures, so one line off is 10 SDs"),
    "pulse": Tolerance(0.5, "lines", "the pulse is ~2.4 lines at 320x240; measured to ~0.05 "
                       "line"),
    "phase": Tolerance(0.25, "lines", "the phase is measured to ~0.05 line per frame; a "
                       "capture's phase against the scene's is only meaningful for replays or "
                       "a phase-locked strobe"),
    "clock": Tolerance(100.0, "ppm", "a replay has none; the render follows the measured "
                       "period whatever it is, so only the nominal clock is checked"),
    "black": Tolerance(0.5, "DN", "the darkest patches read black + ambient (~0.1 DN measured)"),
    "gain": Tolerance(0.05, "ratio - 1", "signal of the capture over the render's (scene's "
                      "sensor model) on lit, glint-free pixels: 0.997-1.002 on unperturbed "
                      "captures; the measured timing's errors move it by ~0.5 %"),
    "band_first_row": Tolerance(0.3, "rows", "band fits of a frame and its render agree to "
                                "~0.05 row; a line of exposure or of phase moves them by 1"),
    "band_height": Tolerance(0.5, "rows", "Eq. (7): (Δe + Δs) S / Δt; one exposure line is 1 "
                             "row"),
    "profile": Tolerance(0.10, "relative RMS", "row profiles of a frame and its render differ "
                         "by 7.4-8.5 % at 4 spp (Monte Carlo noise, the tracker's pose error)"),
    "glint_position": Tolerance(0.5, "px", "median distance of matched glints: the tracker's "
                                "pose error and 4-spp centroids (~0.1-0.3 px)"),
    "glint_peak": Tolerance(0.25, "ratio - 1", "peaks are single pixels: Monte Carlo and shot "
                            "noise ~10 %"),
    "glint_energy": Tolerance(0.15, "ratio - 1", "energies sum the spot: ~5 % noise; a 20 % "
                              "gain error shows here too"),
    "glint_area": Tolerance(0.25, "ratio - 1", "areas count pixels above the threshold: +-1 "
                            "px of ~5"),
    "glints_matched": Tolerance(0.2, "share unmatched", "glints of a band edge come and go "
                                "with the pose (~5 % measured)"),
    "background": Tolerance(0.08, "ratio - 1", "lit skin and sclera; pose and Monte Carlo "
                            "noise ~2 %"),
    "noise": Tolerance(0.15, "ratio - 1", "noise SD of lit skin, median of pixel "
                       "differences: ~3 % between two renders"),
    "clutter": Tolerance(4.0, "per frame", "detections of 3 px or more that no light "
                         "explains: 1-4 a frame at 4 spp, differing by up to 2.7 between a "
                         "capture and its render"),
    "cornea_radius": Tolerance(0.15, "mm", "free-radius fits of 4-spp glints scatter ~0.3 mm "
                               "a sample, ~0.05 mm over a run; Read et al.'s corneas span "
                               "7.37-8.17 mm"),
    "light_offsets": Tolerance(0.15, "px", "per-light mean residual of the free-radius fits "
                               "above what per-glint noise leaves (RMS / sqrt(count)); a light "
                               "0.3 mm off moves its glint ~0.5-0.8 px at 320x240"),
    "gaze": Tolerance(0.3, "deg", "the render is made at the capture's tracked poses: the "
                      "tracker on the render returns them to ~0.1 deg (4 spp)"),
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
