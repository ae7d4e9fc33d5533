"""What is compared, measured the same way on a capture's frame and on its render.

Per frame: the row profile (glints clipped as the timing measurement clips them) and its band
fit (:func:`estimator.capture.timing.measure_frame`: the first lit row and height of every
band); the glints (:func:`estimator.glints.detect_glints`: position, area, peak, energy);
the background level and the noise of the lit skin; the clutter (detections that the tracker
did not identify as any light's glint). Over a run: the corneal radius fitted to each
sample's identified glints with the cornea on the scene's orbit (yaw, pitch and radius: the
glint pattern's scale; a free centre and radius fit scattered 1.1 mm a sample, this one
~0.05 mm) and the glint residuals per light of that fit (a light off its nominal place leaves the same offset
in every sample that sees it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from estimator.capture.timing import (GLINT_CLIP_FACTOR, FrameBands, band_profile_model,
                                      measure_frame)
from estimator.eye import fick_angles, gaze_direction
from estimator.geometry import project_glints
from estimator.glints import detect_glints
from estimator.setup import Setup

__all__ = ["FrameMeasure", "measure_image", "spot_sigma_px", "SPOT_RADIUS_PX", "GeometryFit",
           "fit_geometry", "gaze_differences_deg", "match_identified"]

#: Detections smaller than this (px) are not counted as clutter: at a few spp a render's
#: specular sparkle (Monte Carlo fireflies) gives ~10-30 one- and two-pixel spots a frame,
#: different in every render.
MIN_CLUTTER_AREA_PX = 3
#: Half-width of the window a spot's size is measured in (px): 7 x 7 px, 2.2 σ of a spot of
#: 1 px σ blurred by 1.2 px; spots with another detection nearer than twice it are not
#: measured (the arcs of a 320x240 frame put glints 2.6-7.8 px apart, median 4.7).
SPOT_RADIUS_PX = 3
#: The background is the median of a ring around the window, from SPOT_RADIUS_PX + 2 to
#: SPOT_RADIUS_PX + SPOT_RING_PX px out: outside a blurred spot (the window's own border
#: rose with the blur, and the measured size then fell as the blur grew).
SPOT_RING_PX = 4
#: Fewest identified glints for a free-radius fit of one sample (4 unknowns, 2 rows a glint).
MIN_RADIUS_GLINTS = 5
#: Fewest samples a light must be seen in for its systematic offset.
MIN_LIGHT_SAMPLES = 3


@dataclass
class FrameMeasure:
    """One frame's quantities (see the module docstring); rows in sensor rows, DN above black."""

    index: int
    profile_dn: np.ndarray
    bands: object
    u_px: np.ndarray
    v_px: np.ndarray
    area_px: np.ndarray
    peak_dn: np.ndarray
    energy_dn: np.ndarray
    background_dn: float
    noise_dn: float
    clutter: int
    identified: dict


