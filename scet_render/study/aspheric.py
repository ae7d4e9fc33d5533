"""``scet study aspheric``: the spherical tracker's error on aspheric (conic) corneas.

The tracker (:mod:`estimator`) models the cornea as a sphere; real corneas flatten towards
the limbus (conic constant Q of about -0.25, Q = 0 the sphere; ``[eye] cornea_asphericity``).
For each Q the study derives the scene's eye with that Q (:func:`aspheric_scene`: the setup
by ``dataclasses.replace`` on the Eye, and the scene text with the key, which the datasets'
manifests record) and runs on it exactly what ``scet validate`` runs
(:func:`scet_render.validate.validate_setup`: single-pulse calibration frames and a banded
fixation sequence rendered with Mitsuba, the conic cornea drawn exactly; calibration; both
gaze methods; the feature-level simulation of the same poses, lights and calibration, whose
glints are the exact conic reflections), once per lid condition (:data:`LID_CONDITIONS`:
the renderer's static eyelids at their default openness, no lids, and the scene's moving lids
with lashes and blinks, :data:`MOVING_LIDS`). The samples are scored per band position
(:func:`scet_render.validate.band_position`). Beside it, :func:`feature_level_model_error`
runs the simulator alone at full size, calibration included, noise-free: the model error with
nothing else in it.

Quick mode renders like ``scet validate --quick`` (320 x 240, 4 spp, conductor cornea) with
60 test frames at the scene's 16 pulses per frame; full mode 640 x 480, 16 spp, dielectric,
90 frames.
"""

from __future__ import annotations

import hashlib
import math
import re
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from estimator.banding import scaled_setup
from estimator.eye import ASPHERICITY_MIN
from estimator.scene import load_scene, parse_scene
from estimator.setup import Setup

from ..validate import POSITIONS, SIM_REPEATS, ValidationConfig, band_position, error_statistics

#: The issue's conic constants: the sphere, and flattening up to about the population's
#: extreme (Q ~ -0.25 on average, SD ~0.1-0.2 in keratometry studies).
DEFAULT_ASPHERICITIES = (0.0, -0.1, -0.25, -0.45)
#: The lid conditions: ``"on"``, the renderer's static eyelids at their default openness (1.0:
#: they clear the cornea for every gaze at the screen); ``"off"``, no lids; ``"moving"``, the
#: scene's ``[eyelids]`` table (:data:`MOVING_LIDS`): lids that follow the eye's pitch, lashes
#: and blinks.
LID_CONDITIONS = ("on", "off", "moving")
#: The ``[eyelids]`` table of the moving-lid condition: the default gains and margins (clear
#: of the cornea by 5 deg at every gaze at the screen), 40 lashes, 15 blinks a minute
#: (a typical spontaneous rate, 4-50/min: Bentivoglio et al. 1997, as docs/formats/scene.md cites).
MOVING_LIDS = "[eyelids]\nlash_count = 40\nblink_rate_per_min = 15\n"
_LID_OPENNESS = {"on": 1.0, "off": None, "moving": 1.0}
_LID_FOLDERS = {"on": "lids", "off": "nolids", "moving": "movinglids"}

#: Quick: ``scet validate --quick``'s render settings, at the scene's own 16 pulses per frame
#: only, and 60 frames: 1 s of fixations at 0.25 s each, four grid cells (30 frames held two
#: neighbouring cells in the quick validation's sequence: one gaze region).
QUICK = ValidationConfig(scale=2, spp=4, cornea="conductor", frames=60, pulses_per_frame=(16,))
FULL = ValidationConfig(scale=1, spp=16, cornea="dielectric", frames=90, pulses_per_frame=(16,))


