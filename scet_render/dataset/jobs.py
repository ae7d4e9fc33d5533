"""A dataset render as three steps, so that one machine or many can do the middle one.

1. :func:`prepare_dataset`: the arguments checked, the manifest built, the folder checked (a
   folder of another dataset is refused) and the list of frames still to render: every frame
   that is not complete *and intact* (:func:`frame_intact`: both files decode, the EXR names
   this frame and scene; a truncated PNG or EXR from a crash or a copy is rendered again).
2. :func:`render_frame` (in :mod:`scet_render.dataset.writer`), once per frame, anywhere:
   idempotent, every file written to a temporary name unique to its writer and renamed, so
   two writers of one frame leave it whole (the same bytes either way).
3. :func:`finalize_dataset`: ``labels.jsonl``, written by the driver alone.

Between 1 and 2 the manifest is committed (:func:`commit_manifest`) with what only a renderer
knows: its resolved variant and settings, and the LLVM backend's vector width, which changes
the rendered bytes (forcing 8 lanes instead of this CPU's 16 changed every frame by up to
15 DN). A resume, or a worker on another machine, pins its backend to the recorded width
(:func:`scet_render.render.backend.pin_llvm_vector_width`) before it renders, and is refused
when its CPU cannot run that width; the CPU name and features are recorded beside it
(``render.llvm_host``, for the record: not compared).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from estimator.errors import TrackerInputError
from estimator.formats import atomic_write, frame_name, remove_partials
from estimator.inputs import read_frame
from estimator.setup import Setup

from ..motion import PupilModel
from ..render import SceneOptions, SensorModel
from ..render.textures import read_appearance
from .format import (
    FRAMES_DIR,
    LABELS_NAME,
    MANIFEST_NAME,
    DatasetError,
    RenderSummary,
    _check_int,
    _check_kind,
    mask_name,
)
from .labels import frame_labels, read_exr
from .manifest import _compare_manifests, _manifest, _manifest_bytes, _prepare_folder, _scene_text


@dataclass
class DatasetPlan:
    """What :func:`prepare_dataset` found: the manifest to write, the frames to render.

    Attributes
    ----------
    setup : Setup
    out : Path
    manifest : dict
        Without the renderer's part until :func:`commit_manifest`.
    existing : dict or None
        The folder's manifest (None for a new dataset).
    todo, done : list of int
        Frames to render; frames complete and intact.
    frames, spp, seed : int
    trajectory, cornea : str
    variant : str or None
    sensor : SensorModel
    """

    setup: Setup
    out: Path
    manifest: dict
    existing: dict | None
    todo: list
    done: list
    frames: int
    spp: int
    seed: int
    trajectory: str
    cornea: str
    variant: str | None
    sensor: SensorModel
    committed: bool = field(default=False)
    #: The renderer's eyelids (:class:`scet_render.render.SceneOptions`; None: none). Recorded
    #: in the manifest with the renderer's settings (``render.renderer.scene_options``).
    eyelid_openness: float | None = 1.0
    #: Write ``frames/NNNNNN_mask.png`` beside each frame (``files.mask`` in the manifest).
    masks: bool = True
    #: The pupil's dynamics (light reflex, hippus) the trajectory carries; None: the scene's
    #: pupil size throughout. Recorded in the manifest (``pupil``) when set.
    pupil: PupilModel | None = None

    @property
    def frames_dir(self) -> Path:
        return self.out / FRAMES_DIR

    @property
    def scene_sha256(self) -> str:
        return self.manifest["scene"]["sha256"]

    @property
    def recorded_vector_width(self) -> int | None:
        """The LLVM vector width the folder's frames were rendered with (None: new, or not LLVM)."""
        llvm = ((self.existing or {}).get("render", {}).get("renderer") or {}).get("llvm")
        return int(llvm["vector_width"]) if isinstance(llvm, dict) and "vector_width" in llvm else None


def frame_intact(frames_dir: Path, frame: int, scene_sha256: str, shape, *,
                 masks: bool = False) -> bool:
    """Whether frame ``frame`` is complete and intact: its EXR reads with this frame's index
    and scene, and its PNG (and with ``masks`` its mask PNG) decodes to ``shape`` (height,
    width)."""
    exr, png = frames_dir / frame_name(frame, "exr"), frames_dir / frame_name(frame, "png")
    if not (exr.is_file() and png.is_file()):
        return False
    if masks and not _mask_intact(frames_dir / mask_name(frame), shape):
        return False
    size = (int(shape[1]), int(shape[0]))
    try:  # both refused by their headers before decoding when of another size
        e = read_exr(exr, size)
        img = read_frame(png, size)
    except (DatasetError, TrackerInputError, OSError, ValueError):
        return False
    return (e.frame == frame and e.scene_sha256 == scene_sha256
            and e.radiance.shape == tuple(shape) and img.shape == tuple(shape))


def _mask_intact(path: Path, shape) -> bool:
    import cv2

    if not path.is_file():
        return False
    data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    return img is not None and img.dtype == np.uint8 and img.shape == tuple(shape)