def measure_image(setup: Setup, image, index: int, samples, black_dn: float) -> FrameMeasure:
    """Measure one frame; ``samples`` are the tracker's samples of this frame."""
    img = np.asarray(image, dtype=np.float64)
    clip = black_dn + GLINT_CLIP_FACTOR * max(float(np.percentile(img, 95)) - black_dn, 2.0)
    profile = np.minimum(img, clip).mean(axis=1) - black_dn
    sensor, strobe = setup.sensor, setup.strobe
    pitch = sensor.total_lines * strobe.period_s / sensor.frame_period_s
    rise = sensor.total_lines * min(strobe.pulse_s, sensor.exposure_s) / sensor.frame_period_s
    bands = measure_frame(image, black_dn, index, pitch_guess_rows=pitch, rise_guess_rows=rise,
                          full_scale_dn=float(2 ** sensor.bit_depth - 1))
    if bands.status == "fit failed":
        bands = _bands_at_pitch(setup, profile, index, pitch, rise)
    raw = detect_glints(np.asarray(image), setup, index)
    # In the ideal image, as the tracker's samples are (a pinhole passes them on untouched).
    det = raw.undistorted(setup.camera)
    used = np.concatenate([s.glints_px for s in samples if s.glints_px.size]) \
        if any(s.glints_px.size for s in samples) else np.zeros((0, 2))
    pts = np.stack([det.u_px, det.v_px], axis=1)
    sigma = spot_sigma_px(img, raw.glints_px)
    big = det.area_px >= MIN_CLUTTER_AREA_PX
    identified = {}
    if used.size and pts.size:
        d, _ = cKDTree(used).query(pts)
        clutter = int(np.sum((d > 0.5) & big))
        tree = cKDTree(pts)
        for s in samples:
            for (u, v), light in zip(s.glints_px, s.light_index):
                dd, k = tree.query([u, v])
                if dd <= 0.5:
                    identified[int(s.strobe_index), int(light)] = (
                        float(u), float(v), float(det.peak[k]), float(det.intensity[k]),
                        float(det.area_px[k]), float(sigma[k]))
    else:
        clutter = int(np.sum(big))
    lit = img < clip
    rows_lit = profile > 0.5 * np.median(profile[profile > 0]) if np.any(profile > 0) else \
        np.zeros(profile.size, bool)
    sel = lit & rows_lit[:, None]
    background = float(np.mean(img[sel]) - black_dn) if sel.any() else math.nan
    diff = np.diff(img, axis=1)
    ok = sel[:, 1:] & sel[:, :-1]
    # Mean absolute difference of neighbours: sqrt(pi / 2) / sqrt(2) of it is the SD of
    # Gaussian pixel noise (the DN integers' quantised medians would step by 1 DN).
    noise = float(np.mean(np.abs(diff[ok])) * math.sqrt(math.pi / 2) / math.sqrt(2)) \
        if ok.any() else math.nan
    return FrameMeasure(index, profile, bands, det.u_px, det.v_px, det.area_px.astype(float),
                        det.peak, det.intensity, background, noise, clutter, identified)


def spot_sigma_px(image, glints_px) -> np.ndarray:
    """(k,) each glint spot's size: the RMS width along the rows (px) of its intensity above
    the local background (:data:`SPOT_RING_PX`) in a (2 :data:`SPOT_RADIUS_PX` + 1)² window,
    the square root of the second central moment; NaN for spots nearer than twice the window
    to another detection or too near the frame's edge.

    Along the rows only: the rolling shutter weights a spot's rows by the band's light (a glint
    at a band's edge is cut), not its columns. A Gaussian blur of σ adds σ² to it (second
    moments of a convolution add), so ``sqrt(capture² - render²)`` is the blur the capture
    has beyond its render (:mod:`.optics`)."""
    img = np.asarray(image, dtype=np.float64)
    g = np.asarray(glints_px, dtype=np.float64).reshape(-1, 2)
    out = np.full(g.shape[0], np.nan)
    r, R = SPOT_RADIUS_PX, SPOT_RADIUS_PX + SPOT_RING_PX
    H, W = img.shape
    near = cKDTree(g).query(g, k=2)[0][:, 1] if g.shape[0] > 1 else np.full(g.shape[0], np.inf)
    x = np.arange(-r, r + 1, dtype=np.float64)
    dy, dx = np.mgrid[-R:R + 1, -R:R + 1]
    ring = np.maximum(np.abs(dx), np.abs(dy)) >= r + 2
    for i, (u, v) in enumerate(g):
        cu, cv = int(round(u)), int(round(v))
        if not (np.isfinite(u) and near[i] > 2 * r and R <= cu < W - R and R <= cv < H - R):
            continue
        big = img[cv - R:cv + R + 1, cu - R:cu + R + 1]
        win = big[R - r:R + r + 1, R - r:R + r + 1]
        w = (win - np.median(big[ring])).sum(axis=0)  # column profile above the background
        tot = w.sum()
        if tot <= 0:
            continue
        m = float((w * x).sum() / tot)
        var = float((w * (x - m) ** 2).sum() / tot)
        out[i] = math.sqrt(var) if var > 0 else np.nan
    return out