def parse_asphericities(text: str) -> tuple:
    """Conic constants from ``--q`` text (comma separated), each in (-1, 1].

    Raises
    ------
    ValueError
        Naming ``--q`` and the bad item.
    """
    items = [t.strip() for t in str(text).split(",")]
    if not items or any(not t for t in items):
        raise ValueError(f"--q {text!r}: expected comma-separated numbers, e.g. 0,-0.1,-0.25")
    out = []
    for t in items:
        try:
            q = float(t)
        except ValueError:
            raise ValueError(f"--q {text!r}: {t!r} is not a number") from None
        if not (math.isfinite(q) and ASPHERICITY_MIN < q <= 1.0):
            raise ValueError(f"--q {text!r}: {t} is outside the conic constants of a cornea, "
                             f"{ASPHERICITY_MIN:g} < Q <= 1")
        out.append(q)
    if len(set(out)) != len(out):
        raise ValueError(f"--q {text!r}: a value is given twice")
    return tuple(out)


_EYE_TABLE = re.compile(r"^\[eye\][ \t]*(#[^\n]*)?$", re.M)
_NEXT_TABLE = re.compile(r"^[ \t]*\[", re.M)
_Q_KEY = re.compile(r"^[ \t]*cornea_asphericity[ \t]*=[^\n]*\n?", re.M)


def aspheric_scene(setup: Setup, q: float, scene_text: str | None = None) -> tuple[Setup, str]:
    """The setup with the cornea's conic constant ``q`` and the scene text that says so.

    Parameters
    ----------
    setup : Setup
        As loaded (its ``source`` is read unless ``scene_text`` is given).
    q : float
        Conic constant, -1 < q <= 1.
    scene_text : str, optional

    Returns
    -------
    (Setup, str)
        ``dataclasses.replace`` of the setup's Eye (validated by it; ``source_sha256`` that of
        the new text), and the scene TOML with ``cornea_asphericity = q`` in its ``[eye]``
        table, checked to load to the same setup.

    Raises
    ------
    ValueError
        ``q`` out of range, or a scene text whose ``[eye]`` table cannot be found.
    """
    from ..dataset.manifest import setup_fingerprint

    derived = replace(setup, eye=replace(setup.eye, cornea_asphericity=float(q)))
    text = Path(setup.source).read_text(encoding="utf-8") if scene_text is None else scene_text
    m = _EYE_TABLE.search(text)
    if m is None:
        raise ValueError(f"{setup.source or setup.name}: no [eye] table line to put "
                         "cornea_asphericity in")
    nxt = _NEXT_TABLE.search(text, m.end())
    end = nxt.start() if nxt else len(text)
    body = _Q_KEY.sub("", text[m.end():end])
    out = (text[:m.end()] + f"\ncornea_asphericity = {float(q)!r}  # set by scet study aspheric"
           + body + text[end:])
    # The derived setup names its own text (the manifest's); its source stays the base file.
    derived = replace(derived, source_sha256=hashlib.sha256(out.encode("utf-8")).hexdigest())
    loaded = parse_scene(out, f"{setup.source or setup.name} with cornea_asphericity = {q:g}")
    if setup_fingerprint(loaded) != setup_fingerprint(derived):
        raise ValueError(f"{setup.source or setup.name}: the derived scene text does not load to "
                         "the derived setup")
    return derived, out


def moving_lid_scene(setup: Setup, scene_text: str) -> tuple[Setup, str]:
    """The setup and scene text of :func:`aspheric_scene` with :data:`MOVING_LIDS` appended:
    the setup's ``eyelids`` from the text (its ``source_sha256`` that of the new text),
    checked to load to the same setup. ValueError where the scene has an ``[eyelids]`` table
    already."""
    from ..dataset.manifest import setup_fingerprint

    if setup.eyelids is not None or re.search(r"(?m)^\s*\[eyelids\]", scene_text):
        raise ValueError(f"{setup.source or setup.name}: the scene has its own [eyelids] table; "
                         "the moving-lid condition adds one")
    out = scene_text + ("" if scene_text.endswith("\n") else "\n") + "\n" + MOVING_LIDS
    loaded = parse_scene(out, f"{setup.source or setup.name} with moving lids")
    derived = replace(setup, eyelids=loaded.eyelids,
                      source_sha256=hashlib.sha256(out.encode("utf-8")).hexdigest())
    if setup_fingerprint(loaded) != setup_fingerprint(derived):
        raise ValueError(f"{setup.source or setup.name}: the moving-lid scene text does not load "
                         "to the derived setup")
    return derived, out


