"""Ctrl-C while the ``meshdenoise`` command is still loading: exit 130 with no traceback.

Loading the package takes about a second (numpy, scipy, numba, the filters); a ``KeyboardInterrupt``
then would escape the console script's ``main`` (which is only called once its module is imported) and
print a traceback, or be raised inside one of importlib's callbacks, where Python prints it as
"Exception ignored" and goes on. So in the ``meshdenoise`` program, while it loads, Ctrl-C ends the
process at once with the shell's code for Ctrl-C, 130 (:func:`exit_at_once_on_interrupt`: nothing has
been written yet, there is nothing to clean up); the command line's ``main`` gives Ctrl-C back its usual
``KeyboardInterrupt`` (:func:`interrupt_as_usual`), which the commands unwind (temporary files removed)
before exiting with 130. The imports also call :func:`exit_if_the_command` on a ``KeyboardInterrupt``
(the handler cannot be set off the main thread). In any other program (``import meshdenoise`` in a
script, a notebook) nothing changes.
"""

from __future__ import annotations

import os
import signal
import sys

__all__ = ["is_the_command", "exit_if_the_command", "exit_at_once_on_interrupt", "interrupt_as_usual", "INTERRUPTED"]

#: Exit code of a command interrupted by Ctrl-C (128 + SIGINT), as shells report it.
INTERRUPTED = 130


def is_the_command() -> bool:
    """Whether this process is the ``meshdenoise`` console script (``sys.argv[0]`` names it), not a process it
    started (a Dask worker is given the parent's ``sys.argv``; it writes files, which Ctrl-C must let it remove)."""
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    if not (name in ("meshdenoise", "meshdenoise.exe") or name.startswith("meshdenoise-script")):
        return False
    mp = sys.modules.get("multiprocessing")
    return mp is None or mp.parent_process() is None


def exit_if_the_command() -> None:
    """On a ``KeyboardInterrupt`` while importing: ``SystemExit(130)`` in the ``meshdenoise`` program, else return."""
    if is_the_command():
        raise SystemExit(INTERRUPTED)


def _exit_now(signum, frame) -> None:
    os._exit(INTERRUPTED)


def exit_at_once_on_interrupt() -> None:
    """In the ``meshdenoise`` program: Ctrl-C ends the process at once with 130 until :func:`interrupt_as_usual`.

    Only where Ctrl-C has Python's usual handler: a program started with SIGINT ignored (a background
    job of a script) keeps ignoring it.
    """
    if not is_the_command() or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return
    try:
        signal.signal(signal.SIGINT, _exit_now)
    except ValueError:  # not the main thread
        pass


def interrupt_as_usual() -> None:
    """Ctrl-C raises ``KeyboardInterrupt`` again (undoes :func:`exit_at_once_on_interrupt`)."""
    if signal.getsignal(signal.SIGINT) is _exit_now:
        signal.signal(signal.SIGINT, signal.default_int_handler)
