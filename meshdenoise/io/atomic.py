"""Atomic writing: a temporary file beside the destination, renamed onto it once complete, removed on SIGTERM/SIGHUP."""

from __future__ import annotations

import os
import signal
import tempfile
import threading
from pathlib import Path

from .errors import MeshFileError


def _process_umask() -> int:
    mask = os.umask(0)  # the only portable way to read it is to set it, so read it once, at import
    os.umask(mask)
    return mask


_UMASK = _process_umask()


# Temporary files being written now. A handler for SIGTERM and SIGHUP (installed by the first write,
# in the main thread only) removes them before the signal's previous action: the default one (the
# process ends, as if the handler were not there) or the handler that was installed before ours.
# SIGINT needs nothing here: KeyboardInterrupt unwinds through atomic_path.__exit__. SIGKILL (kill -9)
# and power loss cannot be caught: they leave a hidden ``.<stem>.<random><suffix>`` file beside the
# destination (never the destination itself, which is only ever replaced by a complete file).
_IN_FLIGHT: set[Path] = set()
_PREVIOUS_HANDLERS: dict[int, object] = {}
_CLEANUP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name))


def _remove_in_flight_and_resend(signum, frame) -> None:
    for tmp in list(_IN_FLIGHT):
        try:
            os.unlink(tmp)
        except OSError:
            pass
    _IN_FLIGHT.clear()
    previous = _PREVIOUS_HANDLERS.get(signum, signal.SIG_DFL)
    if callable(previous):
        previous(signum, frame)
        return
    signal.signal(signum, signal.SIG_DFL)  # the default action (terminate), as if we had not been here
    os.kill(os.getpid(), signum)


def _install_cleanup_handlers() -> None:
    if threading.current_thread() is not threading.main_thread():
        return  # signal handlers can only be set from the main thread
    for sig in _CLEANUP_SIGNALS:
        if sig in _PREVIOUS_HANDLERS:
            continue
        current = signal.getsignal(sig)
        if current is signal.SIG_IGN or current is None or current is _remove_in_flight_and_resend:
            continue  # ignored (the process goes on, so must its files) or set outside Python
        try:
            signal.signal(sig, _remove_in_flight_and_resend)
        except (ValueError, OSError):  # pragma: no cover - embedded interpreters
            continue
        _PREVIOUS_HANDLERS[sig] = current


class atomic_path:
    """Context manager giving a temporary path beside ``path``, renamed onto it only on success.

    Nothing is left behind on failure, and a reader never sees a half-written file: the
    temporary file is flushed to disk and then renamed (atomic on POSIX and Windows). A ``path``
    that is a folder, a device (``/dev/null``), a pipe or a socket is refused (``MeshFileError``):
    the rename would replace it. SIGTERM
    and SIGHUP during the write remove the temporary file, then take their previous action
    (by default: the process ends). Only what cannot be caught (SIGKILL, a power cut) can leave
    the hidden temporary ``.<stem>.<8 random characters><suffix>`` beside ``path``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "out.txt"
    >>> with atomic_path(target) as tmp:
    ...     _ = tmp.write_text("done")
    >>> target.read_text()
    'done'
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    def __enter__(self) -> Path:
        if self.path.exists() and not self.path.is_file():  # renaming onto /dev/null would replace the device
            kind = "a folder" if self.path.is_dir() else "a device, pipe or socket"
            raise MeshFileError(f"{self.path}: cannot be written: it is {kind}, not a file")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.path.suffix, dir=self.path.parent)
        except OSError as exc:
            raise MeshFileError(f"{self.path}: cannot be written ({exc.strerror or exc})") from None
        os.close(fd)
        self.tmp = Path(tmp)
        _install_cleanup_handlers()
        _IN_FLIGHT.add(self.tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            return self._finish(exc_type, exc)
        finally:
            _IN_FLIGHT.discard(self.tmp)

    def _finish(self, exc_type, exc) -> bool:
        if exc_type is None and self.tmp.exists() and self.tmp.stat().st_size > 0:
            try:
                with open(self.tmp, "rb") as fh:
                    os.fsync(fh.fileno())
                # mkstemp makes private (0600) files; give the result the mode any other tool would:
                # the replaced file's, or 0666 minus the umask for a new one
                mode = self.path.stat().st_mode & 0o7777 if self.path.exists() else 0o666 & ~_UMASK
                os.chmod(self.tmp, mode)
                os.replace(self.tmp, self.path)
            except OSError as err:
                self.tmp.unlink(missing_ok=True)
                raise MeshFileError(f"{self.path}: cannot be written ({err.strerror or err})") from None
        else:
            self.tmp.unlink(missing_ok=True)
            if exc_type is None:
                raise MeshFileError(f"{self.path}: nothing was written")
            if issubclass(exc_type, OSError):
                raise MeshFileError(f"{self.path}: cannot be written ({exc.strerror or exc})") from None
        return False
