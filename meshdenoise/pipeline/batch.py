"""Running many tasks: in this process, on local Dask worker processes, or on a Dask cluster.

Each task is independent (one input under one setting) and returns one results row; a
failing task becomes a row with its error and never stops the others. Workers read the
inputs and write the outputs themselves, so with ``--scheduler`` the paths must be
visible to every worker (a shared file system).
"""

from __future__ import annotations

import os
from typing import Callable

from .runner import WARNINGS_KEY, run_task_safely
from .schema import Task

__all__ = ["run_tasks"]


def run_tasks(
    tasks: list[Task],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    serial: bool = False,
    on_done: Callable[[dict], None] | None = None,
) -> list[dict]:
    """Run the tasks; returns their rows in task order.

    Parameters
    ----------
    tasks : list of Task
    scheduler : str, optional
        Address of a running Dask distributed scheduler (``tcp://host:8786``).
    workers : int, optional
        Number of local worker processes (default: ``min(cores, tasks)``).
    serial : bool
        Run in this process, one after another (also used when there is one task and no scheduler).
    on_done : callable, optional
        Called with each row as its task finishes (progress bars).
    """
    rows: list[dict | None] = [None] * len(tasks)
    if serial or (scheduler is None and len(tasks) <= 1):
        for k, task in enumerate(tasks):
            rows[k] = _warn_again(run_task_safely(task))
            if on_done:
                on_done(rows[k])
        return rows  # type: ignore[return-value]

    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        n = workers or max(1, min(os.cpu_count() or 1, len(tasks)))
        try:
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
        except KeyboardInterrupt:
            _abandon_starting_clusters()
            _quiet_dask_logs()
            raise
        except Exception as exc:  # e.g. a script without an ``if __name__ == "__main__"`` guard
            import warnings

            warnings.warn(f"local Dask workers could not start ({exc}); running the tasks one after another", UserWarning, stacklevel=2)
            return run_tasks(tasks, serial=True, on_done=on_done)
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="20s")
    try:
        # before any task: pymeshlab must be loaded on each worker's main thread, not on a task thread (_load_pymeshlab_here)
        client.register_plugin(_pymeshlab_on_main_thread())
        futures = {client.submit(run_task_safely, task, pure=False, key=f"meshdenoise-task-{task.index}-{os.getpid()}-{id(task)}"): k for k, task in enumerate(tasks)}
        for future in as_completed(futures):
            k = futures[future]
            try:
                row = future.result()
            except Exception as exc:  # the worker died (a crash inside a native library)
                task = tasks[k]
                row = {"input": str(task.input), **task.setting, "status": "failed", "error": f"{task.input}: worker failed: {exc!r}"}
            rows[k] = _warn_again(row)
            if on_done:
                on_done(row)
    except KeyboardInterrupt:
        _quiet_dask_logs()
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return rows  # type: ignore[return-value]


def _load_pymeshlab_here() -> None:
    """Import pymeshlab in the calling thread, which must outlive every use of pymeshlab in the process (the main thread).

    Importing pymeshlab loads MeshLab's filter plugins into a process-wide ``PluginManager``, Qt objects that
    belong to the importing thread: Qt adopts it (a ``QThreadData``, held by those objects). A Dask worker runs
    its tasks on threads of a pool, so the first task touching pymeshlab imported it there; when that pool
    thread ended (the worker closing), Qt let go of its thread data, and at process exit the
    ``PluginManager``'s destructor, unloading the plugins, freed that ``QThreadData`` with the last plugin and
    then decremented its reference count once more for each plugin loader: a write into freed memory. glibc
    found the damaged free list in a later ``free`` (gnutls' destructor) and aborted the worker:
    ``malloc_consolidate(): unaligned fastbin chunk detected`` after the results (valgrind: invalid access in
    ``QThreadData::deref`` to a block freed by ``~QObjectPrivate``, allocated by ``PluginManager::loadPlugins``).
    Whether glibc notices depends on what else was allocated (it did after our filters had loaded scipy's
    BLAS), the corruption does not; nor does it need our filters, numba's or BLAS's threads, or two tasks at
    once (one task thread per worker). Imported first on the main thread, which lives until exit, the plugins
    belong to it; a task thread then only uses them.
    """
    try:
        import pymeshlab  # noqa: F401
    except Exception:  # a worker where pymeshlab cannot load: its pymeshlab steps fail as tasks, with their message
        pass


def _pymeshlab_on_main_thread():
    """A Dask worker plugin calling :func:`_load_pymeshlab_here` on each worker, present or started later (its
    ``setup`` runs on the worker's event loop, in the main thread of the worker process, before it takes tasks)."""
    from distributed import WorkerPlugin

    class PymeshlabOnMainThread(WorkerPlugin):
        name = "meshdenoise-pymeshlab-on-main-thread"
        idempotent = True  # registered once per scheduler, whatever the number of runs

        def setup(self, worker) -> None:
            _load_pymeshlab_here()

    return PymeshlabOnMainThread()


def _warn_again(row: dict) -> dict:
    """``row`` without the warnings its task raised (on a worker, or here), which are warned again in this process:
    the command line prints each as one ``warning:`` line, a Python caller gets them as warnings."""
    import warnings

    for category, message in row.pop(WARNINGS_KEY, ()):
        warnings.warn(message, category if isinstance(category, type) and issubclass(category, Warning) else UserWarning,
                      stacklevel=3)
    return row


def _quiet_dask_logs() -> None:
    """Ctrl-C: the workers being started or closed fail, and Dask and asyncio log that with tracebacks (a nanny's
    "failed to start", an asyncio task's exception "never retrieved" at exit). The user asked to stop: say nothing."""
    import logging

    for name in ("asyncio", "distributed", "tornado"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def _abandon_starting_clusters() -> None:
    """Ctrl-C while a local cluster starts: its worker processes end with this one (they are daemons), but
    Dask's exit handler would try to close the half-started cluster and print the tracebacks of its failure."""
    from distributed.deploy.spec import SpecCluster

    for cluster in list(SpecCluster._instances):
        cluster.shutdown_on_close = False
