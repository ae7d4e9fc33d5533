"""The prototype's lens, measured on renders: where the tracker's glint detector finds the glints
as the lens blurs and distorts them (``scet study lens``, ``reports/lens.md``).

Each condition is a camera (focal length, working distance, aperture, focus) on a scene's eye
and lights. For a few fixations it renders a banded frame through the lens
(:class:`~scet_render.render.BandedRenderer`, default dielectric cornea with MNEE), applies the
OV5647 sensor model, runs the estimator's :func:`~estimator.glints.detect_glints`, and matches
each ground-truth glint (labels through :meth:`~estimator.geometry.Camera.distort_px`) in a
lit row to the nearest detection within :data:`MATCH_PX`:

* found: the share of those glints detected;
* centroid error: median and 90th percentile distance to the distorted label (px);
* pinhole error: the median distance of the same detections to the pinhole (undistorted)
  labels, what a tracker that ignores the distortion would be off by.

This is the glint level only: gaze error and valid share need calibrations and tracks per
condition (``scet validate``), which this study leaves out.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import numpy as np

from estimator.banding import row_pulse_weights
from estimator.geometry import Camera, look_at_rotation
from estimator.glints import detect_glints
from estimator.setup import Setup

log = logging.getLogger(__name__)

#: A detection farther than this from a label is not that glint (px): blurred glints move their
#: centroid by a fraction of a pixel; neighbours sit ~5 px apart at 643 px.
MATCH_PX = 2.0
#: Rows a pulse lights by less than this share of a full pulse are left out (dim band edges).
LIT_SHARE = 0.5
#: The aperture the sensor model's exposure scale was tuned for (the stock lens,
#: :data:`scet_render.render.DEFAULT_ELECTRONS_PER_RADIANCE`): other apertures collect
#: (2.9 / N)^2 of its light at the same 1 ms exposure and strobe power.
REFERENCE_F_NUMBER = 2.9
#: Fixations (yaw, pitch in rad) the glints are measured at: straight, and 8 deg off on each axis.
POSES = ((0.0, 0.0), (-0.14, 0.05), (0.12, -0.06))


@dataclass(frozen=True)
class LensCondition:
    """One camera of the study: ``label`` names it in the report."""

    label: str
    focal_px: float
    working_distance_m: float | None  # None: the scene's camera position
    f_number: float | None
    focus_offset_m: float = 0.0        # added to the scene's (or the glint plane's) focus


@dataclass(frozen=True)
class LensResult:
    condition: LensCondition
    camera: Camera
    labels: int
    found: float
    median_px: float
    p90_px: float
    pinhole_median_px: float
    blur_px: float


def glint_depth_m(setup: Setup, camera: Camera) -> float:
    """Depth of the glints' virtual images at primary gaze (m): the corneal apex's depth plus
    the image distance of a convex mirror of radius r_c for lights at the camera's distance
    (1/v = 2/r_c + 1/u), measured from the apex."""
    apex = float(camera.world_to_camera(setup.eye.apex())[2])
    u = float(np.median(np.linalg.norm(setup.lights_world_m - setup.eye.apex(), axis=1)))
    return apex + 1.0 / (2.0 / setup.eye.cornea_radius_m + 1.0 / u)


def condition_camera(setup: Setup, c: LensCondition) -> Camera:
    """The scene's camera with the condition's focal length, distance, aperture and focus."""
    cam = setup.camera
    position, R = cam.position_m, cam.rotation
    apex = setup.eye.apex()
    if c.working_distance_m is not None:
        direction = (position - apex) / np.linalg.norm(position - apex)
        position = apex + direction * c.working_distance_m
        R = look_at_rotation(position, apex, [0.0, 1.0, 0.0])
    pitch = cam.pixel_pitch_m or 5.6e-6
    base = Camera(position, R, c.focal_px, c.focal_px, cam.cx_px, cam.cy_px, cam.width_px,
                  cam.height_px, cam.distortion)
    if c.f_number is None:
        return base
    focus = glint_depth_m(setup, base) + c.focus_offset_m
    return Camera(position, R, c.focal_px, c.focal_px, cam.cx_px, cam.cy_px, cam.width_px,
                  cam.height_px, cam.distortion, c.f_number, focus, pitch)


class _Fixation:
    def __init__(self, yaw, pitch):
        self.yaw, self.pitch = yaw, pitch

    def angles_at(self, t):
        t = np.asarray(t, dtype=float)
        return np.full(t.shape, self.yaw), np.full(t.shape, self.pitch)


def measure(setup: Setup, c: LensCondition, *, spp: int = 16, seed: int = 0,
            poses=POSES) -> LensResult:
    """Render, detect and score one condition (see the module docstring)."""
    from scet_render.render import BandedRenderer, SensorModel
    from scet_render.simulate import ground_truth_glints

    camera = condition_camera(setup, c)
    s = dataclasses.replace(setup, camera=camera)
    renderer = BandedRenderer(s, spp=spp, seed=seed)
    # The sensor model's exposure scale is tuned for the stock F2.9 lens; the light a pixel
    # collects from a given radiance goes as 1 / N^2 (sensor module docstring).
    scale = (REFERENCE_F_NUMBER / camera.f_number) ** 2 if camera.is_thin_lens else 1.0
    model = SensorModel.from_sensor(s.sensor)
    model = dataclasses.replace(model, electrons_per_radiance=model.electrons_per_radiance * scale)
    errors, pinhole, total, found = [], [], 0, 0
    for k, (yaw, pitch) in enumerate(poses):
        frame = renderer.render_frame(_Fixation(yaw, pitch), 0)
        dn = model.apply(frame.radiance, np.random.default_rng([seed, k]))
        det = detect_glints(dn, s, 0)
        g, vis, _ = ground_truth_glints(s, yaw, pitch)
        ideal = g[vis]
        labels = camera.distort_px(ideal)
        inside = camera.in_image(labels)
        rows = np.clip(np.rint(labels[:, 1]), 0, camera.height_px - 1)
        _, _, w = row_pulse_weights(s.sensor, s.strobe, 0, rows=rows)
        keep = inside & (w.max(axis=1) >= LIT_SHARE)
        labels, ideal = labels[keep], ideal[keep]
        total += len(labels)
        if not len(labels) or not len(det.u_px):
            continue
        d_uv = np.column_stack([det.u_px, det.v_px])
        dist = np.linalg.norm(labels[:, None, :] - d_uv[None], axis=2)
        nearest = dist.argmin(axis=1)
        near = dist[np.arange(len(labels)), nearest]
        ok = near < MATCH_PX
        found += int(ok.sum())
        errors.append(near[ok])
        pinhole.append(np.linalg.norm(ideal[ok] - d_uv[nearest[ok]], axis=1))
    e = np.concatenate(errors) if errors else np.zeros(0)
    p = np.concatenate(pinhole) if pinhole else np.zeros(0)
    depth = glint_depth_m(setup, camera)
    result = LensResult(c, camera, total, found / total if total else math.nan,
                        float(np.median(e)) if e.size else math.nan,
                        float(np.percentile(e, 90)) if e.size else math.nan,
                        float(np.median(p)) if p.size else math.nan,
                        float(camera.blur_diameter_px(depth)))
    log.info("lens study %s: %d glints, found %.2f, median %.3f px", c.label, total,
             result.found, result.median_px)
    return result


def defocus_conditions(setup: Setup, offsets_mm=(0.0, 2.0, 5.0, -2.0, -5.0)) -> list:
    """The scene's lens with its focus moved off the glints' plane by ``offsets_mm``."""
    cam = setup.camera
    return [LensCondition(f"focus {o:+g} mm", cam.fx_px, None, cam.f_number or 2.9, o * 1e-3)
            for o in offsets_mm]


def optics_conditions(setup: Setup) -> list:
    """Focal length (the stock 3.6 mm lens, 643 px; ~7.3 mm, the paper's 1300 px) x aperture
    (F2.9 stock, F5.6) at the scene's distance, and the stock lens 10 mm farther out."""
    cam = setup.camera
    wd = float(np.linalg.norm(cam.position_m - setup.eye.apex()))
    out = []
    for f_px, name in ((643.0, "3.6 mm"), (1300.0, "7.3 mm")):
        for n in (2.9, 5.6):
            out.append(LensCondition(f"{name} F{n:g} at {wd * 1e3:.0f} mm", f_px, None, n))
    out.append(LensCondition(f"3.6 mm F2.9 at {wd * 1e3 + 10:.0f} mm", 643.0, wd + 0.01, 2.9))
    return out


def _row(r: LensResult) -> str:
    cam = r.camera
    lens = (f"F{cam.f_number:g}, focus {cam.focus_distance_m * 1e3:.1f} mm"
            if cam.is_thin_lens else "pinhole")
    return (f"| {r.condition.label} | {cam.fx_px:g} | {lens} | {r.blur_px:.2f} | {r.labels} | "
            f"{100 * r.found:.0f} % | {r.median_px:.3f} | {r.p90_px:.3f} | "
            f"{r.pinhole_median_px:.3f} |")


def _reading(defocus: list, optics: list) -> str:
    """Sentences computed from the tables (so that a rerun rewrites them with its numbers)."""
    lines = []
    base = next((r for r in defocus if r.condition.focus_offset_m == 0.0), None)
    if base is not None and math.isfinite(base.found):
        tolerated = [abs(r.condition.focus_offset_m) * 1e3 for r in defocus
                     if r.found >= 0.9 * base.found and r.median_px <= 1.5 * base.median_px]
        worst = min(defocus, key=lambda r: (r.found, -abs(r.condition.focus_offset_m)))
        lines.append(
            f"* In focus the detector finds {100 * base.found:.0f} % of the lit glints, centroids "
            f"{base.median_px:.3f} px (median) from the labels. The largest focus error that keeps "
            f"at least 90 % of that share and at most 1.5x the error: {max(tolerated):g} mm "
            f"(of those measured); at {worst.condition.focus_offset_m * 1e3:+g} mm "
            f"({worst.blur_px:.1f} px blur) it finds {100 * worst.found:.0f} %, median "
            f"{worst.median_px:.3f} px.")
        lines.append(
            f"* Ignoring the distortion costs {base.pinhole_median_px:.3f} px (median, against "
            f"the undistorted labels) at these fixations, where the glints sit near the image "
            f"centre; the corners move far more (see `scet scene`).")
    ok = [r for r in optics if math.isfinite(r.found)]
    if ok:
        best = max(ok, key=lambda r: (r.found, -r.median_px))
        lines.append(f"* Of the optics, {best.condition.label} finds the most glints "
                     f"({100 * best.found:.0f} %, median {best.median_px:.3f} px).")
    return "\n".join(lines) if lines else "* No condition measured."


def report(setup: Setup, defocus: list, optics: list, *, spp: int, seed: int,
           poses: int = len(POSES), command: str | None = None, gaze: str | None = None,
           glint_s: float | None = None) -> str:
    """``reports/lens.md``: the two tables, the gaze section ``gaze`` (markdown of
    :func:`scet_render.study.lens_gaze_report.gaze_section`, None: not run) and what they leave
    out; ``command`` is the command line that made it, ``glint_s`` the glint tables' run time."""
    head = ("| condition | focal (px) | lens | blur at the glints (px) | glints | found | "
            "centroid median (px) | p90 (px) | vs pinhole labels (px) |\n|---|---|---|---|---|---|"
            "---|---|---|")
    cam = setup.camera
    command = command or f"scet study lens {setup.name} --spp {spp} --seed {seed} --poses {poses}"
    return f"""# The prototype's lens: glints through blur and distortion

Generated by `{command}`
(`scet_render/study/lens.py`, `lens_gaze.py`). Scene `{setup.name}`: {cam.width_px}x{cam.height_px} px,
distortion {np.round(cam.distortion, 4).tolist()}, pixel pitch
{(cam.pixel_pitch_m or 0) * 1e6:g} um. Each row renders one banded frame at each of
{poses} fixation(s) of {[tuple(round(float(np.degrees(a)), 1) for a in p) for p in POSES[:poses]]}
deg (yaw, pitch; default dielectric cornea with MNEE, {spp} spp, the OV5647 sensor model),
runs the tracker's glint detector and matches every ground-truth glint in a lit row (labels
through the lens's distortion) to the nearest detection within {MATCH_PX:g} px. "blur" is the
thin-lens disc diameter c = A |d - d_f| / d x f / (d_f - f) of a point at the glints' virtual
image depth (apex depth + the convex mirror's image distance, 1/v = 2/r_c + 1/u). "vs pinhole
labels": the same detections against the undistorted labels, what a tracker that ignores
the distortion is off by.""" + ("" if glint_s is None else f""" The glint tables took
{glint_s / 60:.1f} min on this machine.""") + f"""

## Glint centroids against defocus (the scene's lens, focus moved off the glints' plane)

{head}
""" + "\n".join(_row(r) for r in defocus) + f"""

## Optics (focal length, aperture, working distance; focused on the glints)

{head}
""" + "\n".join(_row(r) for r in optics) + """

## Reading

""" + _reading(defocus, optics) + """

""" + (gaze + "\n" if gaze else "") + """## What this leaves out

""" + ("" if gaze else """* Gaze error and valid share per condition: not run here (`--gaze` runs them).
""") + ("""* The gaze tables are small runs (their sizes above: few test fixations, a small calibration
  grid, low spp); `--gaze-frames`, `--gaze-grid` and `--gaze-spp` size a larger one.
""" if gaze else "") + """* Noise against aperture is modelled by the exposure scale only: the sensor model's electrons
  per unit radiance (tuned so that a stock-lens F2.9 glint reaches 70 % of saturation) times
  (2.9 / N)^2, at the same 1 ms exposure and strobe power; a stronger strobe would buy the
  light back. The strobe's real power and the LEDs' limits are not modelled.
* A few fixations only; a study over a motion sequence is a larger run.
"""


def run_study(setup: Setup, *, spp: int = 16, seed: int = 0, defocus_mm=(0.0, 2.0, 5.0, -2.0, -5.0),
              poses: int = len(POSES), progress=None, gaze=None, gaze_steps: int = 0,
              command: str | None = None) -> tuple[str, list, list]:
    """Measure every condition at the first ``poses`` of :data:`POSES`; returns (markdown,
    defocus results, optics results).

    ``gaze``, optional: ``gaze(optics_results, progress) -> markdown`` runs the gaze-level
    conditions (:func:`scet_render.study.lens_gaze.gaze_runner`, ``gaze_steps`` of them,
    reported through ``progress(done, total)``) and the report holds its section."""
    import time

    if isinstance(poses, bool) or not isinstance(poses, int) or not 1 <= poses <= len(POSES):
        raise ValueError(f"poses must be an integer in [1, {len(POSES)}], got {poses!r}")
    conditions = defocus_conditions(setup, defocus_mm)
    optics = optics_conditions(setup)
    total = len(conditions) + len(optics) + (gaze_steps if gaze is not None else 0)
    t0 = time.perf_counter()
    results = []
    for i, c in enumerate(conditions + optics):
        results.append(measure(setup, c, spp=spp, seed=seed, poses=POSES[:poses]))
        if progress is not None:
            progress(i + 1, total)
    d, o = results[:len(conditions)], results[len(conditions):]
    glint_s = time.perf_counter() - t0
    section = None
    if gaze is not None:
        done = len(results)
        section = gaze(o, (lambda k, _: progress(done + k, total)) if progress else None)
    return report(setup, d, o, spp=spp, seed=seed, poses=poses, command=command,
                  gaze=section, glint_s=glint_s), d, o
