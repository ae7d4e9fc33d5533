"""``scet compare``: a capture against its render (issue 13, part 3).

Steps, for the first ``frames`` banded frames of a capture folder:

1. timing: :func:`estimator.capture.timing.measure_capture` (S, exposure, pulse, phase, clock);
2. tracking: :class:`estimator.tracker.Tracker` on the measured timing, with the calibration
   or, without one, the scene's nominal geometry (geometric gaze on the nominal eye);
3. sensor: black level from the frames' darkest patches, the response from the capture's
   signal over the render's under the scene's sensor model on lit skin, the photon-transfer
   gain of :mod:`.sensor_fit` beside it;
4. render: the same frames at the measured timing and the tracked poses
   (:mod:`.render`), through the sensor model with the estimated black level and gain;
5. the tracker and the measurements of :mod:`.measure` on both; the verdict rows of
   :mod:`.verdict`, each with its tolerance;
6. the optics (:mod:`.optics`): the capture's blur beyond the render's, fitted by blurring the
   render; flagged rows that the blurred render explains are blamed on the optics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from estimator.calibration import Calibration
from estimator.capture import CaptureError, CaptureFolder
from estimator.capture.timing import measure_capture
from estimator.errors import InputError
from estimator.setup import Setup
from estimator.tracker import Tracker

from .measure import fit_geometry, gaze_differences_deg, measure_image
from .render import measured_setup, poses_from_samples, render_radiance
from .optics import optics_verdict
from .rows import verdict_rows
from .sensor_fit import fit_sensor

__all__ = ["CompareError", "CompareResult", "compare_capture", "nominal_calibration"]


class CompareError(InputError):
    """A capture that cannot be compared with the scene (the message says why)."""


@dataclass
class CompareResult:
    capture_dir: Path
    setup: Setup
    measured: Setup
    timing: object
    frames: list
    capture_images: dict
    render_images: dict
    capture_measures: dict
    render_measures: dict
    capture_samples: list
    render_samples: list
    sensor: dict
    geometry: dict
    gaze_deg: dict
    rows: list
    findings: dict
    notes: list = field(default_factory=list)

    @property
    def flagged(self) -> list:
        return [r for r in self.rows if not r.passed]

    def to_dict(self) -> dict:
        """JSON-ready (NaN as null)."""
        return _clean({"format": "scet-compare", "version": 1, "capture": str(self.capture_dir),
                "scene": self.setup.name, "frames": list(self.frames),
                "timing": self.timing.to_dict(), "sensor": self.sensor,
                "geometry": self.geometry, "findings": self.findings,
                "gaze_difference_deg": {str(k): float(np.median(v))
                                        for k, v in sorted(self.gaze_deg.items())},
                "rows": [r.to_dict() for r in self.rows], "notes": list(self.notes),
                "flagged": len(self.flagged)})


def _clean(v):
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


def nominal_calibration(setup: Setup) -> Calibration:
    """The scene's own geometry as a calibration: nominal lights, radius, eye centre, orbit."""
    eye = setup.eye
    return Calibration(cornea_radius_m=eye.cornea_radius_m, eye_center_m=eye.rotation_center_m,
                       orbit_radius_m=eye.cornea_offset_m, methods={"all": "scene nominal"})


def _open(capture_dir, setup: Setup) -> CaptureFolder:
    try:
        cap = CaptureFolder(capture_dir, black_level_out_dn=setup.sensor.black_level_dn,
                            size_px=(setup.camera.width_px, setup.camera.height_px))
    except CaptureError as exc:
        raise CompareError(str(exc)) from None
    mode = cap.header.get("camera", {}).get("sensor_mode") if isinstance(
        cap.header.get("camera"), dict) else None
    depth = mode.get("bit_depth") if isinstance(mode, dict) else None
    if isinstance(depth, int) and depth != setup.sensor.bit_depth:
        raise CompareError(f"{cap.path / 'capture.json'}: key 'camera.sensor_mode.bit_depth' is "
                           f"{depth}, the scene {setup.name!r} has a {setup.sensor.bit_depth}-bit "
                           "sensor")
    return cap


