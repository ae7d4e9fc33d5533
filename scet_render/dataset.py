"""Rendered datasets on disk: banded frames, sensor output and per-strobe ground truth.

Layout of a dataset folder (format ``scet-dataset``, version 1)::

    manifest.json        what was rendered and how (see below); written first
    frames/000000.exr    linear radiance, float32, one channel "Y" (pulse-weighted, as rendered)
    frames/000000.png    sensor output (raw DN, black level included): 16-bit PNG for bit
                         depths above 8, 8-bit PNG otherwise
    ...
    labels.jsonl         one JSON object per strobe sample; written last

``manifest.json`` holds the format name and version, the scene (name, file name, sha256 and the
full TOML text), a fingerprint of the exact :class:`~estimator.setup.Setup` rendered (it catches
setups changed in code, e.g. a scaled-down camera), software versions, the seed, the render
settings (spp, Mitsuba variant, cornea model), the trajectory kind, the frame count, the image
size and every :class:`~scet_render.sensor.SensorModel` parameter, and the renderer's own
settings (resolved variant, seed, ambient spp, scene options). It has no time stamps: two runs
with the same arguments on the same software write byte-identical datasets.

Each EXR header carries ``scet_format``, ``scet_version``, ``scet_frame`` (int),
``scet_scene_sha256`` (string), ``scet_pulse_indices`` (a JSON array in a string: the global
indices of the pulses rendered into the frame, those that light visible rows) and
``scet_strobe_times_s`` (a JSON array in a string: their instants, the pulse centres at which
the eye pose was taken; exact float64 values). :func:`read_exr` reads all of it back.

Each line of ``labels.jsonl`` is one strobe that lights visible rows of one frame, in frame then
pulse order::

    frame, strobe          frame index and global pulse index j
    time_s                 strobe instant (the instant the eye pose is taken at), s
    pulse_start_s          s_j, the pulse's rising edge, s
    first_row, last_row    first and last visible rows the pulse lights at all (inclusive)
    full_rows              [start, stop): visible rows that collect the whole pulse (may be empty)
    target_m               gaze target (x, y, z), m
    yaw_rad, pitch_rad     eye rotation (Fick angles), rad
    cornea_center_m        cornea centre (x, y, z), m
    glints_px              per light, the ground-truth glint pixel [u, v] (OpenCV pixel-centre
                           convention), or null where the reflection does not exist
    glints_visible         per light, whether the glint is on the corneal cap and seen

Labels are computed from the setup, the trajectory and the banding model
(:func:`estimator.banding.band_layout`, :func:`scet_render.simulate.ground_truth_glints`), so
they need no rendering and are rebuilt whole at the end of every run.

Writing is crash-safe and resumable. Every file is written to ``<name>.partial`` in its own
folder and moved into place with :func:`os.replace`; a frame counts as done when both its EXR
and PNG exist. All randomness of frame f derives from ``SeedSequence([seed, stream, f])``, so a
run that is killed at any point and started again with the same arguments renders only the
missing frames and ends with a dataset byte-identical to an uninterrupted run. A run pointed at
a folder that holds a different dataset (other scene, seed, frame count, ...) refuses with a
:class:`DatasetMismatchError` that names every differing entry; it never overwrites.
"""

from __future__ import annotations

import hashlib
import json
import math
import numbers
import os
from dataclasses import dataclass, fields, is_dataclass
from enum import Enum
from importlib import metadata
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from estimator.banding import band_layout
from estimator.folders import check_format
from estimator.setup import Setup
from scet_render.motion import FixationalNoise, Trajectory, fixation_sequence, saccade_sequence
from scet_render.sensor import SensorModel
from scet_render.simulate import ground_truth_glints

FORMAT = "scet-dataset"
VERSION = 1
TRAJECTORY_KINDS = ("fixations", "saccades", "grid")
MANIFEST_NAME = "manifest.json"
LABELS_NAME = "labels.jsonl"
FRAMES_DIR = "frames"
PARTIAL_SUFFIX = ".partial"

