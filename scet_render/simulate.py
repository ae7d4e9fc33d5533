"""Feature-level simulator: gaze targets -> eye rotation -> cornea centre -> glints (+ noise).

This is the framework of Böhme et al. (2008) that the SCET paper's Sec. 3 runs on: the only
image features are the glints, computed in closed form (:func:`estimator.geometry.project_glints`;
on an aspheric cornea, ``cornea_asphericity`` != 0, the exact conic reflection of
:func:`estimator.geometry.project_glints_conic`, both through :meth:`estimator.eye.Eye.glints`)
and perturbed by the feature position error e_f, uniform in [-e_f, e_f] pixels on each axis
(or, as an option, Gaussian with standard deviation e_f). Vectorised over targets and lights.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from estimator.errors import InputError
from estimator.formats import GLINTS_FORMAT, GLINTS_VERSION, atomic_file
from estimator.geometry.wire import eye_wire_glints, setup_wire_mirrors
from estimator.setup import Setup

SIM_FORMAT, SIM_VERSION = GLINTS_FORMAT, GLINTS_VERSION
NOISE_MODELS = ("uniform", "gaussian")


@dataclass(frozen=True, slots=True)
class GlintObservations:
    """Glints of every light for a batch of gaze targets.

    Attributes
    ----------
    targets_m : (m, 3) float
        Gaze targets on the screen.
    yaw_rad, pitch_rad : (m,) float
        Eye rotation (Fick angles) that points the optical axis at each target.
    cornea_center_m : (m, 3) float
        Cornea centre for each target.
    glints_true_px : (m, n, 2) float
        Noise-free glint positions (NaN where the reflection is behind the camera).
    glints_px : (m, n, 2) float
        Glint positions with the feature position error added.
    visible : (m, n) bool
        Glint on the corneal cap, lit and seen, and inside the image (of the noise-free glint).
    noise_px : float
        e_f in pixels.
    noise_model : str
        ``"uniform"`` or ``"gaussian"``.
    seed : int or None
    """

    targets_m: np.ndarray
    yaw_rad: np.ndarray
    pitch_rad: np.ndarray
    cornea_center_m: np.ndarray
    glints_true_px: np.ndarray
    glints_px: np.ndarray
    visible: np.ndarray
    noise_px: float
    noise_model: str
    seed: int | None

    @property
    def count(self) -> int:
        return self.targets_m.shape[0]


def ground_truth_glints(setup: Setup, yaw_rad, pitch_rad, *, lights_world_m=None,
                        cornea_radius_m: float | None = None):
    """Noise-free glints for eye rotations (Fick angles, any batch shape).

    The turns of a ``wire_mirror`` light group are the LED seen in each wire turn
    (:func:`estimator.geometry.wire.eye_wire_glints`, two bounces) unless ``lights_world_m``
    overrides the lights (then every light is a point).

    Returns ``(glints_px (..., n, 2), visible (..., n), cornea_center_m (..., 3))``.
    """
    lights = setup.lights_world_m if lights_world_m is None else lights_world_m
    glints, visible, center = setup.eye.glints(setup.camera, lights, yaw_rad, pitch_rad,
                                               cornea_radius_m=cornea_radius_m)
    wires = setup_wire_mirrors(setup) if lights_world_m is None else []
    if wires:
        glints, visible = np.array(glints), np.array(visible)
        eye = setup.eye
        if cornea_radius_m is not None:
            eye = replace(eye, cornea_radius_m=float(cornea_radius_m))
        for _, first, mirror in wires:
            w = eye_wire_glints(eye, setup.camera, mirror, yaw_rad, pitch_rad)
            glints[..., first:first + mirror.turns, :] = w.glints_px
            visible[..., first:first + mirror.turns] = w.visible
    return glints, visible, center


def feature_noise(shape, noise_px: float, model: str, rng: np.random.Generator) -> np.ndarray:
    """Böhme et al.'s feature position error: uniform in [-e_f, e_f] or Gaussian with SD e_f."""
    if not np.isfinite(noise_px) or noise_px < 0:
        raise ValueError(f"noise_px (e_f) must be finite and >= 0, got {noise_px}")
    if model == "uniform":
        return rng.uniform(-noise_px, noise_px, size=shape)
    if model == "gaussian":
        return rng.normal(0.0, noise_px, size=shape)
    raise ValueError(f"noise model must be one of {NOISE_MODELS}, got {model!r}")


