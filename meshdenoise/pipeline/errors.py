"""Errors of pipelines: a validation error (exit code 2, nothing run) and a step failure (exit code 1)."""

from __future__ import annotations

__all__ = ["PipelineError", "PipelineValidationError", "StepFailure", "InputError", "where"]


class PipelineError(Exception):
    """Base class of pipeline errors."""


class PipelineValidationError(PipelineError, ValueError):
    """The pipeline is invalid; the message names the file, the line and the step. Nothing was run."""


class StepFailure(PipelineError, RuntimeError):
    """A step failed while running; the message names the input, the step and its line."""


class InputError(StepFailure):
    """The input is bad (unreadable file, or a mesh no filter can work on): exit code 2, not 1."""


def where(source: str, line: int | None, step: str | None = None) -> str:
    """``file:line: step 3 'sobolev'`` (the parts that are known)."""
    text = str(source)
    if line is not None:
        text += f":{line}"
    if step:
        text += f": {step}"
    return text
