"""Running many tasks: in this process, on local Dask worker processes, or on a Dask cluster.

Each task is independent (one input under one setting) and returns one results row; a
failing task becomes a row with its error and never stops the others. Workers read the
inputs and write the outputs themselves, so with ``--scheduler`` the paths must be
visible to every worker (a shared file system).
"""

from __future__ import annotations

import os
from typing import Callable

from .runner import run_task_safely
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
            rows[k] = run_task_safely(task)
            if on_done:
                on_done(rows[k])
        return rows  # type: ignore[return-value]

    from distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        n = workers or max(1, min(os.cpu_count() or 1, len(tasks)))
        try:
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
        except Exception as exc:  # e.g. a script without an ``if __name__ == "__main__"`` guard
            import warnings

            warnings.warn(f"local Dask workers could not start ({exc}); running the tasks one after another", UserWarning, stacklevel=2)
            return run_tasks(tasks, serial=True, on_done=on_done)
        client = Client(cluster)
    else:
        client = Client(scheduler, timeout="20s")
    try:
        futures = {client.submit(run_task_safely, task, pure=False, key=f"meshdenoise-task-{task.index}-{os.getpid()}-{id(task)}"): k for k, task in enumerate(tasks)}
        for future in as_completed(futures):
            k = futures[future]
            try:
                row = future.result()
            except Exception as exc:  # the worker died (a crash inside a native library)
                task = tasks[k]
                row = {"input": str(task.input), **task.setting, "status": "failed", "error": f"{task.input}: worker failed: {exc!r}"}
            rows[k] = row
            if on_done:
                on_done(row)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return rows  # type: ignore[return-value]