def simulate_glints(setup: Setup, targets_m, *, noise_px: float = 0.0, noise_model: str = "uniform",
                    rng: np.random.Generator | int | None = None, lights_world_m=None,
                    cornea_radius_m: float | None = None) -> GlintObservations:
    """Glints of every light for every gaze target, with Böhme's feature position error.

    Parameters
    ----------
    setup : Setup
    targets_m : (m, 3) float
        World points the eye fixates (usually on the screen).
    noise_px : float
        e_f in pixels.
    noise_model : {"uniform", "gaussian"}
    rng : numpy.random.Generator or int, optional
        Source of the noise; an int is a seed. Needed when ``noise_px > 0``.
    lights_world_m : (n, 3) float, optional
        Override the setup's lights (e.g. a perturbed rig).
    cornea_radius_m : float, optional
        Override the setup's corneal radius.
    """
    targets = np.asarray(targets_m, dtype=np.float64)
    if targets.ndim != 2 or targets.shape[1] != 3:
        raise ValueError(f"targets_m must have shape (m, 3), got {targets.shape}")
    if not np.all(np.isfinite(targets)):
        raise ValueError("targets_m must be finite")
    if not np.isfinite(noise_px) or noise_px < 0:
        raise ValueError(f"noise_px (e_f) must be finite and >= 0, got {noise_px}")
    seed = rng if isinstance(rng, (int, np.integer)) else None
    if noise_px > 0 and rng is None:
        raise ValueError("noise_px > 0 needs an rng or a seed (results must be reproducible)")
    gen = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    yaw, pitch = setup.eye.angles_toward(targets)
    glints, visible, center = ground_truth_glints(setup, yaw, pitch, lights_world_m=lights_world_m,
                                                  cornea_radius_m=cornea_radius_m)
    noisy = glints + feature_noise(glints.shape, noise_px, noise_model, gen) if noise_px > 0 else glints.copy()
    return GlintObservations(targets, yaw, pitch, center, glints, noisy, visible, float(noise_px),
                             noise_model, None if seed is None else int(seed))


_GRID = re.compile(r"^grid:(\d{1,9})x(\d{1,9})$")


def parse_targets(spec: str, setup: Setup) -> np.ndarray:
    """Targets from a spec: ``grid:COLSxROWS`` (cell centres, the paper's 24x15 accuracy grid),
    ``calib:COLSxROWS`` (edge to edge, e.g. the 3x3 and 5x5 calibration patterns), ``centre``,
    or the path of a CSV file with x_m, y_m, z_m columns (a header line is allowed)."""
    m = _GRID.match(spec)
    if m:
        return setup.screen.grid(*_grid_size(spec, m))
    if spec.startswith("calib:"):
        m = _GRID.match("grid:" + spec[len("calib:"):])
        if not m:
            raise InputError(f"bad target spec {spec!r}: expected calib:COLSxROWS, e.g. calib:5x5")
        return setup.screen.grid(*_grid_size(spec, m), margin=0.0)
    if spec in ("centre", "center"):
        return setup.screen.grid(1, 1)
    path = Path(spec)
    if path.suffix == ".csv" and path.exists():
        try:
            data = np.loadtxt(path, delimiter=",", ndmin=2, comments="#",
                              skiprows=1 if not _is_number(path.read_text().split(",")[0]) else 0)
        except ValueError as exc:  # UnicodeDecodeError too
            raise InputError(f"{path}: cannot read targets ({exc})") from None
        if data.shape[1] != 3 or not np.all(np.isfinite(data)):
            raise ValueError(f"{path}: expected finite x_m, y_m, z_m columns, got shape {data.shape}")
        return data
    raise ValueError(f"bad target spec {spec!r}: expected grid:COLSxROWS, calib:COLSxROWS, centre "
                     "or an existing .csv file")


#: Most targets a grid spec may ask for: 100,000 targets of 40 lights are 64 MB of glints; the
#: paper's accuracy grid has 360.
MAX_TARGETS = 100_000


