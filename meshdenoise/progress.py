"""Progress of long computations: code says which stage it is in; whoever listens shows it.

Library code calls :func:`stage` (a context manager) around each long part: ``with
stage("choosing mu"): ...``. Nobody listens by default (a stage then costs a context-variable
lookup). The command line listens with :class:`RichProgress` (a bar on a terminal once a job has
run for :data:`SHOW_AFTER` seconds) or :class:`LogProgress` (a line per stage that took that long,
for logs and pipes), through :func:`listening`.
"""

from __future__ import annotations

import contextlib
import threading
import time
from contextvars import ContextVar
from typing import Any, Callable, Iterator

__all__ = ["stage", "listening", "RichProgress", "LogProgress", "SHOW_AFTER"]

SHOW_AFTER = 2.0  # seconds: shorter jobs show nothing

_listener: ContextVar[Any] = ContextVar("meshdenoise_progress", default=None)


@contextlib.contextmanager
def stage(description: str) -> Iterator[None]:
    """Mark a stage of the current job (no effect when nobody listens)."""
    listener = _listener.get()
    if listener is None:
        yield
        return
    listener.begin(description)
    try:
        yield
    finally:
        listener.end(description)


@contextlib.contextmanager
def listening(listener: Any) -> Iterator[Any]:
    """Send the stages run inside the block to ``listener`` (``begin(text)`` / ``end(text)`` / ``close()``)."""
    token = _listener.set(listener)
    try:
        yield listener
    finally:
        _listener.reset(token)
        listener.close()


class LogProgress:
    """One line per stage that took at least ``min_seconds``: ``name: choosing mu: 12.3 s``."""

    def __init__(self, name: str, write: Callable[[str], None], min_seconds: float | None = None) -> None:
        self.name, self.write = name, write
        self.min_seconds = SHOW_AFTER if min_seconds is None else min_seconds
        self._started: dict[str, float] = {}

    def begin(self, description: str) -> None:
        self._started[description] = time.perf_counter()

    def end(self, description: str) -> None:
        seconds = time.perf_counter() - self._started.pop(description, time.perf_counter())
        if seconds >= self.min_seconds:
            self.write(f"{self.name}: {description}: {seconds:.1f} s")

    def close(self) -> None:
        pass


class RichProgress:
    """A rich bar on stderr, shown once the job has run :data:`SHOW_AFTER` seconds; it counts the stages done.

    ``total`` is the number of stages expected (``None``: an indeterminate bar). Only outermost
    stages count (a stage run inside another is part of it), and the count never passes the total:
    a job that turns out to have more stages than expected shows ``N/?`` from then on. The job's
    name and the stage descriptions are shown as plain text (never read as markup).
    """

    def __init__(self, name: str, console: Any, total: int | None = None, show_after: float | None = None) -> None:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self._progress = Progress(TextColumn("{task.fields[label]}", markup=False), BarColumn(), MofNCompleteColumn(),
                                  TimeElapsedColumn(), console=console, transient=True)
        self._task = self._progress.add_task("", total=total, label=name)
        self._name = name
        self._total = total
        self._done = 0
        self._depth = 0  # stages open now: only the outermost ones are counted
        self._lock = threading.Lock()
        self._shown = False
        self._closed = False
        self._timer = threading.Timer(SHOW_AFTER if show_after is None else show_after, self._show)
        self._timer.daemon = True
        self._timer.start()

    def _show(self) -> None:
        with self._lock:
            if not self._closed and not self._shown:
                self._progress.start()
                self._shown = True

    def begin(self, description: str) -> None:
        with self._lock:
            self._depth += 1
            if self._depth == 1 and self._total is not None and self._done >= self._total:
                self._total = None  # more stages than expected: the total is not known after all
                for task in self._progress.tasks:  # (Progress.update cannot set a total back to None)
                    if task.id == self._task:
                        task.total = None
        self._progress.update(self._task, label=f"{self._name}: {description}")

    def end(self, description: str) -> None:
        with self._lock:
            self._depth = max(self._depth - 1, 0)
            if self._depth:
                return
            self._done += 1
        self._progress.update(self._task, completed=self._done)

    def close(self) -> None:
        self._timer.cancel()
        with self._lock:
            self._closed = True
            if self._shown:
                self._progress.stop()
