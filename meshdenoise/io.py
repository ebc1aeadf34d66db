"""Reading and writing mesh files: errors name the file, writes are atomic."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .arrays import MeshValidationError, check_mesh_arrays

__all__ = [
    "MeshFile",
    "load_mesh",
    "save_mesh",
    "load_arrays",
    "save_arrays",
    "atomic_path",
    "MeshFileError",
    "SUPPORTED_EXTENSIONS",
]

SUPPORTED_EXTENSIONS = (".ply", ".obj", ".off", ".stl")


class MeshFileError(ValueError):
    """A mesh file that cannot be read or written; the message names the file."""


def _check_extension(path: Path) -> None:
    if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
        raise MeshFileError(f"{path}: unsupported extension {path.suffix!r}; use one of {', '.join(SUPPORTED_EXTENSIONS)}")


@dataclass
class MeshFile:
    """A mesh read from a file.

    Attributes
    ----------
    V : ndarray, shape (n, 3), float64
    F : ndarray, shape (m, 3), int64
    vertex_colors : ndarray, shape (n, 4), float64 in [0, 1], or None
        RGBA, when the file has vertex colours.
    notes : list of str
        What was done to read an unusual but legal file (e.g. polygons triangulated).
    path : Path
    """

    V: np.ndarray
    F: np.ndarray
    vertex_colors: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)
    path: Path | None = None


def load_mesh(path: str | os.PathLike) -> MeshFile:
    """Read a PLY, OBJ, OFF or STL file, keeping the file's vertex order and vertex colours.

    Raises
    ------
    MeshFileError
        Naming the file and the problem (missing, unreadable, bad indices, NaN...).
    """
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
        V, F = check_mesh_arrays(m.vertex_matrix(), m.face_matrix(), allow_no_faces=True)
    except (MeshValidationError, TypeError) as exc:
        raise MeshFileError(f"{path}: {exc}") from None
    colors = m.vertex_color_matrix() if m.has_vertex_color() else None
    return MeshFile(V, F, colors, [], path)


def load_arrays(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh file into ``(V (n, 3) float64, F (m, 3) int64)``, keeping the file's vertex order."""
    mesh = load_mesh(path)
    return mesh.V, mesh.F


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


def save_mesh(
    path: str | os.PathLike,
    V: np.ndarray,
    F: np.ndarray,
    vertex_colors: np.ndarray | None = None,
    *,
    binary: bool = True,
) -> Path:
    """Write a mesh (format from the extension) atomically, with vertex colours where the format has them.

    ``vertex_colors`` is (n, 3) or (n, 4) in [0, 1]. Returns the path.
    """
    import pymeshlab

    path = Path(path)
    _check_extension(path)
    V, F = check_mesh_arrays(V, F, allow_no_faces=True)
    kwargs = {}
    if vertex_colors is not None:
        c = np.asarray(vertex_colors, dtype=np.float64)
        if c.shape not in ((V.shape[0], 3), (V.shape[0], 4)):
            raise MeshFileError(f"{path}: vertex_colors must have shape ({V.shape[0]}, 3 or 4), got {c.shape}")
        kwargs["v_color_matrix"] = c if c.shape[1] == 4 else np.hstack([c, np.ones((c.shape[0], 1))])
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32), **kwargs))
    with atomic_path(path) as tmp:
        kwargs = {"binary": binary} if path.suffix.lower() in (".ply", ".stl") else {}
        try:
            ms.save_current_mesh(str(tmp), **kwargs)
        except Exception as exc:
            raise MeshFileError(f"{path}: cannot be written ({exc})") from None
    return path


def save_arrays(path: str | os.PathLike, V: np.ndarray, F: np.ndarray, *, binary: bool = True) -> Path:
    """Write ``(V, F)`` to ``path`` (format from the extension) atomically; returns the path."""
    return save_mesh(path, V, F, binary=binary)