#: The paper's accuracy grid (Sec. 3.2): 24 x 15 cell centres on the screen.
GRID_COLS, GRID_ROWS = 24, 15
#: Fixation length of the "fixations" and "grid" trajectories, s: long enough for a gaze
#: estimate per target, short enough that a 64-frame dataset (1.06 s) visits several targets.
FIXATION_S = 0.25
#: Fixation lengths of the "saccades" trajectory, s (uniform; typical reading/search values).
SACCADE_FIXATION_RANGE_S = (0.1, 0.3)
#: PNG zlib level: fixed, so that the bytes do not depend on OpenCV's default.
PNG_COMPRESSION = 3

# Independent random streams derived from the dataset seed.
_STREAM_TRAJECTORY = 0
_STREAM_RENDER = 1
_STREAM_SENSOR = 2


class DatasetError(ValueError):
    """A dataset folder or file is missing, malformed or of another format or version."""


class DatasetMismatchError(DatasetError):
    """A run was pointed at a folder holding a dataset made with other arguments."""


@dataclass(frozen=True, slots=True)
class RenderSummary:
    """What one :func:`render_dataset` call did.

    Attributes
    ----------
    path : Path
        The dataset folder.
    frames_rendered : tuple of int
        Frames rendered by this call.
    frames_skipped : tuple of int
        Frames already complete on disk (a resumed run).
    """

    path: Path
    frames_rendered: tuple[int, ...]
    frames_skipped: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class StrobeLabel:
    """One line of ``labels.jsonl`` (see the module docstring for the meaning of each field).

    Attributes
    ----------
    frame, strobe : int
    time_s, pulse_start_s : float
    first_row, last_row : int
    full_rows : (int, int)
        Half-open row range.
    target_m, cornea_center_m : (3,) float
    yaw_rad, pitch_rad : float
    glints_px : (n, 2) float
        NaN where the file holds null.
    glints_visible : (n,) bool
    """

    frame: int
    strobe: int
    time_s: float
    pulse_start_s: float
    first_row: int
    last_row: int
    full_rows: tuple[int, int]
    target_m: np.ndarray
    yaw_rad: float
    pitch_rad: float
    cornea_center_m: np.ndarray
    glints_px: np.ndarray
    glints_visible: np.ndarray


# --------------------------------------------------------------------------- trajectories