def prepare_dataset(setup: Setup, out_dir, *, frames: int, spp: int = 16,
                    trajectory: str = "fixations", seed: int = 0, variant: str | None = None,
                    cornea: str = "dielectric", sensor: SensorModel | None = None,
                    scene_text: str | None = None,
                    eyelid_openness: float | None = 1.0, masks: bool = True,
                    pupil: PupilModel | None = None) -> DatasetPlan:
    """Step 1 (module docstring); the arguments as :func:`~scet_render.dataset.render_dataset`.

    Raises
    ------
    DatasetMismatchError, DatasetError, ValueError
        As :func:`~scet_render.dataset.render_dataset`.
    """
    frames = _check_int("frames", frames, 1)
    spp = _check_int("spp", spp, 1)
    seed = _check_int("seed", seed, 0)
    kind = _check_kind(trajectory)
    if not isinstance(cornea, str):
        raise ValueError(f"cornea must be a string, got {cornea!r}")
    if variant is not None and not isinstance(variant, str):
        raise ValueError(f"variant must be a string or None, got {variant!r}")
    SceneOptions(eyelid_openness=eyelid_openness)  # checks it (ValueError) before any work
    if not isinstance(masks, bool):
        raise ValueError(f"masks must be True or False, got {masks!r}")
    if pupil is not None and not isinstance(pupil, PupilModel):
        raise ValueError(f"pupil must be a PupilModel or None, got {type(pupil).__name__}")
    read_appearance(setup)  # the scene's [appearance] table (SceneError), before any work
    if eyelid_openness is None and setup.eyelids is not None:
        # No lids rendered: none in the labels either (nothing hides a glint).
        setup = dataclasses.replace(setup, eyelids=None)
    sensor = SensorModel.from_sensor(setup.sensor) if sensor is None else sensor
    if not isinstance(sensor, SensorModel):
        raise ValueError(f"sensor must be a SensorModel, got {type(sensor).__name__}")
    text = _scene_text(setup, scene_text)
    out = Path(out_dir)
    manifest = _manifest(setup, text, frames=frames, spp=spp, kind=kind, seed=seed,
                         variant=variant, cornea=cornea, sensor=sensor)
    if masks:
        manifest["files"]["mask"] = f"{FRAMES_DIR}/{{frame:06d}}_mask.png"
    if pupil is not None:
        # As JSON reads it back (tuples become lists), so that a resume compares equal.
        manifest["pupil"] = json.loads(json.dumps(dataclasses.asdict(pupil)))
    existing = _prepare_folder(out)
    if existing is not None:
        # The variant that None resolves to is known only once the renderer exists.
        _compare_manifests(existing, manifest, out / MANIFEST_NAME, before_renderer=True,
                           ignore_variant=variant is None)
    shape = (setup.camera.height_px, setup.camera.width_px)
    sha = manifest["scene"]["sha256"]
    done = [f for f in range(frames)
            if frame_intact(out / FRAMES_DIR, f, sha, shape, masks=masks)]
    todo = sorted(set(range(frames)) - set(done))
    return DatasetPlan(setup, out, manifest, existing, todo, done, frames, spp, seed, kind,
                       cornea, variant, sensor, eyelid_openness=eyelid_openness, masks=masks,
                       pupil=pupil)


def commit_manifest(plan: DatasetPlan, variant: str, renderer_settings: dict,
                    llvm_host: dict | None = None) -> None:
    """Complete the manifest with a renderer's variant and settings; write it for a new
    dataset, or check it against the folder's (a renderer that would make other bytes is
    refused with :class:`DatasetMismatchError`)."""
    plan.manifest["render"]["variant"] = variant
    plan.manifest["render"]["renderer"] = renderer_settings
    if llvm_host is not None:
        plan.manifest["render"]["llvm_host"] = llvm_host
    if plan.existing is None:
        plan.out.mkdir(parents=True, exist_ok=True)
        atomic_write(plan.out / MANIFEST_NAME, _manifest_bytes(plan.manifest))
    else:
        _compare_manifests(plan.existing, plan.manifest, plan.out / MANIFEST_NAME)
    plan.frames_dir.mkdir(exist_ok=True)
    plan.committed = True


def finalize_dataset(plan: DatasetPlan, trajectory, labels: dict) -> RenderSummary:
    """Step 3: ``labels.jsonl`` from the labels of the frames rendered now (``labels``: frame ->
    list of dict) and those computed for the frames found done. Every writer has finished by
    now, so the temporaries of any that died mid-write (a killed worker whose task was
    retried elsewhere) are swept: the folder holds the dataset and nothing else."""
    for folder in (plan.out, plan.frames_dir):
        remove_partials(folder)
    lines = [json.dumps(label, allow_nan=False, separators=(",", ":"))
             for f in range(plan.frames)
             for label in (labels[f] if f in labels else frame_labels(plan.setup, trajectory, f))]
    atomic_write(plan.out / LABELS_NAME, "".join(line + "\n" for line in lines))
    todo = set(plan.todo)
    return RenderSummary(plan.out, tuple(plan.todo),
                         tuple(f for f in range(plan.frames) if f not in todo))
