"""Rendering a dataset on a Ray cluster (optional extra ``cluster``), with the bytes of a
serial run.

The driver prepares the dataset and writes its manifest and ``labels.jsonl``
(:mod:`scet_render.dataset.jobs`); the frames are rendered by actors, one per worker, each
holding a warm renderer (building the Mitsuba scene and compiling its kernels costs seconds,
paid once per actor, not per frame), one task per frame, handed out as actors free up. Every
frame's randomness derives from the seed and the frame index alone, and every file is written
to a temporary unique to its writer and renamed, so any worker count, any order, a retried
task or a restarted actor gives the same bytes as the serial run. Actors restart after a
crash (``max_restarts``) and their tasks are retried (``max_task_retries``); a killed driver is
resumed by running the same command again (the frames on disk and intact are kept).

Dr.Jit sizes its thread pool from the CPUs it sees; each actor sets it to the CPUs Ray gave it
(left alone, two actors on two cores each started two threads: 5-22 % slower, DESIGN.md). All
actors must render with the same LLVM vector width (the bytes depend on it): the folder's
recorded width, else the first actor's; an actor that cannot is refused.
"""

from __future__ import annotations

from typing import Callable

from ..cluster import (
    MAX_RESTARTS,
    MAX_TASK_RETRIES,
    NAMESPACE,
    actor_class,
    check_workers,
    ray_session,
    render_on_actors,
    worker_count,
)
from .format import DatasetMismatchError, RenderSummary
from .jobs import commit_manifest, finalize_dataset, prepare_dataset

__all__ = ["FrameRenderer", "MAX_RESTARTS", "MAX_TASK_RETRIES", "NAMESPACE", "render_dataset_ray"]


class FrameRenderer:
    """The actor: a warm renderer for one dataset plan (a Ray actor class once wrapped by
    :func:`render_dataset_ray`; a plain object otherwise, which the tests use)."""

    def __init__(self, plan, vector_width: int | None = None, threads: int | None = None):
        from .writer import dataset_trajectory, open_renderer

        self.plan = plan
        self.trajectory = dataset_trajectory(plan.setup, plan.trajectory, plan.frames, plan.seed,
                                             plan.pupil)
        self.renderer, self.variant, self.settings, self.host = open_renderer(
            plan, threads=threads, vector_width=vector_width)

    def describe(self) -> tuple:
        """(variant, renderer settings, host): what the manifest records."""
        return self.variant, self.settings, self.host

    def render(self, frame: int) -> tuple[int, list]:
        """Render and write ``frame``; (frame, its labels)."""
        from .writer import render_frame

        return frame, render_frame(self.plan, self.renderer, self.trajectory, frame)


def render_dataset_ray(setup, out_dir, *, frames: int, workers: int | None = None,
                       address: str | None = None, cpus_per_worker: int = 1, spp: int = 16,
                       trajectory: str = "fixations", seed: int = 0, variant: str | None = None,
                       cornea: str = "dielectric", sensor=None, scene_text: str | None = None,
                       eyelid_openness: float | None = 1.0, masks: bool = True, pupil=None,
                       progress: Callable[[int, int], None] | None = None) -> RenderSummary:
    """:func:`~scet_render.dataset.render_dataset` with the frames rendered by Ray actors.

    Parameters
    ----------
    workers : int, optional
        Actors (each holds a renderer); default: the cluster's CPUs // ``cpus_per_worker``.
        Without ``address`` a local Ray is started for the run with ``workers`` CPUs.
    address : str, optional
        An existing cluster (``ray start --head`` prints it; ``"auto"`` finds a local one).
    cpus_per_worker : int
        CPUs Ray reserves per actor; Dr.Jit's thread count is set to it.
    The other arguments and the result are those of
    :func:`~scet_render.dataset.render_dataset`, and so is the dataset, byte for byte.
    """
    from .writer import dataset_trajectory

    plan = prepare_dataset(setup, out_dir, frames=frames, spp=spp, trajectory=trajectory,
                           seed=seed, variant=variant, cornea=cornea, sensor=sensor,
                           scene_text=scene_text, eyelid_openness=eyelid_openness,
                           masks=masks, pupil=pupil)
    traj = dataset_trajectory(setup, plan.trajectory, plan.frames, plan.seed, plan.pupil)
    if progress is not None:
        progress(len(plan.done), plan.frames)
    if not plan.todo and plan.existing is not None:
        return finalize_dataset(plan, traj, {})
    check_workers(workers, cpus_per_worker)
    with ray_session(workers, address, cpus_per_worker) as ray:
        n = worker_count(ray, workers, len(plan.todo), cpus_per_worker)
        actor = actor_class(ray, FrameRenderer, cpus_per_worker)
        width = plan.recorded_vector_width
        first = actor.options(name="scet-render-0", get_if_exists=False).remote(
            plan, width, cpus_per_worker)
        variant_, settings, host = ray.get(first.describe.remote())
        width = (settings.get("llvm") or {}).get("vector_width", width)
        actors = [first] + [actor.options(name=f"scet-render-{i}").remote(plan, width, cpus_per_worker)
                            for i in range(1, n)]
        for a in actors[1:]:
            v, s, _ = ray.get(a.describe.remote())
            if (v, s) != (variant_, settings):
                raise DatasetMismatchError(
                    f"{plan.out}: workers would render different bytes (variant {v} against "
                    f"{variant_}, settings {s} against {settings}); use workers of one kind")
        commit_manifest(plan, variant_, settings, host)
        labels = {}
        for frame, frame_labels in render_on_actors(ray, actors, plan.todo):
            labels[frame] = frame_labels
            if progress is not None:
                progress(len(plan.done) + len(labels), plan.frames)
        return finalize_dataset(plan, traj, labels)
