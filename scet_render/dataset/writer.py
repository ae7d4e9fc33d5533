"""Rendered datasets on disk: banded frames, sensor output and per-strobe ground truth.

Layout of a dataset folder (format ``scet-dataset``, version 1)::

    manifest.json        what was rendered and how (see below); written first
    frames/000000.exr    linear radiance, float32, one channel "Y" (pulse-weighted, as rendered)
    frames/000000.png    sensor output (raw DN, black level included): 16-bit PNG for bit
                         depths above 8, 8-bit PNG otherwise
    frames/000000_mask.png  segmentation mask, 8-bit (unless rendered with masks=False)
    ...
    labels.jsonl         one JSON object per strobe sample; written last

``manifest.json`` holds the format name and version, the scene (name, file name, sha256 and the
full TOML text), a fingerprint of the exact :class:`~estimator.setup.Setup` rendered (it catches
setups changed in code, e.g. a scaled-down camera), software versions, the seed, the render
settings (spp, Mitsuba variant, cornea model), the trajectory kind, the frame count, the image
size and every :class:`~scet_render.render.sensor.SensorModel` parameter, and the renderer's own
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
    pupil_center_px        the pupil's centre as imaged through the cornea [u, v]: the
                           projection of the point where the ray from the centre refracts
                           toward the camera (exact, on the sphere or the conic cornea;
                           :mod:`scet_render.render.pupil`); null where that ray misses the cap
    pupil_ellipse_px       [u, v, major, minor, angle_deg]: cv2.fitEllipse of 64 refracted
                           points of the pupil's edge (full axis lengths, px; the major axis's
                           angle from +u toward +v, [0, 180)); null where any is not seen
    pupil_diameter_mm      the pupil's diameter at the strobe instant (the scene's
                           eye.pupil_diameter_mm, or the trajectory's pupil trace)

Scenes with moving lids (``[eyelids]``) add, beside ``lid_closure``, ``glints_occluder`` and
``glints_blocked_fraction``::

    pupil_occluder               "none", "lid" or "lash": what blocks the pupil centre's
                                 refracted ray on its way from the cornea to the camera
    pupil_edge_visible_fraction  share of the 64 edge points whose refracted ray reaches the
                                 camera unblocked (the ellipse is fitted to all 64 regardless:
                                 the outline where the lid covers it is the pupil's, not seen)

Datasets written before the pupil labels existed lack the three pupil keys (their
:class:`StrobeLabel` fields read None); the format version stays 1. The ellipse's centre is
not the centre's image: perspective and the cornea's uneven magnification put them 1-2 px
apart at 320x240 on paper_sim (``benchmarks/bench_pupil_labels.py``); a detector that fits
the pupil's outline measures the ellipse.

Segmentation masks (``frames/NNNNNN_mask.png``, one uint8 class per pixel, the index into
:data:`scet_render.render.MASK_CLASSES`)::

    0 none     nothing of the eye or face (a light seen directly, the environment)
    1 skin     the skin around the eye and the face beyond it
    2 sclera   3 iris   4 pupil  (iris and pupil seen through the cornea, refracted)
    5 lid      6 lash   7 glint

Each pixel's class is what the ray through its centre meets first, as the renderer draws it
(:mod:`scet_render.render.regions`); each row is classified at the eye pose of the strobe
that lights it most, like the image (rows no strobe lights: the ambient instant that weighs
most), and the glints of each strobe are painted over its rows where the labels put them
(every pixel the glint's image, a disk of the light's paraxial virtual image in the cornea,
overlaps). A fixation's frame is classified once when no band's pose moves anything by 0.05 px.
Masks cost 1.4-3.2 % of a frame's render (320x240, 16 spp, after the first frame);
``render_dataset(masks=False)`` (``scet render --no-masks``) leaves them out, and the manifest
says which (``files.mask``). ``DatasetFrame.mask()`` reads one back.

The pupil's size can vary over time (``render_dataset(pupil=PupilModel(...))``: the light
reflex and hippus of :mod:`scet_render.motion.pupil`, seeded from the dataset's seed, recorded
as the manifest's ``pupil``); without it every frame has the scene's size, as before.

Labels are computed from the setup, the trajectory and the banding model
(:func:`estimator.banding.band_layout`, :func:`scet_render.simulate.ground_truth_glints`), so
they need no rendering and are rebuilt whole at the end of every run.

Writing is crash-safe and resumable. Every file is written to a temporary name unique to its
writer (``<name>.<pid>-<thread>-<n>.partial``, :mod:`estimator.formats`) in its own folder and
moved into place with :func:`os.replace`; a frame counts as done when both its EXR and PNG are
intact (they decode; the EXR names the frame and the scene), so a truncated file is rendered
again. The steps (prepare, render each frame, finalize) are :mod:`scet_render.dataset.jobs`;
:mod:`scet_render.dataset.distributed` runs the middle one on a Ray cluster. All randomness of frame f derives from ``SeedSequence([seed, stream, f])``, so a
run that is killed at any point and started again with the same arguments renders only the
missing frames and ends with a dataset byte-identical to an uninterrupted run. A run pointed at
a folder that holds a different dataset (other scene, seed, frame count, ...) refuses with a
:class:`DatasetMismatchError` that names every differing entry; it never overwrites.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable

import numpy as np

from estimator.banding import strobe_instant
from estimator.formats import atomic_file, atomic_write, frame_name
from estimator.setup import Setup

from ..motion import (
    FixationalNoise,
    PupilModel,
    Trajectory,
    blink_schedule,
    fixation_sequence,
    pupil_schedule,
    saccade_sequence,
    with_blinks,
    with_pupil,
)
from ..render import SensorModel
from .format import (
    _STREAM_BLINKS,
    _STREAM_PUPIL,
    _STREAM_RENDER,
    _STREAM_SENSOR,
    _STREAM_TRAJECTORY,
    FIXATION_S,
    FORMAT,
    GRID_COLS,
    GRID_ROWS,
    MANIFEST_NAME,
    SACCADE_FIXATION_RANGE_S,
    VERSION,
    DatasetMismatchError,
    RenderSummary,
    _check_int,
    _check_kind,
    _exr,
    counts_png,
    mask_name,
    mask_png,
)
from .jobs import DatasetPlan, commit_manifest, finalize_dataset, prepare_dataset
from .labels import frame_labels, visible_bands

# --------------------------------------------------------------------------- trajectories


def dataset_trajectory(setup: Setup, kind: str, frames: int, seed: int,
                       pupil: PupilModel | None = None) -> Trajectory:
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
    pupil : PupilModel, optional
        The pupil's dynamics: a seeded :func:`~scet_render.motion.pupil_schedule` from the
        scene's pupil size (its own random stream). None: the scene's size throughout.

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
        traj = saccade_sequence(eye, targets, gen, SACCADE_FIXATION_RANGE_S, noise=noise)
    else:
        n = math.ceil(needed_s / FIXATION_S) + 1
        if kind == "fixations":
            order = np.concatenate([gen.permutation(len(grid))
                                    for _ in range(-(-n // len(grid)))])
        else:
            order = np.arange(n) % len(grid)
        traj = fixation_sequence(eye, grid[order[:n]], FIXATION_S, gen, noise=noise)
    if setup.eyelids is not None and setup.eyelids.blink_rate_per_min > 0:
        blinks = np.random.default_rng(np.random.SeedSequence([seed, _STREAM_BLINKS]))
        traj = with_blinks(traj, blink_schedule(traj.duration_s,
                                                setup.eyelids.blink_rate_per_min, blinks))
    if pupil is not None:
        gen = np.random.default_rng(np.random.SeedSequence([seed, _STREAM_PUPIL]))
        traj = with_pupil(traj, pupil_schedule(traj.duration_s, setup.eye.pupil_diameter_m,
                                               gen, pupil))
    return traj


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
    eyelid_openness: float | None = 1.0,
    masks: bool = True,
    pupil: PupilModel | None = None,
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
    eyelid_openness : float or None
        The renderer's static eyelids: 1 clears the cornea for every gaze at the screen, 0 is
        closed, None renders no lids (:class:`scet_render.render.BandedRenderer`).
    masks : bool
        Write each frame's segmentation mask, ``frames/NNNNNN_mask.png``
        (:func:`scet_render.render.regions.frame_mask`).
    pupil : PupilModel, optional
        Vary the pupil's size over time (:func:`dataset_trajectory`); None keeps the scene's.

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
    plan = prepare_dataset(setup, out_dir, frames=frames, spp=spp, trajectory=trajectory,
                           seed=seed, variant=variant, cornea=cornea, sensor=sensor,
                           scene_text=scene_text, eyelid_openness=eyelid_openness,
                           masks=masks, pupil=pupil)
    traj = dataset_trajectory(setup, plan.trajectory, plan.frames, plan.seed, plan.pupil)
    renderer = None
    if plan.todo or plan.existing is None:
        renderer = make_renderer(plan)
    if progress is not None:
        progress(len(plan.done), plan.frames)
    labels = {}  # frame -> its labels, from the bands its render was checked against
    for k, f in enumerate(plan.todo, start=1):
        labels[f] = render_frame(plan, renderer, traj, f)
        if progress is not None:
            progress(len(plan.done) + k, plan.frames)
    return finalize_dataset(plan, traj, labels)


def open_renderer(plan: DatasetPlan, *, threads: int | None = None,
                  vector_width: int | None = None):
    """A renderer for a plan, without touching the folder: ``(renderer, variant, settings,
    host)`` for :func:`~scet_render.dataset.jobs.commit_manifest`.

    On the LLVM backend the vector width is pinned, before anything is compiled, to
    ``vector_width`` or else to the one the folder's frames were rendered with (none for a new
    dataset: the CPU's own); ``threads`` sets Dr.Jit's thread count (None leaves it).

    Raises
    ------
    DatasetMismatchError
        This machine cannot run the recorded width.
    """
    from ..render.backend import activate, llvm_target, pin_llvm_vector_width

    mi = activate(plan.variant)
    if threads is not None:
        import drjit as dr

        dr.set_thread_count(int(threads))
    host = None
    if mi.variant().startswith("llvm_"):
        want = vector_width if vector_width is not None else plan.recorded_vector_width
        try:
            host = pin_llvm_vector_width(want) if want is not None else llvm_target()
        except ValueError as exc:
            raise DatasetMismatchError(
                f"{plan.out / MANIFEST_NAME}: the frames are rendered with LLVM kernels {want} "
                f"lanes wide; this machine cannot render the same bytes ({exc})") from None
    renderer = _make_renderer(plan.setup, spp=plan.spp, variant=mi.variant(), cornea=plan.cornea,
                              seed=plan.seed, eyelid_openness=plan.eyelid_openness)
    settings = _renderer_settings(renderer)
    if host is not None:
        settings["llvm"] = {"vector_width": host["vector_width"]}
        host = {"cpu": host["cpu"], "features": host["features"]}
    return renderer, renderer.variant, settings, host


def make_renderer(plan: DatasetPlan, *, threads: int | None = None):
    """:func:`open_renderer`, and the plan's manifest committed with its settings."""
    renderer, variant, settings, host = open_renderer(plan, threads=threads)
    commit_manifest(plan, variant, settings, host)
    return renderer


