"""A capture's rolling-shutter and strobe timing, measured from its banded frames alone.

What is observable (HARDWARE.md Sec. 9): the row profile r(y) of a banded frame (mean over the
columns, black level removed) is the scene's smooth row brightness L(y) times the sum of the
bands, each the trapezoid w(y - k_j) of Eqs. (2)-(3): zero below the onset k_j, rising over
a = S min(Δe, Δs)/Δt rows, flat, falling back over a rows, zero after a + b rows,
b = S max(Δe, Δs)/Δt (Eq. (7): a + b is the band height h_s). Onsets are spaced by the pitch

    p = S Δclk / Δt,                                     (1)

with Δclk the strobe period on the Pi's clock. From frame n to n + 1 every band moves by

    δ = S (M Δclk - Δt) / Δt = M p - S,                  (2)

where M is the whole number of strobe periods per frame (the firmware's pulse count) and δ is
seen modulo p. The Arduino's 16 MHz clock is off by up to thousands of ppm, so Δclk is not
known from the firmware's tick settings; but (1) and (2) together give, with Δt from the
``SensorTimestamp`` differences,

    S = M p - δ,      Δclk = Δt (1 + δ / S) / M,      clock_ppm = 1e6 (Δclk / Δclk_nom - 1),

without trusting the strobe's clock; Δclk_nom (the ticks of ``capture.json``'s ``strobe``) only
picks the whole number of periods hidden in δ modulo p (it is right to far better than p/S).
The exposure is Δe = b Δt / S and the pulse width Δs = a Δt / S (the larger of the two is the
exposure unless the capture's metadata say otherwise), the phase of frame n is the delay from
its first readout to the onset of its first band, φ_n = (k_0(n) mod p) Δt / S.

Method: each lit frame's profile is divided by its running mean over one pitch (which removes
L(y) and keeps the bands' periodic pattern) and fitted with g Σ_j w(y - φ - j p; a, b) by least
squares (p, φ, a, b, g free). The pitch, a and b are averaged over frames; the phases are
unwrapped (modulo p) and a straight line in the frame index gives δ. Every standard deviation
comes from the scatter of the per-frame values (of the line's residuals for δ), not from an
assumed noise level. Frames with no light, saturated frames and frames without band structure
(a single pulse lighting one band or the whole frame: calibration frames) are recognised,
reported and left out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .folder import CaptureError, CaptureFolder

__all__ = ["F_STROBE_HZ", "FrameBands", "CaptureTiming", "band_profile_model", "measure_frame",
           "measure_capture"]

#: The strobe firmware's nominal clock (ticks of ``capture.json``'s ``strobe``).
F_STROBE_HZ = 16e6
#: A frame whose brightest row is less than this above black (DN) has no light.
DARK_DN = 2.0
#: Share of pixels at full scale above which a frame is saturated (its band shape is clipped).
SATURATED_SHARE = 0.002
#: Relative modulation (SD of the normalised profile) below which a lit frame has no bands.
FLAT_MODULATION = 0.02
#: Floor of clock_ppm_sd: the scene-dependent bias of the fitted band positions (which a static
#: scene repeats in every frame, so no scatter shows it) reached 0.2 ppm on the test captures.
CLOCK_PPM_FLOOR = 0.5
#: Fewest frames with bands for a drift (and so S without the strobe clock).
MIN_DRIFT_FRAMES = 3
#: Glints out of the row profile: pixels brighter than GLINT_CLIP_FACTOR times the frame's
#: 95th percentile (above black) are clipped to that level before the rows are averaged.
#: Glints are a few bright pixels whose row sums follow the cornea, not the bands: on rendered
#: 320x240 eye frames (4 spp, 16 pulses; skin ~38 DN, glints ~700 DN above black) they left a
#: band fit residual of 0.10 of a 0.14 modulation (refused); clipped, the same frames fit with
#: 0.04 and the pitch within 0.003 row of the truth. Lit skin, sclera and iris stay below it.
GLINT_CLIP_FACTOR = 3.0
#: A band fit is refused when its RMS residual exceeds this share of the profile's SD: the
#: model must explain at least 1 - 0.8² = 36 % of the profile's variance, where five free
#: parameters fitted to noise over ~200 rows explain ~2.5 %. Measured on rendered 320x240
#: frames (4 spp): right fits leave 0.45-0.75 of the SD (the eye's edges and Monte Carlo
#: noise stay in the profile), fits at twice the pitch 1.0-1.05. (0.5 before: it refused
#: every frame of a 60-frame render whose eye covered most of the frame.)
FIT_GATE = 0.8
#: Share of the autocorrelation's top peak that a peak at a third or a half of its lag must
#: hold to be taken as the pitch (the top one then a multiple of it): a true pitch's own peak
#: is as high as its multiples' up to the profile's finite length (measured on rendered
#: frames: 0.7-1.0 of the top); a profile whose period really is the longer one has no
#: local maximum of that height in between.
OCTAVE_SHARE = 0.5
#: The band fit's starting band heights (a + b) in pitches. The dip or bump where bands meet
#: is a few rows wide and its depth follows the overlap a + b - p, so the grid steps it by
#: 0.025 p (0.6 row at p = 24.6) near 1; at 0.05 p steps a 320x240 frame blurred by 1.2 px
#: (bands 1.06 p high) started nearer a flat model than its bands and was refused.
BAND_HEIGHTS = (0.5, 0.8, 0.95, 1.0, 1.025, 1.05, 1.075, 1.1)


def band_profile_model(rows, pitch_rows, phase_rows, rise_rows, width_rows):
    """Σ_j w(y - phase - j pitch): the bands' row weights of Eqs. (2)-(3) in rows.

    w(u) = (min(u, a) - max(u - b, 0)) / a clipped to [0, 1] is the share of a pulse that row
    u rows after the band's onset collects (a = rise_rows, b = width_rows >= a), i.e. the
    trapezoid of Eq. (5) with ramps of a rows and height a + b.
    """
    y = np.asarray(rows, dtype=np.float64)
    a, b = float(rise_rows), float(max(width_rows, rise_rows))
    j_lo = math.floor((y.min() - phase_rows - a - b) / pitch_rows)
    j_hi = math.ceil((y.max() - phase_rows) / pitch_rows)
    u = y[:, None] - phase_rows - np.arange(j_lo, j_hi + 1)[None, :] * pitch_rows
    w = (np.minimum(u, a) - np.maximum(u - b, 0.0)) / max(a, 1e-9)
    return np.clip(w, 0.0, 1.0).sum(axis=1)


@dataclass
class FrameBands:
    """One frame's measurement: ``status`` is ``"bands"`` (measured) or the reason it is not
    (``"dark"``, ``"saturated"``, ``"single band"``, ``"whole frame"``, ``"missing"``,
    ``"fit failed"``). Rows are sensor rows; ``phase_rows`` is the first onset mod the pitch."""

    index: int
    status: str
    detail: str = ""
    pitch_rows: float = math.nan
    phase_rows: float = math.nan
    rise_rows: float = math.nan
    width_rows: float = math.nan
    rms: float = math.nan
    sd: tuple = (math.nan, math.nan, math.nan, math.nan)  # of pitch, phase, rise, width


@dataclass
class CaptureTiming:
    """The measured timing of a capture; every value beside its standard deviation."""

    total_lines: float
    total_lines_sd: float
    exposure_s: float
    exposure_s_sd: float
    pulse_s: float
    pulse_s_sd: float
    phase_s: list
    phase_s_sd: list
    clock_ppm: float
    clock_ppm_sd: float
    pitch_rows: float
    pitch_rows_sd: float
    drift_rows_per_frame: float
    drift_rows_per_frame_sd: float
    frame_period_s: float
    periods_per_frame: int
    frames: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        keys = ("total_lines", "exposure_s", "pulse_s", "phase_s", "clock_ppm", "pitch_rows",
                "drift_rows_per_frame")
        out = {}
        for k in keys:
            out[k], out[k + "_sd"] = _clean(getattr(self, k)), _clean(getattr(self, k + "_sd"))
        out["frame_period_s"] = self.frame_period_s
        out["periods_per_frame"] = self.periods_per_frame
        out["phase_frames"] = [f.index for f in self.frames if f.status == "bands"]
        out["frames"] = [{"index": f.index, "status": f.status, "detail": f.detail}
                         for f in self.frames]
        out["notes"] = list(self.notes)
        return out


def _clean(v):
    if isinstance(v, list):
        return [_clean(x) for x in v]
    return None if v is None or not math.isfinite(v) else float(v)


def _running_mean(r: np.ndarray, window: int) -> np.ndarray:
    c = np.concatenate([[0.0], np.cumsum(r)])
    h = window // 2
    lo = np.clip(np.arange(r.size) - h, 0, r.size)
    hi = np.clip(np.arange(r.size) + window - h, 0, r.size)
    return (c[hi] - c[lo]) / np.maximum(hi - lo, 1)


def _pitch_guess(q: np.ndarray, lo: float, hi: float) -> float:
    """The strongest period of q between lo and hi rows (autocorrelation peak)."""
    q = q - _running_mean(q, 31)  # the scene's smooth row brightness out, the bands kept
    ac = np.correlate(q, q, mode="full")[q.size - 1:]
    lags = np.arange(ac.size)
    neg = np.flatnonzero(ac < 0)  # past the first zero: no longer the zero-lag peak
    start = max(lo, int(neg[0]) if neg.size else lo)
    ok = (lags >= start) & (lags <= min(hi, q.size // 2))
    if not np.any(ok):
        return math.nan
    k = int(lags[ok][np.argmax(ac[ok])])
    # A multiple of the pitch can top its autocorrelation (the eye's structure adds to every
    # other lag; measured on a rendered 320x240 frame: the peak at 2p, 49 rows, above the
    # one at p). A sub-multiple whose own peak holds OCTAVE_SHARE of the top one is the pitch.
    for m in (3, 2):
        c = int(round(k / m))
        if c - 2 < start or c + 3 > ac.size:
            continue
        j = c - 2 + int(np.argmax(ac[c - 2:c + 3]))
        if 0 < j < ac.size - 1 and ac[j] >= ac[j - 1] and ac[j] >= ac[j + 1] \
                and ac[j] >= OCTAVE_SHARE * ac[k]:
            k = j
            break
    # The pitch from the peaks at its multiples m p (each refined by a parabola), a line
    # through the origin: the first peak alone is pulled by the eye's own structure (measured
    # on rendered 320x240 frames, truth 24.56 rows: 24.63-24.69 sharp and 24.69-24.81 blurred
    # by 1.2 px, where the band fit's grid then lost the bands; from the multiples
    # 24.55-24.60 for both).
    ms, lags = [], []
    for m in range(1, 10):
        c = int(round(m * k))
        if c + 3 > min(ac.size, q.size // 2 + 3):
            break
        j = c - 2 + int(np.argmax(ac[c - 2:c + 3])) if m > 1 else k
        if not 0 < j < ac.size - 1 or ac[j] < ac[j - 1] or ac[j] < ac[j + 1]:
            break
        d = ac[j - 1] - 2 * ac[j] + ac[j + 1]
        ms.append(m)
        lags.append(j + 0.5 * (ac[j - 1] - ac[j + 1]) / d if d < 0 else float(j))
    if not ms:
        return float(k)
    ms, lags = np.asarray(ms, dtype=np.float64), np.asarray(lags)
    return float(ms @ lags / (ms @ ms))


def measure_frame(image_dn: np.ndarray, black_dn: float, index: int, *, pitch_guess_rows=None,
                  rise_guess_rows=None, full_scale_dn: float = 1023.0) -> FrameBands:
    """Classify one tracker frame and, when it is banded, fit its bands (see the module text)."""
    img = np.asarray(image_dn, dtype=np.float64)
    if np.mean(img >= full_scale_dn) > SATURATED_SHARE:
        return FrameBands(index, "saturated", f"{100 * np.mean(img >= full_scale_dn):.2f} % of "
                          "pixels at full scale")
    clip_dn = black_dn + GLINT_CLIP_FACTOR * max(float(np.percentile(img, 95)) - black_dn, DARK_DN)
    r = np.minimum(img, clip_dn).mean(axis=1) - black_dn
    if r.max() < DARK_DN:
        return FrameBands(index, "dark", f"brightest row {r.max():.2f} DN above black")
    lit = r > 0.5 * r.max()
    runs = int(np.sum(np.diff(lit.astype(int)) == 1) + (1 if lit[0] else 0))
    if runs == 1 and lit.mean() < 0.9 and not lit[0] and not lit[-1]:
        return FrameBands(index, "single band", f"one lit band of {lit.sum()} rows")
    n = r.size
    p0 = pitch_guess_rows if pitch_guess_rows else _pitch_guess(r / max(r.max(), 1e-9), 4, n / 2)
    if not math.isfinite(p0) or p0 < 4:
        return FrameBands(index, "whole frame", "no periodic band structure")
    env = _running_mean(r, max(int(round(p0)), 2))
    h = int(math.ceil(p0 / 2)) + 1
    inner = np.arange(h, n - h)
    q = r[inner] / np.maximum(env[inner], 1e-9)
    if inner.size < 2 * p0 or np.std(q) / max(np.mean(q), 1e-9) < FLAT_MODULATION:
        return FrameBands(index, "whole frame", "lit without band structure (a single pulse "
                          "lighting every row, or continuous light)")
    a0 = rise_guess_rows if rise_guess_rows else max(1.0, 0.1 * p0)
    y = inner.astype(np.float64)

    def resid(x):
        p, ph, a, b, g = x
        return g * band_profile_model(y, p, ph, a, b) - q

    cands = []  # the phase and band shape: a grid, then least squares from the best three
    for ph0 in np.arange(0.0, p0, 0.5):
        for a_ in sorted({a0, 1.0, 0.1 * p0, 0.2 * p0}):
            for f in BAND_HEIGHTS:
                x0 = [p0, ph0, a_, max(f * p0 - a_, a_ + 0.1), 1.0]
                r0 = resid(x0)
                x0[4] = float(np.dot(q, r0 + q) / max(np.dot(r0 + q, r0 + q), 1e-12))
                cands.append((float(np.sum(resid(x0) ** 2)), x0))
    cands.sort(key=lambda c: c[0])
    lo = [0.97 * p0, -np.inf, 0.05, 0.05, 0.0]
    hi = [1.03 * p0, np.inf, 2.0 * p0, 3.0 * p0, np.inf]
    fit = None
    for _, x0 in cands[:3]:
        try:
            f_ = least_squares(resid, x0, bounds=(lo, hi), x_scale=[0.1, 1, 1, 1, 0.1])
        except ValueError as exc:
            return FrameBands(index, "fit failed", str(exc))
        if fit is None or f_.cost < fit.cost:
            fit = f_
    p, ph, a, b, _ = fit.x
    a, b = min(a, b), max(a, b)
    rms = float(np.sqrt(np.mean(fit.fun ** 2)))
    if rms > FIT_GATE * np.std(q):
        return FrameBands(index, "fit failed", f"the band model leaves {rms:.3f} of a "
                          f"{np.std(q):.3f} modulation")
    J = fit.jac[:, :4]
    try:
        cov = np.linalg.inv(J.T @ J) * rms ** 2 * y.size / max(y.size - 5, 1)
        sd = tuple(float(math.sqrt(max(v, 0.0))) for v in np.diag(cov))
    except np.linalg.LinAlgError:
        sd = (math.nan,) * 4
    if fit.x[2] > fit.x[3]:
        sd = (sd[0], sd[1], sd[3], sd[2])
    return FrameBands(index, "bands", "", float(p), float(ph % p), float(a), float(b), rms, sd)


def _mean_sd(v: np.ndarray, sd_one: np.ndarray) -> tuple[float, float]:
    """Mean and SD: the scatter's standard error, but never below the median single frame's
    fit SD (a static scene biases every frame alike, and that does not average out)."""
    floor = float(np.nanmedian(sd_one)) if np.any(np.isfinite(sd_one)) else math.nan
    if v.size < 2:
        return float(v.mean()), floor
    return float(v.mean()), float(np.nanmax([v.std(ddof=1) / math.sqrt(v.size), floor]))


def measure_capture(folder, *, progress=None, follow: bool = False, timeout_s: float = 5.0,
                    on_frame=None) -> CaptureTiming:
    """Measure S, Δe, Δs, the per-frame phase and the strobe clock's mismatch of a capture.

    ``follow``: read the capture while it is written (:class:`estimator.capture.follow.
    CaptureFollower`, ending when the capture does or after ``timeout_s`` without a frame);
    ``on_frame(FrameBands)`` after each frame (live output); ``progress(done, total)`` with
    the total so far when following.

    Raises
    ------
    CaptureError
        The folder cannot be read, has no strobe settings, or has no banded frame.
    """
    if follow:
        from .follow import CaptureFollower

        follower = CaptureFollower(folder, timeout_s=timeout_s)
        cap = follower.wait_open()
        frame_iter, total = follower.frames(), None
    else:
        follower = None
        cap = CaptureFolder(folder)
        frame_iter, total = cap.frames(), max(cap.index) + 1
    strobe = cap.header.get("strobe")
    where = f"{cap.path / 'capture.json'}"
    if not isinstance(strobe, dict) or not isinstance(strobe.get("period_ticks"), int):
        raise CaptureError(f"{where}: key 'strobe' must hold the firmware settings "
                           "(period_ticks, trim_256th, width_ticks, pulses) to measure the timing")
    clk_nom_s = (strobe["period_ticks"] + float(strobe.get("trim_256th", 0)) / 256) / F_STROBE_HZ
    pulse_nom_s = float(strobe.get("width_ticks", 0)) / F_STROBE_HZ
    frames, expo_meta, starts = [], [], []
    for k, fr in enumerate(frame_iter):
        if fr.image is None:
            frames.append(FrameBands(fr.index, "missing", fr.reason or ""))
        else:
            starts.append((fr.index, fr.start_s))
            good = [f for f in frames if f.status == "bands"]
            guess = float(np.median([f.pitch_rows for f in good])) if good else None
            rise = float(np.median([f.rise_rows for f in good])) if good else None
            frames.append(measure_frame(fr.image, cap.black_level_out_dn, fr.index,
                                        pitch_guess_rows=guess, rise_guess_rows=rise))
            if isinstance(fr.metadata.get("ExposureTime"), (int, float)):
                expo_meta.append(float(fr.metadata["ExposureTime"]) * 1e-6)
        if on_frame is not None:
            on_frame(frames[-1])
        if progress is not None:
            progress(k + 1, total if total is not None else k + 1)
    if follower is None:
        dt = cap.frame_period_s
    else:
        limits = (cap.header.get("controls") or {}).get("FrameDurationLimits") or [0]
        dt = follower.frame_period_s or float(limits[0]) * 1e-6
        if not dt > 0:
            raise CaptureError(f"{cap.path}: fewer than two frames and no FrameDurationLimits: "
                               "cannot tell the frame period")
    M = int(round(dt / clk_nom_s))
    if len(starts) >= 2:  # Δt: a line through the time stamps (finer than their median step)
        si = np.array(starts)
        dt = float(np.polyfit(si[:, 0], si[:, 1], 1)[0])
    good = [f for f in frames if f.status == "bands"]
    if not good:
        counts = {}
        for f in frames:
            counts[f.status] = counts.get(f.status, 0) + 1
        raise CaptureError(f"{cap.path}: no frame with bands to measure ("
                           + ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) + ")")
    notes = []
    p, p_sd = _mean_sd(np.array([f.pitch_rows for f in good]), np.array([f.sd[0] for f in good]))
    a, a_sd = _mean_sd(np.array([f.rise_rows for f in good]), np.array([f.sd[2] for f in good]))
    b, b_sd = _mean_sd(np.array([f.width_rows for f in good]), np.array([f.sd[3] for f in good]))
    idx = np.array([f.index for f in good], dtype=np.float64)
    ph = np.array([f.phase_rows for f in good])
    if len(good) >= MIN_DRIFT_FRAMES:
        un, slope = ph.copy(), 0.0  # unwrap modulo p against the drift seen so far (gaps)
        for i in range(1, un.size):
            gap = idx[i] - idx[i - 1]
            un[i] -= np.round((un[i] - un[i - 1] - slope * gap) / p) * p
            slope = (un[i] - un[0]) / (idx[i] - idx[0])
        A = np.stack([np.ones_like(idx), idx], axis=1)
        coef, *_ = np.linalg.lstsq(A, un, rcond=None)
        res = un - A @ coef
        dof = max(idx.size - 2, 1)
        cov = np.linalg.inv(A.T @ A) * float(res @ res) / dof
        # Neighbouring frames see the scene at nearly the same band positions, so their phase
        # errors are correlated: widen by the AR(1) factor sqrt((1 + rho) / (1 - rho)).
        rho = float(np.clip(np.corrcoef(res[:-1], res[1:])[0, 1], 0.0, 0.95)) \
            if res.size > 3 and np.std(res) > 0 else 0.0
        delta, delta_sd = float(coef[1]), float(math.sqrt(cov[1, 1] * (1 + rho) / (1 - rho)))
        S_guess = p * dt / clk_nom_s
        S = M * p - delta
        m = round((S - S_guess) / p)  # whole periods hidden in δ modulo p
        delta += m * p
        S = M * p - delta
        S_sd = math.hypot(M * p_sd, delta_sd)
        clk = dt * (1 + delta / S) / M
        ppm = 1e6 * (clk / clk_nom_s - 1)
        # Δt from nanosecond time stamps: known to about 1 ns over the run's span.
        dt_rel_sd = 1e-9 / max(dt * (idx[-1] - idx[0]), dt)
        ppm_sd = 1e6 * dt / (M * clk_nom_s) * math.sqrt(
            (delta_sd / S) ** 2 + (delta * S_sd / S ** 2) ** 2 + dt_rel_sd ** 2)
        ppm_sd = math.hypot(ppm_sd, CLOCK_PPM_FLOOR)
    else:
        notes.append(f"{len(good)} banded frame(s): too few for the drift (need "
                     f"{MIN_DRIFT_FRAMES}); S from the nominal strobe clock, clock_ppm unknown")
        delta = delta_sd = ppm = ppm_sd = math.nan
        S = p * dt / clk_nom_s
        S_sd = math.hypot(dt / clk_nom_s * p_sd, S * 3e-3)  # a resonator: up to ~3,000 ppm
    line_s = dt / S
    # The larger of the two is the exposure, unless the metadata say the pulse is the longer.
    expo_first = not (expo_meta and pulse_nom_s > 0 and np.median(expo_meta) < pulse_nom_s)
    (e_r, e_sd), (s_r, s_sd) = ((b, b_sd), (a, a_sd)) if expo_first else ((a, a_sd), (b, b_sd))
    rel = S_sd / S
    phase_s = [float(v * line_s) for v in ph]
    phase_sd = [float(line_s * math.hypot(p_sd, v * rel)) for v in ph]
    skipped = [f for f in frames if f.status != "bands"]
    if skipped:
        notes.append(f"{len(skipped)} frame(s) not measured: " + ", ".join(
            sorted({f.status for f in skipped})))
    return CaptureTiming(
        total_lines=S, total_lines_sd=S_sd,
        exposure_s=e_r * line_s, exposure_s_sd=line_s * math.hypot(e_sd, e_r * rel),
        pulse_s=s_r * line_s, pulse_s_sd=line_s * math.hypot(s_sd, s_r * rel),
        phase_s=phase_s, phase_s_sd=phase_sd, clock_ppm=ppm, clock_ppm_sd=ppm_sd,
        pitch_rows=p, pitch_rows_sd=p_sd, drift_rows_per_frame=delta,
        drift_rows_per_frame_sd=delta_sd, frame_period_s=dt, periods_per_frame=M,
        frames=frames, notes=notes)