def _bands_at_pitch(setup: Setup, profile, index: int, pitch: float, rise: float):
    """The band fit of :func:`~estimator.capture.timing.measure_frame` with the pitch held at
    the measured timing's: phase, ramp and width free, without its gate on the residual (which
    the 4-spp renders of a 320x240 eye pass only by a few %: residual 0.052-0.060 of a 0.11
    modulation against the gate's 0.055). Starts from the measured setup's first onset."""
    sensor, strobe = setup.sensor, setup.strobe
    n = profile.size
    env = uniform_filter1d(profile, max(int(round(pitch)), 2), mode="nearest")
    h = int(math.ceil(pitch / 2)) + 1
    y = np.arange(h, n - h, dtype=np.float64)
    q = profile[h:n - h] / np.maximum(env[h:n - h], 1e-9)
    line_s = sensor.frame_period_s / sensor.total_lines
    ph0 = ((strobe.phase_s - index * sensor.frame_period_s) / line_s) % pitch
    b0 = max(sensor.exposure_s, strobe.pulse_s) / line_s

    def resid(x):
        return x[3] * band_profile_model(y, pitch, x[0], x[1], x[2]) - q

    try:
        fit = least_squares(resid, [ph0, rise, b0, 1.0],
                            bounds=([ph0 - pitch / 2, 0.05, 0.05, 0.0],
                                    [ph0 + pitch / 2, 2 * pitch, 3 * pitch, np.inf]))
    except ValueError as exc:
        return FrameBands(index, "fit failed", str(exc))
    ph, a, b, _ = fit.x
    return FrameBands(index, "bands", "pitch held at the measured timing's", float(pitch),
                      float(ph % pitch), float(min(a, b)), float(max(a, b)),
                      float(np.sqrt(np.mean(fit.fun ** 2))))


def match_identified(a: FrameMeasure, b: FrameMeasure):
    """(a's, b's) (u, v, peak, energy, area, spot size) rows of the glints both runs
    identified as the same light in the same band."""
    keys = sorted(set(a.identified) & set(b.identified))
    if not keys:
        return np.zeros((0, 6)), np.zeros((0, 6))
    return (np.array([a.identified[k] for k in keys]), np.array([b.identified[k] for k in keys]))


@dataclass
class GeometryFit:
    """Free-radius fits of a run's samples and the per-light residuals they leave.

    Attributes
    ----------
    radius_m : (k,) float
        Fitted corneal radius of each sample with enough glints (on the scene's orbit, offset scaled with the radius).
    light_offset_px : (n, 2) float
        Mean glint residual (detected - fitted) of each light, NaN for lights seen in fewer
        than :data:`MIN_LIGHT_SAMPLES` samples.
    light_count : (n,) int
    residual_rms_px : float
        RMS of all glint residuals.
    """

    radius_m: np.ndarray
    light_offset_px: np.ndarray
    light_count: np.ndarray
    residual_rms_px: float

    @property
    def radius_median_m(self) -> float:
        return float(np.median(self.radius_m)) if self.radius_m.size else math.nan

    @property
    def radius_se_m(self) -> float:
        r = self.radius_m
        return float(1.2533 * np.std(r, ddof=1) / math.sqrt(r.size)) if r.size > 2 else math.nan

    @property
    def systematic_rms_px(self) -> float:
        """RMS over the lights of their mean offsets' lengths."""
        ok = np.all(np.isfinite(self.light_offset_px), axis=1)
        if not ok.any():
            return math.nan
        return float(np.sqrt(np.mean(np.sum(self.light_offset_px[ok] ** 2, axis=1))))

    @property
    def systematic_floor_px(self) -> float:
        """What the same RMS is from per-glint noise alone: residual RMS / sqrt(count)."""
        ok = np.all(np.isfinite(self.light_offset_px), axis=1)
        if not ok.any():
            return math.nan
        return float(self.residual_rms_px * np.sqrt(np.mean(1.0 / self.light_count[ok])))