def _grid_size(spec: str, m) -> tuple[int, int]:
    """(cols, rows) of a matched grid spec, refused when empty or absurdly large (a grid that
    would need gigabytes is refused before anything is allocated)."""
    cols, rows = int(m.group(1)), int(m.group(2))
    if cols < 1 or rows < 1 or cols * rows > MAX_TARGETS:
        raise InputError(f"bad target spec {spec!r}: expected 1 to {MAX_TARGETS} targets "
                         f"(COLSxROWS, each at least 1), got {cols}x{rows} = {cols * rows}")
    return cols, rows


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def glint_statistics(obs: GlintObservations) -> dict:
    """Summary numbers of a simulation: visible glints per target and their spread."""
    counts = obs.visible.sum(axis=1)
    g = np.where(obs.visible[..., None], obs.glints_true_px, np.nan)
    has = counts > 0
    spread = np.full((obs.count, 2), np.nan)
    if np.any(has):
        spread[has] = np.nanmax(g[has], axis=1) - np.nanmin(g[has], axis=1)
    return {
        "targets": int(obs.count),
        "lights": int(obs.visible.shape[1]),
        "visible_min": int(counts.min()) if counts.size else 0,
        "visible_mean": float(counts.mean()) if counts.size else 0.0,
        "visible_max": int(counts.max()) if counts.size else 0,
        "targets_without_glints": int((counts == 0).sum()),
        "spread_u_px_mean": float(np.nanmean(spread[:, 0])) if np.any(has) else float("nan"),
        "spread_v_px_mean": float(np.nanmean(spread[:, 1])) if np.any(has) else float("nan"),
    }


def save_observations(path: str | Path, obs: GlintObservations, setup: Setup) -> Path:
    """Write a simulation to ``.npz`` (arrays, no pickles) or ``.csv`` (one row per target and
    light), atomically. The formats are described in docs/formats/glints.md ("Simulation files")."""
    path = Path(path)
    meta = {
        "format": SIM_FORMAT, "version": SIM_VERSION, "scene": setup.name,
        "scene_sha256": setup.source_sha256, "noise_px": obs.noise_px,
        "noise_model": obs.noise_model, "seed": obs.seed, "units": {
            "targets_m": "m", "cornea_center_m": "m", "angles": "rad", "glints": "px (pixel centres)"},
    }
    if path.suffix not in (".npz", ".csv"):
        raise ValueError(f"{path}: output must end in .npz or .csv")
    with atomic_file(path) as tmp:
        _write_observations(tmp, path.suffix, meta, obs, setup)
    return path


def _write_observations(tmp: Path, suffix: str, meta: dict, obs: GlintObservations,
                        setup: Setup) -> None:
    if suffix == ".npz":
        with open(tmp, "wb") as f:
            np.savez_compressed(
                f, meta_json=np.array(json.dumps(meta)), targets_m=obs.targets_m,
                yaw_rad=obs.yaw_rad, pitch_rad=obs.pitch_rad, cornea_center_m=obs.cornea_center_m,
                glints_true_px=obs.glints_true_px, glints_px=obs.glints_px, visible=obs.visible,
                lights_world_m=setup.lights_world_m)
    else:
        m, n = obs.visible.shape
        ti, li = np.meshgrid(np.arange(m), np.arange(n), indexing="ij")
        cols = np.column_stack([
            ti.ravel(), li.ravel(), np.repeat(obs.targets_m, n, axis=0),
            np.repeat(obs.yaw_rad, n), np.repeat(obs.pitch_rad, n),
            obs.glints_px.reshape(-1, 2), obs.glints_true_px.reshape(-1, 2), obs.visible.ravel()])
        header = ("# " + json.dumps(meta) + "\n"
                  "target,light,target_x_m,target_y_m,target_z_m,yaw_rad,pitch_rad,"
                  "u_px,v_px,u_true_px,v_true_px,visible")
        np.savetxt(tmp, cols, delimiter=",", header=header, comments="",
                   fmt=["%d", "%d"] + ["%.9g"] * 3 + ["%.12g"] * 2 + ["%.6f"] * 4 + ["%d"])


def load_observations(path: str | Path) -> tuple[GlintObservations, dict]:
    """Read a ``.npz`` simulation written by :func:`save_observations`; checks format and version."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta_json"]))
            arrays = {k: z[k] for k in z.files if k != "meta_json"}
    except (OSError, KeyError, ValueError) as exc:
        raise ValueError(f"{path}: not a SCET simulation file ({exc})") from None
    if meta.get("format") != SIM_FORMAT or meta.get("version") != SIM_VERSION:
        raise ValueError(f"{path}: expected format {SIM_FORMAT} version {SIM_VERSION}, "
                         f"got {meta.get('format')} version {meta.get('version')}")
    obs = GlintObservations(arrays["targets_m"], arrays["yaw_rad"], arrays["pitch_rad"],
                            arrays["cornea_center_m"], arrays["glints_true_px"], arrays["glints_px"],
                            arrays["visible"], meta["noise_px"], meta["noise_model"], meta["seed"])
    return obs, meta
