"""Running one task (an input under one setting): load, apply the steps, then write the outputs.

Outputs of a task are written only once every step of it succeeded, each atomically
(:func:`meshdenoise.io.save_mesh`): a failing step leaves no output of that task behind.
Input files are only read.
"""

from __future__ import annotations

import os
import time
import traceback
from typing import Any, Callable

import numpy as np

from ..arrays import MeshValidationError
from ..registry import ParameterError
from .errors import InputError, OutputError, ParameterFailure, StepFailure
from .schema import Task
from .state import MeshState
from .execute import RunContext, run_step

__all__ = ["run_task", "run_task_safely", "WARNINGS_KEY"]


def run_task(task: Task, echo: Callable[[str], Any] | None = None) -> dict:
    """Run one task and return its results row; raises :class:`StepFailure` naming input and step."""
    from ..io import MeshFileError, load_mesh, save_mesh

    start = time.perf_counter()
    row: dict = {"input": str(task.input), **task.setting}
    try:
        mesh = load_mesh(task.input)
    except MeshFileError as exc:  # its message already names the file
        raise InputError(str(exc)) from None
    selection = getattr(mesh, "selection", None)  # MeshLab's selection flags of a PLY
    extras = getattr(mesh, "extras", None)
    quality = {where: np.asarray(part["quality"][1], dtype=np.float64) if "quality" in part else None
               for where, part in (("vertex", extras.vertex if extras else {}), ("face", extras.face if extras else {}))}
    state = MeshState(mesh.V, mesh.F, mesh.vertex_colors, vertex_quality=quality["vertex"], face_quality=quality["face"],
                      vertex_selection=selection if selection is not None and selection.any() else None, extras=extras)
    ctx = RunContext(state, task.input, (mesh.V, mesh.F), output_paths=task.output_paths,
                     reference_paths=task.reference_paths, row=row, echo=echo)
    try:
        for step in task.steps:
            try:
                run_step(step, ctx)
            except ParameterError as exc:  # in range, but failing on this mesh (overflow, singular system)
                raise ParameterFailure(f"{task.input}: {step.where}: {exc}") from None
            except MeshValidationError as exc:  # the mesh itself is unusable (a point cloud, NaN coordinates...)
                raise InputError(f"{task.input}: {step.where}: {exc}") from None
            except Exception as exc:  # any library error: name the input and the step
                detail = str(exc) or type(exc).__name__
                raise StepFailure(f"{task.input}: {step.where} failed: {type(exc).__name__}: {detail}") from exc
            _check_finite(step, ctx)
        try:
            for path, V, F, colors, binary, extras, *options in ctx.staged:  # options: save's normals and precision
                if mesh.vertex_colors is None and colors is not None and (colors == 1.0).all():
                    colors = None  # pymeshlab's default white, not the input's: no colours in, no colours out
                save_mesh(path, V, F, colors, binary=binary, extras=extras, **(options[0] if options else {}))
            for tmp, path in ctx.staged_files:
                os.replace(tmp, path)
        except (MeshFileError, OSError) as exc:  # read-only folder, full disk, /proc/x.ply: its message names the file
            raise OutputError(f"{task.input}: {exc}") from None
    finally:
        for tmp, _ in ctx.staged_files:  # left only when the task failed
            tmp.unlink(missing_ok=True)
    row["vertices"] = ctx.state.n_vertices
    row["faces"] = ctx.state.n_faces
    row["seconds"] = round(time.perf_counter() - start, 4)
    row["status"] = "ok"
    return row


def _check_finite(step, ctx) -> None:
    """Refuse a step whose output has NaN or infinite coordinates (an overflowing parameter), naming it."""
    if step.kind in ("save", "metrics", "render"):
        return
    if not np.isfinite(ctx.state.V).all():
        settings = ", ".join(f"{k}={v!r}" for k, v in step.params.items()) or "its defaults"
        raise ParameterFailure(
            f"{ctx.input_path}: {step.where} with {settings} produced non-finite coordinates "
            "(overflow: a parameter is too large or too small for this mesh)"
        )


#: Key of a row from :func:`run_task_safely` holding the task's warnings, ``[(category, message), ...]``; taken out
#: of the row and warned again in the calling process by :func:`~meshdenoise.pipeline.batch.run_tasks`.
WARNINGS_KEY = "_warnings"


def run_task_safely(task: Task) -> dict:
    """:func:`run_task`, with a failure turned into a row (``status: failed``, ``error``); for batches.

    numpy's overflow warnings are not printed (also on Dask workers): a non-finite result is
    refused by the task's own check, whose message names the step and its parameters. The task's
    other warnings are not printed here (a Dask worker's would reach the terminal in Python's format
    with a source line) but kept in the row under :data:`WARNINGS_KEY`.
    """
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("ignore", RuntimeWarning)
        row = _run_task_row(task)
    if caught:
        row[WARNINGS_KEY] = [(w.category, str(w.message)) for w in caught]
    return row


def _run_task_row(task: Task) -> dict:
    try:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
            return run_task(task)
    except StepFailure as exc:
        kind = exc.failure if isinstance(exc, InputError) else "step"
        return {"input": str(task.input), **task.setting, "status": "failed", "error": str(exc), "failure": kind}
    except Exception as exc:  # a bug or an I/O error while writing: still one row, never a lost batch
        return {
            "input": str(task.input),
            **task.setting,
            "status": "failed",
            "error": f"{task.input}: {type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(limit=5),
        }