def _mapping(calibration: Calibration, method: str) -> str:
    """The calibration's Eq. (1) mapping for polynomial gaze (as ``scet track`` picks it)."""
    if method == "geometric":
        if not calibration.has_orbit:
            raise CompareError("the calibration has no eye centre and orbit radius, which "
                               "--method geometric needs")
        return ""
    eq1 = sorted(k for k in calibration.mappings if k.startswith("eq1"))
    if not eq1:
        raise CompareError(f"the calibration has no Eq. (1) gaze mapping for polynomial gaze "
                           f"(has {sorted(calibration.mappings)}); use --method geometric")
    return eq1[-1]


def _track(setup, calibration, method, images, starts):
    mapping = _mapping(calibration, method)
    tracker = Tracker(setup, calibration, method, **({"mapping": mapping} if mapping else {}))
    out = []
    for f in sorted(images):
        out.extend(tracker.process(images[f], f, starts[f]))
    return out


def _signal_ratio(captures, expected, black_c, black_n, window_px=7):
    """Σ (capture - black) / Σ (expected - black) over lit, glint-free pixels of all frames.

    The pixels are chosen on the render smoothed over ``window_px`` and with a margin around
    every glint of either image: a cut on single noisy pixels (28 % Monte Carlo noise at 4 spp)
    keeps their bright or dark tail and biased the ratio by 4-7 % (measured)."""
    from scipy.ndimage import maximum_filter, uniform_filter

    num = den = 0.0
    for f in captures:
        e = expected[f] - black_n
        c = captures[f].astype(np.float64) - black_c
        smooth = uniform_filter(e, window_px)
        lit = smooth[smooth > 0]
        if not lit.size:
            continue
        level = float(np.percentile(lit, 95))
        glint = maximum_filter((smooth > 2 * level) | (e > 4 * level) | (c > 4 * level),
                               window_px) > 0
        sel = (smooth > 0.2 * level) & ~glint
        num += float(c[sel].sum())
        den += float(e[sel].sum())
    return num / den if den > 0 else math.nan


def _nanmedian(values) -> float:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else math.nan


