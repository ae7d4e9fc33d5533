"""The tracker's accuracy on the wire mirror's glints, three ways (issue 35, part 3), for
``scet study wire``:

* **(a) point sources at the nominal pose**: the scene's point lights (each turn's axis at
  mid-width) where the 3D model puts them; r_c, c_e and r_co fitted to the calibration frames
  with the lighting pose held (:func:`estimator.calibration.calibrate_joint` with bounds of
  1e-12 rad and m on the pose);
* **(b) calibrated lighting pose**: the same point lights, the pose fitted too (the default
  calibration, :func:`estimator.folders.calibrate_from_glints`);
* **(c) virtual sources**: ``light_model = "wire_mirror"`` (:mod:`estimator.cornea.wire`), the
  calibration fitting the mirror's pose on the highlights' glints.

and, on renders, the **point-source ideal**: the same poses rendered with the turns replaced by
point-like spheres where the point model puts them (:func:`ideal_setup`,
``bench_wire_track.py --ideal``), calibrated and tracked as (b); (c) - ideal per pose with
paired bootstrap intervals (:func:`paired_difference`).

Each calibrates on the 5 x 5 pattern's glints and runs both gaze methods on the test glints;
the glints are the two-bounce solver's (feature level, noise-free) or centroids measured in
renders (``benchmarks/bench_wire_track.py`` writes them to ``reports/wire_mirror_rendered.npz``,
:data:`RENDERED_FORMAT`). Samples/s: the gaze call over the test samples, on this machine, with
every seen glint and (geometric) with :data:`BAND_GLINTS` of them a sample, as a band holds.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

RENDERED_FORMAT = "scet-wire-rendered-glints"
RENDERED_VERSION = 1
#: The rows of the tables, in order: key, label.
MODELS = (("nominal", "(a) point sources, nominal pose"),
          ("calibrated", "(b) point sources, calibrated pose"),
          ("option", "(c) virtual sources (light_model wire_mirror)"))
#: Glints of a band for the cost column: 16 pulses over 786 lines light bands of ~30 rows, which
#: hold 2-6 of the prototype's glints.
BAND_GLINTS = 4
#: Pose bounds that hold the lighting at its nominal pose in (a) (rad, m): TRF needs lo < hi.
HELD = 1e-12
#: LED diameters (m) of :func:`led_size_accuracy`: the renders' 2 mm, and down to the scene's 0.5 mm.
LED_SIZES_M = (2e-3, 1e-3, 0.5e-3)
#: Repeats and one-call bands of :func:`band_cost`: 5 x 40 bands of (c) take ~2-5 s here.
COST_REPEATS = 5
COST_BANDS = 40
#: Bootstrap resamples of the (c) - ideal intervals: over the rendered table's 24 poses the
#: interval ends move by <= 0.0006 deg (geometric) and <= 0.005 deg (polynomial) over 6 seeds.
BOOTSTRAP_RESAMPLES = 10_000
#: Diameter (m) of the ideal scene's spherical sources: prototype_ov5647.toml's turns.
IDEAL_SOURCE_M = 0.8e-3


def ideal_setup(setup, source_diameter_m: float = IDEAL_SOURCE_M):
    """``setup`` with every ``wire_mirror`` group replaced by plain point lights (``kind =
    "list"``, spheres of ``source_diameter_m``) at the turns' axes, the positions the
    point-source model uses: the scene whose glints the default tracker models exactly (up to
    the spheres' size), the ideal the virtual-source option is held against."""
    from dataclasses import replace

    from estimator.setup import LightGroup

    groups = tuple(LightGroup(g.name, "list", g.points_local_m, g.pose, 0.5 * float(source_diameter_m))
                   if g.emitter is not None else g for g in setup.lights.groups)
    return replace(setup, lights=replace(setup.lights, groups=groups))


def _calibrate(setup, model, glints, targets):
    from estimator.calibration import Calibration, calibrate_joint, calibration_warnings
    from estimator.folders import calibrate_from_glints, fit_supported_mappings
    from estimator.gaze import fit_cornea_centers

    if model != "nominal":
        return calibrate_from_glints(setup, glints, targets,
                                     light_model="wire_mirror" if model == "option" else "points")
    mask = np.isfinite(glints).all(axis=-1)
    light, orbit = calibrate_joint(setup.camera, setup.lights_world_m, glints, targets, mask,
                                   center0_m=setup.eye.cornea_center(0.0, 0.0),
                                   rotation_bound_rad=HELD, translation_bound_m=HELD)
    cal = Calibration.from_fits(light, orbit).with_quality(
        rms_px=float(light.rms_px), frames_used=len(targets), frames_total=len(targets),
        warnings=calibration_warnings(light, orbit, frames_used=len(targets), frames_total=len(targets)))
    c = fit_cornea_centers(setup, cal, glints, mask)
    maps, _ = fit_supported_mappings(c.center_m[c.ok], np.asarray(targets)[c.ok])
    return cal.with_mappings(**maps)


def method_accuracy(setup, cal, glints, targets, methods=("geometric", "polynomial")) -> dict:
    """{method: {"errors_deg" (m,), "samples_per_s"}}: gaze from ``glints`` (m, n, 2) with
    calibration ``cal`` against the true ``targets`` (m, 3), the polynomial method with the
    calibration's highest Eq. (1) mapping; samples/s of the estimation alone."""
    from estimator.gaze import calibrated_problems, geometric_gaze, polynomial_gaze
    from estimator.metrics import angular_error_deg

    problems = calibrated_problems(setup, cal)
    mapping = sorted(k for k in cal.mappings if k.startswith("eq1"))[-1]
    out = {}
    for method in methods:
        t0 = time.perf_counter()
        if method == "polynomial":
            est = polynomial_gaze(setup, cal, glints, mapping=mapping, problems=problems)
        else:
            est = geometric_gaze(setup, cal, glints, problems=problems)
        dt = time.perf_counter() - t0
        err = angular_error_deg(est.point_m, targets, setup.eye.rotation_center_m)
        out[method] = {"errors_deg": err, "samples_per_s": len(targets) / dt}
    return out


def accuracy_table(setup, cal_glints, cal_targets, glints, targets, models=None) -> dict:
    """{model: {"calibration": Calibration, "rms_px", method: {"errors_deg" (m,), "samples_per_s"}}}
    for the :data:`MODELS` (module docstring; ``models``: a subset of their keys); glints
    (m, n, 2) NaN where not seen."""
    from estimator.gaze import calibrated_problems, geometric_gaze

    out = {}
    for model in models or [k for k, _ in MODELS]:
        cal = _calibrate(setup, model, cal_glints, cal_targets)
        problems = calibrated_problems(setup, cal)
        row = {"calibration": cal, "rms_px": float(cal.quality["rms_px"]),
               **method_accuracy(setup, cal, glints, targets)}
        few = band_glints(glints)
        t0 = time.perf_counter()
        geometric_gaze(setup, cal, few, problems=problems)
        row["band_samples_per_s"] = len(targets) / (time.perf_counter() - t0)
        out[model] = row
    return out


def band_glints(glints, k: int = BAND_GLINTS, seed: int = 0):
    """``glints`` (m, n, 2) cut to ``k`` seen glints a sample, chosen at random (seeded): the
    few glints a band holds."""
    rng = np.random.default_rng(seed)
    out = np.full_like(glints, np.nan)
    for i, g in enumerate(glints):
        seen = np.flatnonzero(np.isfinite(g).all(axis=-1))
        keep = rng.choice(seen, min(k, seen.size), replace=False)
        out[i, keep] = g[keep]
    return out


def band_cost(setup, rows: dict, targets, *, repeats: int = COST_REPEATS, bands: int = COST_BANDS) -> dict:
    """Samples/s of the geometric band step for each row, all in one run (the machine's speed
    swings ~2x, so ranges over ``repeats`` and ratios matter, not one figure).

    Parameters
    ----------
    rows : dict
        {label: (setup, calibration, glints (m, n, 2))}: each row's own setup (the ideal's has
        no wire group), calibration and test glints (NaN where not seen).
    targets : (m, 3) float

    Returns
    -------
    dict
        {label: {"batched": (lo, hi), "per_band": (lo, hi)}} samples/s: every sample of the
        grid cut to :data:`BAND_GLINTS` glints in one call, and ``bands`` of them one call each
        (a live band at a time).
    """
    from estimator.gaze import calibrated_problems, geometric_gaze

    out = {}
    for label, (s, cal, glints) in rows.items():
        few = band_glints(glints)
        problems = calibrated_problems(s, cal)
        geometric_gaze(s, cal, few[:1], problems=problems)  # start-up (first calls, compiles)
        batched, per_band = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            geometric_gaze(s, cal, few, problems=problems)
            batched.append(len(few) / (time.perf_counter() - t0))
            t0 = time.perf_counter()
            for i in range(min(bands, len(few))):
                geometric_gaze(s, cal, few[i:i + 1], problems=problems)
            per_band.append(min(bands, len(few)) / (time.perf_counter() - t0))
        out[label] = {"batched": (min(batched), max(batched)), "per_band": (min(per_band), max(per_band))}
    return out


def load_rendered(path) -> dict | None:
    """The rendered centroids of ``benchmarks/bench_wire_track.py``, or None where ``path`` does
    not exist; ValueError naming the file and key for another format or version."""
    path = Path(path)
    if not path.is_file():
        return None
    with np.load(path, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    if str(d.get("format", "")) != RENDERED_FORMAT:
        raise ValueError(f"{path}: format: expected {RENDERED_FORMAT!r}, got {d.get('format')!r}")
    if int(d.get("version", -1)) != RENDERED_VERSION:
        raise ValueError(f"{path}: version: expected {RENDERED_VERSION}, got {d.get('version')!r}")
    for k in ("calibration_targets_m", "calibration_centroids_px", "test_targets_m", "test_centroids_px"):
        if k not in d:
            raise ValueError(f"{path}: {k}: missing")
    return d


def paired_difference(errors_deg, ideal_deg, *, resamples: int = BOOTSTRAP_RESAMPLES,
                      level: float = 0.95, seed: int = 35) -> dict:
    """A row's gaze errors against the ideal's on the same poses: the difference of their
    medians and of their means with paired bootstrap intervals (poses resampled with
    replacement, the same poses for both; percentile interval at ``level``, seeded), and the
    per-pose differences.

    Parameters
    ----------
    errors_deg, ideal_deg : (m,) float
        Errors (deg) on the same m poses; poses where either is NaN are dropped.

    Returns
    -------
    dict
        ``median``, ``median_ci`` (lo, hi), ``mean``, ``mean_ci``, ``per_pose`` (k,) deg,
        ``poses`` k, ``level``.
    """
    a, b = np.asarray(errors_deg, dtype=np.float64), np.asarray(ideal_deg, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"errors_deg and ideal_deg must be (m,) alike, got {a.shape} and {b.shape}")
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    out = {"poses": int(a.size), "per_pose": a - b, "level": level}
    if a.size == 0:
        return out | {"median": np.nan, "median_ci": (np.nan, np.nan), "mean": np.nan, "mean_ci": (np.nan, np.nan)}
    idx = np.random.default_rng(seed).integers(0, a.size, (resamples, a.size))
    q = 100 * np.array([(1 - level) / 2, (1 + level) / 2])
    for name, f in (("median", np.median), ("mean", np.mean)):
        boot = f(a[idx], axis=1) - f(b[idx], axis=1)
        out[name] = float(f(a) - f(b))
        out[f"{name}_ci"] = tuple(float(x) for x in np.percentile(boot, q))
    return out


def rendered_accuracy(setup, rendered: dict, ideal: dict | None = None, *,
                      led_sizes_m=None) -> dict:
    """:func:`accuracy_table` on rendered centroids, plus their error against the labels (the
    solver's glints averaged over the LED's disk) and those labels' offset from the LED
    centre's glints (the point the option models). With ``ideal`` (the same poses rendered
    with point-like sources, ``bench_wire_track.py --ideal``): its row, calibrated and tracked
    the default way on :func:`ideal_setup`, its centroids' error against their labels, and
    the (c) - ideal differences (:func:`paired_difference`) per method, and
    :func:`led_size_accuracy` over ``led_sizes_m`` (default :data:`LED_SIZES_M`)."""
    table = accuracy_table(setup, rendered["calibration_centroids_px"], rendered["calibration_targets_m"],
                           rendered["test_centroids_px"], rendered["test_targets_m"])
    d = _centroid_errors(rendered)
    from ..simulate import ground_truth_glints

    shift = []
    for k in ("calibration", "test"):
        g, v, _ = ground_truth_glints(setup, *setup.eye.angles_toward(rendered[f"{k}_targets_m"]))
        shift.append(np.linalg.norm(np.where(v[..., None], g, np.nan) - rendered[f"{k}_labels_px"], axis=-1).ravel())
    shift = np.concatenate(shift)
    return {"table": table, "centroid_error_px": d, "disk_shift_px": shift[np.isfinite(shift)], "spp": int(rendered["spp"]),
            "led_mm": 1e3 * float(rendered["led_m"]), "frames": (len(rendered["calibration_targets_m"]),
                                                                 len(rendered["test_targets_m"])),
            "seconds": _seconds(rendered),
            "ideal": None if ideal is None else ideal_accuracy(setup, rendered, ideal, table, led_sizes_m=led_sizes_m)}


def _centroid_errors(rendered):
    d = np.concatenate([np.linalg.norm(rendered[f"{k}_centroids_px"] - rendered[f"{k}_labels_px"], axis=-1).ravel()
                        for k in ("calibration", "test")])
    return d[np.isfinite(d)]


def _seconds(rendered):
    return float(np.sum(rendered["calibration_seconds"]) + np.sum(rendered["test_seconds"]))


def ideal_accuracy(setup, rendered: dict, ideal: dict, table: dict, *, led_sizes_m=None) -> dict:
    """The ideal's row (:func:`rendered_accuracy`); ValueError naming the key where ``ideal``
    was not rendered on ``rendered``'s poses and spp."""
    for k in ("calibration_targets_m", "test_targets_m", "spp"):
        same = np.shape(ideal[k]) == np.shape(rendered[k]) and np.allclose(ideal[k], rendered[k], rtol=0, atol=1e-12)
        if not same:
            raise ValueError(f"ideal rendered glints: {k}: not the wire renders' (render both with "
                             "benchmarks/bench_wire_track.py's defaults)")
    row = accuracy_table(ideal_setup(setup), ideal["calibration_centroids_px"], ideal["calibration_targets_m"],
                         ideal["test_centroids_px"], ideal["test_targets_m"], models=("calibrated",))["calibrated"]
    diff = {m: paired_difference(table["option"][m]["errors_deg"], row[m]["errors_deg"])
            for m in ("geometric", "polynomial")}
    # (c) on the wire renders' labels (the solver's glints averaged over the LED's disk,
    # noise-free): what is left of the gap without any rendering noise, the LED's size.
    on_labels = accuracy_table(setup, rendered["calibration_labels_px"], rendered["calibration_targets_m"],
                               rendered["test_labels_px"], rendered["test_targets_m"],
                               models=("option",))["option"]
    return {"row": row, "centroid_error_px": _centroid_errors(ideal), "seconds": _seconds(ideal),
            "option_minus_ideal": diff, "option_on_labels": on_labels,
            "led_sizes": led_size_accuracy(setup, rendered, LED_SIZES_M if led_sizes_m is None else led_sizes_m)}


def led_size_accuracy(setup, rendered: dict, sizes_m=LED_SIZES_M, *, rings: int = 8) -> dict:
    """(c) on noise-free disk glints (:func:`estimator.geometry.wire.led_disk_glints`) of LEDs
    of each diameter in ``sizes_m``, on ``rendered``'s poses: the option's own model error
    from the LED's size (it models a point); ``rings`` of the disk's sample points (8: the
    renders' labels). {size_m: {"rms_px", "median_deg", "max_deg"}}."""
    from dataclasses import replace

    from estimator.geometry.wire import led_disk_glints, setup_wire_mirrors
    from estimator.setup import LightGroup

    out = {}
    for size in sizes_m:
        groups = tuple(LightGroup(g.name, g.kind, g.points_local_m, g.pose, g.source_radius_m,
                                  replace(g.emitter, led_diameter_m=float(size)))
                       if g.emitter is not None else g for g in setup.lights.groups)
        s = replace(setup, lights=replace(setup.lights, groups=groups))
        ((_, first, mirror),) = setup_wire_mirrors(s)
        glints = {}
        for k in ("calibration", "test"):
            t = rendered[f"{k}_targets_m"]
            g = np.full((len(t), s.lights.count, 2), np.nan)
            g[:, first:first + mirror.turns] = led_disk_glints(s.eye, s.camera, mirror, *s.eye.angles_toward(t),
                                                           rings=rings)[0]
            glints[k] = g
        row = accuracy_table(s, glints["calibration"], rendered["calibration_targets_m"], glints["test"],
                             rendered["test_targets_m"], models=("option",))["option"]
        e = row["geometric"]["errors_deg"]
        out[float(size)] = {"rms_px": row["rms_px"], "median_deg": float(np.nanmedian(e)),
                            "max_deg": float(np.nanmax(e))}
    return out


def _f(x, fmt="{:.3f}"):
    return "-" if not np.isfinite(x) else fmt.format(x)


def table_lines(table: dict, ideal: dict | None = None,
                ideal_label: str = "point-source glints (the model's ideal), (b)") -> list[str]:
    """Markdown rows of an :func:`accuracy_table` (and the point-source ideal's, if given)."""
    lines = ["| glints / model | method | median deg | mean deg | max deg | valid | calib RMS px | samples/s "
             f"| samples/s, {BAND_GLINTS} glints |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    rows = ([("ideal", ideal_label, ideal)] if ideal else []) + \
        [(k, label, table[k]) for k, label in MODELS]
    for _, label, r in rows:
        for method in ("geometric", "polynomial"):
            e = r[method]["errors_deg"]
            ok = np.isfinite(e)
            med, mean, mx = ((np.median(e[ok]), e[ok].mean(), e[ok].max()) if ok.any()
                             else (np.nan,) * 3)
            lines.append(f"| {label} | {method} | {_f(med)} | {_f(mean)} | {_f(mx)} | "
                         f"{100 * ok.mean():.0f} % | {_f(r['rms_px'])} | {r[method]['samples_per_s']:.0f} | "
                         + (f"{r['band_samples_per_s']:.0f} |" if method == "geometric" and
                            "band_samples_per_s" in r else "- |"))
    return lines


__all__ = ["accuracy_table", "band_glints", "BAND_GLINTS", "rendered_accuracy", "ideal_accuracy", "ideal_setup",
           "paired_difference", "band_cost", "led_size_accuracy", "LED_SIZES_M", "IDEAL_SOURCE_M",
           "BOOTSTRAP_RESAMPLES", "load_rendered", "table_lines", "MODELS",
           "RENDERED_FORMAT", "RENDERED_VERSION"]

