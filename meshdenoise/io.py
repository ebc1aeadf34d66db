"""Reading and writing mesh files: errors name the file, writes are atomic."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from .arrays import MeshValidationError, check_mesh_arrays

__all__ = ["load_arrays", "save_arrays", "atomic_path", "MeshFileError", "SUPPORTED_EXTENSIONS"]

SUPPORTED_EXTENSIONS = (".ply", ".obj", ".off", ".stl")


class MeshFileError(ValueError):
    """A mesh file that cannot be read or written; the message names the file."""


def _check_extension(path: Path) -> None:
    if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
        raise MeshFileError(f"{path}: unsupported extension {path.suffix!r}; use one of {', '.join(SUPPORTED_EXTENSIONS)}")


def load_arrays(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh file into ``(V (n, 3) float64, F (m, 3) int64)``, keeping the file's vertex order."""
    import pymeshlab

    path = Path(path)
    _check_extension(path)
    if not path.is_file():
        raise MeshFileError(f"{path}: no such file")
    ms = pymeshlab.MeshSet()
    try:
        ms.load_new_mesh(str(path))
    except Exception as exc:  # pymeshlab raises its own exception type with a terse text
        raise MeshFileError(f"{path}: cannot be read as a mesh ({exc})") from None
    m = ms.current_mesh()
    try:
        return check_mesh_arrays(m.vertex_matrix(), m.face_matrix(), allow_no_faces=True)
    except (MeshValidationError, TypeError) as exc:
        raise MeshFileError(f"{path}: {exc}") from None


class atomic_path:
    """Context manager giving a temporary path beside ``path``, renamed onto it only on success.

    Nothing is left behind on failure, and a reader never sees a half-written file.

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
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=self.path.suffix, dir=self.path.parent)
        os.close(fd)
        self.tmp = Path(tmp)
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None and self.tmp.exists() and self.tmp.stat().st_size > 0:
            os.replace(self.tmp, self.path)
        else:
            self.tmp.unlink(missing_ok=True)
            if exc_type is None:
                raise MeshFileError(f"{self.path}: nothing was written")
        return False


def save_arrays(path: str | os.PathLike, V: np.ndarray, F: np.ndarray, *, binary: bool = True) -> Path:
    """Write ``(V, F)`` to ``path`` (format from the extension) atomically; returns the path."""
    import pymeshlab

    path = Path(path)
    _check_extension(path)
    V, F = check_mesh_arrays(V, F, allow_no_faces=True)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    with atomic_path(path) as tmp:
        kwargs = {"binary": binary} if path.suffix.lower() in (".ply", ".stl") else {}
        try:
            ms.save_current_mesh(str(tmp), **kwargs)
        except Exception as exc:
            raise MeshFileError(f"{path}: cannot be written ({exc})") from None
    return path