def compare_capture(capture_dir, setup: Setup, *, calibration=None, method: str = "geometric",
                    frames: int = 8, spp: int = 16, cornea: str = "dielectric", seed: int = 0,
                    variant: str | None = None, progress=None) -> CompareResult:
    """Compare a capture folder with renders of the same frames (module docstring).

    Raises
    ------
    CompareError
        The capture does not fit the scene (size, bit depth), has no banded frame, or no
        frame the tracker could estimate a pose in.
    """
    from ..render.sensor import SensorModel

    capture_dir = Path(capture_dir)
    cap = _open(capture_dir, setup)
    notes = []
    try:
        timing = measure_capture(capture_dir)
    except CaptureError as exc:
        raise CompareError(f"{exc}; nothing to compare") from None
    banded = [f.index for f in timing.frames if f.status == "bands"][:max(1, int(frames))]
    images, starts = {}, {}
    for fr in cap.frames():
        if fr.index in banded and fr.image is not None:
            images[fr.index], starts[fr.index] = fr.image, fr.start_s
    notes.extend(timing.notes)
    msetup = measured_setup(setup, timing)
    if calibration is None:
        calibration, method = nominal_calibration(setup), "geometric"
        notes.append("no calibration given: tracked on the scene's nominal geometry "
                     "(lights, corneal radius, eye centre and orbit), geometric gaze")
    if progress:
        progress("track capture", 0, 1)
    cap_samples = _track(msetup, calibration, method, images, starts)
    try:
        traj = poses_from_samples(msetup, cap_samples)
    except ValueError:
        raise CompareError(f"{capture_dir}: the tracker estimated no sample in frames "
                           f"{sorted(images)} (reasons: "
                           f"{sorted({s.reason for s in cap_samples})}); no pose to render at") from None
    fits = [fit_sensor(images[f], full_scale_dn=float(2 ** setup.sensor.bit_depth - 1))
            for f in sorted(images)]
    black_c = float(np.median([s.black_level_dn for s in fits]))
    K_c = _nanmedian([s.gain_e_per_dn for s in fits])
    radiance = render_radiance(msetup, traj, sorted(images), spp=spp, cornea=cornea, seed=seed,
                               variant=variant,
                               progress=(lambda d, t: progress("render", d, t)) if progress else None)
    nominal = SensorModel.from_sensor(msetup.sensor)
    k_n = nominal.analog_gain / nominal.conversion_gain_e_per_dn
    expected = {f: nominal.mean_electrons(radiance[f]) * k_n + nominal.black_level_dn
                for f in radiance}
    gain = _signal_ratio(images, expected, black_c, nominal.black_level_dn)
    est = replace(nominal, black_level_dn=black_c,
                  analog_gain=nominal.analog_gain * (gain if math.isfinite(gain) else 1.0))
    renders = {f: est.apply(radiance[f], np.random.SeedSequence([seed, 0x5CE7, f]))
               for f in radiance}
    rfits = [fit_sensor(renders[f], full_scale_dn=float(2 ** setup.sensor.bit_depth - 1))
             for f in sorted(renders)]
    K_r = _nanmedian([s.gain_e_per_dn for s in rfits])
    if progress:
        progress("track render", 0, 1)
    ren_samples = _track(msetup, calibration, method, renders, starts)
    cm = {f: measure_image(msetup, images[f], f, [s for s in cap_samples if s.frame_index == f],
                           black_c) for f in images}
    rm = {f: measure_image(msetup, renders[f], f, [s for s in ren_samples if s.frame_index == f],
                           black_c) for f in renders}
    gc, gr = fit_geometry(setup, cap_samples), fit_geometry(setup, ren_samples)
    gaze = gaze_differences_deg(setup, cap_samples, ren_samples)
    sensor = {"black_level_dn": black_c, "scene_black_level_dn": nominal.black_level_dn,
              "response_ratio": gain, "ptc_gain_e_per_dn_capture": K_c,
              "ptc_gain_e_per_dn_render": K_r,
              "scene_gain_e_per_dn": 1.0 / k_n,
              "ptc_pattern_share_capture": _nanmedian([s.pattern_share for s in fits]),
              "read_noise_e_model": nominal.read_noise_e}
    geometry = {"cornea_radius_mm_capture": 1e3 * gc.radius_median_m,
                "cornea_radius_mm_render": 1e3 * gr.radius_median_m,
                "cornea_radius_se_mm": 1e3 * gc.radius_se_m,
                "scene_cornea_radius_mm": 1e3 * setup.eye.cornea_radius_m,
                "light_offset_rms_px_capture": gc.systematic_rms_px,
                "light_offset_rms_px_render": gr.systematic_rms_px,
                "light_offset_floor_px_capture": gc.systematic_floor_px,
                "glint_residual_rms_px_capture": gc.residual_rms_px,
                "light_offsets_px_capture": [None if not np.all(np.isfinite(o)) else o.tolist()
                                             for o in gc.light_offset_px]}
    rows, findings = verdict_rows(setup, msetup, timing, sensor, geometry, gc, gr, cm, rm, gaze,
                                  cap_samples, ren_samples)
    rows, findings = optics_verdict(
        rows, findings, lambda rm_b: verdict_rows(setup, msetup, timing, sensor, geometry, gc,
                                                  gr, cm, rm_b, gaze, cap_samples,
                                                  ren_samples)[0],
        msetup, cm, rm, lambda imgs: _track(msetup, calibration, method, imgs, starts),
        radiance, renders, est, seed, black_c, setup)
    return CompareResult(capture_dir, setup, msetup, timing, sorted(images), images, renders, cm,
                         rm, cap_samples, ren_samples, sensor, geometry, gaze, rows, findings,
                         notes)