# --------------------------------------------------------------------------- feature level only


def feature_level_model_error(setup: Setup, q: float, *, grid=(24, 15),
                              cornea_model: str = "sphere") -> dict:
    """The tracker on noise-free glints of a conic cornea: calibration on the simulator's 5x5
    pattern, both gaze methods on the ``grid`` targets with every visible glint. Nothing but
    the model differs from the truth. ``cornea_model``: the tracker's (``"conic"``: Q
    calibrated with the rest, ``estimator.folders.calibrate_from_glints``).

    Returns
    -------
    dict
        ``cornea_radius_m``, ``calibration_rms_px``, ``eye_center_error_m`` (calibrated c_e
        minus the true one, norm), ``cornea_asphericity`` (the calibration's Q), and per method
        (``"polynomial"``, ``"geometric"``): a
        dict of ``errors_deg`` (k,) and ``rms_px`` (k,) (NaN where the fit failed).
    """
    from estimator.folders import calibrate_from_glints
    from estimator.gaze import calibrated_problems, geometric_gaze, polynomial_gaze
    from estimator.metrics import angular_error_deg

    from ..simulate import parse_targets, simulate_glints

    s = replace(setup, eye=replace(setup.eye, cornea_asphericity=float(q)))
    cal_targets = parse_targets("calib:5x5", s)
    obs = simulate_glints(s, cal_targets, noise_px=0.0)
    g = np.where(obs.visible[..., None], obs.glints_px, np.nan)
    cal = calibrate_from_glints(s, g, cal_targets, cornea_model=cornea_model)
    targets = parse_targets(f"grid:{grid[0]}x{grid[1]}", s)
    obs = simulate_glints(s, targets, noise_px=0.0)
    g = np.where(obs.visible[..., None], obs.glints_px, np.nan)
    problems = calibrated_problems(s, cal)
    mapping = sorted(k for k in cal.mappings if k.startswith("eq1"))[-1]
    out = {"cornea_radius_m": cal.cornea_radius_m,
           "calibration_rms_px": float(cal.quality["rms_px"]),
           "eye_center_error_m": float(np.linalg.norm(cal.eye_center_m - s.eye.rotation_center_m)),
           "cornea_asphericity": cal.cornea_asphericity}
    for method in ("polynomial", "geometric"):
        if method == "polynomial":
            est = polynomial_gaze(s, cal, g, mapping=mapping, problems=problems)
        else:
            est = geometric_gaze(s, cal, g, problems=problems)
        err = angular_error_deg(est.point_m, targets, s.eye.rotation_center_m)
        out[method] = {"errors_deg": err, "rms_px": np.where(np.isfinite(err), est.rms_px, np.nan)}
    return out


# --------------------------------------------------------------------------- rendered


@dataclass(frozen=True, slots=True)
class AsphericCondition:
    """One rendered condition: a conic constant and a lid setting, through ``validate_setup``.

    Attributes
    ----------
    q : float
    lids : str
        The lid condition, one of :data:`LID_CONDITIONS`.
    stats : dict
        (source, method, position) -> :func:`scet_render.validate.error_statistics` tuple
        (position ``"all"`` or one of :data:`~scet_render.validate.POSITIONS`).
    errors : dict
        (source, method) -> (errors_deg, positions): per-sample errors and band positions.
    cornea_radius_m, calibration_rms_px, eye_center_error_m : float
        The calibration's r_c and glint RMS, and its c_e's distance from the true one.
    feature_noise_px : float
        e_f of the simulation (RMS per-axis detection error against the conic labels).
    fit_rms_px : dict
        method -> (k,) RMS glint residuals of the own-glint rendered samples' sphere fits.
    model_rms_px : dict
        method -> (k,) residuals of the same poses' fits to noise-free conic glints of the same
        lights (the model's own part of the residual).
    rejected : dict
        method -> samples refused for a residual over the tracker's limit.
    gaze_targets : int
        Distinct fixation targets of the test sequence.
    all_glints_deg : dict
        method -> (k,) errors of the same calibration on noise-free conic glints of every
        visible light (the 24 x 15 grid): the model error without the band's subset of glints.
    reasons : dict
        method -> {reason: count}.
    timings_s : dict
    cornea_model : str
        The tracker's cornea (``"sphere"``, or ``"conic"``: Q calibrated).
    cornea_asphericity : float
        The calibration's Q (0 for the sphere).
    """

    q: float
    lids: str
    stats: dict
    errors: dict
    cornea_radius_m: float
    calibration_rms_px: float
    eye_center_error_m: float
    feature_noise_px: float
    fit_rms_px: dict
    model_rms_px: dict
    rejected: dict
    reasons: dict
    timings_s: dict
    all_glints_deg: dict
    gaze_targets: int
    cornea_model: str = "sphere"
    cornea_asphericity: float = 0.0


