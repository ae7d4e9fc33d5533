"""Ray for the commands that spread work over processes or machines (``scet render``,
``scet validate`` and ``scet reproduce`` with ``--workers N`` / ``--ray-address ADDR``).

One place starts, joins and leaves Ray, so every command does it the same way:

- without an address, a local Ray is started for the run with ``workers`` CPUs, no dashboard,
  its node address on the loopback interface, and shut down at the end; Ray 2.60 turns its
  token authentication on for it by itself (a warning is logged when ``RAY_AUTH_MODE=disabled``
  turns it off);
- with an address, the run joins that cluster and leaves it running;
- a Ray already initialised in this process (a test, a notebook) is used as it is.

Ray's own warning applies to every cluster a user starts for these commands: anybody who can
reach a Ray cluster's ports can run code on it (docs.ray.io, "Security": "Ray allows any
clients to run arbitrary code"). Measured with Ray 2.60 here: the GCS and raylet of a local
run listen on every interface even with the node address on the loopback, so the token is
what keeps other hosts out; start clusters only on a private network (docs/guide/rendering.md).

:class:`TaskPool` runs independent, deterministic tasks (module-level functions and picklable
arguments) either in this process or as Ray tasks, and returns their results in submission
order, so a run gives the same numbers whatever the worker count.
"""

from __future__ import annotations

import contextlib
import logging
import os
from typing import Callable, Iterator, Sequence

log = logging.getLogger(__name__)

#: Namespace of the actors and tasks (``scet-render-<i>``), so that tools can find them.
NAMESPACE = "scet"
#: Where the local Ray's node advertises itself: the loopback interface.
LOCAL_NODE_IP = "127.0.0.1"
#: Ray's restarts of a crashed actor, and retries of a task whose actor died.
MAX_RESTARTS, MAX_TASK_RETRIES = 3, 3


def import_ray():
    """Ray, or a one-line error naming the extra that installs it."""
    try:
        import ray
    except ImportError:
        raise ValueError("--workers / --ray-address need Ray: pip install 'scet[cluster]'") from None
    return ray


def check_workers(workers, cpus_per_worker: int = 1) -> None:
    """ValueError for a worker count or CPUs per worker below 1 (or not an integer)."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if isinstance(cpus_per_worker, bool) or not isinstance(cpus_per_worker, int) or cpus_per_worker < 1:
        raise ValueError(f"cpus_per_worker must be an integer >= 1, got {cpus_per_worker!r}")


@contextlib.contextmanager
def ray_session(workers: int | None = None, address: str | None = None,
                cpus_per_worker: int = 1) -> Iterator:
    """Ray for the duration of a ``with`` block (see the module docstring); yields the module.

    Parameters
    ----------
    workers : int, optional
        Local run: CPUs of the Ray started for it are ``workers * cpus_per_worker``.
    address : str, optional
        An existing cluster (``ray start --head`` prints it; ``"auto"`` finds a local one).
    cpus_per_worker : int
    """
    check_workers(workers, cpus_per_worker)
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    if address is None:
        if os.environ.get("RAY_AUTH_MODE", "").lower() == "disabled":
            log.warning("RAY_AUTH_MODE=disabled: the local Ray of this run accepts "
                        "unauthenticated clients on every interface it listens on")
        ray.init(num_cpus=(workers or 1) * cpus_per_worker, include_dashboard=False,
                 namespace=NAMESPACE, log_to_driver=False, _node_ip_address=LOCAL_NODE_IP)
    else:
        ray.init(address=address, namespace=NAMESPACE, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def actor_class(ray, cls, cpus_per_worker: int = 1):
    """``cls`` as a Ray actor class of ``cpus_per_worker`` CPUs that Ray restarts after a crash
    (:data:`MAX_RESTARTS`), its tasks retried (:data:`MAX_TASK_RETRIES`)."""
    return ray.remote(num_cpus=cpus_per_worker, max_restarts=MAX_RESTARTS,
                      max_task_retries=MAX_TASK_RETRIES)(cls)


def worker_count(ray, workers: int | None, items: int, cpus_per_worker: int = 1) -> int:
    """Actors to start: ``workers``, else the cluster's CPUs // ``cpus_per_worker``; never more
    than ``items`` and at least 1."""
    n = workers or max(1, int(ray.cluster_resources().get("CPU", 1)) // cpus_per_worker)
    return max(1, min(n, items))


def render_on_actors(ray, actors, items) -> Iterator:
    """``actor.render(item)`` for every item, handed to the actors as they free up; yields the
    results in completion order. The actors are killed at the end (after an error too), so a
    run on a shared cluster leaves none behind."""
    from ray.util import ActorPool

    try:
        yield from ActorPool(actors).map_unordered(lambda a, item: a.render.remote(item), items)
    finally:
        for a in actors:
            ray.kill(a, no_restart=True)


def _call(fn, args):
    return fn(*args)


class TaskPool:
    """Independent tasks in this process (``ray=None``) or as Ray tasks.

    Parameters
    ----------
    ray : module, optional
        An initialised Ray (:func:`ray_session`); None runs the tasks here, one after another.
    cpus_per_task : int
        CPUs Ray reserves per task.
    """

    def __init__(self, ray=None, cpus_per_task: int = 1):
        self.ray = ray
        self._remote = None if ray is None else ray.remote(num_cpus=cpus_per_task, max_retries=3)(_call)

    @property
    def distributed(self) -> bool:
        return self.ray is not None

    def map(self, fn: Callable, arg_tuples: Sequence[tuple],
            on_done: Callable[[int], None] | None = None) -> list:
        """``[fn(*args) for args in arg_tuples]``, in that order.

        ``fn`` must be a module-level function (Ray workers import it) and deterministic in its
        arguments. ``on_done(i)`` is called as task ``i`` finishes (in completion order on Ray).
        """
        if self.ray is None:
            out = []
            for i, args in enumerate(arg_tuples):
                out.append(fn(*args))
                if on_done is not None:
                    on_done(i)
            return out
        refs = [self._remote.remote(fn, tuple(args)) for args in arg_tuples]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list = [None] * len(refs)
        pending = list(refs)
        while pending:
            ready, pending = self.ray.wait(pending, num_returns=1)
            for ref in ready:
                i = index[ref]
                results[i] = self.ray.get(ref)
                if on_done is not None:
                    on_done(i)
        return results


@contextlib.contextmanager
def task_pool(workers: int | None = None, address: str | None = None) -> Iterator[TaskPool]:
    """A :class:`TaskPool`: in this process without ``workers`` and ``address``, else on the Ray
    of :func:`ray_session`."""
    if workers is None and address is None:
        yield TaskPool()
        return
    with ray_session(workers, address) as ray:
        yield TaskPool(ray)
