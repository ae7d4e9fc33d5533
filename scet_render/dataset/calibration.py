"""Single-pulse calibration frames (Sec. 2.4): the eye fixating the calibration grid,
every visible row lit by the same pulse, with a timing sidecar.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from estimator.banding import calibration_setup, strobe_instant
from estimator.folders import timing_document
from estimator.formats import FRAMES_DIR, LABELS_NAME, TIMING_NAME, atomic_write, frame_name
from estimator.setup import Setup

from ..motion import fixation_sequence
from .effective import DIFFERS_MARK, SCENE_NAME, effective_scene_text
from .format import counts_png
from .labels import frame_labels
from .manifest import _scene_text

#: Calibration fixation per target (s); one frame is rendered in its middle.
CALIB_FIXATION_S = 0.1


class CalibrationFrames:
    """Renders and writes the calibration frames of one setup: in this process, or as a Ray
    actor (:func:`render_calibration` with ``workers`` / ``address``).

    ``vector_width`` pins the LLVM backend's width before anything is compiled (the actors of
    one run all render with the first one's); ``threads`` sets Dr.Jit's thread count.
    """

    def __init__(self, cal: Setup, traj, out: Path, *, spp: int, cornea: str, seed: int,
                 eyelid_openness: float | None, vector_width: int | None = None,
                 threads: int | None = None):
        from ..render import BandedRenderer, SensorModel
        from ..render.backend import activate, llvm_target, pin_llvm_vector_width

        mi = activate(None)
        if threads is not None:
            import drjit as dr

            dr.set_thread_count(int(threads))
        self.vector_width = None
        if mi.variant().startswith("llvm_"):
            target = pin_llvm_vector_width(vector_width) if vector_width is not None else llvm_target()
            self.vector_width = None if target is None else target["vector_width"]
        self.traj, self.out, self.seed = traj, Path(out), seed
        self.renderer = BandedRenderer(cal, spp=spp, cornea=cornea, seed=seed,
                                       eyelid_openness=eyelid_openness)
        self.sensor = SensorModel.from_sensor(cal.sensor)

    def describe(self) -> int | None:
        """The LLVM vector width this renderer compiles for (None off the LLVM backend)."""
        return self.vector_width

    def render(self, frame: int) -> int:
        """Render and write ``frames/NNNNNN.png`` unless it is there; returns ``frame``."""
        path = self.out / FRAMES_DIR / frame_name(frame, "png")
        if not path.is_file():
            radiance = self.renderer.render_frame(self.traj, frame).radiance
            dn = self.sensor.apply(radiance, np.random.SeedSequence([self.seed, 3, frame]))
            atomic_write(path, counts_png(dn, self.sensor.bit_depth))
        return frame


def render_calibration(setup: Setup, out_dir, *, spp: int, cornea: str, seed: int = 0,
                       grid=(5, 5), progress=None,
                       eyelid_openness: float | None = 1.0,
                       scene_text: str | None = None, workers: int | None = None,
                       address: str | None = None) -> Path:
    """Render single-pulse calibration frames of the eye fixating the calib grid.

    Writes ``frames/NNNNNN.png`` (frames in the middle of each fixation), ``labels.jsonl``
    (:func:`scet_render.dataset.frame_labels`), ``timing.json`` (with the calibration
    exposure and strobe) and ``scene.toml`` (the effective scene of ``setup``, the one to
    calibrate with: :func:`scet_render.dataset.effective.effective_scene_text`; the timing
    sidecar carries the single-pulse timing), each atomically. Returns the folder.
    ``eyelid_openness`` as :func:`scet_render.dataset.render_dataset` (the frames carry no
    manifest: a folder is reused as it is, so give each eyelid setting its own);
    ``scene_text`` is the scene TOML ``setup`` was loaded from (default: read from
    ``setup.source``). With ``workers`` or ``address`` the frames missing from the folder are
    rendered by Ray actors (:mod:`scet_render.cluster`), the same bytes as here.
    """
    out = Path(out_dir)
    effective = effective_scene_text(setup, _scene_text(setup, scene_text))
    text = effective.text
    if effective.differs:  # what the text could not carry, in a line readers look for
        text = f"{DIFFERS_MARK} {', '.join(effective.differs)}\n" + text
    cal = calibration_setup(setup)
    targets = setup.screen.grid(grid[0], grid[1], margin=0.0)
    traj = fixation_sequence(setup.eye, targets, CALIB_FIXATION_S)
    dt = cal.sensor.frame_period_s
    ends = np.cumsum(traj.segment_duration_s)
    starts = ends - traj.segment_duration_s
    fix = np.flatnonzero(np.asarray(traj.kind) == 0)
    mid = 0.5 * (starts[fix] + ends[fix])
    instant = strobe_instant(cal.strobe.phase_s, cal.strobe.pulse_s)  # pulse centre relative to t0_f
    frames = [int(round((t - instant) / dt)) for t in mid]
    kwargs = dict(spp=spp, cornea=cornea, seed=seed, eyelid_openness=eyelid_openness)
    todo = [f for f in frames if not (out / FRAMES_DIR / frame_name(f, "png")).is_file()]
    done = len(frames) - len(todo)
    if workers is None and address is None or not todo:
        frames_here = CalibrationFrames(cal, traj, out, **kwargs) if todo else None
        for i, f in enumerate(frames):
            if frames_here is not None:
                frames_here.render(f)
            if progress is not None:
                progress(i + 1, len(frames))
    else:
        _render_calibration_ray(cal, traj, out, todo, kwargs, workers, address,
                                lambda n: progress(done + n, len(frames)) if progress else None)
    labels = [x for f in frames for x in frame_labels(cal, traj, f)]
    atomic_write(out / LABELS_NAME, "".join(json.dumps(x) + "\n" for x in labels))
    atomic_write(out / TIMING_NAME, timing_document({f: f * dt for f in frames},
                                                   exposure_s=cal.sensor.exposure_s,
                                                   strobe=cal.strobe))
    atomic_write(out / SCENE_NAME, text)
    return out


def _render_calibration_ray(cal, traj, out, todo, kwargs, workers, address, progress) -> None:
    """The frames ``todo`` rendered by Ray actors, each a warm :class:`CalibrationFrames`."""
    from ..cluster import actor_class, ray_session, render_on_actors, worker_count

    with ray_session(workers, address) as ray:
        actor = actor_class(ray, CalibrationFrames)
        first = actor.remote(cal, traj, out, threads=1, **kwargs)
        width = ray.get(first.describe.remote())
        actors = [first] + [actor.remote(cal, traj, out, vector_width=width, threads=1, **kwargs)
                            for _ in range(1, worker_count(ray, workers, len(todo)))]
        for k, _ in enumerate(render_on_actors(ray, actors, todo)):
            if progress is not None:
                progress(k + 1)