def dataset_trajectory(setup: Setup, kind: str, frames: int, seed: int) -> Trajectory:
    """The eye motion of a dataset: seeded, on the setup's screen, covering every frame.

    Parameters
    ----------
    setup : Setup
    kind : {"fixations", "saccades", "grid"}
        ``"fixations"``: the 24 x 15 grid cells in a seeded random order, :data:`FIXATION_S`
        each; ``"saccades"``: uniformly random screen points held for random times in
        :data:`SACCADE_FIXATION_RANGE_S`; ``"grid"``: the 24 x 15 cells row by row from the top
        left (repeated if needed), :data:`FIXATION_S` each. Main-sequence saccades join the
        fixations; every fixation carries seeded fixational drift and tremor.
    frames : int
        Frames to cover: the trajectory lasts at least (frames + 1) Δt.
    seed : int

    Returns
    -------
    Trajectory
    """
    kind = _check_kind(kind)
    frames = _check_int("frames", frames, 1)
    seed = _check_int("seed", seed, 0)
    gen = np.random.default_rng(np.random.SeedSequence([seed, _STREAM_TRAJECTORY]))
    needed_s = (frames + 1) * setup.sensor.frame_period_s
    eye, screen, noise = setup.eye, setup.screen, FixationalNoise()
    grid = screen.grid(GRID_COLS, GRID_ROWS)
    if kind == "saccades":
        n = math.ceil(needed_s / SACCADE_FIXATION_RANGE_S[0]) + 1
        (x0, x1), (y0, y1) = screen.x_range_m, screen.y_range_m
        targets = np.stack([gen.uniform(x0, x1, n), gen.uniform(y0, y1, n),
                            np.full(n, screen.z_m)], axis=-1)
        return saccade_sequence(eye, targets, gen, SACCADE_FIXATION_RANGE_S, noise=noise)
    n = math.ceil(needed_s / FIXATION_S) + 1
    if kind == "fixations":
        order = np.concatenate([gen.permutation(len(grid)) for _ in range(-(-n // len(grid)))])
    else:
        order = np.arange(n) % len(grid)
    return fixation_sequence(eye, grid[order[:n]], FIXATION_S, gen, noise=noise)


# --------------------------------------------------------------------------- labels


def frame_labels(setup: Setup, trajectory: Trajectory, frame: int) -> list[dict]:
    """Ground truth of every strobe that lights visible rows of ``frame``.

    Parameters
    ----------
    setup : Setup
    trajectory : Trajectory
    frame : int

    Returns
    -------
    list of dict
        One JSON-ready dict per strobe (keys as in the module docstring), by pulse index.
    """
    sensor, strobe = setup.sensor, setup.strobe
    N = sensor.visible_lines
    bands = [b for b in band_layout(sensor, strobe, frame) if b.visible]
    if not bands:
        return []
    start_s = np.array([b.strobe_time_s for b in bands])
    time_s = strobe_instant(start_s, strobe.pulse_s)
    yaw, pitch = trajectory.angles_at(time_s)
    target = trajectory.target_at(time_s)
    glints, visible, center = ground_truth_glints(setup, yaw, pitch)
    out = []
    for i, b in enumerate(bands):
        full_start, full_stop = min(b.full_rows[0], N), min(b.full_rows[1], N)
        out.append({
            "frame": int(frame),
            "strobe": int(b.pulse_index),
            "time_s": float(time_s[i]),
            "pulse_start_s": float(start_s[i]),
            "first_row": int(b.first_row),
            "last_row": int(min(b.last_row, N - 1)),
            "full_rows": [int(full_start), int(max(full_start, full_stop))],
            "target_m": _floats(target[i]),
            "yaw_rad": float(yaw[i]),
            "pitch_rad": float(pitch[i]),
            "cornea_center_m": _floats(center[i]),
            "glints_px": [_floats(g) if np.all(np.isfinite(g)) else None for g in glints[i]],
            "glints_visible": [bool(v) for v in visible[i]],
        })
    return out


def strobe_instant(pulse_start_s, pulse_s: float) -> np.ndarray:
    """(...) instant a pulse stands for: its centre s_j + Δs / 2 (the time stamp that
    :func:`estimator.banding.row_strobe` gives its rows)."""
    return np.asarray(pulse_start_s, dtype=np.float64) + 0.5 * float(pulse_s)


# --------------------------------------------------------------------------- writing


def render_dataset(
    setup: Setup,
    out_dir,
    *,
    frames: int,
    spp: int = 16,
    trajectory: str = "fixations",
    seed: int = 0,
    variant: str | None = None,
    cornea: str = "dielectric",
    sensor: SensorModel | None = None,
    scene_text: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> RenderSummary:
    """Render a banded-frame dataset (or finish an interrupted one) into ``out_dir``.

    Parameters
    ----------
    setup : Setup
        The system to render; it also fixes the image size and the strobe timing.
    out_dir : str or Path
        Dataset folder: new, empty, or holding an unfinished or finished run of the very same
        arguments (which is then completed; a finished one is left as it is).
    frames : int
        Number of frames, >= 1.
    spp : int
        Samples per pixel of the renderer.
    trajectory : {"fixations", "saccades", "grid"}
        Eye motion, see :func:`dataset_trajectory`.
    seed : int
        Seeds the trajectory, the renderer and the sensor noise (>= 0).
    variant : str, optional
        Mitsuba variant; None lets the renderer choose (the choice is recorded).
    cornea : str
        Cornea material of the renderer (``"dielectric"``, or what the renderer supports).
    sensor : SensorModel, optional
        Default: :meth:`SensorModel.from_sensor` of ``setup.sensor``.
    scene_text : str, optional
        The scene TOML; default: read from ``setup.source`` (its sha256 must match
        ``setup.source_sha256``).
    progress : callable, optional
        Called as ``progress(done, total)`` once at the start and after every frame (the CLI
        shows a progress bar with it; this function never prints).

    Returns
    -------
    RenderSummary

    Notes
    -----
    "The same arguments" means the same manifest: scene text, setup fingerprint, frames, spp,
    trajectory, seed, cornea, sensor parameters, the Mitsuba variant (as resolved) and the
    renderer's settings, and the same versions of scet, numpy, Mitsuba, Dr.Jit, OpenEXR and
    OpenCV (any of which can change the bytes). ``progress`` is not part of it. A run against a
    finished dataset checks the manifest, rewrites nothing but an identical ``labels.jsonl``
    and does not start the renderer.

    Raises
    ------
    DatasetMismatchError
        ``out_dir`` holds a dataset made with other arguments, or other software.
    DatasetError
        ``out_dir`` holds something that is not a SCET dataset.
    ValueError
        Bad arguments.
    """
    frames = _check_int("frames", frames, 1)
    spp = _check_int("spp", spp, 1)
    seed = _check_int("seed", seed, 0)
    kind = _check_kind(trajectory)
    if not isinstance(cornea, str):
        raise ValueError(f"cornea must be a string, got {cornea!r}")
    if variant is not None and not isinstance(variant, str):
        raise ValueError(f"variant must be a string or None, got {variant!r}")
    sensor = SensorModel.from_sensor(setup.sensor) if sensor is None else sensor
    if not isinstance(sensor, SensorModel):
        raise ValueError(f"sensor must be a SensorModel, got {type(sensor).__name__}")
    text = _scene_text(setup, scene_text)
    out = Path(out_dir)

    manifest = _manifest(setup, text, frames=frames, spp=spp, kind=kind, seed=seed,
                         variant=variant, cornea=cornea, sensor=sensor)
    existing = _prepare_folder(out)
    if existing is not None:
        # The variant that None resolves to is known only once the renderer exists.
        _compare_manifests(existing, manifest, out / MANIFEST_NAME, before_renderer=True,
                           ignore_variant=variant is None)
    frames_dir = out / FRAMES_DIR
    done = [f for f in range(frames) if _frame_done(frames_dir, f)]
    todo = [f for f in range(frames) if f not in set(done)]
    traj = dataset_trajectory(setup, kind, frames, seed)

    if todo or existing is None:
        renderer = _make_renderer(setup, spp=spp, variant=variant, cornea=cornea, seed=seed)
        manifest["render"]["variant"] = renderer.variant
        manifest["render"]["renderer"] = _renderer_settings(renderer)
        if existing is None:
            out.mkdir(parents=True, exist_ok=True)
            _write_bytes(out / MANIFEST_NAME, _manifest_bytes(manifest))
        else:
            _compare_manifests(existing, manifest, out / MANIFEST_NAME)
    frames_dir.mkdir(exist_ok=True)

    if progress is not None:
        progress(len(done), frames)
    for f in todo:
        _render_frame(renderer, setup, sensor, traj, f, seed, frames_dir,
                      manifest["scene"]["sha256"])
        done.append(f)
        if progress is not None:
            progress(len(done), frames)

    lines = [json.dumps(label, allow_nan=False, separators=(",", ":"))
             for f in range(frames) for label in frame_labels(setup, traj, f)]
    _write_bytes(out / LABELS_NAME, "".join(line + "\n" for line in lines).encode("utf-8"))
    return RenderSummary(out, tuple(todo), tuple(f for f in range(frames) if f not in set(todo)))


def _render_frame(renderer, setup: Setup, sensor: SensorModel, traj: Trajectory, frame: int,
                  seed: int, frames_dir: Path, scene_sha256: str) -> None:
    import cv2

    result = renderer.render_frame(traj, frame)
    radiance = np.ascontiguousarray(result.radiance, dtype=np.float32)
    shape = (setup.camera.height_px, setup.camera.width_px)
    if radiance.shape != shape:
        raise RuntimeError(f"renderer returned frame {frame} with shape {radiance.shape}, "
                           f"expected {shape} (height, width)")
    pulses = np.asarray(result.pulse_indices, dtype=np.int64)
    times = np.asarray(result.pulse_times_s, dtype=np.float64)
    bands = [b for b in band_layout(setup.sensor, setup.strobe, frame) if b.visible]
    want_times = strobe_instant([b.strobe_time_s for b in bands], setup.strobe.pulse_s)
    if (pulses.tolist() != [b.pulse_index for b in bands]
            or not np.allclose(times, want_times, rtol=0.0, atol=1e-12)):
        # The labels are computed from the banding model; they must describe what was rendered.
        raise RuntimeError(f"frame {frame}: the renderer lit pulses {pulses.tolist()} at "
                           f"{times.tolist()} s, the labels expect {[b.pulse_index for b in bands]}"
                           f" at {want_times.tolist()} s")
    dn = sensor.apply(radiance, np.random.SeedSequence([seed, _STREAM_SENSOR, frame]))
    header = {
        "compression": _exr().ZIP_COMPRESSION,
        "type": _exr().scanlineimage,
        "scet_format": FORMAT,
        "scet_version": VERSION,
        "scet_frame": int(frame),
        "scet_scene_sha256": scene_sha256,
        # OpenEXR has no attribute type for vectors of ints or doubles of any length (its
        # Python binding maps 2- and 3-element arrays to V2/V3 types, longer ones only for
        # float32), so both vectors are JSON text: exact and easy to read back.
        "scet_pulse_indices": json.dumps(pulses.tolist()),
        "scet_strobe_times_s": json.dumps(times.tolist()),
    }
    exr_path = frames_dir / f"{frame:06d}.exr"
    tmp = exr_path.with_name(exr_path.name + PARTIAL_SUFFIX)
    with _exr().File(header, {"Y": radiance}) as exr:
        exr.write(str(tmp))
    _commit(tmp, exr_path)
    word = np.uint8 if sensor.bit_depth <= 8 else np.uint16
    ok, png = cv2.imencode(".png", dn.astype(word), [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
    if not ok:
        raise RuntimeError(f"OpenCV could not encode frame {frame} as PNG")
    _write_bytes(frames_dir / f"{frame:06d}.png", png.tobytes())


def _make_renderer(setup: Setup, *, spp: int, variant, cornea: str, seed: int):
    from scet_render.rolling_shutter import BandedRenderer

    # The renderer derives every slice's sampler seed from (its seed, frame index, slice), so
    # frame f renders the same whatever was rendered before it: resumed runs stay identical.
    render_seed = int(np.random.SeedSequence([seed, _STREAM_RENDER]).generate_state(1)[0])
    return BandedRenderer(setup, variant=variant, spp=spp, cornea=cornea, seed=render_seed)


def _renderer_settings(renderer) -> dict:
    """Everything the renderer chose or defaulted that shapes its output."""
    options = renderer.options
    return {
        "seed": renderer.seed,
        "ambient_spp": renderer.ambient_spp,
        "blur_step_px": renderer.blur_step_px,
        "max_ambient_instants": renderer.max_ambient_instants,
        "scene_options": {name: getattr(options, name) for name in options.__slots__},
    }


# --------------------------------------------------------------------------- manifest


def _manifest(setup: Setup, text: str, *, frames, spp, kind, seed, variant, cornea,
              sensor: SensorModel) -> dict:
    return {
        "format": FORMAT,
        "version": VERSION,
        "scene": {
            "name": setup.name,
            "file": Path(setup.source).name if setup.source else "",
            "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest(),
            "toml": text,
        },
        "setup_sha256": setup_fingerprint(setup),
        "software": software_versions(),
        "seed": seed,
        "trajectory": kind,
        "frames": frames,
        "image": {"width_px": setup.camera.width_px, "height_px": setup.camera.height_px,
                  "png_bit_depth": 8 if sensor.bit_depth <= 8 else 16},
        "render": {"spp": spp, "variant": variant, "cornea": cornea, "renderer": None},
        "sensor": sensor.to_dict(),
        "files": {"radiance": f"{FRAMES_DIR}/{{frame:06d}}.exr",
                  "sensor": f"{FRAMES_DIR}/{{frame:06d}}.png", "labels": LABELS_NAME},
    }


def _manifest_bytes(manifest: dict) -> bytes:
    return (json.dumps(manifest, indent=2, allow_nan=False) + "\n").encode("utf-8")


def software_versions() -> dict:
    """Versions of the packages whose behaviour shapes a dataset's bytes ("absent" if missing)."""
    import cv2

    def version(dist):
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return "absent"

    return {"scet": version("scet"), "numpy": np.__version__, "mitsuba": version("mitsuba"),
            "drjit": version("drjit"), "openexr": version("OpenEXR"), "opencv": cv2.__version__}


def setup_fingerprint(setup: Setup) -> str:
    """sha256 of every field of a Setup (arrays and floats exactly), except its source path."""

    def plain(x):
        if is_dataclass(x):
            return {f.name: plain(getattr(x, f.name)) for f in fields(x) if f.name != "source"}
        if isinstance(x, np.ndarray):
            return {"shape": list(x.shape), "data": [float(v).hex() for v in x.ravel()]}
        if isinstance(x, (tuple, list)):
            return [plain(v) for v in x]
        if isinstance(x, Enum):
            return x.name
        if isinstance(x, (bool, str, type(None))):
            return x
        if isinstance(x, numbers.Integral):
            return int(x)
        if isinstance(x, numbers.Real):
            return float(x).hex()
        raise TypeError(f"cannot fingerprint a {type(x).__name__} in the setup")

    text = json.dumps(plain(setup), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _scene_text(setup: Setup, scene_text: str | None) -> str:
    if scene_text is not None:
        if not isinstance(scene_text, str):
            raise ValueError("scene_text must be the scene's TOML text (a str)")
        return scene_text
    path = Path(setup.source)
    try:
        text = path.read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read the scene file {setup.source!r} named by the setup ({exc}); "
                         "pass scene_text=") from None
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    if setup.source_sha256 and digest != setup.source_sha256:
        raise ValueError(f"{path}: the file changed since the setup was loaded (sha256 differs "
                         "from setup.source_sha256); reload it or pass scene_text=")
    return text


def _compare_manifests(found: dict, expected: dict, path: Path, *, before_renderer: bool = False,
                       ignore_variant: bool = False) -> None:
    """Raise DatasetMismatchError naming every entry where ``found`` differs from ``expected``.

    ``before_renderer`` skips what only the renderer knows (its settings; with
    ``ignore_variant``, also the variant that None resolves to).
    """
    want = json.loads(_manifest_bytes(expected))
    skip = set()
    if before_renderer:
        skip.add("render.renderer")
        if ignore_variant:
            skip.add("render.variant")
    diffs = []

    def walk(a, b, where):
        if isinstance(a, dict) and isinstance(b, dict):
            for key in sorted(set(a) | set(b)):
                name = f"{where}.{key}" if where else key
                if name not in skip:
                    walk(a.get(key, "<missing>"), b.get(key, "<missing>"), name)
        elif a != b:
            diffs.append((where, a, b))

    walk(found, want, "")
    if diffs:
        def short(v):
            s = json.dumps(v) if not isinstance(v, str) else repr(v)
            return s if len(s) <= 80 else s[:77] + "..."

        lines = "; ".join(f"{k}: dataset has {short(a)}, this run wants {short(b)}"
                          for k, a, b in diffs)
        raise DatasetMismatchError(
            f"{path}: the folder holds another dataset ({lines}). Use another output folder, or "
            "rerun with the dataset's arguments to resume it")


def _prepare_folder(out: Path) -> dict | None:
    """Existing manifest (None for a new dataset); removes partial files of a killed run."""
    if out.exists() and not out.is_dir():
        raise DatasetError(f"{out}: exists and is not a folder")
    if not out.exists():
        return None
    manifest = out / MANIFEST_NAME
    frames_dir = out / FRAMES_DIR
    if not manifest.exists():
        foreign = [p.name for p in out.iterdir()
                   if not p.name.endswith(PARTIAL_SUFFIX)
                   and not (p == frames_dir and p.is_dir() and not any(frames_dir.iterdir()))]
        if foreign:
            raise DatasetError(f"{out}: not empty and not a SCET dataset (no {MANIFEST_NAME}; "
                               f"found {sorted(foreign)[:5]}); refusing to write into it")
    for folder in (out, frames_dir):
        if folder.is_dir():
            for p in folder.iterdir():
                if p.name.endswith(PARTIAL_SUFFIX) and p.is_file():
                    p.unlink()
    return read_manifest(out) if manifest.exists() else None


def _frame_done(frames_dir: Path, frame: int) -> bool:
    return ((frames_dir / f"{frame:06d}.exr").is_file()
            and (frames_dir / f"{frame:06d}.png").is_file())


# --------------------------------------------------------------------------- reading


def read_manifest(path) -> dict:
    """The manifest of a dataset folder, after checking its format and version.

    Parameters
    ----------
    path : str or Path
        The dataset folder (or its ``manifest.json``).

    Raises
    ------
    DatasetError
        Missing, unreadable, or another format or version.
    """
    path = Path(path)
    file = path if path.name == MANIFEST_NAME and path.is_file() else path / MANIFEST_NAME
    try:
        data = json.loads(file.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise DatasetError(f"{file}: no such file; not a SCET dataset") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{file}: cannot read the manifest ({exc})") from None
    check_format(data, file, FORMAT, VERSION, DatasetError)
    return data


@dataclass(frozen=True, slots=True)
class ExrFrame:
    """One ``frames/NNNNNN.exr`` file.

    Attributes
    ----------
    radiance : (H, W) float32
        Pulse-weighted linear radiance, as rendered.
    frame : int
    pulse_indices : (P,) int64
        Pulses rendered into the frame.
    strobe_times_s : (P,) float
        Their instants (pulse centres).
    scene_sha256 : str
    """

    radiance: np.ndarray
    frame: int
    pulse_indices: np.ndarray
    strobe_times_s: np.ndarray
    scene_sha256: str


def read_exr(path) -> ExrFrame:
    """Read a dataset frame's EXR file, checking its format and version attributes.

    Raises
    ------
    DatasetError
        Unreadable, not written by this module, another version, or no "Y" channel.
    """
    import OpenEXR

    path = Path(path)
    try:
        with OpenEXR.File(str(path)) as exr:
            # The binding empties its header dict when the file closes: copy what we need.
            header, channels = dict(exr.header()), exr.channels()
            names = sorted(channels)
            radiance = np.array(channels["Y"].pixels, copy=True) if "Y" in channels else None
    except (OSError, RuntimeError) as exc:
        raise DatasetError(f"{path}: cannot read the EXR file ({exc})") from None
    if header.get("scet_format") != FORMAT or header.get("scet_version") != VERSION:
        raise DatasetError(f"{path}: expected {FORMAT} version {VERSION} attributes, got "
                           f"{header.get('scet_format')!r} version {header.get('scet_version')!r}")
    if radiance is None or radiance.dtype != np.float32 or radiance.ndim != 2:
        raise DatasetError(f"{path}: expected one float32 channel 'Y', got {names}")
    try:
        pulses = np.array(json.loads(header["scet_pulse_indices"]), dtype=np.int64)
        times = np.array(json.loads(header["scet_strobe_times_s"]), dtype=np.float64)
        frame, sha = int(header["scet_frame"]), str(header["scet_scene_sha256"])
    except (KeyError, TypeError, ValueError) as exc:
        raise DatasetError(f"{path}: malformed SCET header attributes ({exc})") from None
    if pulses.shape != times.shape or pulses.ndim != 1:
        raise DatasetError(f"{path}: scet_pulse_indices and scet_strobe_times_s differ in length")
    return ExrFrame(radiance, frame, pulses, times, sha)


def iter_labels(path) -> Iterator[StrobeLabel]:
    """Iterate over the strobe labels of a finished dataset, in file order.

    Parameters
    ----------
    path : str or Path
        The dataset folder.

    Yields
    ------
    StrobeLabel

    Raises
    ------
    DatasetError
        Not a dataset of this format and version, unfinished (no labels file), or a malformed
        line (the message names the line).
    """
    path = Path(path)
    read_manifest(path)
    file = path / LABELS_NAME
    if not file.is_file():
        raise DatasetError(f"{file}: missing; the run that writes this dataset did not finish "
                           "(rerun render_dataset with the same arguments to complete it)")
    with open(file, encoding="utf-8") as f:
        for number, line in enumerate(f, start=1):
            try:
                yield _label(json.loads(line))
            except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
                raise DatasetError(f"{file}, line {number}: malformed label ({exc})") from None


def _label(d: dict) -> StrobeLabel:
    glints = np.array([[np.nan, np.nan] if g is None else g for g in d["glints_px"]],
                      dtype=np.float64).reshape(-1, 2)
    visible = np.array(d["glints_visible"], dtype=bool)
    if visible.shape != (glints.shape[0],):
        raise ValueError("glints_px and glints_visible differ in length")
    return StrobeLabel(
        frame=int(d["frame"]), strobe=int(d["strobe"]), time_s=float(d["time_s"]),
        pulse_start_s=float(d["pulse_start_s"]), first_row=int(d["first_row"]),
        last_row=int(d["last_row"]), full_rows=(int(d["full_rows"][0]), int(d["full_rows"][1])),
        target_m=_vec3(d["target_m"]), yaw_rad=float(d["yaw_rad"]),
        pitch_rad=float(d["pitch_rad"]), cornea_center_m=_vec3(d["cornea_center_m"]),
        glints_px=glints, glints_visible=visible)


# --------------------------------------------------------------------------- helpers


def _write_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + PARTIAL_SUFFIX)
    with open(tmp, "wb") as f:
        f.write(data)
    _commit(tmp, path)


def _commit(tmp: Path, path: Path) -> None:
    """Flush ``tmp`` to disk and move it onto ``path`` in one step."""
    with open(tmp, "rb+") as f:
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _exr():
    import OpenEXR

    return OpenEXR


def _floats(v) -> list[float]:
    return [float(x) for x in np.asarray(v).ravel()]


def _vec3(v) -> np.ndarray:
    a = np.array(v, dtype=np.float64)
    if a.shape != (3,):
        raise ValueError(f"expected 3 numbers, got {v!r}")
    return a


def _check_int(name: str, value, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def _check_kind(kind) -> str:
    if kind not in TRAJECTORY_KINDS:
        raise ValueError(f"trajectory must be one of {TRAJECTORY_KINDS}, got {kind!r}")
    return kind
