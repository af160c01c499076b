"""Monte Carlo scenes as tasks on a Dask distributed cluster, local or remote.

Why Dask distributed (and not Ray): a scene is an independent, pure, CPU-bound Python
task of seconds with a few hundred bytes of result — exactly ``Client.map`` plus
``as_completed``. Dask is pip-installable pure Python (no native object store, no
per-node daemons with their own runtime), its scheduler and workers are started with
two commands (``dask scheduler``, ``dask worker``) or by the deployment helpers of its
own docs (``dask-jobqueue`` for SLURM/PBS/SGE, ``dask-kubernetes``, SSH, cloud), and a
local cluster is the same API for the tests and a laptop.

Each worker process flies one scene at a time with one numba and one OpenCV thread
(:func:`~evaluation.mc_scene.single_threaded`); a worker plugin
(:class:`WarmUp`) loads the numba caches and OpenCV's matchers once per worker, before
its first task. A seed whose worker dies more often than Dask's retry limit is an
``"error"`` verdict, reported, not a lost run.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from distributed import Client, LocalCluster, as_completed
from distributed.diagnostics.plugin import WorkerPlugin

from evaluation.mc_provenance import code_fingerprint
from evaluation.mc_results import verdict_to_record
from evaluation.mc_scene import error_verdict, fly_record, warm_up

__all__ = ["WarmUp", "dask_client", "fly_on_cluster"]

# The environment every local worker process starts with (before numpy is imported).
_WORKER_ENV = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


class WarmUp(WorkerPlugin):
    """Worker plugin: :func:`warm_up` once when a worker joins (before its first scene).

    The warm-up runs in a thread, not in the worker's event loop: loading (or, on a fresh
    checkout, compiling) the kernels takes seconds to minutes, and a blocked event loop
    misses the heartbeats the scheduler judges a worker alive by.
    """

    name = "stereo-avoid-warm-up"

    async def setup(self, worker) -> None:
        await asyncio.get_running_loop().run_in_executor(None, warm_up)


@contextlib.contextmanager
def dask_client(address: str | None = None, *, n_workers: int = 2) -> Iterator[Client]:
    """A Dask client: connected to the scheduler at ``address`` (``tcp://host:8786``), or
    to a local cluster of ``n_workers`` single-threaded worker processes on this machine
    (scheduler on 127.0.0.1 at free ports). The warm-up plugin is registered on every
    worker, present or future.
    """
    if address is not None:
        client = Client(address, timeout="30s")
        try:
            client.register_plugin(WarmUp())
            yield client
        finally:
            client.close()
        return
    if n_workers < 1:
        raise ValueError(f"n_workers must be >= 1, got {n_workers}")
    with (
        LocalCluster(
            n_workers=n_workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",  # loopback only: nothing of a local run is reachable from outside
            scheduler_port=0,  # a free port
            dashboard_address=":0",  # its HTTP server (health, metrics) on a free port too
            silence_logs=logging.ERROR,
            env=dict(_WORKER_ENV),  # passed on to each worker's Nanny
        ) as cluster,
        Client(cluster) as client,
    ):
        client.register_plugin(WarmUp())
        yield client


def fly_on_cluster(
    client: Client,
    seeds: Iterable[int],
    *,
    family: str,
    perception: str,
    max_time_s: float | None = None,
    on_record: Callable[[dict[str, Any]], None],
) -> None:
    """Fly ``seeds`` as tasks on ``client``'s cluster; ``on_record(record)`` (in this
    process) as each finishes, in the order they finish. Tasks are submitted in seed
    order; a task that keeps killing its workers becomes an ``"error"`` record."""
    seeds = list(seeds)
    futures = client.map(
        fly_record,
        seeds,
        family=family,
        perception=perception,
        max_time_s=max_time_s,
        key=[f"scene-{family}-{perception}-{s}" for s in seeds],
        pure=False,
    )
    seed_of = {f.key: s for f, s in zip(futures, seeds, strict=True)}
    for future in as_completed(futures):
        try:
            record = future.result()
        except Exception as exc:  # the worker died (KilledWorker) or the task was lost
            seed = seed_of[future.key]
            verdict = error_verdict(seed, f"{type(exc).__name__}: {exc}")
            record = verdict_to_record(
                verdict, perception=perception, worker="", code=code_fingerprint()
            )
        future.release()
        on_record(record)
