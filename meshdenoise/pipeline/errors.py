"""Errors of pipelines: a validation error (exit code 2, nothing run) and a step failure (exit code 1)."""

from __future__ import annotations

__all__ = ["PipelineError", "PipelineValidationError", "StepFailure", "InputError", "ParameterFailure", "OutputError", "where"]


class PipelineError(Exception):
    """Base class of pipeline errors."""


class PipelineValidationError(PipelineError, ValueError):
    """The pipeline is invalid; the message names the file, the line and the step. Nothing was run.

    ``parameter`` names the step's key the error is about, when it is about one (the step's parser then
    names that key's line instead of the step's).
    """

    def __init__(self, message: str = "", parameter: str | None = None) -> None:
        super().__init__(message)
        self.parameter = parameter


class StepFailure(PipelineError, RuntimeError):
    """A step failed while running; the message names the input, the step and its line."""


class InputError(StepFailure):
    """The input is bad (unreadable file, or a mesh no filter can work on): exit code 2, not 1.

    ``failure`` is the class written in the results table: ``input`` here, ``parameter`` and
    ``output`` in the subclasses; all three are bad input (exit code 2).
    """

    failure = "input"


class ParameterFailure(InputError):
    """A step's parameters, each in its range, fail on this mesh (singular system, overflow, non-finite output)."""

    failure = "parameter"


class OutputError(InputError):
    """An output cannot be written (read-only folder, full disk, a path under /proc...)."""

    failure = "output"


#: Failure classes of a results row that are bad input (exit code 2); anything else is exit code 1.
BAD_INPUT_FAILURES = ("input", "parameter", "output")


def where(source: str, line: int | None, step: str | None = None) -> str:
    """``file:line: step 3 'sobolev'`` (the parts that are known)."""
    text = str(source)
    if line is not None:
        text += f":{line}"
    if step:
        text += f": {step}"
    return text