def condition_from_run(run, q: float, lids: str, cornea_model: str = "sphere") -> AsphericCondition:
    """Per band position scores and fit residuals of a :class:`ValidationRun` (one strobe
    setting)."""
    from estimator.gaze import calibrated_problems, geometric_gaze, polynomial_gaze
    from estimator.tracker import RESIDUAL_TOO_LARGE

    from estimator.metrics import angular_error_deg

    from ..simulate import parse_targets, simulate_glints
    from ..validate import true_gaze_points

    (ppf, (sset, _)), = run.settings.items()
    by_key = run.labels[ppf]
    height = sset.camera.height_px
    problems = calibrated_problems(sset, run.calibration)
    stats, errors, fit, model, rejected, reasons, every = {}, {}, {}, {}, {}, {}, {}
    grid = parse_targets("grid:24x15", sset)
    obs_all = simulate_glints(sset, grid, noise_px=0.0)
    g_all = np.where(obs_all.visible[..., None], obs_all.glints_px, np.nan)
    for method in ("polynomial", "geometric"):
        samples = run.tracked[(ppf, method)]
        keyed = [by_key[(s.frame_index, s.strobe_index)] for s in samples]
        pos = np.array([band_position(lb, height) for lb in keyed], dtype=object)
        for source, reps in (("rendered", 1), ("simulated", SIM_REPEATS)):
            err = run.errors[(source, ppf, method)]
            p = np.tile(pos, reps)
            errors[(source, method)] = (err, p)
            stats[(source, method, "all")] = error_statistics(err)
            for where in POSITIONS:
                stats[(source, method, where)] = error_statistics(err[p == where])
        own = [i for i, s in enumerate(samples) if s.ok and not s.prior_assisted]
        fit[method] = np.array([samples[i].residual_px for i in own])
        rejected[method] = sum(s.reason == RESIDUAL_TOO_LARGE for s in samples)
        reasons[method] = dict(run.reasons[(ppf, method)])
        model[method] = np.zeros(0)
        if own:
            truth = true_gaze_points(sset, [keyed[i] for i in own])
            obs = simulate_glints(sset, truth, noise_px=0.0)
            g = np.full(obs.glints_px.shape, np.nan)
            for r, i in enumerate(own):
                g[r, samples[i].light_index] = obs.glints_px[r, samples[i].light_index]
            est = (polynomial_gaze(sset, run.calibration, g, mapping=run.mapping, problems=problems)
                   if method == "polynomial" else
                   geometric_gaze(sset, run.calibration, g, problems=problems))
            model[method] = np.asarray(est.rms_px, dtype=np.float64)
        est = (polynomial_gaze(sset, run.calibration, g_all, mapping=run.mapping, problems=problems)
               if method == "polynomial" else
               geometric_gaze(sset, run.calibration, g_all, problems=problems))
        every[method] = angular_error_deg(est.point_m, grid, sset.eye.rotation_center_m)
    cal = run.calibration
    return AsphericCondition(
        float(q), str(lids), stats, errors, cal.cornea_radius_m, float(cal.quality["rms_px"]),
        float(np.linalg.norm(cal.eye_center_m - sset.eye.rotation_center_m)),
        run.noise_by_ppf[ppf], fit, model, rejected, reasons, dict(run.timings), every,
        len({tuple(np.round(lb.target_m, 6)) for lb in by_key.values()}), cornea_model,
        cal.cornea_asphericity)