def _orbit_radius_fit(setup: Setup, sample, lights):
    """(yaw, pitch, r_c) of one sample: the cornea on the scene's orbit about c_e, its offset
    scaled with r_c as Böhme's model scales it, so the radius is the glint pattern's scale."""
    eye, cam = setup.eye, setup.camera
    ratio = eye.cornea_offset_m / eye.cornea_radius_m
    idx, obs = sample.light_index, sample.glints_px
    yaw0, pitch0 = fick_angles(sample.cornea_center_m - eye.rotation_center_m)

    def resid(x):
        c = eye.rotation_center_m + ratio * x[2] * gaze_direction(x[0], x[1])
        pred, vis = project_glints(cam, c, x[2], lights[idx])
        r = np.where(vis[:, None], pred - obs, 0.0)
        return np.nan_to_num(r, nan=0.0).ravel()

    try:
        fit = least_squares(resid, [float(yaw0), float(pitch0), eye.cornea_radius_m],
                            x_scale=[0.01, 0.01, 1e-4], bounds=([-1.5, -1.5, 5e-3], [1.5, 1.5, 11e-3]))
    except ValueError:
        return None
    return fit.x if fit.success else None


def fit_geometry(setup: Setup, samples) -> GeometryFit:
    """Fit each sample's radius (and gaze) to its identified glints (module docstring)."""
    lights = setup.lights_world_m
    n = lights.shape[0]
    rows = [s for s in samples if s.ok and s.light_index.size >= MIN_RADIUS_GLINTS]
    radii, res = [], np.full((len(rows), n, 2), np.nan)
    eye = setup.eye
    ratio = eye.cornea_offset_m / eye.cornea_radius_m
    for k, s in enumerate(rows):
        x = _orbit_radius_fit(setup, s, lights)
        if x is None:
            continue
        radii.append(x[2])
        c = eye.rotation_center_m + ratio * x[2] * gaze_direction(x[0], x[1])
        pred, vis = project_glints(setup.camera, c, x[2], lights[s.light_index])
        res[k, s.light_index] = np.where(vis[:, None], s.glints_px - pred, np.nan)
    count = np.sum(np.isfinite(res[..., 0]), axis=0)
    mean = np.full((n, 2), np.nan)
    seen = count > 0
    mean[seen] = np.nansum(res[:, seen], axis=0) / count[seen, None]
    mean[count < MIN_LIGHT_SAMPLES] = np.nan
    flat = res[np.isfinite(res[..., 0])]
    rms = float(np.sqrt(np.mean(np.sum(flat ** 2, axis=1)))) if flat.size else math.nan
    return GeometryFit(np.array(radii), mean, count, rms)


def gaze_differences_deg(setup: Setup, samples_a, samples_b) -> dict:
    """{band position in its frame: angles (deg) between the two runs' gaze directions} for
    the (frame, strobe) pairs both estimated; gaze is c - c_e (cornea centre from the eye's
    rotation centre)."""
    b = {(s.frame_index, s.strobe_index): s for s in samples_b if s.ok}
    first = {}
    for s in samples_a:
        first[s.frame_index] = min(first.get(s.frame_index, s.strobe_index), s.strobe_index)
    out = {}
    for s in samples_a:
        o = b.get((s.frame_index, s.strobe_index))
        if not s.ok or o is None:
            continue
        g1 = s.cornea_center_m - setup.eye.rotation_center_m
        g2 = o.cornea_center_m - setup.eye.rotation_center_m
        cos = float(np.dot(g1, g2) / (np.linalg.norm(g1) * np.linalg.norm(g2)))
        out.setdefault(s.strobe_index - first[s.frame_index], []).append(
            math.degrees(math.acos(min(1.0, max(-1.0, cos)))))
    return out
