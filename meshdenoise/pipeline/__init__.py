"""Declarative YAML pipelines: check a pipeline file, run it on one or many inputs, write a results table.

Use::

    from meshdenoise.pipeline import load_pipeline, run_pipeline
    plan = load_pipeline("pipelines/scan_cleanup.yaml", overrides={"mu": 2})
    rows = run_pipeline(plan)

See docs/pipelines.md for the file format.
"""

from __future__ import annotations

from .batch import run_tasks
from .errors import PipelineError, PipelineValidationError, StepFailure
from .schema import PipelineProblems, Plan, Task, build_plan, load_pipeline
from .state import MeshState
from .sweep import write_results

__all__ = [
    "load_pipeline",
    "build_plan",
    "run_pipeline",
    "run_tasks",
    "write_results",
    "Plan",
    "Task",
    "PipelineError",
    "PipelineValidationError",
    "PipelineProblems",
    "MeshState",
    "StepFailure",
]


def run_pipeline(plan: Plan, *, scheduler: str | None = None, workers: int | None = None, serial: bool = False, on_done=None) -> list[dict]:
    """Run every task of a checked plan and write the results table when there is one; returns the rows.

    A failing task gives a row with ``status: failed`` and its ``error``; the others go on.
    """
    rows = run_tasks(plan.tasks, scheduler=scheduler, workers=workers, serial=serial, on_done=on_done)
    if plan.writes_results and plan.results:
        write_results(rows, plan.output_dir, plan.results)
    return rows