def run_aspheric_study(scene=None, *, quick: bool, out_dir, report_dir,
                       asphericities=DEFAULT_ASPHERICITIES, seed: int = 0,
                       progress: Callable[[str, int, int], None] | None = None,
                       config: ValidationConfig | None = None, lids=LID_CONDITIONS,
                       cornea_models=("sphere",)):
    """Render, calibrate, track and score every (Q, lids) condition; the feature-level model
    error of every Q; write ``aspheric.md`` (module docstring).

    Parameters
    ----------
    scene : str or Path, optional
        Scene name or file (default ``paper_sim``); its own Q is replaced.
    quick : bool
        :data:`QUICK` or :data:`FULL`.
    out_dir : Path
        Work folder: one sub-folder of ``scet validate``'s layout per condition.
    report_dir : Path
    asphericities : sequence of float
    seed : int
    progress : callable, optional
        ``progress(stage, done, total)``.
    config : ValidationConfig, optional
        Overrides the mode's (one strobe setting).
    lids : sequence of str
        Lid conditions, of :data:`LID_CONDITIONS`.
    cornea_models : sequence of str
        The trackers run on the same renders: ``"sphere"`` first, then optionally ``"conic"``
        (:func:`scet_render.validate.validate_setup`'s ``cornea_model``).

    Returns
    -------
    (list of AsphericCondition, dict q -> feature-level dict, Path of the report)
        The feature-level dict of ``"conic"`` is under the key ``(q, "conic")``.
    """
    from ..validate import validate_setup
    from .aspheric_report import write_aspheric_report

    cfg = config or (QUICK if quick else FULL)
    if len(cfg.pulses_per_frame) != 1:
        raise ValueError("the aspheric study runs one strobe setting (pulses_per_frame of one "
                         "value)")
    models = tuple(cornea_models)
    if not models or models[0] != "sphere" or len(set(models)) != len(models) or \
            not set(models) <= {"sphere", "conic"}:
        raise ValueError(f"cornea_models must be ('sphere',) or ('sphere', 'conic'), got {models}")
    lids = tuple(lids)
    if not lids or not set(lids) <= set(LID_CONDITIONS) or len(set(lids)) != len(lids):
        raise ValueError(f"lids must be distinct conditions of {LID_CONDITIONS}, got {lids}")
    qs = tuple(float(q) for q in asphericities)
    if not qs:
        raise ValueError("asphericities: at least one conic constant is needed")
    base = load_scene(scene)
    t0 = time.perf_counter()
    conditions, features = [], {}
    for q in qs:
        derived, text = aspheric_scene(base, q)
        t = time.perf_counter()
        features[q] = feature_level_model_error(derived, q)
        for model in models[1:]:
            features[(q, model)] = feature_level_model_error(derived, q, cornea_model=model)
        if progress is not None:
            progress(f"Q={q:g} feature level", 1, 1)
        sim_s = time.perf_counter() - t
        for lid in lids:
            name = f"q{q:+.3f}_" + _LID_FOLDERS[lid]
            stage = ((lambda tag: (lambda s, d, n: progress(f"{tag} {s}", d, n)))(name)
                     if progress is not None else None)
            setup_l, text_l = derived, text
            if lid == "moving":
                setup_l, text_l = moving_lid_scene(derived, text)
            for model in models:
                run = validate_setup(scaled_setup(setup_l, cfg.scale), cfg, Path(out_dir) / name,
                                     seed=seed, progress=stage, eyelid_openness=_LID_OPENNESS[lid],
                                     scene_text=text_l, cornea_model=model)
                c = condition_from_run(run, q, lid, model)
                c.timings_s["feature_level"] = sim_s
                conditions.append(c)
    wall_s = time.perf_counter() - t0
    path = write_aspheric_report(Path(report_dir), conditions, features, cfg, base, wall_s, seed)
    return conditions, features, path
