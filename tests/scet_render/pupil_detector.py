"""An outside dark-pupil detector for the pupil label checks: OpenCV only, no SCET code.

The usual first stage of near-IR pupil trackers (Starburst, Li, Winfield & Parkhurst 2005;
ExCuSe and ElSe, Fuhl et al. 2015-2016, start the same way): smooth, threshold the dark pupil
well below the iris, take the largest roughly round dark blob and fit an ellipse to its
outline (``cv2.findContours`` + ``cv2.fitEllipse``).
"""

from __future__ import annotations

import cv2
import numpy as np

#: Pupil threshold as a fraction of the image's median: the pupil (albedo 0.02) reads a few
#: per cent of the iris (0.3), the sclera and skin (0.6-0.7) and the median pixel is one of
#: those, so a third of it sits far above the pupil's noise and far below the iris.
THRESHOLD_OF_MEDIAN = 0.35
#: Closing kernel (px): fills glints on the pupil (a few px across, the ring's chain of them
#: crosses its edge) before the outline is taken, as pupil detectors remove corneal
#: reflections first.
CLOSE_PX = 7
#: Smallest blob taken for a pupil (px) and its least circularity 4 pi area / perimeter^2.
MIN_AREA_PX = 50
MIN_CIRCULARITY = 0.6


def detect_pupil(image, black_level: float = 0.0):
    """(u, v, major, minor, angle_deg) of the dark pupil in an (H, W) image, or None.

    ``image`` is sensor counts or radiance; ``black_level`` is subtracted first.
    """
    img = np.asarray(image, dtype=np.float32) - np.float32(black_level)
    smooth = cv2.GaussianBlur(img, (5, 5), 1.0)
    dark = (smooth < THRESHOLD_OF_MEDIAN * float(np.median(smooth))).astype(np.uint8)
    dark = cv2.morphologyEx(dark, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    dark = cv2.morphologyEx(dark, cv2.MORPH_CLOSE,
                            cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (CLOSE_PX, CLOSE_PX)))
    contours, _ = cv2.findContours(dark, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    best = None
    for c in contours:
        area = cv2.contourArea(c)
        perimeter = cv2.arcLength(c, True)
        if area < MIN_AREA_PX or len(c) < 5 or perimeter == 0:
            continue
        if 4 * np.pi * area / perimeter ** 2 < MIN_CIRCULARITY:
            continue
        if best is None or area > best[0]:
            best = (area, c)
    if best is None:
        return None
    (u, v), (w, h), angle = cv2.fitEllipse(best[1])
    if w < h:
        w, h, angle = h, w, angle + 90.0
    return np.array([u, v, w, h, angle % 180.0])