def render_frame(plan: DatasetPlan, renderer, trajectory: Trajectory, frame: int) -> list[dict]:
    """Step 2 of :mod:`scet_render.dataset.jobs` for one frame: render, check and write it
    (idempotent: the same bytes whoever writes it, never a half file); its labels. The
    manifest must be committed first (by this process or the driver)."""
    return _render_frame(renderer, plan.setup, plan.sensor, trajectory, frame, plan.seed,
                         plan.frames_dir, plan.scene_sha256, plan.masks)


def _render_frame(renderer, setup: Setup, sensor: SensorModel, traj: Trajectory, frame: int,
                  seed: int, frames_dir: Path, scene_sha256: str,
                  masks: bool = False) -> list[dict]:
    """Render, check and write one frame (and its mask); its labels, from the bands it was
    checked against."""

    result = renderer.render_frame(traj, frame)
    radiance = np.ascontiguousarray(result.radiance, dtype=np.float32)
    shape = (setup.camera.height_px, setup.camera.width_px)
    if radiance.shape != shape:
        raise RuntimeError(f"renderer returned frame {frame} with shape {radiance.shape}, "
                           f"expected {shape} (height, width)")
    pulses = np.asarray(result.pulse_indices, dtype=np.int64)
    times = np.asarray(result.pulse_times_s, dtype=np.float64)
    bands = visible_bands(setup, frame)
    want_times = strobe_instant(np.array([b.strobe_time_s for b in bands]), setup.strobe.pulse_s)
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
    with atomic_file(frames_dir / frame_name(frame, "exr")) as tmp:
        with _exr().File(header, {"Y": radiance}) as exr:
            exr.write(str(tmp))
    labels = frame_labels(setup, traj, frame, bands)
    if masks:
        from ..render import frame_mask

        atomic_write(frames_dir / mask_name(frame), mask_png(frame_mask(renderer, traj, frame,
                                                                         labels)))
    atomic_write(frames_dir / frame_name(frame, "png"), counts_png(dn, sensor.bit_depth))
    return labels


def _make_renderer(setup: Setup, *, spp: int, variant, cornea: str, seed: int,
                   eyelid_openness: float | None = 1.0):
    from ..render import BandedRenderer

    # The renderer derives every slice's sampler seed from (its seed, frame index, slice), so
    # frame f renders the same whatever was rendered before it: resumed runs stay identical.
    render_seed = int(np.random.SeedSequence([seed, _STREAM_RENDER]).generate_state(1)[0])
    return BandedRenderer(setup, variant=variant, spp=spp, cornea=cornea, seed=render_seed,
                          eyelid_openness=eyelid_openness)


def _renderer_settings(renderer) -> dict:
    """Everything the renderer chose or defaulted that shapes its output."""
    options = renderer.options
    return {
        "seed": renderer.seed,
        "ambient_spp": renderer.ambient_spp,
        "blur_step_px": renderer.blur_step_px,
        "max_ambient_instants": renderer.max_ambient_instants,
        "scene_options": {name: getattr(options, name) for name in options.__slots__},
        # The [appearance] table rendered, every key resolved (defaults, albedos).
        "appearance": dict(renderer.eye_scene.appearance_table),
    }


# --------------------------------------------------------------------------- helpers
